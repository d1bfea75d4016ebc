"""The additive plus proportional error model: estimation of its sizes, leverages, the iterated
weights of a fit, and its settings."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed
from fitting.data import Curve
from fitting.fit import fit
from fitting.losses import (
    CombinedErrors,
    ErrorEstimate,
    combined_weights,
    estimate_combined_errors,
    leverages,
)
from fitting.measurement import measured

TAU, PECLET, AMPLITUDE = 40.0, 8.0, 3.7


@pytest.mark.parametrize(("additive", "proportional"),
                         [(0.01, 0.03), (0.0, 0.05), (0.02, 0.0), (0.02, 0.10)])
def test_estimated_sizes_match_the_noise_that_made_the_residuals(additive, proportional):
    # 20,000 residuals. What the weights need is the variance at every model value: it must
    # be right within 5 % (its estimate's own spread is about 2 %). A part that is absent
    # has a true value on the bound 0, where its estimate scatters as the square root of
    # its variance's (b = 0.004 for a = 0.02): the variance is the fair measure.
    rng = np.random.default_rng(0)
    model = np.exp(-((np.linspace(0.0, 10.0, 20_000) - 4.0) ** 2) / 2.0)
    residual = np.hypot(additive, proportional * model) * rng.standard_normal(model.size)
    a, b = estimate_combined_errors(residual, model)
    levels = np.linspace(0.0, 1.0, 101)
    true_variance = additive**2 + (proportional * levels) ** 2
    np.testing.assert_allclose(a**2 + (b * levels) ** 2, true_variance, rtol=0.05,
                               atol=1e-6 * true_variance.max())


def test_leverages_are_the_diagonal_of_the_weighted_hat_matrix():
    rng = np.random.default_rng(1)
    jacobian = rng.standard_normal((12, 3))
    weights = rng.uniform(0.5, 2.0, 12)
    root = np.sqrt(weights)[:, None] * jacobian
    hat = root @ np.linalg.inv(root.T @ root) @ root.T
    np.testing.assert_allclose(leverages(jacobian, weights), np.diag(hat), atol=1e-12)
    assert leverages(jacobian, weights).sum() == pytest.approx(3.0, abs=1e-12)


def test_combined_weights_and_the_estimate_in_words():
    np.testing.assert_allclose(combined_weights(np.array([0.0, 1.0, 2.0]), 0.1, 0.5),
                               1.0 / np.array([0.01, 0.26, 1.01]))
    estimate = ErrorEstimate("combined", 0.002, 0.03, 4)
    np.testing.assert_allclose(estimate.standard_deviation(np.array([0.0, 0.1])),
                               [0.002, np.hypot(0.002, 0.003)])
    assert estimate.to_dict() == {"kind": "combined", "additive_sd": 0.002,
                                  "proportional_sd": 0.03, "passes": 4}
    assert "3 % of the model" in estimate.describe("g/L")


def _noisy_curve(seed: int, additive: float, proportional: float, points: int = 40):
    time = np.linspace(0.0, 3 * TAU, points)
    clean = AMPLITUDE * np.asarray(exit_age_closed(time, TAU, PECLET))
    rng = np.random.default_rng(seed)
    noise = np.hypot(additive * clean.max(), proportional * clean) * rng.standard_normal(points)
    return Curve("noisy", time, clean + noise)


def test_combined_fit_weights_are_those_of_its_own_curve_and_estimate():
    curve = _noisy_curve(2, 0.01, 0.05)
    result = fit(measured("adm"), curve, errors="combined")
    estimate = result.error_model
    assert estimate.kind == "combined" and estimate.passes >= 2
    expected = combined_weights(result.predicted, estimate.additive, estimate.proportional)
    # The fitted values stopped changing, so the weights are those of the final curve.
    np.testing.assert_allclose(result.weights / result.weights.max(),
                               expected / expected.max(), rtol=1e-5)
    # The weights' shape counts as one fitted parameter.
    assert result.dof == result.n_points - len(result.free_names) - 1
    assert result.converged
    low, high = result.ci95["tau"]
    assert low <= TAU <= high


def test_absolute_and_relative_fits_report_their_error_sizes():
    curve = _noisy_curve(3, 0.01, 0.0)
    absolute = fit(measured("adm"), curve)
    assert absolute.error_model.kind == "absolute"
    assert absolute.error_model.additive == pytest.approx(absolute.sigma)
    late = Curve("late", curve.time[1:], curve.value[1:])  # no sample where the model is 0
    relative = fit(measured("adm"), late, errors="relative")
    assert relative.error_model.kind == "relative"
    assert relative.error_model.proportional == pytest.approx(relative.sigma)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"errors": "lognormal"}, "errors must be one of"),
        ({"errors": "combined", "weights": np.ones(40)}, "sets the weights itself"),
        ({"errors": "combined", "relative_errors": True}, "give the error model once"),
    ],
)
def test_bad_error_settings_are_one_line_errors(options, words):
    with pytest.raises(ValueError, match=words):
        fit(measured("adm"), _noisy_curve(4, 0.01, 0.02), **options)


def test_combined_errors_settings_reject_nonsense():
    with pytest.raises(ValueError, match="max_passes"):
        CombinedErrors(max_passes=1)
    with pytest.raises(ValueError, match="change"):
        CombinedErrors(change=0.0)


def test_reweighted_passes_stopped_by_their_limit_are_judged_against_the_standard_errors():
    # The rule of fitting.fit._with_settling: a fit whose passes stopped by the limit while
    # its values still moved by a tenth of their smallest relative standard error or more
    # is not converged; one that moved less, or stopped before the limit, or met the change
    # limit, is left as it is.
    from fitting.fit import SETTLED_SHARE, _with_settling

    result = fit(measured("adm"), _noisy_curve(2, 0.01, 0.05), errors="combined")
    assert result.converged
    scale = min(abs(result.stderr[n] / result.values[n]) for n in result.free_names)
    below, above = 0.5 * SETTLED_SHARE * scale, 2.0 * SETTLED_SHARE * scale
    assert _with_settling(result, "combined", 20, below, 20, 1e-8) is result
    assert _with_settling(result, "combined", 19, above, 20, 1e-8) is result
    assert _with_settling(result, "combined", 20, 1e-9, 20, 1e-8) is result
    moved = _with_settling(result, "combined", 20, above, 20, 1e-8)
    assert not moved.converged and not moved.success
    assert moved.message.startswith("not converged: the combined error model's reweighted fits "
                                    "did not settle in 20 passes")
    assert "try absolute errors" in moved.message
    assert moved.values == result.values  # the numbers are kept, and said to be unsettled
    assert "until consistent" in result.method and "until consistent" not in moved.method
    assert "not consistent after 20 passes" in moved.method
    relative = _with_settling(result, "relative", 10, float("inf"), 10, 1e-8)
    assert not relative.converged and "try combined errors" in relative.message
    # Counts have Poisson noise by nature: there the passes hop between optima.
    from fitting.fit import _COUNTING_METHOD

    counted = dataclasses.replace(result, method=f"levenberg-marquardt; {_COUNTING_METHOD} (20 "
                                                 "passes)")
    unsettled = _with_settling(counted, "counting", 20, above, 20, 1e-8)
    assert "fix or tie one of them" in unsettled.message
    assert unsettled.method == "levenberg-marquardt; counting (Poisson) errors: reweighted by " \
        "exposure/model not consistent after 20 passes"
