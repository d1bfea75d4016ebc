"""Long curves: the random-sign lag-1 test from its exact null cumulants against the
randomisation test, plain CSV bodies read by the compiled reader to the same numbers, and a
long curve fitted through the command line to the parameters of the exact evaluation."""

from __future__ import annotations

import json

import numpy as np
import pytest

import fitting.residuals as residuals
from axialmix._csv import DataError, read_table
from axialmix.analytic import exit_age_closed
from fitting.residuals import (
    NORMAL_FROM,
    lag1_autocorrelation_p,
    lag1_signs_normal_p,
)

PERMUTATIONS = 1999


def _drawn_p(e: np.ndarray, seed: int, monkeypatch) -> float:
    """The randomisation test's p with its 1,999 draws, whatever the length."""
    with monkeypatch.context() as patch:
        patch.setattr(residuals, "NORMAL_FROM", 10**12)
        return lag1_autocorrelation_p(e, PERMUTATIONS, seed, null="signs")


def _residual_cases(n: int) -> list[np.ndarray]:
    """Independent noise of one size and of sizes varying tenfold, and noise with a weak
    positive correlation of neighbours (p from about 0.5 down to about 0.005)."""
    rng = np.random.default_rng(n)
    cases = []
    for correlation in (0.0, 0.008, 0.014, 0.02):
        noise = rng.standard_normal(n) * (1.0 + 9.0 * rng.random(n))
        cases.append(noise + correlation * np.roll(noise, 1))
    cases.append(rng.standard_normal(n))
    return cases


