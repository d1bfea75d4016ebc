"""Counting statistics: histograms of particles read as counts, fitted by Poisson maximum
likelihood with intervals of the known scale, and lack of fit tested on merged bins.

References independent of the fit's iterated weights: the Poisson likelihood maximised by
scipy (Nelder–Mead, then BFGS) and the inverse Fisher information from a finite-difference
Jacobian of the expected counts.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.optimize

from axialmix.analytic import exit_age_closed
from fitting.data import Curve, DataError, read_rtd_csv
from fitting.fit import fit, fit_many
from fitting.losses import CountingErrors, counting_weights, poisson_log_likelihood
from fitting.measurement import measured
from fitting.residuals import COUNTS_PER_MERGED_BIN, counting_lack_of_fit, merged_counts

TAU, PECLET, PARTICLES, BIN = 10.0, 8.0, 2000, 0.1
TIMES = np.arange(1, 601) * BIN  # 60 s of 0.1 s bins, reported at their ends


def _expected_counts(tau=TAU, peclet=PECLET, particles=PARTICLES, times=TIMES):
    return particles * BIN * np.asarray(exit_age_closed(times, tau, peclet))


def _histogram(seed, expected=None):
    expected = _expected_counts() if expected is None else expected
    counts = np.random.default_rng(seed).poisson(expected)
    return Curve(name=f"h{seed}", time=TIMES, value=counts / BIN,
                 exposure=np.full(TIMES.size, BIN)), counts


# --- reading ----------------------------------------------------------------------------------

def test_simulator_format_is_read_as_counts_with_bin_widths(tmp_path):
    path = tmp_path / "s.csv"
    path.write_text("# tracer pulse of 7 particles\nt [s],count,bin [s],E [1/s]\n"
                    "0,0,0.5,0\n0.5,2,0.5,0.571\n1,3,0.5,0.857\n1.5,1,0.5,0.286\n"
                    "2,1,0.5,0.286\n2.5,0,0.5,0\n")
    curve = read_rtd_csv(path, normalise=False)
    np.testing.assert_array_equal(curve.exposure, np.full(6, 0.5))
    np.testing.assert_allclose(curve.value * curve.exposure, [0, 2, 3, 1, 1, 0])
    assert curve.value_unit == "particles/s"
    # The E column is still there to pick by name: then it is a signal.
    signal = read_rtd_csv(path, normalise=False, value_column="E")
    assert signal.exposure is None


def test_bin_widths_from_their_unit_or_from_the_spacing(tmp_path):
    path = tmp_path / "ms.csv"
    path.write_text("t [min],counts,bin [s]\n0.5,1,30\n1,4,30\n1.5,6,30\n2,2,30\n2.5,1,30\n")
    curve = read_rtd_csv(path, normalise=False)
    np.testing.assert_allclose(curve.exposure, np.full(5, 0.5))  # 30 s in minutes
    spaced = tmp_path / "spaced.csv"
    spaced.write_text("time,count\n1,1\n2,4\n4,6\n6,2\n9,1\n")
    curve = read_rtd_csv(spaced, normalise=False)
    np.testing.assert_allclose(curve.exposure, [1, 1, 2, 2, 3])
    np.testing.assert_allclose(curve.value, [1, 4, 3, 1, 1 / 3])
    normalised = read_rtd_csv(spaced)
    np.testing.assert_allclose(normalised.value * normalised.exposure, [1, 4, 6, 2, 1])


@pytest.mark.parametrize(("row", "problem"), [
    ("3,2.5,1", "count 2.5 in column 'count' is not a whole number"),
    ("3,-1,1", "count -1 in column 'count' is not a whole number"),
    ("3,2,0", "bin width 0 in column 'bin' is not positive"),
])
def test_bad_counts_are_refused_with_their_row(tmp_path, row, problem):
    path = tmp_path / "bad.csv"
    path.write_text(f"t,count,bin\n1,0,1\n2,3,1\n{row}\n4,1,1\n5,0,1\n")
    with pytest.raises(DataError) as caught:
        read_rtd_csv(path, normalise=False)
    assert f"{path}, row 4: {problem}" in str(caught.value)


def test_a_baseline_cannot_be_taken_from_counts(tmp_path):
    path = tmp_path / "b.csv"
    path.write_text("t,count\n1,0\n2,3\n3,2\n4,1\n5,0\n")
    with pytest.raises(DataError, match="holds counts: a baseline cannot be subtracted"):
        read_rtd_csv(path, normalise=False, baseline="min")


# --- merging and weights ----------------------------------------------------------------------

def test_merged_bins_keep_the_totals_and_expect_enough_counts():
    rng = np.random.default_rng(3)
    expected = rng.exponential(0.3, 997)
    observed = rng.poisson(expected)
    merged, means, first = merged_counts(observed, expected)
    assert merged.sum() == observed.sum()
    assert means.sum() == pytest.approx(expected.sum(), rel=1e-12)
    assert np.all(means >= COUNTS_PER_MERGED_BIN - 1e-9)
    assert first[0] == 0 and np.all(np.diff(first) > 0)
    # Each merged bin's mean is the sum of its bins.
    bounds = np.append(first, expected.size)
    np.testing.assert_allclose(means, [expected[a:b].sum() for a, b in zip(bounds[:-1],
                                                                            bounds[1:],
                                                                            strict=True)])


def test_counting_weights_are_exposure_over_model():
    np.testing.assert_allclose(counting_weights(np.array([2.0, 4.0, 0.0]), np.array([1, 0.5, 1]),
                                                1e-3),
                               [0.5, 0.125, 1 / 4e-3])
    with pytest.raises(ValueError, match="floor"):
        CountingErrors(floor=0.0)


# --- the fit is the Poisson maximum-likelihood fit --------------------------------------------

def test_poisson_fit_is_the_likelihood_maximum_with_fisher_information_errors():
    curve, counts = _histogram(11)
    result = fit(measured("adm"), curve, {}, errors="poisson")
    assert result.error_model.kind == "poisson" and result.converged

    def expected(p):
        tau, peclet, amplitude = np.exp(p)
        return amplitude * BIN * np.asarray(exit_age_closed(TIMES, tau, peclet))

    def negative_log_likelihood(p):
        mu = expected(p)
        return float(np.sum(mu - counts * np.log(mu)))

    start = np.log([8.0, 5.0, 1500.0])
    rough = scipy.optimize.minimize(negative_log_likelihood, start, method="Nelder-Mead",
                                    options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 20000})
    best = scipy.optimize.minimize(negative_log_likelihood, rough.x, method="BFGS",
                                   options={"gtol": 1e-9})
    tau, peclet, amplitude = np.exp(best.x)
    assert result.values["tau"] == pytest.approx(tau, rel=1e-5)
    assert result.values["peclet"] == pytest.approx(peclet, rel=1e-5)
    assert result.values["amplitude"] == pytest.approx(amplitude, rel=1e-5)
    # Inverse Fisher information I = J^T diag(1/mu) J in the physical parameters, J by
    # central differences of the expected counts.
    physical = np.array([tau, peclet, amplitude])
    jacobian = np.empty((TIMES.size, 3))
    for j in range(3):
        step = 1e-6 * physical[j]
        up, down = physical.copy(), physical.copy()
        up[j] += step
        down[j] -= step
        jacobian[:, j] = (expected(np.log(up)) - expected(np.log(down))) / (2 * step)
    information = jacobian.T @ (jacobian / expected(best.x)[:, None])
    errors = np.sqrt(np.diag(np.linalg.inv(information)))
    np.testing.assert_allclose([result.stderr[n] for n in ("tau", "peclet", "amplitude")],
                               errors, rtol=1e-3)
    # The intervals use the normal quantile of the known scale (not Student's t).
    low, high = result.ci95["tau"]
    assert math.log(high / low) / 2 == pytest.approx(1.959964 * errors[0] / tau, rel=1e-3)
    # AIC from the Poisson likelihood of the counts.
    assert result.aic == pytest.approx(
        -2 * poisson_log_likelihood(curve.value, result.predicted, curve.exposure) + 6,
        rel=1e-12)


def test_false_alarms_and_coverage_over_sixty_histograms():
    # 60 histograms of 2,000 particles from the exact closed-closed ADM: lack of fit may be
    # flagged by chance (three tests at 1 % each: about 3 % expected, 1.8 of 60), and the
    # 95 % intervals must cover tau and Pe about 57 times in 60. Bounds: 6 or more false
    # alarms and 51 or fewer covering intervals are each below 1 % likely for a right method.
    curves = [_histogram(100 + i)[0] for i in range(60)]
    results = fit_many(measured("adm"), curves, {}, errors="poisson")
    alarms = sum(r.lack_of_fit.systematic for r in results)
    assert all(r.lack_of_fit.tested for r in results)
    covered = {name: sum(r.ci95[name][0] <= truth <= r.ci95[name][1] for r in results)
               for name, truth in (("tau", TAU), ("peclet", PECLET))}
    assert alarms <= 5, alarms
    assert covered["tau"] >= 52 and covered["peclet"] >= 52, covered


def test_a_model_that_misses_the_counts_is_flagged():
    # Two passages (a bypass): the closed ADM cannot make the second peak.
    expected = 0.6 * _expected_counts() + 0.4 * _expected_counts(tau=30.0, peclet=40.0)
    curve, _ = _histogram(5, expected)
    result = fit(measured("adm"), curve, {}, errors="poisson")
    assert result.lack_of_fit.systematic
    assert "merged to at least 10 expected particles" in result.lack_of_fit.statement


def test_counting_lack_of_fit_of_the_true_curve_is_rarely_flagged():
    expected = _expected_counts()
    alarms = 0
    for seed in range(200):
        counts = np.random.default_rng(seed).poisson(expected)
        verdict = counting_lack_of_fit(counts / BIN, expected / BIN, np.full(TIMES.size, BIN),
                                       0)
        alarms += verdict.systematic
    # Three tests at 1 %: at most about 3 % (6 of 200); 13 or more is below 0.5 % likely.
    assert alarms <= 12, alarms


# --- the user's path --------------------------------------------------------------------------

def test_simulator_histogram_is_fitted_with_counting_errors_by_itself(tmp_path):
    run = [sys.executable, "-c", "from fitting.cli import main; main()"]
    simulated = subprocess.run([*run, "simulate", "continuous", "--rtd-csv", "s.csv",
                                "--seed", "1", "--particles", "4000", "--quiet"],
                               cwd=tmp_path, capture_output=True, text=True)
    assert simulated.returncode == 0, simulated.stderr
    header = (tmp_path / "s.csv").read_text().splitlines()[:2]
    assert header[0].startswith("# axialmix simulate continuous") and "count" in header[0]
    assert header[1] == "t [s],count,bin [s],E [1/s]"
    fitted = subprocess.run([*run, "fit", "s.csv", "--model", "adm", "--out", "f"],
                            cwd=tmp_path, capture_output=True, text=True)
    assert fitted.returncode == 0, fitted.stderr
    assert "counting errors: s.csv holds particle counts" in fitted.stdout
    record = json.loads((tmp_path / "f" / "s.json").read_text())
    assert record["error_model"]["kind"] == "poisson"
    assert "merged to at least 10 expected particles" in record["lack_of_fit"]["statement"]
    amplitude = record["parameters"]["amplitude"]
    assert amplitude["unit"] == "particles"
    # The amplitude is the number of tracer particles counted (the simulator printed it).
    line = next(x for x in simulated.stdout.splitlines() if x.startswith("tracer left"))
    tracer = int(line.split(" of ")[1].split(" particles")[0])
    low, high = amplitude["ci95"]
    assert low <= tracer <= high


def test_a_long_study_of_counts_is_refused_in_one_line(tmp_path):
    from fitting.study.input import read_long_csv

    path = tmp_path / "study.csv"
    path.write_text("run,t [s],count,bin [s]\n" + "".join(
        f"{run},{t},{k},1\n" for run in ("a", "b") for t, k in zip(range(1, 7), (0, 3, 5, 2, 1, 0),
                                                                    strict=True)))
    with pytest.raises(DataError, match="holds particle counts: a long-format study fits "
                                        "signals; fit the histograms as files or a folder"):
        read_long_csv(path, "run")


def test_a_study_of_histogram_files_uses_counting_errors_too(tmp_path, capsys):
    from fitting.cli import main

    folder = tmp_path / "histograms"
    folder.mkdir()
    for seed in range(3):
        _, counts = _histogram(200 + seed)
        rows = "".join(f"{t:.10g},{k}\n" for t, k in zip(TIMES, counts, strict=True))
        (folder / f"h{seed}.csv").write_text("t [s],count\n" + rows)
    assert main(["fit", str(folder), "--model", "adm", "--chunk", "2", "--out",
                 str(tmp_path / "study")]) == 0
    assert "counting errors:" in capsys.readouterr().out
    records = json.loads((tmp_path / "study" / "summary.json").read_text())["curves"]
    assert [r["error_model"]["kind"] for r in records] == ["poisson"] * 3


def test_counting_errors_on_values_that_are_no_counts_are_refused(tmp_path, capsys):
    from fitting.cli import main

    t = np.linspace(0.0, 60.0, 30)
    signal = np.asarray(exit_age_closed(t, 10.0, 8.0))
    with pytest.raises(ValueError, match="counting errors need counts"):
        fit("adm", (t, signal), errors="poisson")
    path = tmp_path / "signal.csv"
    path.write_text("t,c\n" + "".join(f"{a:g},{b:.6g}\n" for a, b in zip(t, signal, strict=True)))
    assert main(["fit", str(path), "--model", "adm", "--errors", "poisson", "--out",
                 str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "counting errors need counts" in err[0]
    assert not (tmp_path / "out").exists()


def test_a_counting_fit_is_drawn_on_the_bins_its_lack_of_fit_test_merges():
    # The figure's points are the merged bins: their counts (value × merged exposure) add up
    # to every particle counted, there are as many as the test's bins, and each expects at
    # least 10 particles of the model drawn.
    from fitting.report import fit_figure

    curve, counts = _histogram(12)
    result = fit(measured("adm"), curve, {}, errors="poisson")
    figure = fit_figure(result)
    merged, expected, first = merged_counts(counts, BIN * np.asarray(result.predicted))
    exposure = np.add.reduceat(np.full(TIMES.size, BIN), first)
    assert figure["observed"].size == result.lack_of_fit.n_points == merged.size
    np.testing.assert_allclose(figure["observed"] * exposure, merged, rtol=1e-12)
    assert math.isclose(float(np.sum(figure["observed"] * exposure)), float(counts.sum()))
    assert np.all((figure["observed"] + figure["residual"]) * exposure
                  >= COUNTS_PER_MERGED_BIN - 1e-9)
    assert np.all(np.diff(figure["time"]) > 0)
    assert "merged" in figure["data_label"]
