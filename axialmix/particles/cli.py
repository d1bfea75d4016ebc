"""``axialmix simulate``: run the particle simulator on a preset blender from the command line.

``axialmix simulate vblender`` runs the batch V-blender (1,000,000 particles, 1000/100/100/1000
exchanges per step) from a loading and writes, for each reported step, the species-1 count
of every compartment and the chi-square homogeneity statistic. ``axialmix simulate
continuous`` runs a continuous blender (four-compartment or axial x radial grid) with a
tracer pulse and writes its RTD and outflow samples. Progress goes to standard error;
Ctrl-C stops the run and writes what was done. Output files are written atomically.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from axialmix.particles import presets
from axialmix.particles.feed import constant_feed, feeder_feed
from axialmix.particles.sampling import (
    chi_square,
    exit_age_from_outflow,
    relative_standard_deviation,
    sample_outflow,
    sample_variance,
    species_fraction,
)
from axialmix.particles.simulate import ENGINES, TracerPulse, simulate, stderr_progress

__all__ = ["add_simulate_parser", "write_json_atomically"]


def write_json_atomically(path: str | Path, data: dict) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file and ``os.replace``.

    A reader (or an interrupted run) never sees a half-written file.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(handle, "w") as stream:
            json.dump(data, stream, indent=1)
            stream.write("\n")
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {value}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative whole number, got {value}")
    return value


def _loading(text: str) -> str | list[float]:
    if "," not in text:
        return text
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"loading must be a name or five percentages, got {text!r}"
        ) from None


def _int_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated whole numbers, got {text!r}"
        ) from None


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--steps", type=_positive_int, default=30_000, help="time steps to run")
    parser.add_argument(
        "--report-every",
        type=_positive_int,
        default=None,
        help="record and report progress every this many steps",
    )
    parser.add_argument("--seed", type=_non_negative_int, default=0, help="random seed")
    parser.add_argument(
        "--engine",
        choices=ENGINES,
        default="count",
        help="count (species counts) or identity (individual particles)",
    )
    parser.add_argument("--json", metavar="PATH", default=None, help="write results as JSON here")
    parser.add_argument("--quiet", action="store_true", help="no progress on standard error")


def add_simulate_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``simulate`` command (with ``vblender`` and ``continuous``) to a CLI.

    **Arguments:**

    - `subparsers`: the object returned by ``ArgumentParser.add_subparsers()``.

    **Returns:** the ``simulate`` parser; each sub-command sets ``func`` to a function of the
    parsed arguments returning the exit status (0 done, 2 bad input).
    """
    simulate_parser = subparsers.add_parser(
        "simulate",
        help="stochastic particle simulation of a blender",
        description="Stochastic particle simulation of a blender (the checker of the models).",
    )
    kinds = simulate_parser.add_subparsers(dest="blender", required=True)

    vblender = kinds.add_parser("vblender", help="batch V-blender chain V1-V5")
    vblender.add_argument(
        "--loading",
        type=_loading,
        default="E",
        help="loading name (E, end, centre, top_bottom, uniform) or five "
        "percentages of species 1, e.g. 100,100,50,0,0",
    )
    vblender.add_argument(
        "--particles",
        type=_positive_int,
        default=1_000_000,
        help="particles in all (a multiple of 5)",
    )
    vblender.add_argument(
        "--exchanges",
        type=_int_list,
        default=[1000, 100, 100, 1000],
        help="particles exchanged per step across V1-V2,V2-V3,V3-V4,V4-V5",
    )
    _common(vblender)
    vblender.set_defaults(func=_run_vblender)

    continuous = kinds.add_parser("continuous", help="continuous blender with a tracer pulse")
    continuous.add_argument(
        "--preset",
        choices=("four-compartment", "grid"),
        default="four-compartment",
        help="which continuous blender",
    )
    continuous.add_argument(
        "--particles", type=_positive_int, default=None, help="particles held (default 10,000)"
    )
    continuous.add_argument("--n-axial", type=_positive_int, default=50, help="grid: axial slices")
    continuous.add_argument(
        "--n-radial", type=_positive_int, default=5, help="grid: radial compartments"
    )
    continuous.add_argument(
        "--tracer",
        type=_positive_int,
        default=None,
        help="tracer particles in the pulse (default: half the inlet hold-up)",
    )
    continuous.add_argument(
        "--pulse-step",
        type=_non_negative_int,
        default=0,
        help="step at whose start the tracer is injected",
    )
    continuous.add_argument(
        "--feeder",
        action="store_true",
        help="fluctuating feed: lactose 12.16+-2.46 g/s, pre-blend "
        "6.55+-1.16 g/s (default: constant feed)",
    )
    continuous.add_argument(
        "--feeder-period",
        type=float,
        default=1.0,
        help="seconds a drawn feeder rate is held (the feeders' fluctuation time scale)",
    )
    continuous.add_argument(
        "--samples",
        type=_non_negative_int,
        default=20,
        help="outflow samples: of the tracer, evenly spaced after the pulse; with --feeder, "
        "of the pre-blend over the second half of the run",
    )
    continuous.add_argument(
        "--sample-size", type=_positive_int, default=100, help="particles per outflow sample"
    )
    _common(continuous)
    continuous.set_defaults(func=_run_continuous)
    return simulate_parser


