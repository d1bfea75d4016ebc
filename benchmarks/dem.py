"""The hybrid DEM + compartment run of the source's bladed mixer against full DEM.

    python benchmarks/dem.py [--quick] [--out DIR]
    python benchmarks/dem.py --section RUN.npz   # a recorded paddle section (see below)

Needs the ``dem`` extra. Steps (MODELS.md §9):

1. a learning DEM run of the mixer (its own seed): partitions by method I (flux variability)
   and II (velocity variance) of ten axial regions, and the region network learned from its
   cell sequences (lag 0.1 s, bootstrap blocks of one blade passage, 0.5 s);
2. the reference: a full DEM run from the same kind of start with another seed, and its
   noise floor from two equivalent halves of every species;
3. hybrid runs (DEM at the impeller end, the count engine elsewhere) for both partitions and
   over DEM shares and exchange intervals, each compared with the reference at the end.

With ``--section``, a recorded periodic paddle section (``axialmix dem learn`` writes
``run.npz``) is analysed instead: v, D_z and its lag dependence from the tracks through
axialmix.trajectories; networks learned on the first half of the run for several cell layouts
and lags, their equivalent ADM, Markov test, and how well each predicts the spreading of a
tracer in the second half against the DEM's own noise floor: from two random halves of the
tracer (their sampling noise alone), and (axialmix.dem.repeat_floor) from the same tracer over
the run's two halves and, with ``--others``, over the second halves of independent runs of the
same section (other seeds; every pair of runs), floors that hold what the whole bed shares.

    python benchmarks/dem.py --section A/run.npz --others B/run.npz,C/run.npz \
        --estimator likelihood --layouts 24x1,24x1x4,48x1x4 --lags 0.5,1.0 --bootstrap 0

With ``--every-run`` each run is the section in turn and the errors over the floors of
independent runs are pooled over the runs; beside them, the error of no network at all, the
mean tracer of the other runs (axialmix.dem.independent_mean_error), says how far each run is
from the others. With ``--pool`` each network is learned on the
first halves of all the runs together (the section's and the others'), and still judged on
the section's second half, which no network has seen.

Layouts are axial layers x equal-area rings, or axial x rings x angular sectors (AxRxS; the
sectors hold equal shares of the spheres of the learning window, and the independent runs use
the same sector edges).

The mixer is the source's geometry (radius 0.1 m, length 0.5 m; see axialmix.dem.BladedMixer)
with 1,500 + 1,500 spheres of 8.2 mm: the same 5 % solid fill as the source's 5,000 + 5,000
of 5.5 mm at a third of the cost (the two CPU cores of this machine are shared). CPU seconds
are process time of each part, measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from axialmix.dem import BladedMixer, RunSettings, axial_cells, learn_network, run_dem
from axialmix.dem._analysis import flux_partition, region_counts, velocity_partition
from axialmix.dem._hybrid import composition_errors, dem_noise_floor, run_hybrid

SOURCE_7_5 = [(1.60, 3.47), (26.69, 20.45), (2.42, 10.89), (7.39, 2.11), (12.87, 9.60),
              (11.39, 9.38), (10.60, 11.24), (1.18, 9.90), (1.32, 2.95), (0.29, 3.49)]
SOURCE_7_6 = [(3.99, 7.35), (5.17, 3.95), (15.79, 10.60), (2.29, 5.13), (11.83, 3.26),
              (8.15, 5.31), (9.45, 3.38), (1.60, 1.09), (1.46, 2.02), (3.86, 3.43)]
N_REGIONS = 10


def section(path: str, lags: tuple[float, ...] = (0.05, 0.25, 0.5, 1.0),
            delays_s: tuple[float, ...] = (1.0, 2.0, 4.0), estimator: str = "logm",
            layouts: tuple[tuple[int, ...], ...] = ((12, 1), (24, 1), (24, 1, 4), (48, 1, 4)),
            others: tuple[str, ...] = (), bootstrap: int = 200, pool: bool = False) -> dict:
    """Print the section's table; returns ``{(layout, lag_s): (error, floor of runs, error of
    the others' mean tracer)}`` (mean tracer fractions; the last two NaN without `others`).
    With `pool`, each network is learned on the first halves of this run and of the `others`
    together."""
    from axialmix.dem import (
        DEMRun,
        cell_length_limit,
        cells_of_run,
        dem_transport,
        independent_mean_error,
        markov_test,
        repeat_floor,
        tracer_spreading,
    )

    run = DEMRun.load(path)
    repeats = [DEMRun.load(other) for other in others]
    for other, name in zip(repeats, others, strict=True):
        if (other.geometry != run.geometry or other.n_frames != run.n_frames
                or not np.isclose(other.frame_interval, run.frame_interval)):
            raise SystemExit(f"{name}: not a run of the same section, frames and interval as "
                             f"{path}")
    g = run.geometry
    dt = run.frame_interval
    print(f"paddle section: {run.n_particles} spheres, {run.times[-1]:.2f} s recorded every "
          f"{dt:g} s, DEM CPU {run.cpu_seconds:.0f} s")
    transport = dem_transport(run, lags=(0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0))
    print(f"DEM tracks (axialmix.trajectories): v = {transport.velocity * 1e3:.2f} mm/s, "
          f"D_z = {transport.dispersion * 1e6:.1f} mm²/s (window {transport.window[0]:.2f}-"
          f"{transport.window[1]:.2f} s), Pe over 0.74 m = {transport.peclet:.1f}")
    print("lag (s)   apparent D_z = MSD/(2 lag) (mm²/s)")
    for lag, d in zip(transport.lags, transport.lag_dispersion, strict=True):
        print(f"{lag:7.2f}   {d * 1e6:8.1f}")
    limit = cell_length_limit(transport.velocity, transport.dispersion)
    print(f"cell length rule: dx <= 2 D_z/|v| = {limit * 1e3:.1f} mm")
    half = run.n_frames // 2
    print("\ncells        lag (s)  v net (mm/s) [95 %]        D_z net (mm²/s) [95 %]   clipped"
          "  CK err/noise  tracer err/floor: one start, phase-averaged (err/floor), own chain, "
          "DEM itself | err over the floor of two windows, of independent runs")
    print(f"networks estimated by {estimator}"
          + (", each learned on the first halves of every run together" if pool else "")
          + (f"; independent runs of the section: {', '.join(others)}" if others else ""))
    found = {}
    for layout in layouts:
        n_cells, n_radial, n_sectors = (tuple(layout) + (1, 1))[:3]
        # Sectors placed on the learning window (the first half) of this run, and the same
        # cells (edges) for the independent runs.
        mine = cells_of_run(run, n_cells, n_radial=n_radial, n_sectors=n_sectors,
                            edge_frames=slice(0, half))
        cells, n, per_layer = mine.cells, mine.n_cells, mine.per_layer
        cells_others = [cells_of_run(o, n_cells, n_radial=n_radial,
                                     sector_edges=mine.sector_edges).cells for o in repeats]
        centres = mine.centres
        for lag_s in lags:
            lag = max(1, round(lag_s / dt))
            label = (f"{'x'.join(str(k) for k in (n_cells, n_radial, n_sectors)[:len(layout)])}"
                     f" ({g.length / n_cells * 1e3:.0f} mm)")
            # The learning window: this run's first half, or with `pool` the first halves of
            # every run (the second halves, where the tracer is judged, are never seen).
            learning = [cells[:half]] + ([c[:half] for c in cells_others] if pool else [])
            try:
                learned = learn_network(learning, n, dt, lag, round(g.revolution_time / dt),
                                        centres=centres, period=g.length, estimator=estimator,
                                        n_bootstrap=bootstrap)
            except ValueError as refusal:  # no rate matrix gives T at this lag
                print(f"{label:12s} {lag * dt:6.2f}  {refusal}", flush=True)
                continue
            v, d = learned.transport()
            (vlo, vhi), (dlo, dhi) = learned.transport_interval()
            # Chapman-Kolmogorov at 2 and 4 lags, where the learning window holds them.
            steps = tuple(k for k in (2, 4) if k * lag < half)
            if steps:
                test = markov_test(cells[:half], n, dt, (lag,), ck_steps=steps)
                ck = float(np.max(test.ck_error / np.maximum(test.ck_sampling, 1e-12)))
            else:
                ck = float("nan")
            # The tracer: spheres in the first axial cell (all rings) at one start (mid-run)
            # and at starts every 0.05 s over the second half (all blade phases); the noise
            # floor from two random halves of the spheres.
            # Delays that are whole multiples of every lag: there a Markov chain of the lag is
            # defined without interpolating between its steps.
            delays = tuple(round(t / dt) for t in delays_s)
            one = tracer_spreading(cells, learned, dt, half, delays, cells_per_layer=per_layer)
            starts = np.arange(half, run.n_frames - max(delays), round(0.05 / dt))
            spread = tracer_spreading(cells, learned, dt, starts, delays,
                                      cells_per_layer=per_layer)
            oracle = own_chain_error(cells, n, per_layer, lag, starts, delays, spread)
            # The DEM predicting itself: the tracer released over the first half against the
            # same tracer over the second half (the run's slow, shared fluctuations, which
            # two halves of the spheres of one window do not see).
            early = tracer_spreading(cells, learned, dt, np.arange(0, half - max(delays),
                                                                  round(0.05 / dt)),
                                     delays, cells_per_layer=per_layer)
            window = float(np.abs(early.dem - spread.dem).mean() / spread.floor.mean())
            # The floors of two equivalent measurements (axialmix.dem.repeat_floor): the same
            # tracer over the first and the second half of this run, and over the second half
            # of this run and of independent runs (other seeds), every pair, when given.
            by_windows = spread.error.mean() / repeat_floor(early, spread).mean()
            if cells_others:
                twins = [tracer_spreading(c, learned, dt, starts, delays,
                                          cells_per_layer=per_layer)
                         for c in cells_others]
                floor_runs = float(repeat_floor(spread, *twins).mean())
                by_runs = f"{spread.error.mean() / floor_runs:6.2f}"
                # No network: the mean tracer of the independent runs as the prediction.
                others_mean = float(independent_mean_error(spread, *twins).mean())
            else:
                floor_runs, by_runs, others_mean = float("nan"), "     -", float("nan")
            found[(tuple(layout), lag * dt)] = (float(spread.error.mean()), floor_runs,
                                                others_mean)
            print(f"{label:12s} {lag * dt:6.2f}  {v * 1e3:7.2f} [{vlo * 1e3:6.2f},{vhi * 1e3:6.2f}]"
                  f"   {d * 1e6:7.1f} [{dlo * 1e6:6.1f},{dhi * 1e6:6.1f}]   {learned.clipped:5.2f}"
                  f"   {ck:6.2f}     {one.ratio:5.2f}      {spread.ratio:5.2f} "
                  f"({spread.error.mean():.4f}/{spread.floor.mean():.4f})"
                  f"   {oracle:6.2f}   {window:6.2f} | {by_windows:6.2f} {by_runs}"
                  + (f"   ({learned.failed} of the bootstrap replicates have no rates)"
                     if learned.failed else ""), flush=True)
    print("own chain: the second half's own transition matrix at the lag, T^(delay/lag) from "
          "the tracer's start cells, against the same DEM fractions (err/floor): what any "
          "Markov chain on these cells at this lag can reach (1 where the cells are Markov); "
          "DEM itself: the tracer over the first half against the tracer over the second "
          "(err/floor), the run's own window-to-window difference; the last two: the "
          "network's error over axialmix.dem.repeat_floor of the two windows, and of this "
          "run and the independent runs (--others, every pair), the floors that hold what "
          "the whole bed shares")
    return found


def own_chain_error(cells, n, per_layer, lag, starts, delays, spread) -> float:
    """Error over the noise floor of the second half's own empirical chain ``T(lag)^k``
    (NaN where a delay is not a whole number of lags)."""
    from axialmix.dem import count_matrix

    if any(d % lag for d in delays):
        return float("nan")
    counts = count_matrix(cells[starts[0]:], n, lag)
    transition = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
    p0 = np.zeros(n)
    for s0 in starts:
        members = cells[s0] // per_layer == 0
        p0 += np.bincount(cells[s0][members], minlength=n) / members.sum()
    p0 /= len(starts)
    errors = [np.abs(spread.dem[k] - (p0 @ np.linalg.matrix_power(transition, d // lag))
                     .reshape(-1, per_layer).sum(axis=1)).mean()
              for k, d in enumerate(delays)]
    return float(np.mean(errors) / spread.floor.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="600 spheres, runs of 1-1.5 s")
    parser.add_argument("--out", default=None, help="write results.json here")
    parser.add_argument("--section", default=None, metavar="RUN", help="analyse a section run")
    parser.add_argument("--lags", default="0.05,0.25,0.5,1.0",
                        help="with --section: lags of the learned networks, s (comma-separated)")
    parser.add_argument("--delays", default="1,2,4",
                        help="with --section: tracer delays compared, s (comma-separated)")
    parser.add_argument("--estimator", default="logm",
                        choices=("logm", "likelihood", "stationary"),
                        help="with --section: how rates are estimated from the counts")
    parser.add_argument("--others", default="", metavar="RUN[,RUN...]",
                        help="independent runs of the same section (other seeds): the noise "
                             "floor of independent runs")
    parser.add_argument("--bootstrap", type=int, default=200,
                        help="bootstrap replicates of each network (0: no intervals)")
    parser.add_argument("--layouts", default="12x1,24x1,24x1x4,48x1x4",
                        help="with --section: cells as AxR or AxRxS: axial layers x equal-area "
                             "rings x angular sectors of equal occupancy (comma-separated)")
    parser.add_argument("--pool", action="store_true",
                        help="with --section and --others: learn each network on the first "
                             "halves of all the runs together (their second halves unseen)")
    parser.add_argument("--every-run", action="store_true",
                        help="with --section and --others: each run in turn is the section "
                             "(learned on its first half, judged on its second against the "
                             "others), and the errors pooled over the runs")
    args = parser.parse_args()
    if args.section:
        options = (tuple(float(x) for x in args.lags.split(",")),
                   tuple(float(x) for x in args.delays.split(",")), args.estimator,
                   tuple(tuple(int(v) for v in x.split("x")) for x in args.layouts.split(",")))
        runs = [args.section] + [x for x in args.others.split(",") if x]
        if (args.every_run or args.pool) and len(runs) < 2:
            raise SystemExit("--every-run and --pool need --others")
        rounds = range(len(runs)) if args.every_run else range(1)
        found = [section(runs[i], *options, tuple(runs[:i] + runs[i + 1:]), args.bootstrap,
                         args.pool)
                 for i in rounds]
        if args.every_run:
            # Each run learned on its first half and judged on its second against the floor
            # of the independent runs: the mean error over the runs over their mean floor.
            print("\npooled over the runs (each the section in turn): network error / floor of "
                  "independent runs, per run and pooled")
            for key in found[0]:
                per_run = [f[key][0] / f[key][1] for f in found if key in f]
                pooled = (np.mean([f[key][0] for f in found if key in f])
                          / np.mean([f[key][1] for f in found if key in f]))
                print(f"{'x'.join(map(str, key[0])):10s} lag {key[1]:5.2f} s: "
                      + " ".join(f"{x:5.2f}" for x in per_run) + f"   pooled {pooled:5.2f}")
            # The same tracers predicted by no network: the mean of the other runs' tracers
            # (the best data from other runs give; sqrt(1 + 1/m) times an exact prediction's
            # error for m other runs). It depends on the axial cells only.
            m = len(runs) - 1
            print(f"no network, the mean tracer of the {m} other runs / floor of independent "
                  f"runs (expected {np.sqrt(1 + 1 / m):.2f} for runs of equal noise):")
            for axial in dict.fromkeys(key[0][0] for key in found[0]):
                key = next(k for k in found[0] if k[0][0] == axial)
                per_run = [f[key][2] / f[key][1] for f in found if key in f]
                pooled = (np.mean([f[key][2] for f in found if key in f])
                          / np.mean([f[key][1] for f in found if key in f]))
                print(f"{axial:3d} axial cells:        " + " ".join(f"{x:5.2f}" for x in per_run)
                      + f"   pooled {pooled:5.2f}")
        return
    if args.quick:
        mixer = BladedMixer(particles=(300, 300), diameter=0.0082)
        learn_s, ref_s = 1.5, 1.0
    else:
        mixer = BladedMixer(particles=(1500, 1500), diameter=0.0082)
        learn_s, ref_s = 3.0, 6.0
    learn_settings = RunSettings(duration=learn_s, record_interval=0.05, settle_time=0.5, seed=11)
    ref_settings = RunSettings(duration=ref_s, record_interval=0.05, settle_time=0.5, seed=12)
    clock = time.time()
    learning = run_dem(mixer, learn_settings)
    print(f"learning run: {learning.n_particles} spheres, {learn_s} s, dt {learning.time_step:.3g}"
          f" s, CPU {learning.cpu_seconds:.1f} s", flush=True)
    part1 = flux_partition(learning, N_REGIONS, interval=0.25)
    part2 = velocity_partition(learning, N_REGIONS)
    print(part1.table())
    print(part2.table(), flush=True)
    cells = axial_cells(learning.positions[:, :, 2], mixer.length, N_REGIONS)
    lag = 2
    learned = learn_network(cells, N_REGIONS, learning.frame_interval, lag,
                            block_frames=round(0.5 / learning.frame_interval),
                            centres=(np.arange(N_REGIONS) + 0.5) * mixer.length / N_REGIONS)
    reference = run_dem(mixer, ref_settings)
    print(f"reference full DEM: CPU {reference.cpu_seconds:.1f} s", flush=True)
    ref_counts = region_counts(reference, N_REGIONS)
    floor = dem_noise_floor(reference, N_REGIONS)
    print(f"DEM noise floor (two equivalent halves, end of run): {floor.average:.2f} %")

    def hybrid(n_dem, interval, label):
        settings = RunSettings(duration=ref_s, record_interval=0.05 if interval <= 0.05
                               else interval, settle_time=0.5, seed=13)
        run = run_hybrid(mixer, learned, ref_counts[0], n_dem, settings,
                         exchange_interval=interval, seed=n_dem)
        errors = composition_errors(ref_counts[-1], run.counts[-1])
        share = n_dem / N_REGIONS
        total = run.dem_cpu_seconds + run.compartment_cpu_seconds
        print(f"{label}: DEM regions 1-{n_dem} ({share:.0%}), exchange {interval} s: error "
              f"{errors.average:.2f} %, DEM CPU {run.dem_cpu_seconds:.1f} s, compartment CPU "
              f"{run.compartment_cpu_seconds:.2f} s ({run.compartment_share:.1%}), saving "
              f"{1 - total / reference.cpu_seconds:.0%}", flush=True)
        return run, errors

    results = {"mixer": {"particles": list(mixer.particles), "diameter_m": mixer.diameter,
                         "rpm": mixer.rpm}, "reference_cpu_s": reference.cpu_seconds,
               "noise_floor_percent": floor.average, "noise_floor_table": floor.relative.tolist(),
               "partition_flux": list(part1.dem_regions),
               "partition_velocity": list(part2.dem_regions), "runs": []}
    for method, part, source in (("I (flux)", part1, SOURCE_7_5),
                                 ("II (velocity)", part2, SOURCE_7_6)):
        n_dem = max(1, min(N_REGIONS - 1, max(part.dem_regions) + 1))
        run, errors = hybrid(n_dem, 0.1, f"method {method}")
        print("\nregion  ours species0/species1 (%)   source red/blue or blue/red (%)   "
              "floor (%)")
        for i in range(N_REGIONS):
            ours = errors.relative[i]
            print(f"{i + 1:6d}  {ours[0]:8.2f} {ours[1]:8.2f}        {source[i][0]:8.2f} "
                  f"{source[i][1]:8.2f}        {floor.relative[i, 0]:6.2f} "
                  f"{floor.relative[i, 1]:6.2f}")
        print(f"average {errors.average:.2f} % (source {np.mean(source):.2f} %); "
              f"sigma_j² {errors.variance.round(1).tolist()}\n", flush=True)
        results["runs"].append({"method": method, "n_dem": n_dem, "interval_s": 0.1,
                                "error_percent": errors.average,
                                "table": errors.relative.tolist(),
                                "dem_cpu_s": run.dem_cpu_seconds,
                                "compartment_cpu_s": run.compartment_cpu_seconds})
    print("DEM share x exchange interval (like the source's Tables 7.7 and 7.8):")
    for n_dem in (3, 4, 6):
        for interval in (0.05, 0.2):
            run, errors = hybrid(n_dem, interval, "share")
            results["runs"].append({"method": "share", "n_dem": n_dem, "interval_s": interval,
                                    "error_percent": errors.average,
                                    "dem_cpu_s": run.dem_cpu_seconds,
                                    "compartment_cpu_s": run.compartment_cpu_seconds})
    print(f"total wall time {time.time() - clock:.0f} s")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        Path(args.out, "results.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
