"""Model comparison: Gaussian criteria against an independent likelihood, the recommendation
(which model, and when the data cannot tell models apart), and ``axialmix fit --model a,b``."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from scipy import stats

from axialmix.analytic import exit_age_closed
from fitting.cli import main
from fitting.diagnostics import INDISTINGUISHABLE_AICC, compare_models
from fitting.fit import fit
from fitting.report import comparison_record, comparison_table

TAU, POINTS = 40.0, 60
TIME = np.linspace(0.0, 3.0 * TAU, POINTS)


def _noisy(values: np.ndarray, level: float, seed: int) -> np.ndarray:
    return values + level * values.max() * np.random.default_rng(seed).normal(size=values.size)


@pytest.fixture(scope="module")
def adm_curve():
    return TIME, _noisy(np.asarray(exit_age_closed(TIME, TAU, 8.0)), 0.02, 21)


def _gaussian_log_likelihood(result) -> float:
    """The log-likelihood with variances ``s² / w_i``, ``s²`` at its maximum, by scipy."""
    weights = np.asarray(result.weights)
    residuals = np.asarray(result.residuals)
    used = weights > 0
    scale = np.sum(weights[used] * residuals[used] ** 2) / used.sum()
    return float(np.sum(stats.norm.logpdf(residuals[used],
                                          scale=np.sqrt(scale / weights[used]))))


def test_criteria_are_the_gaussian_likelihood_with_the_fits_own_weights(adm_curve):
    plain = fit("adm", adm_curve)
    relative = fit("tanks", adm_curve, relative_errors=True)
    comparison = compare_models([plain, relative])
    for i, result in enumerate((plain, relative)):
        log_l = _gaussian_log_likelihood(result)
        k, n = len(result.free_names) + 1, result.n_points
        assert comparison.log_likelihood[i] == pytest.approx(log_l, rel=1e-12)
        assert comparison.aicc[i] == pytest.approx(-2 * log_l + 2 * k + 2 * k * (k + 1)
                                                   / (n - k - 1), rel=1e-12)
        assert comparison.bic[i] == pytest.approx(-2 * log_l + k * math.log(n), rel=1e-12)
    assert min(comparison.delta_aicc) == 0.0
    assert sum(comparison.akaike_weights) == pytest.approx(1.0)


def test_a_model_that_misses_the_curve_loses_to_the_one_that_describes_it(adm_curve):
    comparison = compare_models([fit("tanks", adm_curve), fit("adm", adm_curve)])
    assert comparison.systematic == (True, False)
    assert comparison.best == "adm" and comparison.indistinguishable == ()
    assert comparison.recommendation.startswith("adm is recommended")
    assert "tanks does not describe the curve" in comparison.recommendation
    table = comparison_table(comparison)
    assert "SYSTEMATIC" in table and "Recommendation: adm is recommended" in table
    # A 100-column terminal holds it; every parameter is still there, and --wide gives one
    # row a model.
    assert max(len(line) for line in table.splitlines()) <= 100
    assert "tau " in table and "peclet " in table and "n_tanks " in table
    wide = comparison_table(comparison, wide=True)
    assert "fitted parameters (value +/- std. error)" in wide and "SSE" in wide
    assert len(wide.splitlines()) == 4 + 2  # title, header, rule, recommendation
    record = json.loads(json.dumps(comparison_record(comparison)))
    assert [m["model"] for m in record["models"]] == ["tanks", "adm"]
    assert record["models"][0]["lack_of_fit"]["systematic"] is True


def test_the_data_cannot_tell_apart_models_that_both_describe_a_noisy_curve():
    # Pe 40 is close to 21 tanks: under 8 % noise the two shapes differ by about one unit of
    # AICc, so which is lower depends on the draw (this one: ΔAICc 0.7).
    curve = TIME, _noisy(np.asarray(exit_age_closed(TIME, TAU, 40.0)), 0.08, 2)
    comparison = compare_models([fit("adm", curve), fit("tanks", curve)])
    assert comparison.systematic == (False, False)
    assert max(comparison.delta_aicc) < INDISTINGUISHABLE_AICC
    assert comparison.indistinguishable
    assert comparison.recommendation.startswith("The data cannot tell")


def test_every_model_with_lack_of_fit_is_said_to_describe_nothing(adm_curve):
    time, values = adm_curve
    shifted = (time, values + 0.1 * values.max())
    comparison = compare_models([fit("adm", shifted), fit("tanks", shifted)])
    assert comparison.systematic == (True, True)
    assert comparison.recommendation.startswith("No model describes this curve")


def test_fits_of_different_curves_are_refused(adm_curve):
    time, values = adm_curve
    with pytest.raises(ValueError, match="same curve"):
        compare_models([fit("adm", adm_curve), fit("adm", (time, 1.01 * values))])
    with pytest.raises(ValueError, match="at least two"):
        compare_models([fit("adm", adm_curve)])


def _write_curve(path, time, values):
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["time_s", "E"])
        writer.writerows(zip(time, values, strict=True))


def test_command_line_compares_comma_separated_models_in_one_table(adm_curve, tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    _write_curve(data / "one.csv", *adm_curve)
    _write_curve(data / "two.csv", adm_curve[0], 1.2 * adm_curve[1])
    out = tmp_path / "out"
    status = main(["fit", str(data), "--model", "adm,tanks", "--fix", "n_tanks=5",
                   "--out", str(out)])
    printed = capsys.readouterr().out
    assert status == 0
    assert printed.count("Recommendation:") == 2 and "AICc" in printed
    for name in ("one", "two"):
        record = json.loads((out / f"{name}.comparison.json").read_text())
        assert [m["model"] for m in record["models"]] == ["adm", "tanks"]
        assert record["best"] == "adm" and record["recommendation"]
        assert [f["model"] for f in record["fits"]] == ["adm", "tanks"]
        tanks = json.loads((out / f"{name}.tanks.json").read_text())
        fixed = tanks["parameters"]["n_tanks"]
        assert (fixed["value"], fixed["stderr"], fixed["vary"]) == (5.0, None, False)
        assert (out / f"{name}.adm.png").is_file()
    with open(out / "summary.csv") as stream:
        rows = list(csv.DictReader(stream))
    assert [(r["curve"], r["model"]) for r in rows] == [("one", "adm"), ("one", "tanks"),
                                                       ("two", "adm"), ("two", "tanks")]
    assert json.loads((out / "summary.json").read_text())["models"] == ["adm", "tanks"]


@pytest.mark.parametrize(("options", "message"), [
    (["--model", "adm,adm"], "given twice"),
    (["--model", "adm,"], "empty name"),
    (["--model", "adm,tanks", "--fix", "k_f=1"], "no compared model has k_f"),
    (["--model", "adm,tanks", "--grid"], "one --model"),
])
def test_command_line_comparison_refuses_bad_options_in_one_line(options, message, adm_curve,
                                                                 tmp_path, capsys):
    _write_curve(tmp_path / "one.csv", *adm_curve)
    out = tmp_path / "out"
    status = main(["fit", str(tmp_path / "one.csv"), *options, "--out", str(out)])
    error = capsys.readouterr().err.strip()
    assert status == 2 and message in error and len(error.splitlines()) == 1
    assert not out.exists()