def _fail(message: str) -> int:
    print(f"axialmix simulate: error: {message}", file=sys.stderr)
    return 2


def _finish(args, data: dict) -> int:
    if args.json is not None:
        try:
            write_json_atomically(args.json, data)
        except OSError as err:
            return _fail(f"cannot write {args.json}: {err.strerror or err}")
    if data["interrupted"]:
        print(
            f"interrupted after {data['steps_completed']} steps; results so far kept",
            file=sys.stderr,
        )
    return 0


def _run_vblender(args) -> int:
    try:
        if len(args.exchanges) != 4:
            raise ValueError(f"--exchanges needs 4 numbers, got {len(args.exchanges)}")
        network = presets.v_blender(args.particles, args.exchanges)
        initial = presets.v_blender_loading(network, args.loading)
        result = simulate(
            network,
            initial,
            args.steps,
            engine=args.engine,
            seed=args.seed,
            report_every=args.report_every,
            progress=None if args.quiet else stderr_progress,
        )
    except ValueError as err:
        return _fail(str(err).rstrip("."))
    reports = [
        {
            "step": int(step),
            "species1_counts": counts[:, 0].tolist(),
            "chi_square": chi_square(counts, 0),
        }
        for step, counts in zip(result.report_steps, result.counts, strict=True)
    ]
    print("step      " + " ".join(f"{n:>9}" for n in network.names) + "   chi-square")
    for row in reports:
        counts = " ".join(f"{c:9d}" for c in row["species1_counts"])
        print(f"{row['step']:<9} {counts}   {row['chi_square']:.6g}")
    data = {
        "blender": "vblender",
        "engine": result.engine,
        "seed": result.seed,
        "particles": network.n_particles,
        "exchanges": list(args.exchanges),
        "loading": args.loading,
        "compartments": list(network.names),
        "steps_requested": result.steps_requested,
        "steps_completed": result.steps_completed,
        "interrupted": result.interrupted,
        "wall_seconds": result.wall_seconds,
        "reports": reports,
    }
    return _finish(args, data)


