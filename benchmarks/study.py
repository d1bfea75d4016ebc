"""A study of many synthetic curves: throughput and accuracy against lmfit and scipy loops.

Curves: the closed–closed ADM (exact, :func:`axialmix.analytic.closed.exit_age_closed`) with
tau log-uniform over 7–225 s and Pe log-uniform over 8–137 (the ranges of MODELS.md section 1),
amplitude 1, 15–60 samples each (uniform count) evenly spread over 0–3 tau, and Gaussian noise
of standard deviation 2 % of the curve's peak. Each is fitted as ``axialmix fit`` fits a
study (:class:`fitting.study.batch.StudyRun`: measurement model A E(t), combined error model,
the records and summary written to a temporary folder):

* in one process, timed after the solver programs have been compiled (a warm-up chunk comes
  first: curves of every padded length, and 256 curves drawn apart from the study's, among
  them some the engine hands to the multi-start solver's path): as ``axialmix fit`` runs it
  (one thread, which starts each chunk's compiled fits before it writes the records of the
  chunk before, :func:`fitting.study.batch.default_threads`) and on two threads, each
  fitting and writing chunks of its own, with the same records; once more with absolute
  errors (one unweighted fit a curve, the peers' error model), with and without the
  per-curve record files; and without the per-curve record files (``--no-curve-files``: the
  journal and summaries hold every record); the CPU cores the first run kept busy (CPU time
  over wall time) bound what more processes can add;
* ``fitting.fit.fit_many`` on the first ``--subset`` curves in one call, as a Python user
  fits many curves and as the peers do (values and intervals, no records or files), with the
  combined error model and with absolute errors, timed after a warm-up call;
* on a local Dask cluster of two worker processes
  (:func:`fitting.study.batch.local_cluster`, as ``axialmix fit --workers 2`` makes), timed
  after each worker has fitted the warm-up chunk (the cluster's start is shown apart);
* the peers, on the first ``--subset`` curves: a loop of ``scipy.optimize.curve_fit``, a
  loop of ``lmfit`` (least squares, ``leastsq``), and the scipy loop shared out over a
  ``joblib`` pool of ``--workers`` processes (what a user would try next; timed after each
  process has fitted a warm-up curve, the pool's start shown apart), all on the same model
  ``A E(t)``, E the NumPy Bromwich integral of ``benchmarks/startup.py``'s peer (independent
  of JAX), started from the moment estimates; their intervals are
  ``value ± t(0.975, n - 3) × standard error``.

Before anything is timed, the peers' E is compared with the exact E
(:func:`axialmix.analytic.closed.exit_age_closed`) at the true tau and Pe on every curve of
the study; if it is off by more than 1e-8 of the curve's peak anywhere, the benchmark stops.

The table gives curves per second and the ratio to the one-process run, the median and
95th-percentile relative errors of tau and Pe, and interval coverage (share of curves whose
95 % interval holds the true value); the last lines give the ratios the targets are stated
in, for each of our ways. Run with ``nice``: it loads every core it is given. The studies
write their output folders (temporary) into the current folder, as ``axialmix fit --out``
would.

    python benchmarks/study.py [--curves 10000] [--dask-curves N] [--subset 2000] [--chunk 64]
                               [--workers 2]
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# The sibling script benchmarks/fitting.py would shadow the `fitting` package (here and in
# the Dask workers, which inherit sys.path).
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]

TAU_RANGE = (7.0, 225.0)
PECLET_RANGE = (8.0, 137.0)
SAMPLES = (15, 60)
NOISE = 0.02
#: Where the studies' output folders are made (temporary folders, removed afterwards): the
#: current folder, as a user's ``--out`` would be.
SCRATCH = os.getcwd()


def synthetic_study(count: int, seed: int):
    """The curves, true (tau, Pe) per curve, and the exact E at each curve's times."""
    from axialmix.analytic.closed import exit_age_closed
    from fitting.data import Curve
    from fitting.study.input import Study

    rng = np.random.default_rng(seed)
    tau = np.exp(rng.uniform(*np.log(TAU_RANGE), count))
    peclet = np.exp(rng.uniform(*np.log(PECLET_RANGE), count))
    sizes = rng.integers(SAMPLES[0], SAMPLES[1] + 1, count)
    curves, exact_values = [], []
    for i in range(count):
        t = np.linspace(0.0, 3.0 * tau[i], sizes[i])
        exact = np.asarray(exit_age_closed(t, tau[i], peclet[i]))
        noisy = exact + NOISE * exact.max() * rng.standard_normal(t.size)
        curves.append(Curve(f"c{i:05d}", t, noisy, time_unit="s"))
        exact_values.append(exact)
    study = Study(tuple(curves), (), tuple(() for _ in curves), tuple(None for _ in curves),
                  "synthetic")
    return study, tau, peclet, exact_values


