"""Tests of axialmix.line units and lines against exact formulas and independent quadrature."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from axialmix import rtd
from axialmix.line import Line, LineSettings, Unit
from axialmix.network import four_compartment, tanks_in_series

ADM = Unit.closed_closed(1.0, 200.0, name="blender")
TANK = Unit.tanks(0.5, 1.0, name="hopper")
TIMES = np.linspace(0.0, 4.0, 401)


def _gauss(function, upper, panels):
    """∫_0^upper f by composite 12-point Gauss–Legendre quadrature, one vectorised call of f.

    Independent of the package's grids and rules; the panels used below are at most a tenth
    of the narrowest spread of the curves integrated, which makes the rule exact to round-off
    for these smooth (or, at t = 0, one-sided) integrands.
    """
    nodes, weights = np.polynomial.legendre.leggauss(12)
    edges = np.linspace(0.0, upper, panels + 1)
    half = np.diff(edges)[:, None] / 2
    points = (edges[:-1, None] + half * (nodes + 1)).ravel()
    return float(np.sum((half * weights).ravel() * np.asarray(function(points))))


def _numerical_convolution(first, second, t, panels=400):
    """∫_0^t E1(t - s) E2(s) ds by Gauss–Legendre quadrature (see :func:`_gauss`)."""
    return _gauss(lambda s: np.asarray(first(t - s)) * np.asarray(second(s)), t, panels)


def _laplace(unit, s, upper):
    """Numerical Laplace transform of a unit's E for real s (independent of G)."""
    return _gauss(lambda t: np.asarray(unit.exit_age(t)) * np.exp(-s * t), upper, 2000)