def _run_continuous(args) -> int:
    try:
        if args.preset == "grid":
            cells = args.n_axial * args.n_radial
            total = 40 * cells if args.particles is None else args.particles
            if total % cells:
                raise ValueError(f"--particles must be a multiple of the {cells} compartments")
            network = presets.axial_radial_grid(
                args.n_axial, args.n_radial, particles_per_compartment=total // cells
            )
        else:
            network = presets.four_compartment(particles=args.particles or 10_000)
        if not (np.isfinite(args.feeder_period) and args.feeder_period > 0):
            raise ValueError(f"--feeder-period must be positive, got {args.feeder_period}")
        if args.pulse_step >= args.steps:
            raise ValueError(f"--pulse-step {args.pulse_step} must be before --steps {args.steps}")
        steps = args.steps
        if args.feeder:
            names = ["lactose", "pre-blend", "tracer"]
            hold = max(1, round(args.feeder_period / network.step_seconds))
            fed = feeder_feed(
                network, [12.16, 6.55], [2.46, 1.16], steps, hold_steps=hold, seed=args.seed
            )
            feed = np.concatenate([fed, np.zeros(fed.shape[:2] + (1,), np.int64)], axis=2)
            first = np.rint(network.holdups * 12.16 / (12.16 + 6.55)).astype(np.int64)
            initial = np.column_stack([first, network.holdups - first, np.zeros_like(first)])
        else:
            names = ["bulk", "tracer"]
            feed = constant_feed(network, [1.0, 0.0], steps)
            initial = np.column_stack([network.holdups, np.zeros_like(network.holdups)])
        tracer_species = len(names) - 1
        inlet_holdup = int(network.holdups[network.inlets()].sum())
        tracer = TracerPulse(
            args.pulse_step, args.tracer or max(inlet_holdup // 2, 1), tracer_species
        )
        result = simulate(
            network,
            initial,
            steps,
            engine=args.engine,
            seed=args.seed,
            feed=feed,
            tracer=tracer,
            report_every=args.report_every,
            progress=None if args.quiet else stderr_progress,
        )
        times, exit_age = exit_age_from_outflow(
            result.outflow, tracer_species, tracer.step, tracer.particles, network.step_seconds
        )
        samples = _outflow_samples(args, result, names, tracer)
    except ValueError as err:
        return _fail(str(err).rstrip("."))
    left = float(exit_age.sum() * network.step_seconds)
    mean = float(np.sum(times * exit_age) * network.step_seconds / left) if left > 0 else None
    print(
        f"{args.preset}: {network.n_particles} particles, {network.n_compartments} compartments, "
        f"{result.steps_completed} steps of {network.step_seconds:g} s"
    )
    print(
        f"tracer left: {left:.4f} of {tracer.particles}; mean residence time of those: "
        f"{mean if mean is None else round(mean, 4)} s"
    )
    if samples.get("rsd") is not None:
        print(
            f"outflow samples: {len(samples['steps'])} of {args.sample_size} particles, "
            f"RSD of {samples['species']}: {samples['rsd']:.4g}"
        )
    if samples.get("vrr") is not None:
        print(f"variance reduction ratio: {samples['vrr']:.4g}")
    data = {
        "blender": args.preset,
        "engine": result.engine,
        "seed": result.seed,
        "particles": network.n_particles,
        "compartments": list(network.names),
        "species": names,
        "step_seconds": network.step_seconds,
        "throughput_per_step": network.throughput,
        "tracer": {"step": tracer.step, "particles": tracer.particles, "species": tracer_species},
        "steps_requested": result.steps_requested,
        "steps_completed": result.steps_completed,
        "interrupted": result.interrupted,
        "wall_seconds": result.wall_seconds,
        "rtd": {
            "time_s": times.tolist(),
            "exit_age_per_s": exit_age.tolist(),
            "fraction_left": left,
            "mean_residence_time_s": mean,
        },
        "outflow_samples": samples,
    }
    return _finish(args, data)


def _outflow_samples(args, result, names: list[str], tracer: TracerPulse) -> dict:
    # Without feeder fluctuations the samples measure the tracer, as in an RTD experiment
    # (evenly spaced from the pulse on); with them, the pre-blend fraction over the second
    # half of the run, against inflow samples of the same size and times (VRR).
    steps_done = result.steps_completed
    species = 1 if args.feeder else len(names) - 1
    first = steps_done // 2 if args.feeder else tracer.step
    out: dict = {
        "species": names[species],
        "particles_per_sample": args.sample_size,
        "steps": [],
        "fractions": [],
        "rsd": None,
    }
    if args.samples == 0 or steps_done <= first:
        return out
    sample_steps = np.unique(np.linspace(first, steps_done - 1, args.samples + 1).astype(int)[1:])
    drawn = sample_outflow(result.outflow, sample_steps, args.sample_size, seed=[args.seed, 2])
    fractions = species_fraction(drawn, species)
    out["steps"] = sample_steps.tolist()
    out["fractions"] = fractions.tolist()
    if fractions.size >= 2 and fractions.mean() > 0:
        out["rsd"] = relative_standard_deviation(fractions)
    if args.feeder:
        fed = result.fed.sum(axis=1)
        inflow = species_fraction(
            sample_outflow(fed, sample_steps, args.sample_size, seed=[args.seed, 3]), species
        )
        out["inflow_fractions"] = inflow.tolist()
        out["variance_in"] = sample_variance(inflow)
        out["variance_out"] = sample_variance(fractions)
        out["vrr"] = out["variance_in"] / out["variance_out"] if out["variance_out"] > 0 else None
    return out