def accuracy(tau, peclet, estimates, intervals) -> dict[str, float]:
    """Median and 95th-percentile relative errors, coverage of the 95 % intervals."""
    out = {}
    for k, (name, truth) in enumerate((("tau", tau), ("Pe", peclet))):
        value = estimates[:, k]
        error = np.abs(value / truth - 1.0)
        error = np.where(np.isfinite(error), error, np.inf)
        low, high = intervals[:, k, 0], intervals[:, k, 1]
        out[f"{name}_median"] = float(np.median(error))
        out[f"{name}_p95"] = float(np.quantile(error, 0.95))
        out[f"{name}_coverage"] = float(np.mean((low <= truth) & (truth <= high)))
    return out


def ours(study, records_of):
    """Estimates and intervals of tau and Pe from study records."""
    estimates, intervals = [], []
    for record in records_of:
        p = record["parameters"]
        estimates.append([p["tau"]["value"], p["peclet"]["value"]])
        intervals.append([p["tau"]["ci95"] or [np.nan, np.nan],
                          p["peclet"]["ci95"] or [np.nan, np.nan]])
    return np.array(estimates, float), np.array(intervals, float)


#: Curves of the warm-up drawn apart from the study's (another seed): enough that the few per
#: cent the engine hands to the multi-start solver's path are among them, so those programs
#: are compiled before the timing too.
WARM_UP_CURVES = 256
WARM_UP_SEED = 99991


def warm_curves(study):
    """The warm-up: one curve of each padded length class (16, 32, 64 samples) of the study,
    then :data:`WARM_UP_CURVES` other curves from the same ranges (not the study's)."""
    from fitting.solve import padded_length

    seen = {}
    for curve in study.curves:
        seen.setdefault(padded_length(len(curve)), curve)
    return list(seen.values()) + list(_warm_up_others())


@functools.lru_cache(maxsize=1)
def _warm_up_others() -> tuple:
    """The warm-up's curves drawn apart from the study's (made once: every run warms up)."""
    others, *_ = synthetic_study(WARM_UP_CURVES, WARM_UP_SEED)
    return others.curves


def run_one_process(plan, study, threads=None, curve_files=True):
    from fitting.study.batch import StudyRun, fit_chunk

    fit_chunk(plan, warm_curves(study))
    with tempfile.TemporaryDirectory(dir=SCRATCH) as folder:
        run = StudyRun(plan, study, folder, CHUNK, curve_files=curve_files)
        began, cpu = time.perf_counter(), time.process_time()
        run.run(progress=False, threads=threads)
        seconds = time.perf_counter() - began
        cores = (time.process_time() - cpu) / seconds
        records = list(run.records())
    run_one_process.cores = cores  # the CPU cores the run kept busy (CPU time over wall time)
    return seconds, records


def run_fit_many(plan, curves):
    """``fitting.fit.fit_many`` on the curves in one call, as a Python user fits many curves
    (the study's model, settings and error model; no records or files): seconds after a
    warm-up call, and each curve's tau and Pe with their 95 % intervals."""
    from fitting.fit import fit_many
    from fitting.solve import MultiStart
    from fitting.study.batch import plan_model

    options = dict(loss="sse", errors=plan.errors, multistart=MultiStart(n_starts=plan.starts))
    model, settings = plan_model(plan), dict(plan.parameters)
    fit_many(model, warm_curves(_Curves(curves)), settings, **options)
    began = time.perf_counter()
    results = fit_many(model, list(curves), settings, **options)
    seconds = time.perf_counter() - began
    estimates = np.array([[r.values["tau"], r.values["peclet"]] for r in results], float)
    intervals = np.array([[r.ci95["tau"] or (np.nan, np.nan),
                           r.ci95["peclet"] or (np.nan, np.nan)] for r in results], float)
    return seconds, estimates, intervals


class _Curves:
    """Curves as a study's ``curves`` (what :func:`warm_curves` reads)."""

    def __init__(self, curves):
        self.curves = tuple(curves)


