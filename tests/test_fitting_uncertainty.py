"""Uncertainty of fits: exact least-squares errors, profiles, information criteria,
identifiability of the four-compartment fluxes."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from axialmix.network import four_compartment_chain_transport, four_compartment_exit_age
from fitting.diagnostics import (
    identifiability,
    profile_intervals,
    profile_likelihood,
    regions,
    with_profile_intervals,
)
from fitting.fit import fit, fit_many
from fitting.models import custom_model
from fitting.parameters import Parameter
from fitting.uncertainty import (
    effective_degrees_of_freedom,
    gauss_newton_uncertainty,
    information_criteria,
)

TIME = np.linspace(0.0, 20.0, 30)


def _basis(t):
    """Columns of a model linear in its parameters: y = a exp(-t/5) + b t exp(-t/5) + c."""
    decay = np.exp(-t / 5.0)
    return np.stack([decay, t * decay, np.ones_like(t)], axis=1)


def _linear(t, p):
    decay = jnp.exp(-t / 5.0)
    return p["a"] * decay + p["b"] * t * decay + p["c"]


LINEAR = custom_model("linear", _linear, {"a": Parameter(1.0), "b": Parameter(1.0),
                                          "c": Parameter(0.1)})


@pytest.fixture(scope="module")
def linear_fits():
    rng = np.random.default_rng(7)
    truth = np.array([2.0, 0.3, 0.05])
    clean = _basis(TIME) @ truth
    observed = clean + 0.05 * rng.normal(size=TIME.size)
    weights = rng.uniform(0.5, 2.0, size=TIME.size)
    results = fit_many(LINEAR, [(TIME, observed), (TIME, observed)],
                       weights=[np.ones(TIME.size), weights])
    return observed, weights, results


def _exact_least_squares(observed, w):
    """Weighted least squares in closed form: the estimate (X' W X)^-1 X' W y, its covariance
    s² (X' W X)^-1 with s² = RSS / (n - p), and n - p."""
    design = _basis(TIME)
    normal = design.T @ (w[:, None] * design)
    estimate = np.linalg.solve(normal, design.T @ (w * observed))
    dof = TIME.size - 3
    variance = np.sum(w * (design @ estimate - observed) ** 2) / dof
    return estimate, variance * np.linalg.inv(normal), dof


@pytest.mark.parametrize("weighted", [False, True])
def test_linear_model_standard_errors_equal_the_exact_least_squares_formula(linear_fits,
                                                                             weighted):
    observed, weights, results = linear_fits
    result = results[1] if weighted else results[0]
    estimate, covariance, dof = _exact_least_squares(
        observed, weights if weighted else np.ones(TIME.size))
    errors = np.sqrt(np.diag(covariance))
    quantile = stats.t.ppf(0.975, dof)
    assert result.converged
    for i, name in enumerate("abc"):
        # The fit stops once a Gauss-Newton step would move a parameter by less than xtol =
        # 1e-6 (in units of its start magnitude, here 1 or 0.1); the errors are unaffected
        # to first order.
        assert result.values[name] == pytest.approx(estimate[i], rel=0, abs=1e-6)
        assert result.stderr[name] == pytest.approx(errors[i], rel=1e-6)
        low, high = result.ci95[name]
        assert low == pytest.approx(estimate[i] - quantile * errors[i], rel=1e-6, abs=1e-9)
        assert high == pytest.approx(estimate[i] + quantile * errors[i], rel=1e-6, abs=1e-9)
    correlation = covariance / np.outer(errors, errors)
    np.testing.assert_allclose(result.correlation, correlation, rtol=1e-6, atol=1e-9)
    assert result.dof == dof


def test_information_criteria_follow_the_gaussian_likelihood_form(linear_fits):
    _, _, results = linear_fits
    result = results[0]
    n, k = result.n_points, 3
    assert result.aic == pytest.approx(n * math.log(result.sse / n) + 2 * k, rel=1e-12)
    assert result.bic == pytest.approx(n * math.log(result.sse / n) + k * math.log(n), rel=1e-12)
    assert information_criteria(result.sse, n, k) == (result.aic, result.bic)


def test_profile_of_a_linear_model_is_the_exact_parabola_and_matches_the_wald_interval(
    linear_fits,
):
    observed, _, results = linear_fits
    result = results[0]
    design = _basis(TIME)
    inverse = np.linalg.inv(design.T @ design)
    estimate, minimum = np.linalg.lstsq(design, observed, rcond=None)[:2]
    grid = estimate[0] + np.linspace(-3, 3, 61) * result.stderr["a"]
    profile = profile_likelihood(result, "a", grid)
    # For a linear model, fixing a and re-fitting b, c raises the SSE by exactly
    # (a - a_hat)² / [(X'X)^-1]_aa above the least-squares minimum.
    expected = minimum[0] + (grid - estimate[0]) ** 2 / inverse[0, 0]
    np.testing.assert_allclose(profile.sse, expected, rtol=1e-8)
    assert profile.converged.all()
    # The crossings are linearly interpolated on a grid of 0.1 standard errors: the
    # interpolation error of a parabola there is below 1e-3 of the half-width.
    low, high = result.ci95["a"]
    half_width = (high - low) / 2
    assert profile.ci95[0] == pytest.approx(low, abs=1e-3 * half_width)
    assert profile.ci95[1] == pytest.approx(high, abs=1e-3 * half_width)


@pytest.mark.parametrize("weighted", [False, True])
def test_profile_intervals_of_a_linear_model_equal_the_exact_intervals(linear_fits, weighted):
    observed, weights, results = linear_fits
    result = results[1] if weighted else results[0]
    estimate, covariance, dof = _exact_least_squares(
        observed, weights if weighted else np.ones(TIME.size))
    half = stats.t.ppf(0.975, dof) * np.sqrt(np.diag(covariance))
    profiled = with_profile_intervals(result, profile_intervals(result))
    assert profiled.profiled == ("a", "b", "c")
    for i, name in enumerate("abc"):
        # The held values' refits are least-squares solutions (to the solver's 1e-6 step
        # tolerance), so the ends agree with the closed form to about 1e-5 of the half-width.
        low, high = profiled.ci95[name]
        assert low == pytest.approx(estimate[i] - half[i], abs=1e-4 * half[i])
        assert high == pytest.approx(estimate[i] + half[i], abs=1e-4 * half[i])
    record = profiled.to_dict()["parameters"]
    assert {record[n]["interval"] for n in "abc"} == {"profile"}
    assert result.to_dict()["parameters"]["a"]["interval"] == "linearised"


def test_profile_intervals_refit_as_the_vmapped_profile_does():
    # A nonlinear model: the engine's refits at each held value (profile_intervals) and the
    # vmapped solver's (profile_likelihood) reach the same minima.
    rng = np.random.default_rng(3)
    t = np.linspace(0.2, 30.0, 60)
    clean = 7.0 / (1.0 + 0.4 * t) * np.exp(-t / 6.0)
    model = custom_model("decay", lambda t, p: p["A"] / (1.0 + p["k"] * t) * jnp.exp(-t / p["T"]),
                         {"A": Parameter(5.0, min=0.0), "k": Parameter(0.2, min=0.0),
                          "T": Parameter(4.0, min=0.0)})
    result = fit(model, (t, clean + 0.05 * rng.normal(size=t.size)))
    profiles = profile_intervals(result, ["k"], factor=4.0, points_per_side=4)
    grid = profiles["k"].values
    reference = profile_likelihood(result, "k", grid)
    np.testing.assert_allclose(profiles["k"].sse, reference.sse, rtol=1e-6)
    low, high = with_profile_intervals(result, profiles).ci95["k"]
    assert low < result.values["k"] < high


def test_effective_degrees_of_freedom_are_n_minus_p_for_inverse_variance_weights():
    rng = np.random.default_rng(4)
    jacobian = rng.normal(size=(15, 3))
    weights = rng.uniform(0.5, 2.0, 15)
    assert effective_degrees_of_freedom(jacobian, weights, np.ones(15)) == pytest.approx(12.0)
    # A point whose weight is far below its inverse variance holds almost no residual: about
    # one degree of freedom less (its own, less its small leverage).
    factors = np.ones(15)
    factors[0] = 1e-20
    assert 11.0 < effective_degrees_of_freedom(jacobian, weights, factors) < 11.6
    # Monte Carlo: the expected weighted sum of squares of a linear fit, weights not 1/variance.
    variance = rng.uniform(0.1, 3.0, 15)
    weights = 1 / np.maximum(variance, 1.0)
    noise = rng.normal(size=(20000, 15)) * np.sqrt(variance)
    sqrt_w = np.sqrt(weights)
    projection = np.eye(15) - sqrt_w[:, None] * jacobian @ np.linalg.solve(
        jacobian.T @ (weights[:, None] * jacobian), jacobian.T * sqrt_w[None, :])
    residual = (noise * sqrt_w) @ projection.T
    mean_sse = np.mean(np.sum(residual**2, axis=1))
    dof = effective_degrees_of_freedom(jacobian, weights, weights * variance)
    # The mean of 20,000 sums has a relative standard error of about 0.3 %.
    assert mean_sse == pytest.approx(dof, rel=0.012)
    assert dof < 11.5


def test_effective_degrees_of_freedom_equal_the_explicit_n_by_n_trace():
    # The O(n p²) form against the definition tr(W (I - P) V (I - P)ᵀ) with the n x n
    # projection P = J (Jᵀ W J)⁻¹ Jᵀ W, on small problems with some points weighted zero.
    rng = np.random.default_rng(8)
    for n, p in [(5, 1), (9, 2), (20, 3), (40, 4)]:
        jacobian = rng.normal(size=(n, p)) * 10.0 ** rng.uniform(-2, 2, p)
        weights = rng.uniform(0.2, 3.0, n)
        weights[rng.permutation(n)[: n // 5]] = 0.0
        factors = rng.uniform(0.1, 4.0, n)
        projection = jacobian @ np.linalg.solve(jacobian.T @ (weights[:, None] * jacobian),
                                                jacobian.T * weights[None, :])
        residual_map = np.eye(n) - projection
        variance = np.divide(factors, weights, out=np.zeros(n), where=weights > 0)
        explicit = np.trace(np.diag(weights) @ residual_map @ np.diag(variance)
                            @ residual_map.T)
        assert effective_degrees_of_freedom(jacobian, weights, factors) == pytest.approx(
            explicit, rel=1e-12)


def test_standard_errors_do_not_depend_on_the_units_of_the_parameters():
    # Measuring a parameter in units 1e8 times smaller multiplies its Jacobian column by
    # 1e-8 and its standard error by 1e8, exactly; the curvature must not become "singular"
    # because its entries span 16 orders of magnitude.
    rng = np.random.default_rng(9)
    jacobian = _basis(TIME)
    residual = rng.normal(size=TIME.size)
    reference = gauss_newton_uncertainty(jacobian, residual, np.ones(TIME.size))
    for factor in (1e-8, 1e8, 1e-100, 1e100):
        units = np.array([factor, 1.0, 1.0 / factor])
        scaled = gauss_newton_uncertainty(jacobian * units, residual, np.ones(TIME.size))
        assert not scaled.singular
        np.testing.assert_allclose(scaled.all_stderr * units, reference.all_stderr, rtol=1e-10)
        np.testing.assert_allclose(scaled.correlation, reference.correlation, atol=1e-12)
        assert effective_degrees_of_freedom(jacobian * units, np.ones(TIME.size),
                                            np.ones(TIME.size)) == pytest.approx(TIME.size - 3)


def test_gauss_newton_uncertainty_marks_a_singular_curvature():
    jacobian = np.array([[1.0, 2.0], [2.0, 4.0], [3.0, 6.0]])  # second column = 2 x first
    uncertainty = gauss_newton_uncertainty(jacobian, np.array([0.1, -0.1, 0.05]), np.ones(3))
    assert uncertainty.singular
    assert np.isnan(uncertainty.all_stderr).all()


# --- four-compartment fluxes ------------------------------------------------------------------

RATES = {"k_f": 2.125, "k_r": 2.125, "k_s": 0.625, "k_out": 1.0}  # horizontal blender (source)
NETWORK_TIME = np.linspace(0.0, 12.0, 40)


def _four_compartment_data():
    rng = np.random.default_rng(11)
    clean = np.asarray(four_compartment_exit_age(NETWORK_TIME, *RATES.values()))
    return NETWORK_TIME, clean + 0.01 * clean.max() * rng.normal(size=clean.size)


START = {name: 0.7 * value for name, value in RATES.items()}


@pytest.fixture(scope="module")
def four_compartment_tied():
    return fit("four-compartment", _four_compartment_data(),
               {**START, "k_r": Parameter(START["k_r"], min=0.0, expr="k_f")})


def _log_curvature_eigenvalues(result):
    """Eigenvalues of the curvature in log-parameters from central finite differences."""
    names = result.free_names
    values = np.array([result.values[n] for n in names])

    def predicted(log_values):
        rates = dict(result.values)
        rates.update(dict(zip(names, np.exp(log_values), strict=True)))
        for name, setting in result.init_params.items():
            if setting.expr is not None:
                rates[name] = rates[setting.expr]
        return np.asarray(four_compartment_exit_age(NETWORK_TIME, *(rates[k] for k in RATES)))

    step = 1e-5
    columns = []
    for j in range(len(names)):
        shift = np.zeros(len(names))
        shift[j] = step
        columns.append((predicted(np.log(values) + shift) - predicted(np.log(values) - shift))
                       / (2 * step))
    jacobian = np.stack(columns, axis=1)
    return np.sort(np.linalg.eigvalsh(jacobian.T @ jacobian))[::-1]


def _check_diagnosis(result):
    diagnosis = identifiability(result)
    print(f"\n{result.free_names}: {result.message}")
    print(result.report())
    print(diagnosis)
    assert result.converged
    # The diagnosis is the eigen-decomposition of the curvature in log-parameters (zero
    # eigenvalues agree to round-off relative to the largest).
    expected = _log_curvature_eigenvalues(result)
    np.testing.assert_allclose(diagnosis.eigenvalues, expected, rtol=1e-5,
                               atol=1e-9 * expected[0])
    directions = diagnosis.directions
    np.testing.assert_allclose(directions.T @ directions, np.eye(len(result.free_names)),
                               atol=1e-12)
    for i in diagnosis.poorly_determined:
        assert diagnosis.half_widths[i] > math.log(2) or diagnosis.ratios[i] < 1e-12
    return diagnosis


def test_profile_regions_of_a_double_well_are_both_found():
    # SSE = (x² - 1)² + 0.1 lies below 0.2 where x² is within sqrt(0.1) of 1: two ranges.
    x = np.linspace(-2.0, 2.0, 4001)
    found = regions(x, (x**2 - 1) ** 2 + 0.1, 0.2)
    inner, outer = math.sqrt(1 - math.sqrt(0.1)), math.sqrt(1 + math.sqrt(0.1))
    np.testing.assert_allclose(np.array(found), [[-outer, -inner], [inner, outer]],
                               atol=1e-5)
    # Open ends where the profile stays below the threshold up to the grid's edge.
    assert regions(x, x**2, 5.0) == ((None, None),)
    assert regions(x, x, 0.0) == ((None, 0.0),)


def test_rtd_of_the_four_compartment_model_is_unchanged_by_swapping_k_f_and_k_s_when_tied():
    # With k_r = k_f every connection is two-way with one rate, and relabelling compartments
    # 2 and 3 maps the network onto itself with k_f and k_s exchanged.
    t = np.linspace(0.0, 15.0, 61)
    one = np.asarray(four_compartment_exit_age(t, 2.125, 2.125, 0.625, 0.8))
    other = np.asarray(four_compartment_exit_age(t, 0.625, 0.625, 2.125, 0.8))
    np.testing.assert_allclose(one, other, rtol=1e-12, atol=1e-14 * one.max())
    # Without the tie the symmetry is gone.
    assert np.max(np.abs(np.asarray(four_compartment_exit_age(t, 2.125, 1.0, 0.625, 0.8))
                         - np.asarray(four_compartment_exit_age(t, 0.625, 1.0, 2.125, 0.8)))) \
        > 1e-3 * one.max()


def test_profile_of_k_s_finds_the_mirror_solution_of_the_tied_fit(four_compartment_tied):
    result = four_compartment_tied
    k_f, k_s = result.values["k_f"], result.values["k_s"]
    profile = profile_likelihood(result, "k_s", np.geomspace(0.25, 5.0, 49))
    print(profile)
    assert profile.converged.all()
    assert len(profile.regions) == 2
    # The fit lands on either of the two mirror-image solutions (which one follows the
    # round-off of the processor): one region holds the fitted k_s, the other the fitted k_f.
    (low_1, high_1), (low_2, high_2) = profile.regions
    assert (low_1 < k_s < high_1 and low_2 < k_f < high_2) or (
        low_1 < k_f < high_1 and low_2 < k_s < high_2)
    # The mirror's own minimum equals the fit's: the re-fits there reach the fit's SSE to
    # within the grid's coarseness (a 6 % step in k_s; the profile is flat to second order).
    near_mirror = np.abs(np.log(profile.values / k_f)) < 0.07
    assert np.min(profile.sse[near_mirror]) < result.sse * (1 + 0.5 * (
        profile.threshold / result.sse - 1))


def test_report_names_the_twin_solution_of_a_tied_fit(four_compartment_tied, linear_fits):
    from fitting.report import identifiability_statements

    result = four_compartment_tied
    k_f, k_s = result.values["k_f"], result.values["k_s"]
    twins = [s for s in identifiability_statements(result) if s.startswith("Twin solution")]
    assert len(twins) == 1
    assert f"k_f = {k_s:.4g}, k_s = {k_f:.4g} fits exactly" in twins[0]
    # The twin it names fits exactly as well (the exchange symmetry, evaluated directly).
    one = np.asarray(four_compartment_exit_age(NETWORK_TIME, k_f, k_f, k_s, result.values["k_out"]))
    other = np.asarray(four_compartment_exit_age(NETWORK_TIME, k_s, k_s, k_f,
                                                 result.values["k_out"]))
    np.testing.assert_allclose(other, one, rtol=1e-10, atol=1e-13 * one.max())
    # Other models get no such statement.
    for fitted in linear_fits[2]:
        assert not any("Twin" in s or "mirror" in s for s in identifiability_statements(fitted))


def test_four_compartment_with_k_r_tied_to_k_f_is_identifiable(four_compartment_tied):
    diagnosis = _check_diagnosis(four_compartment_tied)
    assert diagnosis.poorly_determined == ()
    assert four_compartment_tied.values["k_r"] == four_compartment_tied.values["k_f"]


# The free fit walks k_r towards zero over hundreds of L-BFGS steps (the loss keeps falling
# by tiny amounts along a nearly flat valley), which takes minutes on two shared cores.
@pytest.mark.slow
def test_four_compartment_with_k_r_free_leaves_a_combination_undetermined():
    result = fit("four-compartment", _four_compartment_data(), START)
    diagnosis = _check_diagnosis(result)
    assert diagnosis.poorly_determined != ()


def test_equivalent_adm_and_axial_chain_of_a_four_compartment_fit(four_compartment_tied):
    tied = four_compartment_tied
    k_f, k_r = tied.values["k_f"], tied.values["k_r"]
    velocity, dispersion, _ = four_compartment_chain_transport(k_f, k_r, 0.31)
    assert velocity == pytest.approx((k_f - k_r) * 0.31 / 2, abs=1e-15)
    assert dispersion == pytest.approx((k_f + k_r) * 0.31**2 / 8)
    assert tied.equivalent_adm(0.31)[f"tau_{tied.curve.time_unit}"] > 0


def test_fit_many_pads_curves_of_different_lengths_with_zero_weights(linear_fits):
    observed, _, _ = linear_fits
    short = 20
    # Same padded shape as the fixture's batch, so the compiled solver is reused.
    results = fit_many(LINEAR, [(TIME, observed), (TIME[:short], observed[:short])])
    design = _basis(TIME[:short])
    estimate = np.linalg.lstsq(design, observed[:short], rcond=None)[0]
    padded = results[1]
    assert padded.n_points == short and padded.dof == short - 3
    assert padded.residuals.shape == (short,)
    for i, name in enumerate("abc"):
        assert padded.values[name] == pytest.approx(estimate[i], rel=0, abs=1e-6)


def test_network_file_model_reproduces_the_four_compartment_curve(tmp_path):
    from axialmix.network import four_compartment
    from fitting.models import network_model

    path = tmp_path / "four.json"
    four_compartment(2.0, 1.0, 0.5, 1.5).to_json(path)
    every_rate = network_model(path)
    assert "k_out_C4" in every_rate.parameter_names
    grouped = network_model(path, groups={
        "k_f": ["k_C1_C2", "k_C3_C4"], "k_r": ["k_C2_C1", "k_C4_C3"],
        "k_s": ["k_C1_C3", "k_C3_C1", "k_C2_C4", "k_C4_C2"], "k_out": ["k_out_C4"],
    })
    assert grouped.parameter_names == ("k_f", "k_r", "k_s", "k_out")
    time = np.linspace(0.0, 10.0, 25)
    rates = {"k_f": 0.7, "k_r": 0.2, "k_s": 0.9, "k_out": 0.4}
    np.testing.assert_allclose(grouped(time, rates),
                               four_compartment_exit_age(time, *rates.values()), rtol=1e-10,
                               atol=1e-14)
    np.testing.assert_allclose(every_rate(time, every_rate.parameters().valuesdict()),
                               four_compartment_exit_age(time, 2.0, 1.0, 0.5, 1.5), rtol=1e-10,
                               atol=1e-14)
