"""``axialmix simulate``: run the particle simulator on a preset blender from the command line.

``axialmix simulate vblender`` runs the batch V-blender (1,000,000 particles, 1000/100/100/1000
exchanges per step) from a loading and reports, for each reported step, the species-1 count
of every compartment and the chi-square homogeneity statistic. ``axialmix simulate
continuous`` runs a continuous blender (four-compartment or axial x radial grid) with a
tracer pulse; it writes its RTD (``--rtd-csv``: a histogram of the tracer particles leaving,
``t [s]``, ``count``, ``bin [s]`` and ``E [1/s]``, which ``axialmix fit`` reads as counts with
counting errors) and its outflow samples (``--samples-csv``: ``t [s]`` and one value column),
and everything as JSON (``--json``). ``axialmix simulate network NET.json`` runs a closed
network from a file as :mod:`axialmix.network` reads it (the ``network.json`` that
``axialmix dem learn`` writes, say): a tracer loaded into some compartments (``--tracer``)
mixes through the others, and each report gives its count per compartment and the
chi-square of its spread.

Exit status (:mod:`axialmix._exits`): 0 done; 2 bad input, one line ``axialmix simulate:
error: ...`` naming the option, nothing written (runs that would not fit in memory are
refused before they start, with the estimate); 130 interrupted (Ctrl-C): the results of the
steps done are written and no partial file is left. Every file is written atomically with
the mode the umask gives, as ``axialmix fit`` does.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import signal
import sys
import threading
from pathlib import Path

__all__ = ["add_parser", "run"]

_COMMAND = "simulate"
# axialmix (and with it JAX) is imported only once the command runs, so that `--help` is quick
# and Ctrl-C during those imports is handled by `run` like any other moment.
_MAX_SEED = 2**32 - 1  # axialmix.particles.MAX_SEED, without importing the simulator here
_RUN_LENGTH_IN_TAU = 10.0  # default continuous run: the tracer has left (e^-10 of it remains)
_SAMPLE_WINDOW_IN_TAU = 4.0  # default tracer samples: pulse to pulse + 4 tau


class _BadInput(Exception):
    """Bad input found after parsing: reported on one line, exit status 2."""


class _Interruption:
    """Remembers Ctrl-C, so that a KeyboardInterrupt swallowed where Python ignores
    exceptions (a garbage-collector callback, a ``__del__``) still stops the run at the
    next checkpoint."""

    def __init__(self) -> None:
        self.requested = False

    def handler(self, signum, frame) -> None:
        self.requested = True
        raise KeyboardInterrupt

    def checkpoint(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


_interruption = _Interruption()


def _whole_number(text: str, minimum: int) -> int:
    try:
        number = float(text) if any(c in text.lower() for c in ".e") else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if isinstance(number, float):
        if not (math.isfinite(number) and number.is_integer()):
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
        number = int(number)
    if number < minimum:
        kind = "positive" if minimum == 1 else "non-negative"
        raise argparse.ArgumentTypeError(f"expected a {kind} whole number, got {number}")
    return number


def _positive_int(text: str) -> int:
    return _whole_number(text, 1)


def _non_negative_int(text: str) -> int:
    return _whole_number(text, 0)


def _seed(text: str) -> int:
    value = _whole_number(text, 0)
    if value > _MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected a seed from 0 to {_MAX_SEED}, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
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


def _common(parser: argparse.ArgumentParser, steps_default: int | None) -> None:
    steps_help = (
        f"time steps to run (default: {steps_default})"
        if steps_default is not None
        else f"time steps to run (default: {_RUN_LENGTH_IN_TAU:g} mean residence times of "
        "the blender)"
    )
    parser.add_argument("--steps", type=_positive_int, default=steps_default, help=steps_help)
    parser.add_argument(
        "--report-every",
        type=_positive_int,
        default=None,
        metavar="STEPS",
        help="record (and report) the counts every this many steps (default: first and last)",
    )
    parser.add_argument(
        "--seed", type=_seed, default=0, help=f"random seed, 0 to {_MAX_SEED} (default: 0)"
    )
    parser.add_argument(
        "--engine",
        choices=("count", "identity"),
        default="count",
        help="count (species counts) or identity (individual particles) (default: count)",
    )
    parser.add_argument("--json", metavar="PATH", default=None, help="write results as JSON here")
    parser.add_argument(
        "--quiet", action="store_true", help="no progress bar on standard error"
    )


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``simulate`` command (with ``vblender`` and ``continuous``) to a CLI.

    **Arguments:**

    - `subparsers`: the object returned by ``ArgumentParser.add_subparsers()``.

    **Returns:** the ``simulate`` parser.
    """
    simulate_parser = subparsers.add_parser(
        _COMMAND,
        help="stochastic particle simulation of a blender",
        description="Stochastic particle simulation of a blender (the checker of the models).",
    )
    kinds = simulate_parser.add_subparsers(dest="blender", required=True)

    vblender = kinds.add_parser(
        "vblender",
        help="batch V-blender chain V1-V5",
        description="Batch V-blender chain V1-V5: species-1 counts and chi-square per report.",
    )
    # "--exchanges -1,2,3,4": a value starting with a minus sign that holds only numbers and
    # commas is a value, not an option.
    vblender._negative_number_matcher = re.compile(r"^-[\d.,eE+-]+$")
    vblender.add_argument(
        "--loading",
        type=_loading,
        default="E",
        help="loading name (E, end, centre, top_bottom, uniform) or five percentages of "
        "species 1, e.g. 100,100,50,0,0 (default: E)",
    )
    vblender.add_argument(
        "--particles",
        type=_positive_int,
        default=1_000_000,
        help="particles in all, a multiple of 5 (default: 1000000)",
    )
    vblender.add_argument(
        "--exchanges",
        type=_int_list,
        default=[1000, 100, 100, 1000],
        metavar="N,N,N,N",
        help="particles exchanged per step across V1-V2,V2-V3,V3-V4,V4-V5 "
        "(default: 1000,100,100,1000)",
    )
    _common(vblender, 30_000)

    learned = kinds.add_parser(
        "network",
        help="a closed network from a file (a network learned from DEM, say)",
        description="A closed compartment network from a network file (JSON or TOML, as "
        "axialmix.network reads it, e.g. the network.json of `axialmix dem learn`): a tracer "
        "loaded into some compartments mixes through the others; its counts per compartment "
        "and the chi-square of its spread per report.",
    )
    learned.add_argument("network", metavar="NET.json", help="the network file (.json or .toml)")
    learned.add_argument(
        "--particles", type=_positive_int, default=10_000,
        help="particles in all, shared out by the network's hold-ups (default: 10000)",
    )
    learned.add_argument(
        "--step", type=_positive_float, default=None, metavar="SECONDS",
        help="step length [s] of a continuous-time network (default: the network's own step, "
        "else the one at which the fastest compartment hands on a tenth of its particles)",
    )
    learned.add_argument(
        "--tracer", default=None, metavar="NAME[,NAME...]",
        help="compartments whose particles are the tracer at the start (default: the first)",
    )
    _common(learned, 1000)

    continuous = kinds.add_parser(
        "continuous",
        help="continuous blender with a tracer pulse",
        description="Continuous blender with a tracer pulse: its RTD and outflow samples, as "
        "CSV files that `axialmix fit` reads.",
    )
    continuous.add_argument(
        "--preset",
        choices=("four-compartment", "grid"),
        default="four-compartment",
        help="four-compartment (k_f = k_r = 2.125 1/s, k_s = 0.625 1/s, k_out = 1 1/s, steps "
        "of 0.01 s, tau = 6.25 s) or grid (axial x radial, tau = 100 s) "
        "(default: four-compartment)",
    )
    continuous.add_argument(
        "--particles",
        type=_positive_int,
        default=None,
        help="particles held (default: 10000 for four-compartment, 40 per compartment for grid)",
    )
    continuous.add_argument(
        "--n-axial", type=_positive_int, default=50, help="grid: axial slices (default: 50)"
    )
    continuous.add_argument(
        "--n-radial", type=_positive_int, default=5, help="grid: radial compartments (default: 5)"
    )
    continuous.add_argument(
        "--tracer",
        type=_positive_int,
        default=None,
        metavar="PARTICLES",
        help="tracer particles in the pulse (default: half the inlet hold-up)",
    )
    continuous.add_argument(
        "--pulse-step",
        type=_non_negative_int,
        default=0,
        metavar="STEP",
        help="step at whose start the tracer is injected (default: 0)",
    )
    continuous.add_argument(
        "--feeder",
        action="store_true",
        help="fluctuating feed: lactose 12.16+-2.46 g/s, pre-blend 6.55+-1.16 g/s "
        "(default: constant feed)",
    )
    continuous.add_argument(
        "--feeder-period",
        type=_positive_float,
        default=1.0,
        metavar="SECONDS",
        help="seconds [s] a drawn feeder rate is held (default: 1.0)",
    )
    continuous.add_argument(
        "--samples",
        type=_non_negative_int,
        default=30,
        help="outflow samples: of the tracer, evenly spaced over 4 mean residence times "
        "after the pulse; with --feeder, of the pre-blend over the second half of the run "
        "(default: 30)",
    )
    continuous.add_argument(
        "--sample-size",
        type=_positive_int,
        default=100,
        metavar="PARTICLES",
        help="particles per outflow sample (default: 100)",
    )
    continuous.add_argument(
        "--rtd-csv",
        metavar="PATH",
        default=None,
        help="write the RTD here: a histogram of the tracer leaving, columns 't [s]', 'count' "
        "(particles per bin), 'bin [s]' and 'E [1/s]' (axialmix fit reads the counts with "
        "counting errors)",
    )
    continuous.add_argument(
        "--samples-csv",
        metavar="PATH",
        default=None,
        help="write the outflow samples here: columns 't [s]' and '<species> [fraction]'",
    )
    _common(continuous, None)
    return simulate_parser


