"""The batched fit engine by chunk size: compile time, curves per second, and memory.

Curves as in ``benchmarks/study.py`` (closed–closed ADM, tau 7–225 s, Pe 8–137, 15–60 samples
over 0–3 tau, 2 % noise of the peak), fitted as a study fits them (measurement model
``A E(t)``, combined error model) by :func:`fitting.fit.fit_many`, with the engine's programs
holding 1, 64 or 1,024 curves (unused lanes idle). Each row is a fresh process with an empty
compilation cache, so its compile time is real; curves per second are timed after
compilation (a second pass over the same curves). The last row fits a long study through
``fitting.study.batch.StudyRun`` (records written to a temporary folder), at a tenth of its
size and at its size, and reports the resident memory when the run starts (the curves the
caller holds) and the process's peak: the run's own share, the peak above the start, is
bounded by the chunk, not the study.

    python benchmarks/engine.py [--curves 2000] [--study 100000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

_HERE = Path(__file__).resolve().parent

ROW = r"""
import json, os, sys, time, resource
sys.path[:] = [p for p in sys.path if os.path.abspath(p or '.') != os.path.abspath(%(here)r)]
sys.path.insert(0, %(here)r)
import numpy as np
import study as benchmark_study
sys.path.pop(0)
from fitting import engine
from fitting.fit import fit_many
from fitting.solve import MultiStart
from fitting.study.batch import StudyPlan, plan_model
chunk, count = %(chunk)d, %(count)d
engine.CHUNK["cpu"] = chunk
engine.CHUNK["gpu"] = chunk
study, tau, peclet, _ = benchmark_study.synthetic_study(count, 2024)
plan = StudyPlan("adm")
model = plan_model(plan)
options = dict(loss="sse", errors=plan.errors, multistart=MultiStart(n_starts=plan.starts))
began = time.perf_counter()
first = fit_many(model, list(study.curves), dict(plan.parameters), **options)
first_seconds = time.perf_counter() - began
compile_seconds = sum(r.compile_time for r in first)
began = time.perf_counter()
again = fit_many(model, list(study.curves), dict(plan.parameters), **options)
seconds = time.perf_counter() - began
same = all(a.values == b.values for a, b in zip(first, again))
print(json.dumps({"first": first_seconds, "compile": compile_seconds, "seconds": seconds,
                  "same": same, "rss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""

STUDY = r"""
import json, os, sys, time, tempfile, resource
sys.path[:] = [p for p in sys.path if os.path.abspath(p or '.') != os.path.abspath(%(here)r)]
sys.path.insert(0, %(here)r)
import study as benchmark_study
sys.path.pop(0)
from fitting.study.batch import StudyPlan, StudyRun
from fitting.solve import enable_compilation_cache
enable_compilation_cache()
study = benchmark_study.synthetic_study(%(count)d, 7)[0]  # the curves only (no exact values)


def resident_kb():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") // 1024


plan = StudyPlan("adm")
with tempfile.TemporaryDirectory(dir=os.getcwd()) as folder:  # a disk folder, as --out is
    run = StudyRun(plan, study, folder, 256)
    before = resident_kb()  # Python, JAX and the study's curves in memory
    began = time.perf_counter()
    run.run(progress=False)
    seconds = time.perf_counter() - began
print(json.dumps({"seconds": seconds, "before_kb": before,
                  "rss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
"""


def run(code: str, cache: str) -> dict:
    environment = {**os.environ, "XDG_CACHE_HOME": cache}
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=environment, check=True).stdout
    return json.loads(output.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--curves", type=int, default=2000)
    parser.add_argument("--study", type=int, default=100_000,
                        help="curves of the memory row (0: skip it)")
    args = parser.parse_args()
    print(f"{os.cpu_count()} CPUs; load average before: {os.getloadavg()[0]:.2f}", flush=True)
    header = (f"{'curves per program':>19}{'curves':>8}{'compile s':>11}{'first run s':>13}"
              f"{'curves/s':>10}{'peak RSS MB':>13}  repeatable")
    print(header)
    print("-" * len(header))
    for chunk in (1, 64, 1024):
        with tempfile.TemporaryDirectory() as cache:
            row = run(ROW % {"here": str(_HERE), "chunk": chunk, "count": args.curves}, cache)
        print(f"{chunk:>19}{args.curves:>8}{row['compile']:>11.1f}{row['first']:>13.1f}"
              f"{args.curves / row['seconds']:>10.1f}{row['rss_kb'] / 1024:>13.0f}  "
              f"{'yes' if row['same'] else 'NO'}", flush=True)
    if args.study:
        print("\nstudies through StudyRun (chunks of 256 curves), each in a fresh process; "
              "'before' is the resident memory when the run starts (Python, JAX and the "
              "study's curves, which the caller holds), 'run's own' the peak above it")
        print(f"{'curves':>8}{'seconds':>9}{'curves/s':>10}{'before MB':>11}{'peak RSS MB':>13}"
              f"{'run own MB':>12}")
        for count in (max(args.study // 10, 1), args.study):
            with tempfile.TemporaryDirectory() as cache:
                row = run(STUDY % {"here": str(_HERE), "count": count}, cache)
            print(f"{count:>8}{row['seconds']:>9.1f}{count / row['seconds']:>10.1f}"
                  f"{row['before_kb'] / 1024:>11.0f}{row['rss_kb'] / 1024:>13.0f}"
                  f"{(row['rss_kb'] - row['before_kb']) / 1024:>12.0f}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