def run_dask(plan, study, workers: int):
    from dask.distributed import Client

    from fitting.study.batch import StudyRun, fit_chunk, local_cluster

    began = time.perf_counter()
    cluster = local_cluster(workers)
    client = Client(cluster)
    warm = warm_curves(study)
    futures = [client.submit(fit_chunk, plan, warm, workers=[address], pure=False)
               for address in client.scheduler_info()["workers"]]
    client.gather(futures)
    startup = time.perf_counter() - began
    try:
        with tempfile.TemporaryDirectory(dir=SCRATCH) as folder:
            run = StudyRun(plan, study, folder, CHUNK)
            began = time.perf_counter()
            run.run(scheduler=cluster.scheduler_address, progress=False)
            seconds = time.perf_counter() - began
            records = list(run.records())
    finally:
        client.close()
        cluster.close()
    return startup, seconds, records


def startup_benchmark():
    """benchmarks/startup.py as a module (its peer model and the check of it)."""
    spec = importlib.util.spec_from_file_location("startup_benchmark", _HERE / "startup.py")
    startup = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(startup)
    return startup


def check_peers(study, tau, peclet, exact_values) -> None:
    """Every peer's E against the exact E at the true parameters of every curve (exits if off)."""
    startup = startup_benchmark()
    cases = [(curve.time, tau[i], peclet[i], exact_values[i])
             for i, curve in enumerate(study.curves)]
    startup.check_peer_model(startup.peer_model(), cases,
                             "peer model check (scipy, lmfit and pool peers)")


def moment_start(t, y):
    density = np.clip(y, 0, None)
    area = np.trapezoid(density, t)
    mean = np.trapezoid(t * density, t) / area
    variance = np.trapezoid((t - mean) ** 2 * density, t) / area
    ratio = variance / mean**2
    peclet = 2.0
    for _ in range(100):  # sigma^2/tau^2 = 2/Pe - 2/Pe^2 (1 - e^-Pe)
        peclet = 2 / ratio * (1 - (1 - np.exp(-peclet)) / peclet)
    return mean, min(max(peclet, 0.5), 1e4), area


_PEER_MODELS: dict = {}


def scipy_loop(curves, model_source: str):
    """``curve_fit`` of ``A E(t)`` on each ``(t, y)``: estimates and 95 % intervals of tau, Pe.

    The model is built from its source in the calling process (so that a pool's worker
    processes build it too), once per process.
    """
    from scipy import stats
    from scipy.optimize import curve_fit

    if model_source not in _PEER_MODELS:
        namespace: dict = {}
        exec(model_source, namespace)
        _PEER_MODELS[model_source] = namespace["exit_age"]
    exit_age = _PEER_MODELS[model_source]

    def model(t, tau, peclet, amplitude):
        return amplitude * exit_age(t, tau, peclet)

    estimates, intervals = [], []
    for t, y in curves:
        start = moment_start(t, y)
        try:
            values, covariance = curve_fit(model, t, y, p0=start,
                                           bounds=([1e-9, 1e-6, 1e-12], np.inf))
            errors = np.sqrt(np.diag(covariance))
        except (RuntimeError, ValueError):
            values, errors = np.full(3, np.nan), np.full(3, np.nan)
        half = stats.t.ppf(0.975, t.size - 3) * errors
        estimates.append(values[:2])
        intervals.append([[values[0] - half[0], values[0] + half[0]],
                          [values[1] - half[1], values[1] + half[1]]])
    return np.array(estimates).reshape(-1, 2), np.array(intervals).reshape(-1, 2, 2)


def run_scipy(study, subset: int):
    source = startup_benchmark().PEER_MODEL
    curves = [(c.time, c.value) for c in study.curves[:subset]]
    scipy_loop(curves[:1], source)  # the model built, scipy loaded
    began = time.perf_counter()
    estimates, intervals = scipy_loop(curves, source)
    return time.perf_counter() - began, estimates, intervals


def run_pool(study, subset: int, workers: int):
    """The scipy loop shared out over a joblib pool of `workers` processes (loky)."""
    from joblib import Parallel, delayed

    source = startup_benchmark().PEER_MODEL
    curves = [(c.time, c.value) for c in study.curves[:subset]]
    pieces = max(1, min(len(curves), 4 * workers))  # a few pieces per process: balance
    bounds = np.linspace(0, len(curves), pieces + 1).astype(int)
    with Parallel(n_jobs=workers, backend="loky") as pool:
        began = time.perf_counter()
        pool(delayed(scipy_loop)(curves[:1], source) for _ in range(2 * workers))
        startup = time.perf_counter() - began
        began = time.perf_counter()
        parts = pool(delayed(scipy_loop)(curves[a:b], source)
                     for a, b in zip(bounds[:-1], bounds[1:], strict=True))
        seconds = time.perf_counter() - began
    estimates = np.concatenate([p[0] for p in parts])
    intervals = np.concatenate([p[1] for p in parts])
    return startup, seconds, estimates, intervals