@pytest.mark.parametrize("n", [NORMAL_FROM, 3 * NORMAL_FROM // 2])
def test_lag1_from_cumulants_matches_the_randomisation_test(n, monkeypatch):
    # The randomisation p of B draws estimates (1 + B p) / (B + 1) with a standard error of
    # sqrt(B p (1 - p)) / (B + 1): the two agree within four of those (plus 0.002 for the
    # approximation, measured within 0.003 of 100,000 draws even at 400 residuals).
    for seed, e in enumerate(_residual_cases(n)):
        approximate = lag1_autocorrelation_p(e, PERMUTATIONS, seed, null="signs")
        assert approximate == lag1_signs_normal_p(e)
        drawn = _drawn_p(e, seed, monkeypatch)
        expected = (1 + PERMUTATIONS * approximate) / (PERMUTATIONS + 1)
        spread = np.sqrt(PERMUTATIONS * approximate * (1 - approximate) + 1) / (PERMUTATIONS + 1)
        assert abs(drawn - expected) <= 4 * spread + 0.002, (seed, drawn, approximate)


def test_lag1_below_the_threshold_is_the_randomisation_test_unchanged(monkeypatch):
    e = _residual_cases(NORMAL_FROM - 1)[1]
    assert lag1_autocorrelation_p(e, PERMUTATIONS, 0, null="signs") == _drawn_p(e, 0, monkeypatch)
    # The random-order null always draws.
    with monkeypatch.context() as patch:
        patch.setattr(residuals, "lag1_signs_normal_p", lambda e: pytest.fail("used"))
        lag1_autocorrelation_p(_residual_cases(NORMAL_FROM)[0], 19, 0, null="order")


def test_lag1_keeps_the_draws_for_residuals_concentrated_on_a_few_points(monkeypatch):
    e = np.random.default_rng(1).standard_normal(NORMAL_FROM) * 1e-3
    e[100:104] = [5.0, 4.0, -3.0, 6.0]  # four points hold nearly all of sum e_i e_(i+1)
    assert lag1_signs_normal_p(e) is None
    assert lag1_autocorrelation_p(e, PERMUTATIONS, 0, null="signs") == _drawn_p(e, 0, monkeypatch)


def test_lag1_from_cumulants_sees_a_strong_correlation_and_zero_residuals():
    rng = np.random.default_rng(2)
    noise = rng.standard_normal(50_000)
    smooth = noise + 0.5 * np.roll(noise, 1)
    assert lag1_signs_normal_p(smooth) < 1e-100
    alternating = smooth * (-1.0) ** np.arange(smooth.size)  # r1 near -0.4
    assert lag1_signs_normal_p(alternating) == pytest.approx(1.0)
    assert lag1_autocorrelation_p(np.zeros(NORMAL_FROM), null="signs") == 1.0


# --- plain CSV bodies --------------------------------------------------------------------------

def _read(path, columns=(0, 1), plain=True, monkeypatch=None):
    import axialmix._csv as csv_module

    table = read_table(path)
    if not plain:
        with monkeypatch.context() as patch:
            patch.setattr(csv_module, "_plain_numbers", lambda *a: None)
            return table.numbers(list(columns))
    return table.numbers(list(columns))


@pytest.mark.parametrize("body, delimiter, newline", [
    ("plain", ",", "\n"), ("plain", ";", "\n"), ("plain", "\t", "\r\n"),
    ("signs", ",", "\n"), ("no final newline", ",", "\n"),
])
def test_plain_bodies_are_read_to_the_same_numbers(tmp_path, body, delimiter, newline,
                                                   monkeypatch):
    rng = np.random.default_rng(4)
    values = rng.standard_normal((3000, 3)) * 10.0 ** rng.integers(-12, 12, (3000, 3))
    cells = [[repr(float(v)) for v in row] for row in values]
    if body == "signs":
        cells = [["+" + c if not c.startswith("-") else c for c in row] for row in cells]
        cells[5][1] = "1.e5"
        cells[6][1] = ".25"
        cells[7][1] = "-0"
    text = newline.join(delimiter.join(row) for row in cells)
    if body != "no final newline":
        text += newline
    path = tmp_path / "curve.csv"
    path.write_text(f"# a comment{newline}t [s]{delimiter}c{delimiter}x{newline}{text}",
                    newline="")
    import axialmix._csv as csv_module

    table = read_table(path)
    assert csv_module._plain_numbers(table, [0, 2]) is not None  # the compiled reader ran
    rows, numbers = _read(path, (0, 2))
    slow_rows, slow_numbers = _read(path, (0, 2), plain=False, monkeypatch=monkeypatch)
    np.testing.assert_array_equal(rows, slow_rows)
    np.testing.assert_array_equal(numbers, slow_numbers)
    assert rows[0] == 3


@pytest.mark.parametrize("line", [
    "1.0,2.0,", "1.0,,2.0", "1.0,2.0,3.0,4.0", "1.0,2.0", "1.0,nan,2.0", "1.0,1e999,2.0",
    "1.0, 2.0,3.0", "", "# comment", "1.0,e5,2.0", "1.0,1.2.3,2.0", '1.0,"2.0",3.0',
    "1.0,1_0,2.0",
])
def test_bodies_that_are_not_plain_are_read_row_by_row(tmp_path, line, monkeypatch):
    # A line the compiled reader does not take (or one it takes because only unused cells
    # differ): the same result or the same error as the row-by-row reader's.
    good = "\n".join(f"{i}.5,{i * 2}.25,{i}e-3" for i in range(50))
    path = tmp_path / "curve.csv"
    path.write_text(f"t,c,x\n{good}\n{line}\n{good}\n")
    import axialmix._csv as csv_module

    if line not in ("1.0,2.0,", "1.0,2.0,3.0,4.0"):
        assert csv_module._plain_numbers(read_table(path), [0, 1]) is None
    try:
        expected = _read(path, plain=False, monkeypatch=monkeypatch)
    except DataError as error:
        with pytest.raises(DataError) as raised:
            _read(path)
        assert str(raised.value) == str(error)
    else:
        got = _read(path)
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])


# --- a long curve through the command line -----------------------------------------------------

