"""One long curve fitted by the closed–closed ADM: seconds, peak memory and the fitted values.

Curves of 10^4, 10^5 and 10^6 samples, uniform over 0 to 100 s, of the exact closed–closed E
with tau 20 s and Pe 10 plus noise (1 % of the peak additive and 2 % of the curve
proportional), written as CSV files and fitted as ``axialmix fit FILE --model adm`` fits them
(raw values read by :func:`fitting.data.read_rtd_csv`, the measurement model ``A E(t)``,
combined errors, the lack-of-fit verdict), each in a fresh process that reports its own peak
resident memory (``resource.getrusage``). Each curve is fitted twice with one compilation
cache folder: the first process compiles (its compile seconds are shown), the second loads
the compiled program, as a second ``axialmix fit`` would; the table shows the second.
The 'adm' model evaluates curves of 16,384 points or more on Chebyshev panels of exact
values (:mod:`axialmix.analytic.panels`); the last columns are its check at the fitted
values against the exact E on every point (largest deviation over the peak) and the seconds
that exact evaluation took. For scale, ``python -c "import jax"`` is timed in the same run.

    python benchmarks/long_curve.py [--sizes 10000 100000 1000000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TAU, PECLET = 20.0, 10.0

ROW = r"""
import json, resource, sys, time
began = time.perf_counter()
from fitting.data import read_rtd_csv
from fitting.fit import fit
from fitting.measurement import Inlet, measured
from fitting.solve import MultiStart, enable_compilation_cache
enable_compilation_cache()
imported = time.perf_counter()
curve = read_rtd_csv(%(path)r, normalise=False)
read = time.perf_counter()
model = measured("adm", Inlet.pulse(), ())
result = fit(model, curve, errors="combined", multistart=MultiStart(n_starts=None))
fitted = time.perf_counter()
verdict = result.lack_of_fit
judged = time.perf_counter()
rss_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
check = model.base.long_curve_check(curve.time - result.values["dead_time"], result.values)
checked = time.perf_counter()
print(json.dumps({
    "imports": imported - began, "read": read - imported, "fit": fitted - read,
    "compile": result.compile_time, "lack_of_fit": judged - fitted,
    "total": judged - began, "rss_kb": rss_kb,
    "tau": result.values["tau"], "tau_se": result.stderr["tau"],
    "peclet": result.values["peclet"], "peclet_se": result.stderr["peclet"],
    "systematic": verdict.systematic,
    "check": check[0] / check[1], "check_seconds": checked - judged,
}))
"""

IMPORT_JAX = r"""
import json, resource, time
began = time.perf_counter()
import jax
print(json.dumps({"seconds": time.perf_counter() - began,
                  "rss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""


def write_curve(path: Path, samples: int, seed: int) -> None:
    """A noisy closed–closed ADM curve of `samples` points over 0 to 100 s as CSV."""
    from axialmix.analytic import exit_age_closed

    t = np.linspace(0.0, 100.0, samples)
    e = np.asarray(exit_age_closed(t, TAU, PECLET))
    rng = np.random.default_rng(seed)
    y = e + 0.01 * e.max() * rng.standard_normal(samples) + 0.02 * e * rng.standard_normal(samples)
    np.savetxt(path, np.column_stack([t, y]), delimiter=",", header="time_s,value",
               comments="", fmt="%.10g")


def run(code: str, cache: str) -> dict:
    """Run `code` in a fresh Python with the compilation cache in `cache`; its JSON line and
    the process's wall seconds."""
    environment = {**os.environ, "XDG_CACHE_HOME": cache}
    environment.pop("AXIALMIX_COMPILATION_CACHE", None)
    began = time.perf_counter()
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=environment, check=True).stdout
    row = json.loads(output.strip().splitlines()[-1])
    row["wall"] = time.perf_counter() - began
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    args = parser.parse_args()
    print(f"{os.cpu_count()} CPUs; load average before: {os.getloadavg()[0]:.2f}", flush=True)
    with tempfile.TemporaryDirectory() as cache:
        scale = run(IMPORT_JAX, cache)
    print(f'python -c "import jax": {scale["wall"]:.2f} s wall (import {scale["seconds"]:.2f} s), '
          f'peak RSS {scale["rss_kb"] / 1024:.0f} MB\n', flush=True)
    header = (f"{'samples':>9}{'compile s':>10}{'process s':>10}{'read s':>7}{'fit s':>7}"
              f"{'verdict s':>10}{'peak RSS MB':>12}{'tau (s)':>28}{'Pe':>26}"
              f"{'check':>8}{'check s':>8}")
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory() as folder:
        for index, samples in enumerate(args.sizes):
            path = Path(folder) / f"curve{samples}.csv"
            write_curve(path, samples, 1 + index)
            with tempfile.TemporaryDirectory() as cache:
                cold = run(ROW % {"path": str(path)}, cache)
                warm = run(ROW % {"path": str(path)}, cache)
            tau = (f"{warm['tau']:.5f} ± {warm['tau_se']:.1e} "
                   f"({(warm['tau'] - TAU) / warm['tau_se']:+.1f})")
            peclet = (f"{warm['peclet']:.4f} ± {warm['peclet_se']:.1e} "
                      f"({(warm['peclet'] - PECLET) / warm['peclet_se']:+.1f})")
            check = f"{warm['check']:.0e}"
            print(f"{samples:>9}{cold['compile']:>10.1f}{warm['wall']:>10.1f}"
                  f"{warm['read']:>7.2f}{warm['fit']:>7.2f}{warm['lack_of_fit']:>10.2f}"
                  f"{warm['rss_kb'] / 1024:>12.0f}{tau:>28}{peclet:>26}{check:>8}"
                  f"{warm['check_seconds']:>8.2f}", flush=True)
    print("\ncompile s: the first process's compilation (the others load it); process s: the "
          "second process's wall time, start to end; fit s: the fit itself (the program loaded "
          "from the cache); verdict s: the lack-of-fit tests; peak RSS: of the second process, "
          "before the check; tau and Pe: fitted value ± standard error (error against the "
          "truth, tau 20 s and Pe 10, in standard errors); check: the panels' largest "
          "deviation from the exact E over the peak, on every point at the fitted values "
          "(curves are padded to a power of two, so all three are fitted on panels); check "
          "s: that exact evaluation.")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