def run_lmfit(study, subset: int):
    import lmfit
    from scipy import stats

    exit_age = startup_benchmark().peer_model()

    def model(t, tau, peclet, amplitude):
        return amplitude * exit_age(t, tau, peclet)

    fitter = lmfit.Model(model)
    estimates, intervals = [], []
    began = time.perf_counter()
    for curve in study.curves[:subset]:
        t, y = curve.time, curve.value
        tau0, peclet0, area0 = moment_start(t, y)
        params = fitter.make_params(tau=dict(value=tau0, min=1e-9),
                                    peclet=dict(value=peclet0, min=1e-6),
                                    amplitude=dict(value=area0, min=1e-12))
        result = fitter.fit(y, params, t=t, method="leastsq")
        row, band = [], []
        for name in ("tau", "peclet"):
            value = result.params[name].value
            error = result.params[name].stderr
            half = stats.t.ppf(0.975, t.size - 3) * (error if error is not None else np.nan)
            row.append(value)
            band.append([value - half, value + half])
        estimates.append(row)
        intervals.append(band)
    return time.perf_counter() - began, np.array(estimates), np.array(intervals)


CHUNK = 64


def line(label, count, seconds, unit, figures) -> str:
    rate = count / seconds
    return (f"{label:<34}{count:>7}{seconds:>10.1f}{rate:>10.1f}{rate / unit:>9.2f}"
            f"{figures['tau_median']:>9.2%}{figures['tau_p95']:>9.2%}"
            f"{figures['Pe_median']:>9.2%}{figures['Pe_p95']:>9.2%}"
            f"{figures['tau_coverage']:>8.1%}{figures['Pe_coverage']:>8.1%}")