def test_long_curve_fit_through_the_command_line_matches_the_exact_evaluation(tmp_path):
    # 20,000 samples (padded to 32,768: the 'adm' model evaluates them on panels) against the
    # same fit with the exact E on every point: the same values to 1e-9 relative, standard
    # errors to 1e-6 relative (measured: 8e-11 and 1e-7).
    from fitting.cli import main
    from fitting.fit import fit
    from fitting.measurement import Inlet, measured
    from fitting.models import custom_model, get_model
    from fitting.parameters import Parameter

    rng = np.random.default_rng(12)
    t = np.linspace(0.0, 100.0, 20_000)
    e = np.asarray(exit_age_closed(t, 20.0, 10.0))
    y = e + 0.01 * e.max() * rng.standard_normal(t.size) + 0.02 * e * rng.standard_normal(t.size)
    path = tmp_path / "long.csv"
    np.savetxt(path, np.column_stack([t, y]), delimiter=",", header="time_s,value",
               comments="", fmt="%.12g")
    assert main(["fit", str(path), "--model", "adm", "--out", str(tmp_path / "out")]) == 0
    record = json.loads((tmp_path / "out" / "long.json").read_text())

    adm = get_model("adm")
    exact = custom_model(
        "adm-exact", lambda t, p: exit_age_closed(t, p["tau"], p["peclet"]),
        {"tau": Parameter(1.0, min=0.0), "peclet": Parameter(10.0, min=0.0)},
        initial_guess=adm.initial_guess)
    from fitting.data import read_rtd_csv

    reference = fit(measured(exact, Inlet.pulse(), ()), read_rtd_csv(path, normalise=False),
                    errors="combined")
    assert not record["lack_of_fit"]["systematic"]  # the reweighted passes ran
    for name in ("tau", "peclet", "amplitude"):
        fitted = record["parameters"][name]
        assert fitted["value"] == pytest.approx(reference.values[name], rel=1e-9), name
        assert fitted["stderr"] == pytest.approx(reference.stderr[name], rel=1e-6), name
    assert abs(record["parameters"]["tau"]["value"] - 20.0) < 4 * reference.stderr["tau"]
    # The panels at the fitted values, against the exact E on every point.
    values = {n: record["parameters"][n]["value"] for n in ("tau", "peclet")}
    largest, peak = adm.long_curve_check(t, values)
    assert largest <= 1e-10 * peak
    # The fit made the same check itself, in the curve's unit, and says so.
    check = record["evaluation_check"]
    amplitude = record["parameters"]["amplitude"]["value"]
    assert check["points"] == t.size
    assert check["peak"] == pytest.approx(peak * amplitude, rel=1e-9)
    # Both deviations are round-off (about 1e-14 of the peak), so they agree only in size.
    assert check["largest_deviation"] <= 1e-10 * check["peak"]
    assert record["converged"]
    assert any("Chebyshev panels" in line for line in record["identifiability"])


def test_a_long_curve_whose_interpolated_model_misses_the_exact_one_is_not_a_success():
    # The fit's every-point check, made to fail: the fit is not called a success and its
    # message says why (never a silent fallback).
    import dataclasses

    import fitting.fit as fitting_fit
    from fitting.data import Curve
    from fitting.measurement import Inlet, measured
    from fitting.models import get_model

    t = np.linspace(0.0, 100.0, 9_000)  # padded to 16,384: panels
    y = np.asarray(exit_age_closed(t, 20.0, 10.0))
    y = y + 0.01 * y.max() * np.random.default_rng(3).standard_normal(t.size)
    adm = get_model("adm")
    missing = dataclasses.replace(adm, long_curve_check=lambda t, p: (1e-6, 1.0))
    result = fitting_fit.fit(measured(missing, Inlet.pulse(), ()), Curve("c", t, y),
                             errors="absolute")
    assert result.evaluation_check == pytest.approx((1e-6 * result.values["amplitude"],
                                                     result.values["amplitude"]))
    assert not result.success
    assert "not the exact model's" in result.message