# ------------------------------------------------------------------ units
@pytest.mark.parametrize(
    "unit, upper",
    [
        (Unit.closed_closed(2.0, 7.5), 40.0),
        (Unit.open_open(2.0, 7.5), 60.0),
        (Unit.tanks(2.0, 3.5), 60.0),
        (Unit.network(four_compartment(2.125, 2.125, 0.625, 1.0)), 200.0),
    ],
)
def test_transfer_function_equals_numerical_laplace_transform_of_exit_age(unit, upper):
    for s in (0.0, 0.3, 1.7):
        expected = _laplace(unit, s, upper)
        assert complex(unit.transfer_function(s)) == pytest.approx(expected, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize(
    "unit, upper",
    [
        (Unit.closed_closed(2.0, 7.5), 40.0),
        (Unit.open_open(2.0, 7.5), 60.0),
        (Unit.tanks(2.0, 3.5), 60.0),
        (Unit.network(four_compartment(2.125, 2.125, 0.625, 1.0)), 200.0),
    ],
)
def test_unit_moments_equal_quadrature_of_exit_age(unit, upper):
    mean = _gauss(lambda t: t * np.asarray(unit.exit_age(t)), upper, 2000)
    second = _gauss(lambda t: (t - mean) ** 2 * np.asarray(unit.exit_age(t)), upper, 2000)
    assert float(unit.mean()) == pytest.approx(mean, rel=1e-9)
    assert float(unit.variance()) == pytest.approx(second, rel=1e-8)


def test_dead_zone_and_series_units_have_the_substituted_transfer_function_and_moments():
    # MODELS.md §6: G(s) = G_cc(s (1 + beta k_d / (s + k_d))), mean (1 + beta) tau, variance
    # (1 + beta)² v + 2 beta tau / k_d; an ADM then a tank multiplies G by 1 / (1 + s tau_t).
    tau, peclet, beta, k_d, tank = 3.0, 12.0, 0.4, 0.25, 0.8
    adm = Unit.closed_closed(tau, peclet)
    s = np.array([0.05, 0.3 + 0.2j, 1.5j])
    dead = Unit.closed_closed_exchange(tau, peclet, beta, k_d)
    substituted = s * (1 + beta * k_d / (s + k_d))
    np.testing.assert_allclose(dead.transfer_function(s), adm.transfer_function(substituted),
                               rtol=1e-12)
    assert float(dead.mean()) == pytest.approx((1 + beta) * tau, rel=1e-12)
    assert float(dead.variance()) == pytest.approx(
        (1 + beta) ** 2 * float(adm.variance()) + 2 * beta * tau / k_d, rel=1e-12)
    gamma = Unit.tanks(tau, 2.5)
    dead_tanks = Unit.tanks_exchange(tau, 2.5, beta, k_d)
    np.testing.assert_allclose(dead_tanks.transfer_function(s),
                               gamma.transfer_function(substituted), rtol=1e-12)
    series = Unit.closed_closed_tank(tau, peclet, tank)
    np.testing.assert_allclose(series.transfer_function(s),
                               adm.transfer_function(s) / (1 + s * tank), rtol=1e-12)
    assert float(series.mean()) == pytest.approx(tau + tank, rel=1e-12)
    assert float(series.variance()) == pytest.approx(float(adm.variance()) + tank**2, rel=1e-12)


def test_moments_from_transfer_function_match_the_closed_forms():
    # A model that gives only E, F and G: its moments come from G'(0) and G''(0).
    bare = Unit.from_model(
        type(ADM.model)(
            name="closed_without_moments",
            parameter_names=("tau", "peclet"),
            exit_age=ADM.model.exit_age,
            cumulative=ADM.model.cumulative,
            transfer_function=ADM.model.transfer_function,
        ),
        {"tau": 1.5, "peclet": 7.5},
    )
    exact = Unit.closed_closed(1.5, 7.5)
    assert float(bare.mean()) == pytest.approx(float(exact.mean()), rel=1e-12)
    assert float(bare.variance()) == pytest.approx(float(exact.variance()), rel=1e-10)


@pytest.mark.parametrize(
    "unit", [Unit.closed_closed(1.0, 50.0), Unit.open_open(1.0, 20.0), Unit.tanks(1.0, 2.5)]
)
def test_ramp_response_is_the_integral_of_the_cumulative_distribution(unit):
    times = np.array([0.3, 0.9, 1.1, 2.5, 6.0, 20.0])
    expected = [_gauss(unit.cumulative, t, 400) for t in times]
    # Romberg over [0, 20] where no closed form exists: about 1e-12 of the span, as documented.
    np.testing.assert_allclose(unit.ramp_response(times), expected, rtol=1e-12, atol=2e-11)
    # ∫_0^t F = t - mean + ∫_t^∞ (1 - F): exactly t - mean once the RTD has ended.
    assert float(unit.ramp_response(times)[-1]) == pytest.approx(20.0 - float(unit.mean()),
                                                                 rel=1e-12)


def test_network_unit_of_equal_tanks_equals_the_gamma_unit():
    # E, G and the moments of network units are checked against quadrature above; here the
    # cumulative curves: F and the ramp response (an augmented matrix exponential).
    network_unit = Unit.network(tanks_in_series(3, 2.0))
    gamma_unit = Unit.tanks(2.0, 3.0)
    t = np.array([0.1, 0.7, 2.0, 5.0])
    np.testing.assert_allclose(network_unit.cumulative(t), gamma_unit.cumulative(t), rtol=1e-12)
    np.testing.assert_allclose(network_unit.ramp_response(t), gamma_unit.ramp_response(t),
                               rtol=1e-12)


def test_empirical_unit_is_the_exact_piecewise_linear_curve():
    time = np.array([0.0, 1.0, 2.5, 3.0, 5.0])
    values = np.array([0.0, 2.0, 1.0, 0.5, 0.0])
    unit = Unit.empirical(time, values)
    area = np.trapezoid(values, time)
    # Interpolant, its integral, the exact moments and the transform, against quadrature.
    e = lambda t: np.interp(t, time, values, left=0.0, right=0.0) / area  # noqa: E731
    t = np.array([0.5, 1.7, 2.9, 4.0, 6.0])
    np.testing.assert_allclose(unit.exit_age(t), e(t), rtol=1e-14)
    f = [quad(e, 0.0, x, points=time, limit=200)[0] for x in t]
    np.testing.assert_allclose(unit.cumulative(t), f, rtol=1e-12)
    # ∫_0^x F = x F(x) - ∫_0^x s E(s) ds (integration by parts), one quadrature each.
    r = [x * fx - quad(lambda y: y * e(y), 0.0, x, points=time, limit=200)[0]
         for x, fx in zip(t, f, strict=True)]
    np.testing.assert_allclose(unit.ramp_response(t), r, rtol=1e-12)
    mean = quad(lambda x: x * e(x), 0.0, 5.0, points=time)[0]
    variance = quad(lambda x: (x - mean) ** 2 * e(x), 0.0, 5.0, points=time)[0]
    assert float(unit.mean()) == pytest.approx(mean, rel=1e-13)
    assert float(unit.variance()) == pytest.approx(variance, rel=1e-12)
    for s in (1e-9, 0.4, 2.0):
        expected = quad(lambda x, s=s: e(x) * np.exp(-s * x), 0.0, 5.0, points=time)[0]
        assert complex(unit.transfer_function(s)) == pytest.approx(expected, rel=1e-12)


def test_units_differentiate_in_their_parameters():
    t = jnp.array([0.5, 1.0, 1.5])

    def curve(peclet):
        return jnp.sum(Line(Unit.closed_closed(1.0, peclet), TANK).exit_age(t) * t)

    gradient = jax.grad(curve)(40.0)
    step = 1e-4
    finite = (curve(40.0 + step) - curve(40.0 - step)) / (2 * step)
    assert float(gradient) == pytest.approx(float(finite), rel=1e-6)


# ------------------------------------------------------------------ lines
def test_line_exit_age_equals_numerical_convolution_of_the_exact_curves():
    line = Line(ADM, TANK)
    exit_age = np.asarray(line.exit_age(TIMES))
    picks = [40, 90, 100, 105, 133, 200, 260, 399]
    expected = np.array([
        _numerical_convolution(ADM.exit_age, TANK.exit_age, TIMES[k]) for k in picks
    ])
    peak = exit_age.max()
    assert np.abs(exit_age[picks] - expected).max() < 1e-6 * peak
    # Between the grid nodes (interpolated) as well.
    off_grid = np.array([1.0137, 1.4411, 2.0003])
    expected = [_numerical_convolution(ADM.exit_age, TANK.exit_age, t) for t in off_grid]
    np.testing.assert_allclose(line.exit_age(off_grid), expected, atol=1e-6 * peak)


def test_line_means_and_variances_add_and_match_its_curve():
    line = Line(ADM, TANK, Unit.closed_closed(0.3, 20.0))
    assert float(line.mean()) == float(ADM.mean() + TANK.mean()) + 0.3
    expected_variance = float(ADM.variance() + TANK.variance() + Unit.closed_closed(0.3, 20.0)
                              .variance())
    assert float(line.variance()) == pytest.approx(expected_variance, rel=1e-15)
    # The moments of the computed curve (trapezoid on a fine grid whose O(h²) error is
    # about 1e-8 here) agree with the sums.
    t = np.linspace(0.0, 14.0, 14001)
    mean, variance = rtd.moments(t, line.exit_age(t))
    assert float(mean) == pytest.approx(float(line.mean()), rel=1e-7)
    assert float(variance) == pytest.approx(float(line.variance()), rel=1e-6)


def test_line_transfer_function_is_the_product_and_its_curves_agree():
    line = Line(ADM, TANK)
    s = np.array([0.0, 0.7, 2.0 + 1.0j])
    np.testing.assert_allclose(
        line.transfer_function(s), ADM.transfer_function(s) * TANK.transfer_function(s),
        rtol=1e-14,
    )
    # F and the ramp response of the line are the convolutions F_ADM ⊗ E_tank and
    # E_ADM ⊗ R_tank (the tank's R in closed form), by adaptive quadrature.
    t = np.array([0.8, 1.02, 1.3, 2.2, 3.9])
    peak = float(jnp.max(line.exit_age(TIMES)))
    expected_f = [_numerical_convolution(ADM.cumulative, TANK.exit_age, x) for x in t]
    expected_r = [_numerical_convolution(ADM.exit_age, TANK.ramp_response, x) for x in t]
    np.testing.assert_allclose(line.cumulative(t), expected_f, atol=1e-9 * peak)
    np.testing.assert_allclose(line.ramp_response(t), expected_r, atol=1e-9 * peak)


def test_measured_curves_in_a_line_are_convolved_exactly():
    # Two piecewise-linear curves on one uniform grid: rtd.convolve is exact for them, so the
    # line must reproduce it at the samples whatever its own grid.
    time = np.linspace(0.0, 10.0, 41)
    first = np.exp(-((time - 3.0) ** 2)) * (time < 7.0)
    second = time * np.exp(-time)
    line = Line(Unit.empirical(time, first), Unit.empirical(time, second))
    exact = rtd.convolve(time, first / np.trapezoid(first, time),
                         second / np.trapezoid(second, time))
    np.testing.assert_allclose(line.exit_age(time), exact, atol=1e-13)


def test_measured_curve_with_a_model_unit_matches_quadrature():
    time = np.linspace(0.0, 6.0, 61)
    values = np.maximum(0.0, np.sin(np.pi * time / 6.0)) ** 2
    line = Line(Unit.empirical(time, values), Unit.tanks(1.0, 2.0))
    area = np.trapezoid(values, time)

    def measured(s):
        return np.interp(s, time, values, left=0.0, right=0.0) / area

    def tanks(s):
        return 4.0 * s * np.exp(-2.0 * s) if s > 0 else 0.0

    t = np.array([1.0, 3.0, 6.0, 8.0])
    expected = [
        quad(lambda s, x=x: measured(s) * tanks(x - s), 0.0, x, points=time[time < x],
             limit=400, epsabs=1e-14, epsrel=1e-13)[0]
        for x in t
    ]
    np.testing.assert_allclose(line.exit_age(t), expected, atol=1e-9)


def test_line_rejects_inconsistent_units():
    with pytest.raises(ValueError, match="share one time unit"):
        Line(ADM, Unit.tanks(1.0, 2.0, time_unit="min"))
    with pytest.raises(ValueError, match="n_tanks >= 1"):
        Line(ADM, Unit.tanks(1.0, 0.5))
    with pytest.raises(ValueError, match="not uniformly sampled"):
        Line(ADM, Unit.empirical([0.0, 1.0, 3.0], [0.0, 1.0, 0.0]))
    with pytest.raises(ValueError, match="intervals must be"):
        LineSettings(intervals=4)


def test_unit_rejects_bad_parameters_with_one_line():
    with pytest.raises(ValueError, match="peclet must be positive"):
        Unit.closed_closed(1.0, -2.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        Unit.empirical([0.0, 2.0, 1.0], [0.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="continuous network"):
        Unit.network(tanks_in_series(2, 1.0, time_step=0.1))


def test_plots_draw_lines_responses_funnels_and_windows():
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    from axialmix.line import (
        Disturbance,
        conservative_diversion_window,
        funnel,
        outlet_response,
        plot_diversion,
        plot_funnel,
        plot_line,
        plot_response,
    )

    sample_times = np.arange(0.0, 31.0, 1.0)
    feeder = Unit.empirical(sample_times, sample_times * np.exp(-sample_times / 4.0),
                            name="feeder")

    def line_for(parameters):  # a measured feeder curve and a fitted blender
        return Line(feeder, Unit.tanks(parameters[0], parameters[1]))

    line = line_for(jnp.array([60.0, 3.0]))
    t = np.linspace(0.0, 300.0, 101)
    ax = plot_line(line, t)
    assert [text.get_text() for text in ax.get_legend().get_texts()] == [
        "feeder", "tanks", "line"]
    plot_response(outlet_response(line, Disturbance.ramp(0.1, 20.0, 10.0), t))
    plot_funnel(funnel(line, [5.0, 20.0, 80.0], [0.1, 0.2, 0.3], magnitude_unit="%"))
    # The fit-uncertainty route vmaps lines that hold a measured curve.
    window = conservative_diversion_window(
        line_for, [60.0, 3.0], np.diag([4.0, 0.01]), Disturbance.square(0.2, 30.0, 10.0), t,
        target=1.0, lower=0.97, upper=1.03, samples=4,
    )
    assert window.start <= window.nominal.start and window.stop >= window.nominal.stop
    plot_diversion(window)
    matplotlib.pyplot.close("all")
