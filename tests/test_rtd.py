"""Tests of axialmix.rtd against exact densities, exact quadrature sums and invariants."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import gamma as gamma_function
from scipy.special import gammainc

from axialmix import rtd


def gamma_density(time, shape, scale):
    """Gamma exit-age density (tanks in series) with mean shape*scale, variance shape*scale²."""
    return time ** (shape - 1) * np.exp(-time / scale) / (gamma_function(shape) * scale**shape)


def test_gamma_density_moments_match_exact_mean_and_variance():
    shape, scale = 3.0, 2.0
    time = np.linspace(0.0, 120.0, 6001)
    mean, var = rtd.moments(time, gamma_density(time, shape, scale))
    # The integrands have zero slope at t = 0 and the tail is 1e-21, so the Euler-Maclaurin
    # error starts at the h⁴ f''' term: about 1e-10 here, far below O(h²) = 4e-4.
    np.testing.assert_allclose(mean, shape * scale, rtol=1e-9)
    np.testing.assert_allclose(var, shape * scale**2, rtol=1e-9)


def test_trapezoid_area_of_exponential_equals_exact_geometric_sum():
    # Sum of the trapezoid rule for exp(-t/tau)/tau on [0, n h]: a geometric series.
    tau, step, n = 2.0, 0.25, 200
    time = step * np.arange(n + 1)
    r = np.exp(-step / tau)
    exact_sum = step / tau * ((1 - r ** (n + 1)) / (1 - r) - (1 + r**n) / 2)
    area = rtd.trapezoid(np.exp(-time / tau) / tau, time)
    np.testing.assert_allclose(area, exact_sum, rtol=1e-13)


def test_trapezoid_bias_for_exponential_is_second_order():
    # E'(0) = -1/tau²: the Euler-Maclaurin bias of the area is h²/(12 tau²); halving h quarters it.
    tau = 1.5
    biases = []
    for step in (0.2, 0.1, 0.05):
        time = np.arange(0.0, 60.0 + step / 2, step)
        biases.append(float(rtd.trapezoid(np.exp(-time / tau) / tau, time)) - 1.0)
        np.testing.assert_allclose(biases[-1], step**2 / (12 * tau**2), rtol=1e-2)
    ratios = np.array(biases[:-1]) / np.array(biases[1:])
    np.testing.assert_allclose(ratios, 4.0, rtol=1e-2)


def test_variance_of_exponential_on_non_uniform_grid_converges_at_second_order():
    tau = 1.0
    errors = []
    for n in (200, 400, 800):
        u = np.linspace(0.0, 1.0, n + 1)
        time = 40.0 * (u + 0.3 * u * (1 - u))  # smoothly graded, non-uniform steps
        _, var = rtd.moments(time, np.exp(-time / tau) / tau)
        errors.append(abs(float(var) - tau**2))
    assert errors[0] > errors[1] > errors[2]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 2.0, atol=0.15)


def test_normalise_gives_unit_area_for_a_scaled_signal():
    time = np.linspace(0.0, 30.0, 301)
    signal = 7.3 * gamma_density(time, 4.0, 1.2)
    exit_age = rtd.normalise(time, signal)
    np.testing.assert_allclose(rtd.trapezoid(exit_age, time), 1.0, rtol=1e-14)
    np.testing.assert_allclose(exit_age, signal / 7.3, rtol=1e-6)


def test_cumulative_of_gamma_density_matches_regularised_incomplete_gamma():
    shape, scale = 3.0, 1.0
    errors = []
    for n in (100, 200, 400):
        time = np.linspace(0.0, 20.0, n + 1)
        f = rtd.cumulative(time, gamma_density(time, shape, scale))
        assert f[0] == 0.0
        errors.append(np.max(np.abs(np.asarray(f) - gammainc(shape, time / scale))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 2.0, atol=0.1)


def test_exit_age_from_cumulative_recovers_gamma_density_at_second_order():
    shape = 3.0
    errors = []
    for n in (100, 200, 400):
        time = 20.0 * np.linspace(0.0, 1.0, n + 1) ** 1.5  # non-uniform
        exit_age = rtd.exit_age_from_cumulative(time, gammainc(shape, time))
        errors.append(np.max(np.abs(np.asarray(exit_age) - gamma_density(time, shape, 1.0))))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 2.0, atol=0.2)


def test_exit_age_from_cumulative_is_exact_for_quadratic_f():
    time = np.array([0.0, 0.3, 0.5, 1.1, 1.2, 2.0])
    f = 0.5 + 2.0 * time - 0.7 * time**2
    np.testing.assert_allclose(
        rtd.exit_age_from_cumulative(time, f), 2.0 - 1.4 * time, rtol=0, atol=1e-12
    )


def test_convolution_of_two_exponentials_matches_closed_form():
    a, b = 1.0, 2.5
    errors = []
    for n in (400, 800, 1600):
        time = np.linspace(0.0, 20.0, n + 1)
        out = rtd.convolve(time, a * np.exp(-a * time), b * np.exp(-b * time))
        exact = a * b / (b - a) * (np.exp(-a * time) - np.exp(-b * time))
        errors.append(np.max(np.abs(np.asarray(out) - exact)))
    assert errors[-1] < 1e-4
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(orders, 2.0, atol=0.1)


def test_convolution_is_exact_for_piecewise_linear_curves():
    rng = np.random.default_rng(7)
    time = np.linspace(0.0, 3.0, 31)
    exit_age = rng.uniform(0.0, 2.0, time.size)
    inlet = rng.uniform(-1.0, 1.0, time.size)
    # Independent exact reference: on each grid interval both interpolants are linear, so
    # their product is quadratic and Simpson's rule on that interval is exact.
    expected = np.zeros_like(time)
    for k in range(1, time.size):
        left, right = time[:k], time[1 : k + 1]
        middle = (left + right) / 2
        value = 0.0
        for s, weight in ((left, 1.0), (middle, 4.0), (right, 1.0)):
            value += weight * np.interp(s, time, inlet) * np.interp(time[k] - s, time, exit_age)
        expected[k] = np.sum(value * (right - left) / 6)
    np.testing.assert_allclose(rtd.convolve(time, exit_age, inlet), expected, atol=1e-13)


def test_convolution_of_linear_ramps_is_cubic():
    time = np.linspace(0.0, 2.0, 11)
    np.testing.assert_allclose(rtd.convolve(time, time, time), time**3 / 6, atol=1e-14)


def test_rtd_convolution_of_gamma_densities_is_gamma_with_summed_shape():
    time = np.linspace(0.0, 40.0, 2001)
    first = rtd.RTD(time, gamma_density(time, 2.0, 1.0))
    second = rtd.RTD(time, gamma_density(time, 3.0, 1.0))
    series = first.convolve(second)
    np.testing.assert_allclose(series.exit_age, gamma_density(time, 5.0, 1.0), atol=2e-5)
    np.testing.assert_allclose(series.mean(), first.mean() + second.mean(), rtol=1e-5)
    np.testing.assert_allclose(series.variance(), first.variance() + second.variance(), rtol=1e-4)
    # The convolution is cubic between samples, so its trapezoid area is off by O(h²), h = 0.02.
    np.testing.assert_allclose(series.cumulative()[-1], 1.0, rtol=1e-4)


def test_rtd_output_of_step_inlet_is_cumulative_distribution():
    time = np.linspace(0.0, 15.0, 1501)
    unit = rtd.RTD(time, gamma_density(time, 3.0, 1.0))
    np.testing.assert_allclose(unit.output(np.ones_like(time)), unit.cumulative(), atol=1e-12)


def test_rtd_from_signal_is_normalised_and_immutable():
    time = np.linspace(0.0, 30.0, 601)
    unit = rtd.RTD.from_signal(time, 5.0 * gamma_density(time, 3.0, 2.0))
    np.testing.assert_allclose(unit.integral(), 1.0, rtol=1e-14)
    with pytest.raises(AttributeError):
        unit.time = time  # type: ignore[misc]


def test_variance_gradient_wrt_rate_matches_finite_differences_and_exact():
    time = jnp.linspace(0.0, 60.0, 6001)

    def stirred_tank_variance(rate):
        return rtd.RTD(time, rate * jnp.exp(-rate * time)).variance()

    rate, h = 1.3, 1e-5
    gradient = jax.jit(jax.grad(stirred_tank_variance))(rate)
    central = (stirred_tank_variance(rate + h) - stirred_tank_variance(rate - h)) / (2 * h)
    np.testing.assert_allclose(gradient, central, rtol=1e-7)
    np.testing.assert_allclose(gradient, -2.0 / rate**3, rtol=1e-4)  # d(1/k²)/dk


def test_moments_vmap_over_a_batch_of_curves():
    time = jnp.linspace(0.0, 50.0, 2001)
    scales = jnp.array([0.5, 1.0, 2.0])
    curves = jax.vmap(lambda s: time**2 * jnp.exp(-time / s) / (2 * s**3))(scales)
    means = jax.vmap(lambda curve: rtd.mean_residence_time(time, curve))(curves)
    variances = rtd.variance(time, curves)  # batched along the leading axis directly
    for scale, curve, mean, var in zip(scales, curves, means, variances, strict=True):
        np.testing.assert_allclose(mean, rtd.mean_residence_time(time, curve), rtol=1e-13)
        np.testing.assert_allclose(var, rtd.variance(time, curve), rtol=1e-13)
        # Quadrature (h = 0.025, error O(h⁴) here) and the tail cut at t = 50: about 1e-7.
        np.testing.assert_allclose(mean, 3 * scale, rtol=1e-6)
        np.testing.assert_allclose(var, 3 * scale**2, rtol=1e-6)


@pytest.mark.parametrize(
    ("time", "curve", "message"),
    [
        ([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 1.0, 0.0], "strictly increasing"),
        ([0.0, 1.0, 2.0], [0.0, np.nan, 0.0], "exit_age must not be NaN"),
        ([0.0, 1.0, 2.0], [0.0, 1.0], "samples"),
    ],
)
def test_malformed_curves_raise_one_line_value_errors(time, curve, message):
    with pytest.raises(ValueError, match=message):
        rtd.moments(time, curve)


def test_convolution_rejects_non_uniform_grid():
    time = np.array([0.0, 1.0, 3.0, 4.0])
    with pytest.raises(ValueError, match="uniformly spaced"):
        rtd.convolve(time, np.ones(4), np.ones(4))
