"""Studies on Dask: a two-worker cluster gives the summary of the one-process run."""

from __future__ import annotations

import csv
import json
import logging
import subprocess
import sys

import numpy as np
import pytest

from axialmix.analytic.closed import exit_age_closed
from fitting.data import Curve
from fitting.study.batch import StudyPlan, StudyRun
from fitting.study.ensemble import Ensemble, run_ensemble
from fitting.study.input import Study

distributed = pytest.importorskip("distributed")


def _study(count: int, seed: int) -> Study:
    """Noisy closed-closed ADM curves of 17-30 samples (one padded length: one program)."""
    rng = np.random.default_rng(seed)
    curves = []
    for i in range(count):
        tau, peclet, size = rng.uniform(20, 90), rng.uniform(8, 80), int(rng.integers(17, 31))
        t = np.linspace(0.0, 3.0 * tau, size)
        theta = np.r_[t / tau, 3.0 + np.arange(1, 33 - size)]  # one grid length: one compile
        exact = np.asarray(exit_age_closed(theta, 1.0, peclet))[:size] / tau
        noisy = exact * (1 + 0.02 * rng.standard_normal(size))
        curves.append(Curve(f"d{i}", t, noisy, time_unit="s", source="synthetic"))
    levels = tuple((("low", "high")[i % 2],) for i in range(count))
    return Study(tuple(curves), ("speed",), levels, tuple(None for _ in curves), "synthetic")


#: Two outflow rates, two seeds: a particle ensemble small enough for the default suite.
ENSEMBLE = Ensemble(settings=((("k_out", 1.0),), (("k_out", 2.0),)), seeds=(1, 2),
                    particles=2_000, tracer=400, steps=1_200, bin_steps=40)


def _without_wall_time(path) -> list[list[str]]:
    with open(path, newline="") as stream:
        rows = list(csv.reader(stream))
    keep = [i for i, name in enumerate(rows[0]) if name != "wall_time_s"]
    return [[row[i] for i in keep] for row in rows]


def test_two_worker_cluster_gives_the_one_process_summary(tmp_path):
    study = _study(4, seed=3)
    plan = StudyPlan("adm", length_m=0.5)
    alone = StudyRun(plan, study, tmp_path / "alone", chunk=2)
    alone.run(progress=False)
    # Two single-threaded workers in this process (a cluster of processes takes ~10 s to
    # start here; the study-marked test below runs one through the command line).
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        spread = StudyRun(plan, study, tmp_path / "dask", chunk=2)
        assert spread.run(scheduler=cluster.scheduler_address, progress=False) == len(study)
        simulated = run_ensemble(ENSEMBLE, chunk=1, scheduler=cluster.scheduler_address)
    # Particle ensembles take the same path: each run depends on its setting and seed only.
    local = run_ensemble(ENSEMBLE, chunk=3)
    assert simulated.ids == local.ids == ("s0-seed1", "s0-seed2", "s1-seed1", "s1-seed2")
    assert simulated.levels == local.levels == (("1.0", "1"), ("1.0", "2"), ("2.0", "1"),
                                                ("2.0", "2"))
    for a, b in zip(simulated.curves, local.curves, strict=True):
        np.testing.assert_array_equal(a.value, b.value)
        np.testing.assert_array_equal(a.time, b.time)
    assert not np.array_equal(local.curves[0].value, local.curves[1].value)  # seeds differ
    assert _without_wall_time(tmp_path / "dask" / "summary.csv") == _without_wall_time(
        tmp_path / "alone" / "summary.csv")
    one = json.loads((tmp_path / "alone" / "summary.json").read_text())["curves"]
    two = json.loads((tmp_path / "dask" / "summary.json").read_text())["curves"]
    assert [c["curve"] for c in two] == list(study.ids)
    assert [c["parameters"] for c in two] == [c["parameters"] for c in one]
    assert [c["physical"] for c in two] == [c["physical"] for c in one]


@pytest.mark.study
def test_command_line_on_two_worker_processes_equals_one_process(tmp_path):
    study = _study(40, seed=11)
    lines = ["run,speed,t,c"]
    for curve, (speed,) in zip(study.curves, study.levels, strict=True):
        lines += [f"{curve.name},{speed},{float(t)!r},{float(c)!r}"
                  for t, c in zip(curve.time, curve.value, strict=True)]
    path = tmp_path / "study.csv"
    path.write_text("\n".join(lines) + "\n")
    command = [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())",
               "fit", str(path), "--curve-column", "run", "--length", "0.5", "--chunk", "8"]
    one = subprocess.run([*command, "--out", str(tmp_path / "one")], capture_output=True,
                         text=True)
    two = subprocess.run([*command, "--workers", "2", "--out", str(tmp_path / "two")],
                         capture_output=True, text=True)
    assert one.returncode == 0, one.stderr
    assert two.returncode == 0, two.stderr
    assert _without_wall_time(tmp_path / "two" / "summary.csv") == _without_wall_time(
        tmp_path / "one" / "summary.csv")
    print(f"{len(study)} curves: --workers 2 summary equals the one-process summary")


@pytest.mark.study
def test_local_cluster_workers_run_jax_on_one_thread():
    # Each worker fits one chunk at a time; a second compute thread of JAX's CPU runtime
    # would spin on the core the other worker needs (see WORKER_ENVIRONMENT).
    import os

    from fitting.study.batch import WORKER_ENVIRONMENT, local_cluster

    with local_cluster(2) as cluster, distributed.Client(cluster) as client:
        seen = client.run(lambda: os.environ.get("PJRT_NPROC"))
    assert WORKER_ENVIRONMENT == {"PJRT_NPROC": "1"}
    assert list(seen.values()) == ["1", "1"]
