"""Tests of the finite-volume ADM solver against the exact closed–closed solution."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import simpson

from axialmix.adm import (
    SolverConfig,
    dimensionless_parameters,
    exit_age,
    outlet_response,
    profiles,
    step_response,
)
from axialmix.analytic import (
    exit_age_closed,
    mean_closed,
    step_response_closed,
    variance_closed,
)

PECLET_NUMBERS = (0.1, 1.0, 10.0, 100.0, 1000.0)
# Level edges of the default resolution (both sides of each) and values in between.
PECLET_EDGES = (0.01, 2.5, 2.5001, 25.0, 25.0001, 180.0, 180.0001, 1300.0, 1300.01, 3000.0)
THETA = np.linspace(0.0, 3.0, 301)
# Long window for moments: E decays like exp(-theta) at Pe -> 0, so 40 tau leaves < 1e-17.
LONG_THETA = np.linspace(0.0, 40.0, 40001)


# One compiled program per function and shape, reused by every test: the Peclet number is
# traced, so the resolution level is selected at run time (lax.switch).
jit_exit_age = jax.jit(exit_age)
jit_step_response = jax.jit(step_response)


def peak_error(curve, reference):
    return float(np.max(np.abs(np.asarray(curve) - reference)) / np.max(reference))


@pytest.mark.parametrize("peclet", PECLET_NUMBERS)
def test_exit_age_matches_exact_closed_closed_solution(peclet):
    reference = np.asarray(exit_age_closed(THETA, 1.0, peclet))
    assert peak_error(jit_exit_age(THETA, 1.0, peclet), reference) <= 1e-3


@pytest.mark.parametrize("peclet", PECLET_EDGES)
def test_default_resolution_is_accurate_at_level_edges(peclet):
    reference = np.asarray(exit_age_closed(THETA, 1.0, peclet))
    assert peak_error(jit_exit_age(THETA, 1.0, peclet), reference) <= 1e-3


def test_exit_age_scales_with_tau():
    tau = 37.5
    t = THETA * tau
    reference = np.asarray(exit_age_closed(t, tau, 20.0))
    assert peak_error(jit_exit_age(t, tau, 20.0), reference) <= 1e-3


def moments(theta, curve):
    area = simpson(curve, x=theta)
    mean = simpson(theta * curve, x=theta) / area
    variance = simpson((theta - mean) ** 2 * curve, x=theta) / area
    return area, mean, variance


@pytest.mark.parametrize("peclet", PECLET_NUMBERS)
def test_closed_closed_exit_age_is_normalised(peclet):
    area, _, _ = moments(LONG_THETA, np.asarray(jit_exit_age(LONG_THETA, 1.0, peclet)))
    assert abs(area - 1.0) <= 1e-4


@pytest.mark.parametrize("peclet", PECLET_NUMBERS)
def test_closed_closed_mean_and_variance_match_exact_formulas(peclet):
    tau = 2.0
    t = LONG_THETA * tau
    _, mean, variance = moments(t, np.asarray(jit_exit_age(t, tau, peclet)))
    assert abs(mean / float(mean_closed(tau, peclet)) - 1.0) <= 1e-3
    assert abs(variance / float(variance_closed(tau, peclet)) - 1.0) <= 1e-3


@pytest.mark.parametrize("peclet", (0.1, 10.0, 1000.0))
def test_step_response_matches_exact_cumulative_distribution(peclet):
    reference = np.asarray(step_response_closed(THETA, 1.0, peclet))
    assert np.max(np.abs(np.asarray(jit_step_response(THETA, 1.0, peclet)) - reference)) <= 1e-3


@pytest.mark.parametrize("peclet", (1.0, 100.0))
def test_step_response_is_the_integral_of_the_exit_age(peclet):
    theta = np.linspace(0.0, 5.0, 5001)
    exit_curve = np.asarray(exit_age(theta, 1.0, peclet))
    cumulative = np.concatenate(
        [[0.0], np.cumsum((exit_curve[1:] + exit_curve[:-1]) / 2 * np.diff(theta))]
    )
    step = np.asarray(step_response(theta, 1.0, peclet))
    # Trapezoid error at spacing 1e-3 is below 1e-6 here; the rest is the two solves.
    assert np.max(np.abs(step - cumulative)) <= 1e-4


def exact_convolution(t, tau, peclet, inlet_times, inlet_values):
    """Outlet of a piecewise-linear inlet by direct quadrature of c_in(t - s) E(s)."""
    lag = np.linspace(0.0, t.max(), 20001)
    exit_curve = np.asarray(exit_age_closed(lag, tau, peclet))
    outlet = []
    for time in t:
        shifted = time - lag
        signal = np.interp(shifted, inlet_times, inlet_values, right=inlet_values[-1])
        signal = np.where(shifted < inlet_times[0], 0.0, signal)
        outlet.append(simpson(signal * exit_curve, x=lag))
    return np.asarray(outlet)


@pytest.mark.parametrize("peclet", (2.0, 60.0))
def test_outlet_response_is_the_convolution_with_the_exact_exit_age(peclet):
    rng = np.random.default_rng(3)
    tau = 10.0
    inlet_times = np.linspace(1.0, 25.0, 49)
    inlet_values = 1.0 + 0.3 * rng.standard_normal(inlet_times.size)
    t = np.linspace(0.0, 40.0, 41)
    reference = exact_convolution(t, tau, peclet, inlet_times, inlet_values)
    outlet = np.asarray(outlet_response(t, tau, peclet, inlet_times, inlet_values))
    assert np.max(np.abs(outlet - reference)) <= 1e-3 * np.max(np.abs(reference))


def test_outlet_response_to_a_constant_inlet_is_the_step_response():
    t = np.linspace(0.0, 30.0, 61)
    outlet = outlet_response(t, 5.0, 8.0, np.array([0.0, 1.0]), np.array([2.0, 2.0]))
    np.testing.assert_allclose(outlet, 2.0 * np.asarray(step_response(t, 5.0, 8.0)), atol=1e-12)


@pytest.mark.parametrize("peclet", (0.5, 20.0, 400.0))
def test_pulse_profiles_conserve_mass(peclet):
    # d/dt of the tracer inside = v (c_in - c_out): the amount left is 1 - F(t).
    tau = 3.0
    t = np.linspace(0.05, 3.0, 60) * tau
    x, concentration = profiles(t, tau, peclet)
    inside = np.asarray(concentration).mean(axis=1)  # integral over x of the cell averages
    left = 1.0 - np.asarray(step_response_closed(t, tau, peclet))
    assert x.shape == (concentration.shape[1],)
    assert np.max(np.abs(inside - left)) <= 1e-3


def test_step_profiles_fill_the_mixer():
    _, concentration = profiles(np.array([0.5, 2.0, 12.0]), 1.0, 5.0, inlet="step")
    concentration = np.asarray(concentration)
    assert np.all(np.diff(concentration[0]) < 0)  # front moving in from the inlet
    np.testing.assert_allclose(concentration[-1], 1.0, atol=1e-6)


def finite_difference_jacobian(function, params, relative_step=1e-5):
    columns = []
    for index in range(params.size):
        step = relative_step * params[index]
        up, down = params.copy(), params.copy()
        up[index] += step
        down[index] -= step
        columns.append((np.asarray(function(up)) - np.asarray(function(down))) / (2 * step))
    return np.stack(columns, axis=-1)


def weighted_square_loss(params, theta, weights):
    return jnp.sum(weights * exit_age(theta * params[0], params[0], params[1]) ** 2)


jit_loss = jax.jit(weighted_square_loss)
jit_loss_gradient = jax.jit(jax.grad(weighted_square_loss))


@pytest.mark.parametrize("peclet", PECLET_NUMBERS)
def test_gradients_match_central_finite_differences(peclet):
    theta = jnp.asarray(THETA) * 1.1
    weights = jnp.asarray(np.random.default_rng(0).uniform(0.5, 1.5, THETA.size))
    params = np.array([1.3, peclet])
    gradient = np.asarray(jit_loss_gradient(jnp.asarray(params), theta, weights))
    reference = finite_difference_jacobian(lambda p: jit_loss(p, theta, weights), params)
    np.testing.assert_allclose(gradient, reference, rtol=1e-5)


def test_forward_mode_works_with_default_settings():
    theta = jnp.asarray(THETA) * 1.1
    weights = jnp.asarray(np.random.default_rng(0).uniform(0.5, 1.5, THETA.size))
    params = jnp.array([1.3, 40.0])
    forward = jax.jit(jax.jacfwd(weighted_square_loss))(params, theta, weights)
    reverse = jit_loss_gradient(params, theta, weights)
    np.testing.assert_allclose(forward, reverse, rtol=1e-10)


def test_hessian_matches_finite_differences_of_the_gradient():
    theta = jnp.asarray(THETA) * 1.1
    config = SolverConfig.for_peclet(40.0)

    def loss(params):
        return jnp.sum(exit_age(theta * params[0], params[0], params[1], config=config) ** 2)

    params = np.array([1.3, 40.0])
    hessian = np.asarray(jax.jit(jax.hessian(loss))(jnp.asarray(params)))
    np.testing.assert_allclose(hessian, hessian.T, rtol=1e-8)
    gradient = jax.jit(jax.grad(loss))
    reference = finite_difference_jacobian(lambda p: gradient(jnp.asarray(p)), params)
    np.testing.assert_allclose(hessian, reference, rtol=1e-5)


def test_vmapped_gradients_agree_with_single_gradients():
    theta = jnp.asarray(THETA) * 1.1
    weights = jnp.ones(THETA.size)
    batch = jnp.array([[1.0, 0.5], [2.0, 20.0], [1.0, 500.0]])
    batched = jax.jit(jax.vmap(jit_loss_gradient, in_axes=(0, None, None)))(batch, theta, weights)
    for row, params in zip(np.asarray(batched), batch, strict=True):
        np.testing.assert_allclose(row, jit_loss_gradient(params, theta, weights), rtol=1e-10)


def test_jit_and_vmap_agree_with_single_calls():
    taus = np.array([0.7, 1.0, 2.0])
    pecletes = np.array([0.5, 20.0, 500.0])
    theta = jnp.asarray(THETA)
    batched = jax.jit(jax.vmap(lambda tau, pe: exit_age(theta * 2.0, tau, pe)))(taus, pecletes)
    for row, tau, pe in zip(np.asarray(batched), taus, pecletes, strict=True):
        np.testing.assert_allclose(row, exit_age(THETA * 2.0, tau, pe), rtol=1e-12, atol=1e-12)


def test_explicit_config_for_batches_is_accurate():
    config = SolverConfig.for_peclet(200.0)
    pecletes = jnp.array([50.0, 120.0, 200.0])
    theta = jnp.asarray(THETA)
    batched = jax.vmap(lambda pe: exit_age(theta, 1.0, pe, config=config))(pecletes)
    for row, pe in zip(np.asarray(batched), np.asarray(pecletes), strict=True):
        reference = np.asarray(exit_age_closed(THETA, 1.0, pe))
        assert peak_error(row, reference) <= 1e-3


def test_solver_config_time_nodes_reach_the_horizon():
    config = SolverConfig(cells=10, max_step=0.1, first_step=0.01, horizon=2.0)
    nodes = config.time_nodes()
    assert nodes[0] == 0.0 and nodes[-1] == 2.0
    assert np.all(np.diff(nodes) > 0) and np.max(np.diff(nodes)) <= 0.1 + 1e-12


def test_dimensionless_parameters_from_physical_values():
    tau, peclet = dimensionless_parameters(velocity=0.01, dispersion=1.7e-4, length=0.31)
    np.testing.assert_allclose([tau, peclet], [31.0, 0.01 * 0.31 / 1.7e-4], rtol=1e-14)


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: exit_age(THETA, -1.0, 10.0), "tau"),
        (lambda: exit_age(THETA, 1.0, 0.0), "peclet"),
        (lambda: exit_age(THETA, 1.0, np.nan), "peclet"),
        (lambda: exit_age(np.array([0.0, np.inf]), 1.0, 10.0), "t"),
        (lambda: step_response(THETA, 1.0, -5.0), "peclet"),
        (lambda: exit_age(THETA, 1.0, 10.0, config="fine"), "config"),
        (
            lambda: outlet_response(THETA, 1.0, 10.0, [0.0, 1.0, 1.0], [1.0, 2.0, 3.0]),
            "inlet_times",
        ),
        (lambda: outlet_response(THETA, 1.0, 10.0, [0.0, 1.0], [1.0, 2.0, 3.0]), "inlet_values"),
        (lambda: profiles(THETA, 1.0, 10.0, inlet="ramp"), "inlet"),
        (lambda: profiles(THETA[::-1], 1.0, 10.0), "t"),
        (lambda: SolverConfig(cells=2, max_step=0.1, first_step=0.01, horizon=2.0), "cells"),
        (lambda: SolverConfig(cells=20, max_step=0.1, first_step=0.5, horizon=2.0), "first_step"),
        (lambda: SolverConfig.for_peclet(-3.0), "peclet_max"),
        (lambda: dimensionless_parameters(1.0, 0.0, 1.0), "dispersion"),
    ],
)
def test_bad_arguments_raise_value_error_naming_them(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_fit_with_the_finite_volume_model_recovers_exact_parameters():
    # A fit vmaps the model inside the optimiser's while loop (batched predicate): the
    # default resolution dispatch must work there. Noise-free data from the exact solution;
    # the FV solver's own error (< 1e-3 of the peak) bounds the parameter error.
    from fitting.fit import fit
    from fitting.solve import Optimiser

    t = np.linspace(2.0, 120.0, 30)
    observed = np.asarray(exit_age_closed(t, 40.0, 25.0))
    # L-BFGS: Levenberg-Marquardt on the FV model's gradients crawls here (status SLOW).
    result = fit("adm-fv", (t, observed), optimiser=Optimiser(method="lbfgs"))
    assert result.converged, result.message
    assert result.values["tau"] == pytest.approx(40.0, rel=1e-3)
    assert result.values["peclet"] == pytest.approx(25.0, rel=1e-2)


@pytest.mark.parametrize("function", [exit_age, step_response])
def test_non_increasing_times_raise_value_error_naming_t(function):
    with pytest.raises(ValueError, match="t must be strictly increasing"):
        function(np.array([0.0, 2.0, 1.0]), 1.0, 10.0)


@pytest.mark.parametrize("peclet", [1e-3, 4000.0, 1e5])
def test_default_solver_refuses_a_concrete_peclet_outside_its_verified_range(peclet):
    from axialmix.adm import VERIFIED_PECLET_RANGE

    low, high = VERIFIED_PECLET_RANGE
    assert not low <= peclet <= high
    for function in (exit_age, step_response):
        with pytest.raises(ValueError, match="^peclet .* outside the range"):
            function(THETA, 1.0, peclet)


def test_traced_peclet_outside_the_verified_range_gives_nan_inside_it_the_curve():
    from axialmix.adm import VERIFIED_PECLET_RANGE

    low, high = VERIFIED_PECLET_RANGE
    peclets = jnp.array([0.5 * low, low, 1000.0, high, 1e5])
    curves = np.asarray(jax.vmap(lambda pe: jit_exit_age(THETA, 1.0, pe))(peclets))
    assert np.isnan(curves[[0, 4]]).all()
    inside = curves[1:4]
    assert np.isfinite(inside).all()
    for row, pe in zip(inside, peclets[1:4], strict=True):
        assert peak_error(row, np.asarray(exit_age_closed(THETA, 1.0, float(pe)))) <= 1e-3
    # Gradients at a Pe inside stay finite (the NaN branch does not leak into them).
    slope = jax.grad(lambda pe: jnp.sum(jit_exit_age(THETA, 1.0, pe)))(100.0)
    assert np.isfinite(float(slope))
    # An explicit config is the user's choice of resolution and is not checked.
    finer = SolverConfig(cells=1400, max_step=0.003, first_step=5e-4, horizon=1.3)
    curve = np.asarray(exit_age(THETA, 1.0, 4000.0, config=finer))
    assert peak_error(curve, np.asarray(exit_age_closed(THETA, 1.0, 4000.0))) <= 1e-3