def run(args: argparse.Namespace) -> int:
    """Run the parsed ``simulate`` command; returns the exit status (0, 2 or 130)."""
    interrupted = 130  # axialmix._exits.INTERRUPTED, before axialmix is imported
    _interruption.requested = False
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, _interruption.handler) if main_thread else None
    try:
        from axialmix._exits import error_line

        if args.blender == "vblender":
            return _run_vblender(args)
        if args.blender == "network":
            return _run_network(args)
        return _run_continuous(args)
    except _BadInput as error:
        return error_line(_COMMAND, str(error))
    except KeyboardInterrupt:
        print("interrupted; no partial file written", file=sys.stderr)
        return interrupted
    finally:
        if main_thread:
            signal.signal(signal.SIGINT, previous)


# ------------------------------------------------------------------ checks before running
def _check_outputs(**paths: str | None) -> None:
    """Refuse an output (option name -> path) whose folder is missing or not writable, that
    is a folder, or that another output option names too, before any work."""
    seen: dict[str, str] = {}
    for name, path in paths.items():
        if path is None:
            continue
        option = "--" + name.replace("_", "-")
        folder = os.path.dirname(os.path.abspath(path))
        if os.path.isdir(path):
            raise _BadInput(f"{option} {path} is a folder, not a file")
        if not os.path.isdir(folder):
            raise _BadInput(f"{option}: cannot write {path}: folder {folder} does not exist")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise _BadInput(f"{option}: cannot write {path}: folder {folder} is not writable")
        where = os.path.realpath(path)
        if where in seen:
            raise _BadInput(f"{option} {path}: the same file as {seen[where]}; each output "
                            "needs its own")
        seen[where] = option


