"""``axialmix dem``: DEM sections on LAMMPS, networks learned from them, the hybrid run.

Sub-commands, each writing fixed file names into ``--out DIR``:

* ``axialmix dem learn``: run a DEM section (or read runs saved before, ``--run``, given once
  per run: several runs of one section are learned as one network), learn
  the network of its cells: ``network.json`` (a network file :mod:`axialmix.network` and
  ``axialmix simulate network`` read),
  ``rates.csv`` (every connection's rate and 95 % bootstrap interval), ``learn.json`` (the
  DEM's v, D_z and Pe from its tracks beside the network's equivalent ADM, the Markov test,
  the cell-length rule) and ``run.npz`` (the recorded run, for ``--run``).
* ``axialmix dem hybrid``: the source's bladed mixer: a learning DEM run, partition method I
  or II (or ``--dem-regions``), the hybrid run: ``composition.csv`` (per-region counts over
  time), ``hybrid.json``, ``composition.png``.
* ``axialmix dem validate``: as ``hybrid``, plus a full DEM reference run: ``errors.csv``
  (e_ij per region and species with the DEM's noise floor), ``validation.json``,
  ``validation.png``.

Needs the optional ``dem`` extra (LAMMPS); without it the command stops with one line and
status 2, writing nothing. Exit status as every sub-command (:mod:`axialmix._exits`): 0 done,
2 bad input, 130 interrupted (what was recorded is written).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

__all__ = ["add_parser", "run"]

_COMMAND = "dem"


class _BadInput(Exception):
    """Bad options, reported on one line with status 2."""


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _whole(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {value}")
    return value


def _count(text: str) -> int:
    value = _whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number, got {value}")
    return value


def _particles(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected counts per species like 1500,1500, got {text!r}") from None
    if not values or min(values) < 0 or sum(values) == 0:
        raise argparse.ArgumentTypeError(f"expected non-negative counts, got {text!r}")
    return values


def _common(parser: argparse.ArgumentParser, duration: float) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.add_argument("--duration", type=_positive, default=duration,
                        help=f"simulated time after settling, s (default {duration:g})")
    parser.add_argument("--record-interval", type=_positive, default=0.05,
                        help="time between recorded frames, s (default 0.05)")
    parser.add_argument("--settle", type=_positive, default=0.5,
                        help="settling time before the impeller starts, s (default 0.5)")
    parser.add_argument("--rpm", type=_positive, default=60.0, help="impeller speed (default 60)")
    parser.add_argument("--seed", type=_count, default=12345, help="random seed (default 12345)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``dem`` parser and its sub-commands on `subparsers`; returns it."""
    parser = subparsers.add_parser(
        _COMMAND, help="DEM on LAMMPS: learn networks, hybrid DEM + compartment runs",
        description="DEM sections of bladed blenders on LAMMPS (optional extra), networks "
        "learned from them, and the hybrid DEM + compartment run checked against full DEM.")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    learn = actions.add_parser("learn", help="learn a network from a DEM section")
    _common(learn, 4.0)
    learn.add_argument("--run", metavar="FILE", default=None, action="append",
                       help="a run.npz written before, instead of running DEM; give it again "
                       "for more runs of the same section (other seeds), learned as one "
                       "network")
    learn.add_argument("--geometry", choices=("section", "mixer"), default="section",
                       help="periodic paddle section (default) or the source's bladed mixer")
    learn.add_argument("--particles", type=_particles, default=None,
                       help="spheres per species, e.g. 3000 (default: the geometry's)")
    learn.add_argument("--cells", type=_count, default=12, help="axial cells (default 12)")
    learn.add_argument("--radial", type=_count, default=1,
                       help="equal-area radial rings per axial cell (default 1)")
    learn.add_argument("--sectors", type=_count, default=1,
                       help="angular sectors per ring, each holding an equal share of the "
                       "recorded spheres (default 1; 4 tells the rising, resting and "
                       "falling parts of the bed apart)")
    learn.add_argument("--lag", type=_positive, default=0.1, help="lag, s (default 0.1)")
    learn.add_argument("--bootstrap", type=_whole, default=200,
                       help="bootstrap replicates (default 200; the 95 %% intervals need at "
                       "least 20, and 0 gives the rates alone)")
    learn.add_argument("--estimator", choices=("logm", "likelihood", "stationary"),
                       default="logm",
                       help="rates from the counts: the matrix logarithm with negative rates "
                       "clipped (default); the rates of largest likelihood on the "
                       "connections seen from frame to frame (a valid network at any lag); "
                       "or those with the occupancy held as the network's steady state")
    for name, helptext in (("hybrid", "hybrid run of the source's bladed mixer"),
                           ("validate", "hybrid against a full DEM run of the mixer")):
        sub = actions.add_parser(name, help=helptext)
        _common(sub, 4.0)
        sub.add_argument("--particles", type=_particles, default=(1500, 1500),
                         help="spheres per species (default 1500,1500)")
        sub.add_argument("--diameter", type=_positive, default=0.0082,
                         help="sphere diameter, m (default 0.0082: the source's 5 %% fill "
                         "with 3,000 spheres)")
        sub.add_argument("--regions", type=_count, default=10,
                         help="axial regions (default 10, as the source)")
        sub.add_argument("--method", choices=("flux", "velocity"), default="velocity",
                         help="partition method I (flux) or II (velocity, default)")
        sub.add_argument("--dem-regions", type=_count, default=None,
                         help="regions in DEM from the impeller end (default: the partition's)")
        sub.add_argument("--learn-duration", type=_positive, default=3.0,
                         help="learning DEM run, s (default 3)")
        sub.add_argument("--exchange-interval", type=_positive, default=0.1,
                         help="time between interface exchanges, s (default 0.1)")
    return parser


