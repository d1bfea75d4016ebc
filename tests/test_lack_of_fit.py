"""The lack-of-fit verdict every fit carries: calibration of its statistics, what it sees
(a missing background, a tail the model cannot make), what it leaves alone (exact curves,
curves the model describes), and how the reports say it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from axialmix.analytic import exit_age_closed
from fitting.diagnostics import lack_of_fit
from fitting.fit import fit
from fitting.report import fit_record, fit_table, identifiability_statements
from fitting.residuals import (
    LACK_OF_FIT_LEVEL,
    MIN_TEST_POINTS,
    lack_of_fit_test,
    lag1_autocorrelation_p,
)

TAU, PECLET, POINTS, NOISE = 40.0, 8.0, 60, 0.02
TIME = np.linspace(0.0, 3.0 * TAU, POINTS)


@pytest.fixture(scope="module")
def exact():
    return np.asarray(exit_age_closed(TIME, TAU, PECLET))


@pytest.fixture(scope="module")
def noise(exact):
    """Additive noise of 2 % of the peak (one fixed draw)."""
    return NOISE * exact.max() * np.random.default_rng(11).normal(size=POINTS)


@pytest.fixture(scope="module")
def described(exact, noise):
    """An ADM fit to a noisy ADM curve: the model describes the curve."""
    return fit("adm", (TIME, exact + noise))


@pytest.fixture(scope="module")
def background(exact, noise):
    """An ADM fit to the same curve on a constant background of 10 % of its peak."""
    return fit("adm", (TIME, exact + noise + 0.1 * exact.max()))


def test_random_sign_p_of_lag1_autocorrelation_is_calibrated_for_independent_unequal_noise():
    rng = np.random.default_rng(5)
    n, trials = 40, 2000
    # Independent, symmetric, of very different size at each point (as fit residuals of a
    # curve with proportional noise are): the random-sign null needs no equal sizes.
    scale = np.exp(np.linspace(-3.0, 1.0, n))
    p = np.array([lag1_autocorrelation_p(scale * rng.standard_t(3, size=n), permutations=199,
                                         seed=i, null="signs") for i in range(trials)])
    for alpha in (0.01, 0.05, 0.2):  # binomial 3-sigma bands around alpha
        band = 3 * np.sqrt(alpha * (1 - alpha) / trials)
        assert abs(np.mean(p <= alpha) - alpha) < band


def test_random_sign_p_sees_an_offset_that_reordering_does_not():
    rng = np.random.default_rng(6)
    shifted = 1.0 + 0.3 * rng.normal(size=50)
    assert lag1_autocorrelation_p(shifted, null="order") > 0.05
    assert lag1_autocorrelation_p(shifted, null="signs") <= 1 / 2000


def test_verdict_standardises_by_weights_and_drops_zero_weight_points():
    rng = np.random.default_rng(7)
    n = 80
    residuals = rng.normal(size=n)
    bump = np.zeros(n)
    bump[20:40] = 50.0 * np.sin(np.linspace(0, np.pi, 20))
    weights = np.ones(n)
    weights[20:40] = 0.0
    assert not lack_of_fit_test(residuals, None).systematic
    assert lack_of_fit_test(residuals + bump, None).systematic
    dropped = lack_of_fit_test(residuals + bump, weights)
    assert not dropped.systematic and dropped.n_points == n - 20
    # Units do not matter: residuals in another unit with weights 1/unit² give the same test.
    scaled = lack_of_fit_test(1e-9 * residuals, np.full(n, 1e18))
    plain = lack_of_fit_test(residuals)
    assert (scaled.runs_test_p, scaled.lag1_p) == (plain.runs_test_p, plain.lag1_p)
    assert scaled.lag1_autocorrelation == pytest.approx(plain.lag1_autocorrelation, rel=1e-12)
    # Proportional noise with 1/size² weights: standardised, it is plain noise again.
    size = np.exp(np.linspace(-4.0, 2.0, n))
    assert lack_of_fit_test(size * residuals, 1 / size**2).lag1_p == pytest.approx(plain.lag1_p)


def test_too_few_points_are_not_tested():
    verdict = lack_of_fit_test(np.arange(MIN_TEST_POINTS - 1.0))
    assert not verdict.tested and not verdict.systematic
    assert "fewer than" in verdict.statement


def test_a_curve_the_model_describes_is_not_flagged(described):
    verdict = described.lack_of_fit
    assert verdict.tested and not verdict.systematic
    assert verdict.runs_test_p >= LACK_OF_FIT_LEVEL and verdict.lag1_p >= LACK_OF_FIT_LEVEL
    statements = identifiability_statements(described)
    assert statements[-1].startswith("All fitted parameters are determined")
    assert any(s.startswith("No lack of fit") for s in statements)


def test_noise_free_exact_curve_is_an_exact_fit_not_a_systematic_one(exact):
    result = fit("adm", (TIME, exact))
    assert not result.lack_of_fit.tested and not result.lack_of_fit.systematic
    assert "reproduces the curve exactly" in result.lack_of_fit.statement


def test_constant_background_of_ten_percent_of_the_peak_fires_the_verdict(background):
    verdict = background.lack_of_fit
    assert verdict.systematic and verdict.lag1_p < LACK_OF_FIT_LEVEL
    statements = identifiability_statements(background)
    assert statements[-1].startswith("The adm model does not describe this curve")
    assert "understate the uncertainty" in statements[-1]
    assert not any("are determined by this curve" in s for s in statements)
    assert "SYSTEMATIC" in fit_table(background)
    assert "does not describe this curve" in background.report()
    record = json.loads(json.dumps(fit_record(background)))
    assert record["lack_of_fit"]["systematic"] is True
    assert set(record["lack_of_fit"]) >= {"systematic", "runs_test_p", "lag1_autocorrelation",
                                          "statement"}


def test_known_noise_level_compares_the_scaled_sum_of_squares_with_chi_square(described,
                                                                              exact):
    true_sigma = NOISE * float(exact.max())
    verdict = lack_of_fit(described, noise=true_sigma)
    chi_square = described.sse / true_sigma**2
    assert verdict.scaled_sse == pytest.approx(chi_square / described.dof, rel=1e-12)
    assert verdict.scaled_sse_p == pytest.approx(stats.chi2.sf(chi_square, described.dof),
                                                 rel=1e-9)
    assert not verdict.systematic
    # Claiming three times less noise than there is: the sum of squares is about nine times
    # its expected value, which no fit that describes the curve leaves.
    overstated = lack_of_fit(described, noise=true_sigma / 3)
    assert overstated.systematic and overstated.scaled_sse_p < 1e-12
    assert described.lack_of_fit.scaled_sse is None  # the noise level is estimated there


def test_verdict_uses_the_relative_error_weights_of_a_relative_error_fit(exact):
    rng = np.random.default_rng(12)
    observed = exact * (1 + 0.03 * rng.normal(size=POINTS))
    result = fit("adm", (TIME, observed), relative_errors=True)
    weights = np.asarray(result.weights)
    standardised = np.sqrt(weights) * np.asarray(result.residuals)
    # Points below the floor (1e-3 of the peak) have capped weights and are left out.
    size = np.abs(np.asarray(result.predicted))
    described = (weights > 0) & (size >= 1e-3 * size.max())
    assert 0 < np.count_nonzero(~described) < POINTS // 4
    direct = lack_of_fit_test(standardised[described])
    assert result.lack_of_fit.n_points == np.count_nonzero(described)
    assert result.lack_of_fit.lag1_autocorrelation == pytest.approx(
        direct.lag1_autocorrelation, rel=1e-12)
    assert not result.lack_of_fit.systematic