def _available_memory() -> int | None:
    """Bytes of memory available now (MemAvailable), or None where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as stream:
            for line in stream:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None


def _check_memory(args, network, steps: int, n_species: int, reports: int, extra_per_step: int,
                  tracked: bool = False) -> None:
    """Refuse a run whose arrays would not fit in the memory available now."""
    from axialmix.particles import memory_estimate

    estimate = memory_estimate(
        network, steps, n_species, engine=args.engine, reports=reports, tracked=tracked
    )
    per_step = estimate.per_step + extra_per_step * steps
    total = per_step + estimate.per_particle + estimate.fixed
    available = _available_memory()
    if available is None or total <= 0.8 * available:
        return
    if per_step >= estimate.per_particle:
        culprit = f"--steps {steps}"
    else:
        culprit = f"--particles {network.n_particles} with --engine {args.engine}"
    raise _BadInput(
        f"{culprit} needs about {total / 1e9:.3g} GB of memory, more than the "
        f"{available / 1e9:.3g} GB available; choose fewer"
    )


def _simulate(args, network, initial, steps: int, report_every: int | None, **options):
    """Run the simulator with a progress bar; returns the result (interrupted or not)."""
    from axialmix._progress import progress_bar
    from axialmix.particles import simulate

    every = report_every or max(1, steps // 200)
    bar = progress_bar(total=steps, description=_COMMAND, unit="step",
                       enabled=False if args.quiet else None)

    def progress(step: int, total: int, elapsed: float) -> None:
        bar.update(step - bar.n)
        _interruption.checkpoint()

    _interruption.checkpoint()
    try:
        return simulate(network, initial, steps, engine=args.engine, seed=args.seed,
                        report_every=every, progress=progress, **options)
    except ValueError as error:
        raise _BadInput(str(error).rstrip(".")) from None
    finally:
        bar.close()


def _run_record(result) -> dict:
    """How far a run got and how long it took, for every sub-command's JSON."""
    return {"steps_requested": result.steps_requested,
            "steps_completed": result.steps_completed,
            "interrupted": result.interrupted, "wall_seconds": result.wall_seconds}