def _plain(value):
    # JSON has no NaN or infinity: they are written as null.
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _check_out(path: str) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise _BadInput(f"--out {path}: exists and is not a folder")
    return out


def _learn(args, out: Path) -> int:
    import numpy as np

    from axialmix._files import write_csv, write_json
    from axialmix.dem import (
        MIN_REPLICATES,
        BladedMixer,
        DEMRun,
        PaddleSection,
        RunSettings,
        cell_length_limit,
        cells_of_run,
        dem_transport,
        learn_network,
        markov_test,
        run_dem,
    )

    more = []  # further runs of the same section, learned with the first
    if args.run is not None:
        try:
            run, *more = (DEMRun.load(path) for path in args.run)
        except (ValueError, FileNotFoundError) as error:
            raise _BadInput(str(error)) from None
        for path, other in zip(args.run[1:], more, strict=True):
            if (other.geometry != run.geometry
                    or not np.isclose(other.frame_interval, run.frame_interval)):
                raise _BadInput(f"{path}: not a run of the geometry and frame interval of "
                                f"{args.run[0]}")
        ran = False
    else:
        kind = PaddleSection if args.geometry == "section" else BladedMixer
        try:
            options = {"rpm": args.rpm}
            if args.particles is not None:
                options["particles"] = args.particles
            geometry = kind(**options)
            settings = RunSettings(duration=args.duration, record_interval=args.record_interval,
                                   settle_time=args.settle, seed=args.seed)
        except ValueError as error:
            raise _BadInput(str(error)) from None
        frames = args.duration / args.record_interval
        if frames - args.lag / args.record_interval < 2 * geometry.revolution_time \
                / args.record_interval:
            raise _BadInput(f"--duration {args.duration:g} s must cover two impeller "
                            f"revolutions ({2 * geometry.revolution_time:g} s) beyond the lag")
        run = run_dem(geometry, settings)
        ran = True
        out.mkdir(parents=True, exist_ok=True)
        run.save(out / "run.npz")  # kept whatever the learning below says
    kept = f" (the DEM run is kept in {out / 'run.npz'}: give it with --run)" if ran else ""
    g = run.geometry
    lag = max(1, round(args.lag / run.frame_interval))
    block = max(1, round(g.revolution_time / run.frame_interval))
    runs = [run, *more]
    for k, each in enumerate(runs):
        if each.n_frames - lag < 2 * block:
            name = f"{args.run[k]}: " if more else ""
            raise _BadInput(f"{name}the run has {each.n_frames} frames; two revolutions of "
                            f"{block} frames beyond the lag are needed (a longer --duration)"
                            + kept)
    try:
        layout = cells_of_run(run, args.cells, n_radial=args.radial, n_sectors=args.sectors)
    except ValueError as error:
        raise _BadInput(f"{error}{kept}") from None
    cells, n, names, centres = layout.cells, layout.n_cells, layout.names, layout.centres
    # Further runs in the first run's cells (its sector edges); learned as one network.
    cells = [cells] + [cells_of_run(other, args.cells, n_radial=args.radial,
                                    sector_edges=layout.sector_edges).cells
                       for other in more]
    width = g.length / args.cells
    try:
        learned = learn_network(cells, n, run.frame_interval, lag, block,
                                n_bootstrap=args.bootstrap, seed=args.seed, names=names,
                                centres=centres, period=g.length if g.periodic else None,
                                estimator=args.estimator)
    except ValueError as error:
        raise _BadInput(f"{error}{kept}") from None
    interrupted = any(each.interrupted for each in runs)
    transports = [dem_transport(each) for each in runs]
    transport = transports[0]
    v, d = learned.transport()
    (vlo, vhi), (dlo, dhi) = learned.transport_interval()
    test = markov_test(cells, n, run.frame_interval,
                       tuple(sorted({lag, 2 * lag, 4 * lag, max(1, lag // 2)})), base_lag=lag,
                       ck_steps=(2, 4))
    out.mkdir(parents=True, exist_ok=True)
    learned.network().to_json(out / "network.json")
    rows = [(names[i], names[j], learned.rates[i, j], learned.lower[i, j], learned.upper[i, j])
            for i, j in learned.connections()]
    write_csv(out / "rates.csv", ["source", "target", "rate [1/s]", "lower [1/s]",
                                  "upper [1/s]"], rows)
    record = {
        "geometry": type(g).__name__, "particles": run.n_particles,
        "frames": run.n_frames, "frame_interval_s": run.frame_interval,
        "lag_s": learned.lag_seconds, "cells": n, "cell_length_m": width,
        "axial_cells": args.cells, "radial_rings": args.radial, "angular_sectors": args.sectors,
        "sector_edges_rad": (None if layout.sector_edges is None
                             else layout.sector_edges.tolist()),
        "estimator": args.estimator,
        "dem": {"v_m_per_s": transport.velocity, "D_z_m2_per_s": transport.dispersion,
                "D_z_window_s": list(transport.window), "Pe": transport.peclet,
                "blender_length_m": transport.blender_length,
                "lags_s": transport.lags.tolist(),
                "D_z_at_lag_m2_per_s": transport.lag_dispersion.tolist()},
        "network": {"v_m_per_s": v, "v_95": [vlo, vhi], "D_z_m2_per_s": d, "D_z_95": [dlo, dhi],
                    "clipped_rate_share": learned.clipped, "blocks": learned.blocks,
                    "bootstrap_replicates_without_rates": learned.failed},
        "cell_length_limit_m": cell_length_limit(transport.velocity, transport.dispersion),
        "markov": {"lags_s": test.lags_seconds.tolist(), "timescales_s": test.timescales.tolist(),
                   "ck_steps": test.ck_steps.tolist(), "ck_error": test.ck_error.tolist(),
                   "ck_sampling": test.ck_sampling.tolist()},
        "interrupted": interrupted,
    }
    if more:
        record["runs"] = list(args.run)
        record["dem_further_runs"] = [
            {"run": path, "particles": each.n_particles, "frames": each.n_frames,
             "v_m_per_s": t.velocity, "D_z_m2_per_s": t.dispersion, "Pe": t.peclet}
            for path, each, t in zip(args.run[1:], more, transports[1:], strict=True)]
    write_json(out / "learn.json", _plain(record))
    for k, (each, t) in enumerate(zip(runs, transports, strict=True)):
        print(f"DEM{f' {args.run[k]}' if more else ''} ({each.n_particles} spheres, "
              f"{each.times[-1]:.2f} s): v = {t.velocity * 1e3:.2f} mm/s, "
              f"D_z = {t.dispersion * 1e6:.1f} mm²/s, Pe = {t.peclet:.1f}")
    if all(math.isfinite(x) for x in (vlo, vhi, dlo, dhi)):
        print(f"network ({n} cells of {width * 1e3:.1f} mm, lag {learned.lag_seconds:g} s): "
              f"v = {v * 1e3:.2f} mm/s [{vlo * 1e3:.2f}, {vhi * 1e3:.2f}], D_z = {d * 1e6:.1f} "
              f"mm²/s [{dlo * 1e6:.1f}, {dhi * 1e6:.1f}]")
    else:
        usable = learned.replicates.shape[0]
        why = (f"{usable} usable bootstrap replicate(s), at least {MIN_REPLICATES} needed"
               if usable < MIN_REPLICATES else
               f"{learned.failed} of {args.bootstrap} bootstrap replicates have no rates")
        print(f"network ({n} cells of {width * 1e3:.1f} mm, lag {learned.lag_seconds:g} s): "
              f"v = {v * 1e3:.2f} mm/s, D_z = {d * 1e6:.1f} mm²/s (no 95 % intervals: {why})")
    print(f"cell length rule: cells <= {record['cell_length_limit_m'] * 1e3:.1f} mm "
          f"(these are {width * 1e3:.1f} mm)")
    print(test.report())
    print(f"results written to {out}")
    return 130 if interrupted else 0


def _mixer_runs(args, out: Path, validate: bool) -> int:
    import numpy as np

    from axialmix._files import write_csv, write_json
    from axialmix.dem import (
        BladedMixer,
        RunSettings,
        axial_cells,
        composition_errors,
        dem_noise_floor,
        flux_partition,
        learn_network,
        region_counts,
        run_dem,
        run_hybrid,
        velocity_partition,
    )

    try:
        mixer = BladedMixer(particles=args.particles, diameter=args.diameter, rpm=args.rpm)
        learn_settings = RunSettings(duration=args.learn_duration,
                                     record_interval=args.record_interval,
                                     settle_time=args.settle, seed=args.seed)
        settings = RunSettings(duration=args.duration, record_interval=args.record_interval,
                               settle_time=args.settle, seed=args.seed + 1)
    except ValueError as error:
        raise _BadInput(str(error)) from None
    if args.dem_regions is not None and args.dem_regions >= args.regions:
        raise _BadInput(f"--dem-regions {args.dem_regions} must be below --regions "
                        f"{args.regions}")
    block = round(0.5 * mixer.revolution_time / args.record_interval)  # a blade passage
    if args.learn_duration / args.record_interval < 2 * block + 2:
        raise _BadInput("--learn-duration must cover at least two blade passages and the lag")
    learning = run_dem(mixer, learn_settings)
    if learning.interrupted:
        return 130
    partition = (flux_partition(learning, args.regions, interval=0.25)
                 if args.method == "flux" else velocity_partition(learning, args.regions))
    n_dem = args.dem_regions or max(1, min(args.regions - 1, max(partition.dem_regions) + 1))
    cells = axial_cells(learning.positions[:, :, 2], mixer.length, args.regions)
    lag = max(1, round(0.1 / args.record_interval))
    learned = learn_network(cells, args.regions, learning.frame_interval, lag, max(1, block),
                            centres=(np.arange(args.regions) + 0.5) * mixer.length
                            / args.regions)
    reference = run_dem(mixer, settings) if validate else None
    start = (region_counts(reference, args.regions)[0] if reference is not None
             else region_counts(learning, args.regions)[0])
    hybrid = run_hybrid(mixer, learned, start, n_dem, settings,
                        exchange_interval=args.exchange_interval, seed=args.seed)
    out.mkdir(parents=True, exist_ok=True)
    species = len(mixer.particles)
    rows = [(float(t), i + 1, *map(int, hybrid.counts[k, i]))
            for k, t in enumerate(hybrid.times) for i in range(args.regions)]
    write_csv(out / "composition.csv",
              ["t [s]", "region", *[f"species {s}" for s in range(species)]], rows)
    record = {
        "mixer": {"particles": list(mixer.particles), "diameter_m": mixer.diameter,
                  "rpm": mixer.rpm, "regions": args.regions},
        "partition": {"method": partition.method, "score": partition.score.tolist(),
                      "recommended_dem_regions": [i + 1 for i in partition.dem_regions]},
        "dem_regions": n_dem, "exchange_interval_s": args.exchange_interval,
        "learning_cpu_s": learning.cpu_seconds,
        "hybrid_dem_cpu_s": hybrid.dem_cpu_seconds,
        "hybrid_compartment_cpu_s": hybrid.compartment_cpu_seconds,
        "compartment_share": hybrid.compartment_share,
        "exchanged": int(hybrid.exchanged.sum()), "interrupted": hybrid.interrupted,
    }
    print(partition.table())
    print(f"hybrid: DEM in regions 1-{n_dem}, CPU DEM {hybrid.dem_cpu_seconds:.1f} s, "
          f"compartments {hybrid.compartment_cpu_seconds:.2f} s "
          f"({hybrid.compartment_share:.1%}); {int(hybrid.exchanged.sum())} swapped")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fraction = hybrid.counts[:, :, 0] / np.maximum(hybrid.counts.sum(axis=2), 1)
    if reference is not None:
        ref = region_counts(reference, args.regions)
        # The reference frames matching the hybrid's record times.
        index = np.clip(np.round(hybrid.times / reference.frame_interval).astype(int), 0,
                        reference.n_frames - 1)
        errors = composition_errors(ref[index[-1]], hybrid.counts[-1])
        floor = dem_noise_floor(reference, args.regions, frame=int(index[-1]), seed=args.seed)
        write_csv(out / "errors.csv",
                  ["region", *[f"e species {s} [%]" for s in range(species)],
                   *[f"floor species {s} [%]" for s in range(species)]],
                  [(i + 1, *errors.relative[i], *floor.relative[i])
                   for i in range(args.regions)])
        saving = 1 - (hybrid.dem_cpu_seconds + hybrid.compartment_cpu_seconds) / \
            reference.cpu_seconds
        record.update({"reference_cpu_s": reference.cpu_seconds, "saving": saving,
                       "average_error_percent": errors.average,
                       "noise_floor_percent": floor.average,
                       "sigma2": errors.variance.tolist()})
        print(f"against full DEM (CPU {reference.cpu_seconds:.1f} s): average error "
              f"{errors.average:.2f} %, DEM noise floor {floor.average:.2f} %, saving "
              f"{saving:.0%}")
        reference_fraction = ref[index][:, :, 0] / np.maximum(ref[index].sum(axis=2), 1)
    fig, ax = plt.subplots(figsize=(7, 4))
    for k in range(0, hybrid.times.size, max(1, hybrid.times.size // 5)):
        line, = ax.plot(np.arange(1, args.regions + 1), fraction[k], "o-",
                        label=f"hybrid t = {hybrid.times[k]:.1f} s")
        if reference is not None:
            ax.plot(np.arange(1, args.regions + 1), reference_fraction[k], "x--",
                    color=line.get_color(), label=f"full DEM t = {hybrid.times[k]:.1f} s")
    ax.axvspan(0.5, n_dem + 0.5, color="0.9", zorder=0)
    ax.set_xlabel("region (DEM shaded)")
    ax.set_ylabel("fraction of species 0")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / ("validation.png" if validate else "composition.png"), dpi=110)
    plt.close(fig)
    write_json(out / ("validation.json" if validate else "hybrid.json"), _plain(record))
    print(f"results written to {out}")
    return 130 if hybrid.interrupted else 0


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix dem ACTION`` with parsed `args`; returns the exit status."""
    from axialmix import _exits
    from axialmix.dem import DEMUnavailable, lammps_module

    try:
        out = _check_out(args.out)
        lammps_module()
        if args.action == "learn":
            return _learn(args, out)
        return _mixer_runs(args, out, validate=args.action == "validate")
    except (_BadInput, DEMUnavailable) as error:
        return _exits.error_line(_COMMAND, str(error))
    except KeyboardInterrupt:
        return _exits.INTERRUPTED
