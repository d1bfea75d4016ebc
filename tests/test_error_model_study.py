"""Coverage studies of the error models (opt-in: ``pytest --studies``; minutes each).

* The shipped examples' design with the default (combined) error model: each example curve is
  fitted, its fitted curve is taken as the truth, and 40 copies per example (200 in all) with
  additive noise of 1 % of the peak plus 5 % proportional noise are fitted again.
* The command line with ``--errors relative``: 200 raw curves (exact closed-closed ADM, tau
  40 s, Pe 8, amplitude 3.7) with 3 % multiplicative noise, 20 samples with the tail cut at
  2 tau, each written as a CSV file and fitted by ``axialmix fit`` in this process.

With 200 repetitions the binomial standard deviation of a 95 % share is 1.5 %, so 90-99 % is
about three standard deviations either side.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed
from fitting.cli import main
from fitting.data import Curve, read_rtd_csv
from fitting.fit import fit, fit_many
from fitting.measurement import measured

pytestmark = pytest.mark.study

EXAMPLES = Path(__file__).parents[1] / "examples" / "data"


def test_examples_with_the_default_error_model_converge_and_cover_90_to_99_percent():
    model = measured("adm")
    rng = np.random.default_rng(7)
    hits = {"tau": 0, "peclet": 0}
    results = []
    for path in sorted(EXAMPLES.glob("*.csv")):
        curve = read_rtd_csv(path, normalise=False)
        base = fit(model, curve, errors="combined")
        assert base.converged, path.stem
        assert all(np.all(np.isfinite(base.ci95[n])) for n in base.free_names), path.stem
        truth = base.predicted
        noise = np.hypot(0.01 * truth.max(), 0.05 * truth)
        copies = [Curve(f"{path.stem}-{i}", curve.time,
                        truth + noise * rng.standard_normal(truth.size)) for i in range(40)]
        for result in fit_many(model, copies, errors="combined"):
            results.append(result)
            for name in hits:
                low, high = result.ci95[name]
                hits[name] += low <= base.values[name] <= high
    assert len(results) == 200
    assert all(r.converged for r in results)
    assert all(np.all(np.isfinite(r.ci95[n])) for r in results for n in r.free_names)
    shares = {name: count / len(results) for name, count in hits.items()}
    print(f"examples, combined errors: coverage tau {100 * shares['tau']:.1f} %, "
          f"Pe {100 * shares['peclet']:.1f} %")
    for name, share in shares.items():
        assert 0.90 <= share <= 0.99, f"{name} covered in {100 * share:.1f} % of fits"


def test_relative_errors_through_the_command_cover_90_to_99_percent(tmp_path):
    tau, peclet, amplitude = 40.0, 8.0, 3.7
    time = np.linspace(2 * tau / 20, 2 * tau, 20)
    exact = amplitude * np.asarray(exit_age_closed(time, tau, peclet))
    rng = np.random.default_rng(2024)
    hits = {"tau": 0, "peclet": 0}
    converged = 0
    for i in range(200):
        values = exact * (1 + 0.03 * rng.standard_normal(time.size))
        path = tmp_path / "curve.csv"
        path.write_text("time_s,concentration\n" + "".join(
            f"{t:.17g},{v:.17g}\n" for t, v in zip(time, values, strict=True)))
        out = tmp_path / f"out{i}"
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert main(["fit", str(path), "--errors", "relative", "--out", str(out)]) == 0
        record = json.loads((out / "curve.json").read_text())
        converged += record["converged"]
        for name, truth in (("tau", tau), ("peclet", peclet)):
            low, high = record["parameters"][name]["ci95"]
            hits[name] += low <= truth <= high
    print(f"command line, relative errors: converged {converged}/200, coverage tau "
          f"{hits['tau'] / 2:.1f} %, Pe {hits['peclet'] / 2:.1f} %")
    assert converged == 200
    for name, count in hits.items():
        assert 180 <= count <= 198, f"{name} covered in {count / 2:.1f} % of fits"