def _finish(args, result, writers: list) -> int:
    """Write the outputs (each atomically) and return 0, or 130 when the run was interrupted."""
    from axialmix._exits import INTERRUPTED, OK

    for write in writers:
        write()
    if result.interrupted or _interruption.requested:
        print(
            f"interrupted after {result.steps_completed} of {result.steps_requested} steps; "
            "results so far written",
            file=sys.stderr,
        )
        return INTERRUPTED
    return OK


# ------------------------------------------------------------------ vblender
def _run_vblender(args) -> int:
    from axialmix._files import write_json
    from axialmix.particles import chi_square, particle_v_blender, v_blender_loading

    _check_outputs(json=args.json)
    if len(args.exchanges) != 4:
        raise _BadInput(f"--exchanges needs 4 numbers, got {len(args.exchanges)}")
    with _option("--particles/--exchanges"):
        network = particle_v_blender(args.particles, args.exchanges)
    with _option("--loading"):
        initial = v_blender_loading(network, args.loading)
    reports = 2 + (args.steps // args.report_every if args.report_every else 200)
    _check_memory(args, network, args.steps, initial.shape[1], reports, 0)
    result = _simulate(args, network, initial, args.steps, args.report_every)
    wanted = [
        (int(step), counts)
        for step, counts in zip(result.report_steps, result.counts, strict=True)
        if step in (0, result.steps_completed)
        or (args.report_every is not None and step % args.report_every == 0)
    ]
    reports = [
        {"step": step, "species1_counts": counts[:, 0].tolist(),
         "chi_square": chi_square(counts, 0)}
        for step, counts in wanted
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
        **_run_record(result),
        "reports": reports,
    }
    writers = [] if args.json is None else [lambda: write_json(args.json, data)]
    return _finish(args, result, writers)


# ------------------------------------------------------------------ network file
#: Share of its particles the fastest compartment hands on per step by default.
_DEFAULT_STEP_SHARE = 0.1


def _read_network_file(path: str):
    from axialmix.network import CompartmentNetwork

    file = Path(path)
    if not file.is_file():
        raise _BadInput(f"{path}: no such network file")
    try:
        if file.suffix.lower() == ".toml":
            return CompartmentNetwork.from_toml(file)
        return CompartmentNetwork.from_json(file)
    except (ValueError, OSError) as error:
        raise _BadInput(f"{path}: {str(error).rstrip('.')}") from None


def _run_network(args) -> int:
    import numpy as np

    from axialmix._files import write_json
    from axialmix.particles import ParticleNetwork, chi_square

    _check_outputs(json=args.json)
    network = _read_network_file(args.network)
    if network.inlets or network.outlets:
        raise _BadInput(f"{args.network}: the network has inlets or outlets; `simulate network` "
                        "runs closed networks (a batch, or a periodic section)")
    if network.holdups is None:
        raise _BadInput(f"{args.network}: the network gives no hold-ups; a particle "
                        "simulation shares its particles out by them")
    step = args.step
    if network.time_step is not None:
        if step is not None and step != network.time_step:
            raise _BadInput(f"--step {step:g}: the network is discrete with steps of "
                            f"{network.time_step:g} s")
        step = network.time_step
    elif step is None:
        # Continuous rates (1/s): a step at which no compartment hands on more than a tenth
        # of its particles, so that moving whole particles once a step follows the rates.
        outflow = np.zeros(len(network.compartments))
        for connection in network.connections:
            outflow[network.compartments.index(connection.source)] += connection.rate
        fastest = float(outflow.max()) if outflow.size else 0.0
        if not fastest > 0:
            raise _BadInput(f"{args.network}: no connection has a positive rate")
        step = _DEFAULT_STEP_SHARE / fastest
    tracer_names = [network.compartments[0]] if args.tracer is None else [
        n.strip() for n in args.tracer.split(",") if n.strip()]
    unknown = [n for n in tracer_names if n not in network.compartments]
    if unknown or not tracer_names:
        raise _BadInput(f"--tracer: no compartment {', '.join(unknown) or '(none given)'} in "
                        f"{args.network} (compartments: {', '.join(network.compartments[:8])}"
                        f"{', ...' if len(network.compartments) > 8 else ''})")
    with _option("--particles/--step"):
        particles = ParticleNetwork.from_network(network, total_particles=args.particles,
                                                 time_step=step if network.time_step is None
                                                 else None, round_moves=True)
    holdups = np.asarray(particles.holdups)
    is_tracer = np.isin(np.asarray(particles.names), tracer_names)
    initial = np.column_stack([np.where(is_tracer, 0, holdups), np.where(is_tracer, holdups, 0)])
    reports = 2 + (args.steps // args.report_every if args.report_every else 200)
    _check_memory(args, particles, args.steps, 2, reports, 0)
    result = _simulate(args, particles, initial, args.steps, args.report_every)
    wanted = [
        (int(k), counts) for k, counts in zip(result.report_steps, result.counts, strict=True)
        if k in (0, result.steps_completed)
        or (args.report_every is not None and k % args.report_every == 0)
    ]
    rows = [{"step": k, "time_s": k * step, "tracer_counts": counts[:, 1].tolist(),
             "chi_square": chi_square(counts, 1)} for k, counts in wanted]
    tracer_total = int(initial[:, 1].sum())
    print(f"{args.network}: {len(particles.names)} compartments, {particles.n_particles} "
          f"particles ({tracer_total} tracer in {', '.join(tracer_names)}), steps of {step:.4g} s")
    print(f"{'step':<9} {'time [s]':>10} {'chi-square':>12}  tracer compartments (of "
          f"{len(particles.names)})")
    for row in rows:
        held = sum(c > 0 for c in row["tracer_counts"])
        print(f"{row['step']:<9} {row['time_s']:>10.4g} {row['chi_square']:>12.6g}  {held}")
    data = {
        "blender": "network",
        "network": str(args.network),
        "engine": result.engine,
        "seed": result.seed,
        "particles": particles.n_particles,
        "step_seconds": step,
        "compartments": list(particles.names),
        "holdups": holdups.tolist(),
        "tracer": {"compartments": tracer_names, "particles": tracer_total},
        **_run_record(result),
        "reports": rows,
    }
    writers = [] if args.json is None else [lambda: write_json(args.json, data)]
    return _finish(args, result, writers)


# ------------------------------------------------------------------ continuous
def _continuous_network(args):
    from axialmix.particles import particle_axial_radial_grid, particle_four_compartment

    if args.preset == "grid":
        if args.n_axial < 2:
            raise _BadInput(f"--n-axial must be at least 2 for the grid, got {args.n_axial}")
        cells = args.n_axial * args.n_radial
        total = 40 * cells if args.particles is None else args.particles
        if total % cells:
            raise _BadInput(f"--particles must be a multiple of the {cells} compartments")
        with _option("--particles"):
            return particle_axial_radial_grid(
                args.n_axial, args.n_radial, particles_per_compartment=total // cells
            )
    with _option("--particles"):
        return particle_four_compartment(particles=args.particles or 10_000)


@contextlib.contextmanager
def _option(name: str):
    """Turn a ValueError of the library into bad input naming the option it came from."""
    try:
        yield
    except ValueError as error:
        raise _BadInput(f"{name}: {str(error).rstrip('.')}") from None


def _sample_range(args, steps_done: int, tracer_step: int, tau: float, dt: float):
    """First and last step of the outflow samples' span."""
    if args.feeder:
        return steps_done // 2, steps_done - 1
    return tracer_step, min(steps_done - 1,
                            tracer_step + math.ceil(_SAMPLE_WINDOW_IN_TAU * tau / dt))


def _check_samples(args, network, steps: int, tracer, tau: float) -> None:
    """Refuse, before the run, samples larger than what the blender holds."""
    if args.samples == 0:
        return
    if args.sample_size > network.n_particles:
        raise _BadInput(f"--sample-size {args.sample_size} is more than the "
                        f"{network.n_particles} particles the blender holds")
    # Whether the outflow fills the samples depends on the run; an outflow that falls short
    # is refused after it, before anything is written (see _outflow_samples).


def _run_continuous(args) -> int:
    import numpy as np

    from axialmix._files import csv_text, write_csv, write_json, write_text
    from axialmix.particles import (
        TracerPulse,
        constant_feed,
        exit_age_from_outflow,
        feeder_feed,
    )

    _check_outputs(json=args.json, rtd_csv=args.rtd_csv, samples_csv=args.samples_csv)
    network = _continuous_network(args)
    dt = network.step_seconds
    tau = network.n_particles * dt / network.throughput  # steady hold-up / throughput
    steps = args.steps or math.ceil(_RUN_LENGTH_IN_TAU * tau / dt)
    if args.pulse_step >= steps:
        raise _BadInput(f"--pulse-step {args.pulse_step} must be before --steps {steps}")
    n_species = 3 if args.feeder else 2
    reports = 2 + (steps // args.report_every if args.report_every else 200)
    # The RTD and its times (float64) are made from the outflow record after the run.
    _check_memory(args, network, steps, n_species, reports, 16,
                  tracked=args.engine == "identity")
    if args.feeder:
        names = ["lactose", "pre-blend", "tracer"]
        hold = max(1, round(args.feeder_period / dt))
        fed = feeder_feed(network, [12.16, 6.55], [2.46, 1.16], steps, hold_steps=hold,
                          seed=args.seed)
        feed = np.concatenate([fed, np.zeros(fed.shape[:2] + (1,), np.int64)], axis=2)
        first = np.rint(network.holdups * 12.16 / (12.16 + 6.55)).astype(np.int64)
        initial = np.column_stack([first, network.holdups - first, np.zeros_like(first)])
    else:
        names = ["bulk", "tracer"]
        feed = constant_feed(network, [1.0, 0.0], steps)
        initial = np.column_stack([network.holdups, np.zeros_like(network.holdups)])
    tracer_species = len(names) - 1
    inlet_holdup = int(network.holdups[network.inlets()].sum())
    if args.tracer is not None and args.tracer > inlet_holdup:
        raise _BadInput(
            f"--tracer {args.tracer} does not fit in the inlet compartment(s), which hold "
            f"{inlet_holdup} particles"
        )
    tracer = TracerPulse(args.pulse_step, args.tracer or max(inlet_holdup // 2, 1),
                         tracer_species)
    _check_samples(args, network, steps, tracer, tau)
    result = _simulate(args, network, initial, steps, args.report_every, feed=feed,
                       tracer=tracer)
    times, exit_age = exit_age_from_outflow(
        result.outflow, tracer_species, tracer.step, tracer.particles, dt
    )
    left_steps = np.nonzero(exit_age)[0]
    if left_steps.size and exit_age.sum() * dt * tracer.particles >= tracer.particles - 0.5:
        # Every tracer particle has left: the RTD ends one step after the last one did.
        keep = min(int(left_steps[-1]) + 2, times.size)
        times, exit_age = times[:keep], exit_age[:keep]
    samples = _outflow_samples(args, result, names, tracer, tau)
    left = float(exit_age.sum() * dt)
    mean = float(np.sum(times * exit_age) * dt / left) if left > 0 else None
    print(
        f"{args.preset}: {network.n_particles} particles, {network.n_compartments} compartments, "
        f"{result.steps_completed} steps of {dt:g} s ({result.steps_completed * dt:g} s; "
        f"mean residence time of the network {tau:.4g} s)"
    )
    print(
        f"tracer left: {left:.4f} of {tracer.particles} particles; mean residence time of "
        f"those: {'-' if mean is None else f'{mean:.4g}'} s"
    )
    if samples["steps"]:
        window = f"t = {samples['times_s'][0]:g} to {samples['times_s'][-1]:g} s"
        line = (f"outflow samples: {len(samples['steps'])} of {args.sample_size} particles, "
                f"{samples['species']} fraction, {window}")
        if samples.get("rsd") is not None:
            line += f"; RSD {samples['rsd']:.4g}"
        print(line)
    if samples.get("vrr") is not None:
        print(f"variance reduction ratio: {samples['vrr']:.4g}")
    data = {
        "blender": args.preset,
        "engine": result.engine,
        "seed": result.seed,
        "particles": network.n_particles,
        "compartments": list(network.names),
        "species": names,
        "step_seconds": dt,
        "throughput_per_step": network.throughput,
        "mean_residence_time_s": tau,
        "tracer": {"step": tracer.step, "particles": tracer.particles, "species": tracer_species},
        **_run_record(result),
        "rtd": {
            "time_s": times.tolist(),
            "exit_age_per_s": exit_age.tolist(),
            "fraction_left": left,
            "mean_residence_time_s": mean,
        },
        "outflow_samples": samples,
    }
    writers = []
    if args.rtd_csv is not None:
        # A histogram of the tracer particles leaving, one bin per step, reported at the bin's
        # end; E(0) = 0 (the discrete convention), so the curve starts where the pulse
        # entered. The counts make `axialmix fit` use counting (Poisson) errors.
        counts = np.rint(exit_age * tracer.particles * dt).astype(np.int64)
        rtd_rows = [("0", "0", f"{dt:.10g}", "0")] + [
            (f"{t:.10g}", str(int(k)), f"{dt:.10g}", f"{e:.10g}")
            for t, k, e in zip(times, counts, exit_age, strict=True)
        ]
        comment = (f"# axialmix simulate continuous ({args.preset}, seed {result.seed}): "
                   f"tracer pulse of {tracer.particles} particles; count = tracer particles "
                   f"leaving in the bin of width 'bin [s]' ending at t (Poisson counts: "
                   f"axialmix fit uses counting errors); E = count / ({tracer.particles} bin)\n")
        writers.append(lambda: write_text(args.rtd_csv, comment + csv_text(
            ["t [s]", "count", "bin [s]", "E [1/s]"], rtd_rows)))
    if args.samples_csv is not None:
        sample_rows = list(zip(samples["times_s"], samples["fractions"], strict=True))
        header = ["t [s]", f"{samples['species']} [fraction]"]
        writers.append(lambda: write_csv(args.samples_csv, header, sample_rows))
    if args.json is not None:
        writers.append(lambda: write_json(args.json, data))
    return _finish(args, result, writers)


def _outflow_samples(args, result, names: list[str], tracer, tau: float) -> dict:
    # Without feeder fluctuations the samples measure the tracer, as an RTD experiment does:
    # evenly spaced over 4 tau after the pulse, where the tracer passes (their spread is the
    # RTD, so no RSD is given). With them, the pre-blend fraction over the second half of the
    # run (a homogeneity test: RSD), against inflow samples of the same size and times (VRR).
    import numpy as np

    from axialmix.particles import (
        relative_standard_deviation,
        sample_outflow,
        sample_variance,
        species_fraction,
    )

    dt = result.network.step_seconds
    steps_done = result.steps_completed
    species = 1 if args.feeder else len(names) - 1
    first, last = _sample_range(args, steps_done, tracer.step, tau, dt)
    out: dict = {
        "species": names[species],
        "particles_per_sample": args.sample_size,
        "steps": [],
        "times_s": [],
        "fractions": [],
        "rsd": None,
    }
    if args.samples == 0 or last <= first:
        return out
    sample_steps = np.unique(np.linspace(first, last, args.samples + 1).astype(int)[1:])
    with _option("--samples"):  # an outflow that fell short of the planned one
        drawn = sample_outflow(result.outflow, sample_steps, args.sample_size,
                               seed=[args.seed, 2])
    fractions = species_fraction(drawn, species)
    out["steps"] = sample_steps.tolist()
    # What leaves during step k is reported at the end of the step, (k + 1) dt, and tracer
    # samples from the pulse on, as the RTD is (axialmix.particles.exit_age_from_outflow).
    origin = 0 if args.feeder else tracer.step
    out["times_s"] = ((sample_steps + 1 - origin) * dt).tolist()
    out["fractions"] = fractions.tolist()
    if args.feeder:
        if fractions.size >= 2 and fractions.mean() > 0:
            out["rsd"] = relative_standard_deviation(fractions)
        fed = result.fed.sum(axis=1)
        with _option("--samples"):
            inflow = species_fraction(
                sample_outflow(fed, sample_steps, args.sample_size, seed=[args.seed, 3]),
                species)
        out["inflow_fractions"] = inflow.tolist()
        out["variance_in"] = sample_variance(inflow)
        out["variance_out"] = sample_variance(fractions)
        out["vrr"] = out["variance_in"] / out["variance_out"] if out["variance_out"] > 0 else None
    return out