def main() -> None:
    global CHUNK
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--curves", type=int, default=10_000)
    parser.add_argument("--dask-curves", type=int, default=None,
                        help="curves for the Dask run (default: --curves)")
    parser.add_argument("--subset", type=int, default=2000,
                        help="curves for the peer loops (their 95th percentiles rest on the "
                             "worst 5 %%: 100 curves at the default)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--chunk", type=int, default=64)
    parser.add_argument("--seed", type=int, default=2024)
    args = parser.parse_args()
    CHUNK = args.chunk
    from fitting.solve import enable_compilation_cache
    from fitting.study.batch import StudyPlan

    enable_compilation_cache()
    print(f"{os.cpu_count()} CPUs; load average before: {os.getloadavg()[0]:.2f}", flush=True)
    study, tau, peclet, exact_values = synthetic_study(args.curves, args.seed)
    check_peers(study, tau, peclet, exact_values)  # before anything is timed
    plan = StudyPlan("adm")
    header = (f"{'method':<34}{'curves':>7}{'seconds':>10}{'curves/s':>10}{'ratio':>9}"
              f"{'tau med':>9}{'tau p95':>9}{'Pe med':>9}{'Pe p95':>9}{'cov tau':>8}"
              f"{'cov Pe':>8}")
    rows = []

    seconds, records = run_one_process(plan, study)
    figures = accuracy(tau, peclet, *ours(study, records))
    unit = args.curves / seconds
    rates = {"ours": unit}
    cores = run_one_process.cores
    rows.append(line("axialmix study, one process", args.curves, seconds, unit, figures))
    converged = np.mean([r["converged"] for r in records])
    print(rows[-1], f"(converged {converged:.1%})", flush=True)
    seconds, other = run_one_process(plan, study, threads=2)
    same = all(a["parameters"] == b["parameters"] for a, b in
               zip(records, other, strict=True))
    rates["two threads"] = args.curves / seconds
    rows.append(line("axialmix study, 2 threads", args.curves, seconds, unit,
                     accuracy(tau, peclet, *ours(study, other)))
                + f"  (parameters equal: {same})")
    print(rows[-1], flush=True)
    absolute = StudyPlan("adm", errors="absolute")
    for name, label, files, words in (
            ("absolute", "absolute errors", True, "the peers' error model"),
            ("absolute, no files", "absolute, no files", False,
             "the peers' error model, summary only")):
        seconds, plain = run_one_process(absolute, study, curve_files=files)
        rates[name] = args.curves / seconds
        rows.append(line(f"axialmix study, {label}", args.curves, seconds, unit,
                         accuracy(tau, peclet, *ours(study, plain))) + f"  ({words})")
        print(rows[-1], flush=True)

    seconds, bare = run_one_process(plan, study, curve_files=False)
    rates["no files"] = args.curves / seconds
    rows.append(line("axialmix study, no curve files", args.curves, seconds, unit,
                     accuracy(tau, peclet, *ours(study, bare)))
                + "  (--no-curve-files)")
    print(rows[-1], flush=True)

    subset = min(args.subset, args.curves)
    curves = study.curves[:subset]
    seconds, estimates, intervals = run_fit_many(plan, curves)
    rates["fit_many"] = subset / seconds
    rows.append(line(f"axialmix fit_many, same {subset}", subset, seconds, unit,
                     accuracy(tau[:subset], peclet[:subset], estimates, intervals))
                + "  (values and intervals, as the peers)")
    print(rows[-1], flush=True)
    seconds, estimates, intervals = run_fit_many(absolute, curves)
    rates["fit_many absolute"] = subset / seconds
    rows.append(line(f"axialmix fit_many, absolute, {subset}", subset, seconds, unit,
                     accuracy(tau[:subset], peclet[:subset], estimates, intervals))
                + "  (the peers' error model and outputs)")
    print(rows[-1], flush=True)

    seconds, estimates, intervals = run_scipy(study, subset)
    rates["scipy"] = subset / seconds
    rows.append(line("scipy curve_fit loop", subset, seconds, unit,
                     accuracy(tau[:subset], peclet[:subset], estimates, intervals)))
    print(rows[-1], flush=True)
    seconds, estimates, intervals = run_lmfit(study, subset)
    rows.append(line("lmfit loop (leastsq)", subset, seconds, unit,
                     accuracy(tau[:subset], peclet[:subset], estimates, intervals)))
    print(rows[-1], flush=True)
    startup, seconds, estimates, intervals = run_pool(study, subset, args.workers)
    rates["pool"] = subset / seconds
    rows.append(line(f"scipy loop, joblib {args.workers} processes", subset, seconds, unit,
                     accuracy(tau[:subset], peclet[:subset], estimates, intervals))
                + f"  (+{startup:.1f} s start)")
    print(rows[-1], flush=True)

    count = args.dask_curves or args.curves
    part = study if count == args.curves else type(study)(
        study.curves[:count], (), study.levels[:count], study.inlets[:count], "synthetic")
    startup, seconds, dask_records = run_dask(plan, part, args.workers)
    rates["dask"] = count / seconds
    same = all(a["parameters"] == b["parameters"] for a, b in
               zip(records[:count], dask_records, strict=True))
    rows.append(line(f"axialmix study, Dask {args.workers} workers", count, seconds, unit,
                     accuracy(tau[:count], peclet[:count], *ours(part, dask_records)))
                + f"  (+{startup:.1f} s start; parameters equal: {same})")
    print(rows[-1], flush=True)

    print()
    print(f"{args.curves} closed-closed ADM curves, tau {TAU_RANGE[0]:g}-{TAU_RANGE[1]:g} s, "
          f"Pe {PECLET_RANGE[0]:g}-{PECLET_RANGE[1]:g}, {SAMPLES[0]}-{SAMPLES[1]} samples, "
          f"noise {NOISE:.0%} of the peak; ratio: curves/s over the one-process run")
    print(header)
    print("-" * len(header))
    print("\n".join(rows))
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    for name, label in (("ours", "study run (records and files)"),
                        ("no files", "study run without curve files"),
                        ("absolute", "study run, the peers' error model"),
                        ("absolute, no files", "  the same without curve files"),
                        ("fit_many", "fit_many, combined errors"),
                        ("fit_many absolute", "fit_many, the peers' error model")):
        print(f"{label:<38} {rates[name]:7.1f} curves/s: {rates[name] / rates['scipy']:5.2f} x "
              f"the scipy loop, {rates[name] / rates['pool']:5.2f} x the {args.workers}-process "
              "pool")
    print(f"Dask {args.workers} workers {rates['dask'] / rates['ours']:.2f} x one process "
          f"(the one-process run kept {cores:.2f} of {os.cpu_count()} CPU cores busy: "
          f"{os.cpu_count() / cores:.2f} x is the most more processes can add)")


if __name__ == "__main__":
    main()
