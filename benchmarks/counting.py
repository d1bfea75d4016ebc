"""Counting statistics on the simulator's own histograms: false alarms and coverage.

``axialmix simulate continuous --rtd-csv`` writes the histogram of a tracer pulse leaving
the four-compartment particle blender (nominal k_f = k_r = 2.125 1/s, k_s = 0.625 1/s,
k_out = 1 1/s, steps of 0.01 s; its whole-particle moves make the rates it runs slightly
different, see :func:`simulated_truth`; tau = 6.25 s); ``axialmix fit`` reads its counts and
fits them with counting (Poisson) errors. This script runs both through the command line, the
path users take, for many seeds, and prints

* the false-alarm rate of the lack-of-fit verdict (the particle model is the network's
  stochastic version, so every alarm is false; three tests at 1 % each: about 3 % expected);
* the coverage of the 95 % intervals of each rate, of the amplitude (the tracer particles
  counted, printed by the simulator) and of the equivalent ADM's tau, variance and Pe (the
  network's mean residence time, 6.25 s, and its variance);
* the fit times.

The rates of one curve are known to be poorly identifiable (the fit's identifiability report
says so for each curve): their local (Gauss–Newton) intervals hold only near one optimum,
and the four-compartment model has twin optima (k_f and k_s exchanged when k_r = k_f). The
reported intervals hold the other optima the starts find, but not the valleys between them
that no start reached, so the rates' coverage measures that, not the error model; the
profile intervals follow the valleys. tau and the amplitude are determined by every curve.

Run: ``python benchmarks/counting.py --histograms 100 --work DIR`` (about 10 minutes on 2
cores; ``--histograms 10`` for a smoke run); ``--profile`` gives the rates profile-likelihood
intervals instead (``fit --profile k_f,k_r,k_s,k_out``; about 40 s a histogram). The
simulated files and fits stay in DIR.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import time
from pathlib import Path

# benchmarks/fitting.py would shadow the `fitting` package when this runs as a file.
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]



def simulated_truth() -> dict[str, float]:
    """What the simulator runs: the preset's moves per step are whole particles, so its rates
    are those of ``particle_four_compartment().to_network()`` (k_f 2.115, k_r 2.125, k_s
    0.626 to 0.668 by connection, k_out 0.971 1/s), averaged over the connections that share
    a name; its mean residence time is hold-up over throughput (6.25 s) and its variance that
    of the same network."""
    from axialmix.network import moment_matched_adm_from_moments, residence_time_moments
    from axialmix.particles import particle_four_compartment

    network = particle_four_compartment().to_network()
    step = network.time_step
    rate = {(c.source, c.target): c.rate / step for c in network.connections}
    moments = residence_time_moments(network)
    mean, variance = float(moments.mean), float(moments.variance)
    adm = moment_matched_adm_from_moments(mean, variance, None).as_dict()
    return {
        "k_f": (rate["C1", "C2"] + rate["C3", "C4"]) / 2,
        "k_r": (rate["C2", "C1"] + rate["C4", "C3"]) / 2,
        "k_s": sum(rate[pair] for pair in (("C1", "C3"), ("C3", "C1"), ("C2", "C4"),
                                            ("C4", "C2"))) / 4,
        "k_out": network.outlets[0].rate / step,
        "tau_s": mean, "variance_s2": variance, "peclet": float(adm["peclet"]),
    }


def _cli(arguments: list[str]) -> tuple[int, str]:
    from fitting.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            code = main(arguments)
        except SystemExit as stop:
            code = stop.code
    return int(code or 0), out.getvalue()


def simulate(work: Path, histograms: int) -> dict[str, int]:
    """The histograms ``h001.csv``..., one seed each; returns the tracer particles of each."""
    data = work / "histograms"
    data.mkdir(parents=True, exist_ok=True)
    tracers = {}
    for seed in range(1, histograms + 1):
        name = f"h{seed:03d}"
        path = data / f"{name}.csv"
        if not path.exists():
            code, text = _cli(["simulate", "continuous", "--rtd-csv", str(path), "--seed",
                               str(seed), "--quiet"])
            if code:
                raise SystemExit(f"simulate --seed {seed} failed ({code})")
        header = path.read_text().splitlines()[0]
        tracers[name] = int(header.split("tracer pulse of ")[1].split(" particles")[0])
        print(f"\rsimulated {seed} of {histograms}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return tracers


def fit(work: Path, profile: bool = False) -> tuple[list[dict], float]:
    """``axialmix fit`` of the folder (with ``--profile k_f,k_r,k_s,k_out`` if `profile`);
    the per-curve records and the wall time."""
    out = work / ("fits-profile" if profile else "fits")
    start = time.perf_counter()
    code, text = _cli(["fit", str(work / "histograms"), "--model", "four-compartment",
                       "--out", str(out)]
                      + (["--profile", "k_f,k_r,k_s,k_out"] if profile else []))
    wall = time.perf_counter() - start
    if code:
        raise SystemExit(f"fit failed ({code})")
    if "counting errors:" not in text:
        raise SystemExit("the fit did not choose counting errors by itself")
    records = [json.loads(p.read_text()) for p in sorted(out.glob("h*.json"))]
    return records, wall


def covered(interval, truth) -> bool:
    if interval is None:
        return False
    low, high = interval  # None: unbounded on that side (a factor of 1e20 or more)
    return (low is None or low <= truth) and (high is None or truth <= high)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--histograms", type=int, default=100)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--profile", action="store_true",
                        help="profile-likelihood intervals of the four rates (--profile)")
    args = parser.parse_args(argv)
    tracers = simulate(args.work, args.histograms)
    records, wall = fit(args.work, args.profile)
    n = len(records)
    if n != args.histograms:
        raise SystemExit(f"{n} fits for {args.histograms} histograms")
    alarms = sum(r["lack_of_fit"]["systematic"] for r in records)
    kinds = {r["error_model"]["kind"] for r in records}
    truth = simulated_truth()
    rows = []
    for name in ("k_f", "k_r", "k_s", "k_out"):
        hits = sum(covered(r["parameters"][name]["ci95"], truth[name]) for r in records)
        rows.append((name, truth[name], hits))
    hits = sum(covered(r["parameters"]["amplitude"]["ci95"], tracers[r["data"]])
               for r in records)
    rows.append(("amplitude", "tracer", hits))
    for name, key in (("tau", "tau_s"), ("variance", "variance_s2"), ("peclet", "peclet")):
        hit = sum(covered(r["physical"][key]["ci95"], truth[key]) for r in records)
        rows.append((name, float(truth[key]), hit))
    converged = sum(bool(r["converged"]) for r in records)
    dispersion = [r["error_model"]["proportional_sd"] for r in records]
    print(f"{n} simulated histograms (four-compartment particle blender, 0.01 s bins), "
          f"fitted by `axialmix fit FOLDER --model four-compartment"
          f"{' --profile k_f,k_r,k_s,k_out' if args.profile else ''}`: error model "
          f"{', '.join(sorted(kinds))}, {converged} converged, {wall:.0f} s in all "
          f"({wall / n:.2f} s a curve)")
    print(f"lack of fit flagged: {alarms} of {n} ({100 * alarms / n:.1f} %; every alarm is "
          "false here)")
    print(f"Pearson dispersion: median {statistics.median(dispersion):.3f} "
          f"(1 expected), range {min(dispersion):.3f} to {max(dispersion):.3f}")
    print(f"{'quantity':<10} {'truth':>8} {'95 % intervals covering':>24}")
    for name, truth, hit in rows:
        shown = f"{truth:g}" if isinstance(truth, float) else truth
        print(f"{name:<10} {shown:>8.6} {f'{hit} of {n} ({100 * hit / n:.0f} %)':>24}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
