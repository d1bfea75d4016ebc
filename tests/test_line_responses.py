"""Tests of disturbance responses, funnel plots and variance reduction ratios (axialmix.line)."""

import jax
import numpy as np
import pytest
from scipy.integrate import quad

from axialmix import rtd
from axialmix.line import (
    Disturbance,
    FunnelSettings,
    Line,
    Unit,
    funnel,
    outlet_response,
    series_variance_reduction_ratio,
    spectral_variance_reduction_ratio,
    white_noise_variance_reduction_ratio,
)

DURATIONS = np.array([0.125, 0.375, 1.0, 3.0])  # multiples of rtdpy's step 2**-10
MAGNITUDES = np.array([-1.0, 2.0])


# ------------------------------------------------------------------ funnel
@pytest.mark.parametrize("n_tanks, step", [(1.0, 2.0**-14), (2.0, 2.0**-10), (5.0, 2.0**-10),
                                           (20.0, 2.0**-10)])
def test_funnel_equals_rtdpy_funnelplot_for_tanks_in_series(n_tanks, step):
    rtdpy = pytest.importorskip("rtdpy")
    ours = funnel(Unit.tanks(1.0, n_tanks), DURATIONS, MAGNITUDES)
    # rtdpy convolves with a rectangle rule; with durations on its grid its error at the
    # worst time is O(step²), except for one tank (E(0) = 1/tau), where it is step/2 of the
    # deviation: hence the finer step there (1.5e-5 relative).
    model = rtdpy.Ncstr(tau=1.0, n=n_tanks, dt=step, time_end=14.0)
    _, _, theirs = model.funnelplot(DURATIONS, MAGNITUDES)
    scale = np.abs(theirs).max()
    assert np.abs(np.asarray(ours.max_deviation) - theirs).max() < 1e-4 * scale


def test_funnel_equals_rtdpy_funnelplot_for_the_closed_adm_within_its_grid_error():
    rtdpy = pytest.importorskip("rtdpy")
    ours = np.asarray(funnel(Unit.closed_closed(1.0, 20.0), DURATIONS, MAGNITUDES).max_deviation)
    coarse, fine = (
        rtdpy.AD_cc(tau=1.0, peclet=20.0, dt=2.0**-10, time_end=6.0, nx=nx).funnelplot(
            DURATIONS, MAGNITUDES)[2]
        for nx in (200, 400)
    )
    # rtdpy's method of lines is second order in its nodes: (fine - coarse) / 3 estimates the
    # error of `fine` (3e-5 of the largest deviation here), and the extrapolated
    # (4 fine - coarse) / 3 must agree with the exact funnel to a tenth of that correction.
    correction = np.abs(fine - coarse).max()
    assert np.abs(ours - fine).max() < correction / 3 * 1.2
    assert np.abs(ours - (4 * fine - coarse) / 3).max() < 0.1 * correction


def test_funnel_of_a_stirred_tank_is_its_cumulative_distribution():
    # E decreases from t = 0, so the worst window starts with the disturbance: 1 - e^{-d/tau}.
    result = funnel(Unit.tanks(2.0, 1.0), DURATIONS, MAGNITUDES)
    np.testing.assert_allclose(result.max_fraction, -np.expm1(-DURATIONS / 2.0), rtol=1e-13)
    np.testing.assert_allclose(result.worst_time, DURATIONS, rtol=1e-9)


@pytest.mark.parametrize("unit", [Unit.closed_closed(1.0, 20.0), Unit.open_open(1.0, 5.0)])
def test_funnel_equals_the_peak_of_an_exact_convolution_with_a_square(unit):
    # Independent route without F: convolve E with each square on a fine grid and take the
    # largest value. The grid square falls from 1 to 0 over two steps around d (a jump cannot
    # be sampled) and E is linear between samples: an O(h²) error, measured 2.4e-6 of the
    # value at h = 1e-3 for the ADM, hence the tolerance.
    step = 1e-3
    t = np.arange(0.0, 12.0 + step / 2, step)
    exit_age = np.asarray(unit.exit_age(t))
    result = funnel(unit, DURATIONS, np.array([1.0]))
    for duration, worst, worst_time in zip(DURATIONS, np.asarray(result.max_fraction),
                                           np.asarray(result.worst_time), strict=True):
        square = (t < duration - step / 2).astype(float) + 0.5 * (np.abs(t - duration) < step / 2)
        outlet = np.asarray(rtd.convolve(t, exit_age, square))
        assert worst == pytest.approx(outlet.max(), rel=1e-5)
        assert worst_time == pytest.approx(t[np.argmax(outlet)], abs=0.02)


def test_funnel_of_a_line_and_its_units():
    line = Line(Unit.closed_closed(1.0, 50.0), Unit.tanks(0.5, 2.0))
    result = funnel(line, DURATIONS, MAGNITUDES, magnitude_unit="%")
    assert result.max_deviation.shape == (MAGNITUDES.size, DURATIONS.size)
    np.testing.assert_allclose(result.max_deviation, MAGNITUDES[:, None] * result.max_fraction)
    # The line damps more than its blender alone, and a long square passes completely.
    alone = funnel(line.units[0], DURATIONS, MAGNITUDES).max_fraction
    assert np.all(np.asarray(result.max_fraction) < np.asarray(alone))
    long = funnel(line, np.full(DURATIONS.size, 40.0), MAGNITUDES)
    np.testing.assert_allclose(long.max_fraction, 1.0, atol=1e-9)
    assert result.to_dict()["max_deviation"] == np.asarray(result.max_deviation).tolist()
    assert result.to_dict()["magnitude_unit"] == "%"


@pytest.mark.study
def test_funnel_differentiates_in_the_model_parameters():
    def worst(peclet):
        return funnel(Unit.closed_closed(1.0, peclet), [0.375], [1.0],
                      settings=FunnelSettings(grid_points=256)).max_fraction[0]

    gradient = jax.grad(worst)(20.0)
    step = 1e-3
    finite = (worst(20.0 + step) - worst(20.0 - step)) / (2 * step)
    assert float(gradient) == pytest.approx(float(finite), rel=1e-6)


def test_funnel_rejects_bad_durations():
    with pytest.raises(ValueError, match="durations must be positive"):
        funnel(Unit.tanks(1.0, 2.0), [0.0, 1.0], [1.0])


# ------------------------------------------------------------------ responses
def test_trace_response_equals_adaptive_convolution_with_the_interpolated_trace():
    unit = Unit.tanks(5.0, 3.0)
    times = np.linspace(0.0, 30.0, 61)
    rng = np.random.default_rng(3)
    values = rng.normal(0.0, 1.0, times.size)
    disturbance = Disturbance.trace(times, values)
    on_samples = outlet_response(unit, disturbance, times)  # FFT path
    between = np.array([3.3, 11.1, 29.9, 34.0])
    off_samples = outlet_response(unit, disturbance, between)  # direct path

    def inlet(s):
        return np.interp(s, times, values) if s >= times[0] else 0.0

    def exit_age(s):
        return 27.0 / 125.0 / 2.0 * s**2 * np.exp(-0.6 * s) if s > 0 else 0.0

    for t, got in [(times[k], on_samples.outlet[k]) for k in (7, 30, 60)] + list(
        zip(between, off_samples.outlet, strict=True)
    ):
        expected = quad(lambda s, t=t: inlet(s) * exit_age(t - s), 0.0, t,
                        points=times[times < t], limit=400, epsabs=1e-13)[0]
        assert float(got) == pytest.approx(expected, abs=1e-11)
    np.testing.assert_allclose(on_samples.inlet, values, atol=1e-15)


def test_trace_response_of_a_network_unit_equals_the_network_outlet_response():
    # axialmix.network integrates the piecewise-linear inlet by an augmented matrix
    # exponential, state by state: an independent route to the same outlet.
    from axialmix.network import four_compartment
    from axialmix.network import outlet_response as network_outlet_response

    network = four_compartment(2.125, 2.125, 0.625, 1.0)
    times = np.linspace(0.0, 12.0, 49)
    values = np.cos(times) ** 2 + 0.5
    line_route = outlet_response(Unit.network(network), Disturbance.trace(times, values), times)
    np.testing.assert_allclose(line_route.outlet, network_outlet_response(network, times, values),
                               atol=1e-12)


def test_ramp_response_of_a_stirred_tank_has_its_closed_form():
    tau, magnitude, duration, start = 4.0, 0.3, 6.0, 2.0
    t = np.array([1.0, 3.0, 7.9, 8.0, 15.0])
    response = outlet_response(Unit.tanks(tau, 1.0), Disturbance.ramp(magnitude, duration, start),
                               t)

    def unit_ramp(x):  # response of a stirred tank to the ramp u = x: x - tau (1 - e^{-x/tau})
        x = np.maximum(x, 0.0)
        return x - tau * (1.0 - np.exp(-x / tau))

    expected = magnitude / duration * (unit_ramp(t - start) - unit_ramp(t - start - duration))
    np.testing.assert_allclose(response.outlet, expected, rtol=1e-12, atol=1e-15)


def test_responses_add_and_match_their_definitions():
    unit = Unit.closed_closed(2.0, 15.0)
    t = np.linspace(0.0, 10.0, 41)
    step = Disturbance.step(0.2, 1.0)
    pulse = Disturbance.pulse(0.5, 3.0)
    square = Disturbance.square(-0.1, 2.0, 4.0)
    total = outlet_response(unit, step + pulse + square, t).outlet
    expected = (0.2 * unit.cumulative(t - 1.0) + 0.5 * unit.exit_age(t - 3.0)
                - 0.1 * (unit.cumulative(t - 4.0) - unit.cumulative(t - 6.0)))
    np.testing.assert_allclose(total, expected, atol=1e-14)
    with pytest.raises(ValueError, match="different units"):
        step + Disturbance.step(1.0, value_unit="%")
    with pytest.raises(ValueError, match="the disturbance is in"):
        outlet_response(unit, Disturbance.step(1.0, time_unit="min"), t)


# ------------------------------------------------------------------ variance reduction
def test_spectral_vrr_of_band_limited_noise_has_its_closed_form():
    # |G(i w)|² = 1 / (1 + (w tau / n)²)^n; for n = 1, 2 its integral over [0, W] is elementary.
    tau, band = 3.0, 2.0
    w = np.linspace(0.0, band, 200001)
    flat = np.ones_like(w)
    x = band * tau
    assert float(spectral_variance_reduction_ratio(Unit.tanks(tau, 1.0), w, flat)) == (
        pytest.approx(x / np.arctan(x), rel=1e-9))
    y = x / 2.0
    exact_two = band / ((y / (1 + y**2) + np.arctan(y)) / (2 * tau / 2.0))
    assert float(spectral_variance_reduction_ratio(Unit.tanks(tau, 2.0), w, flat)) == (
        pytest.approx(exact_two, rel=1e-9))


def test_vrr_from_the_transfer_function_equals_the_discrete_white_noise_formula():
    # Feed held for dt between independent samples: spectrum dt sinc²(w dt / 2) with
    # ∫_0^∞ = pi; the outlet variance from |G|² (averaged over the sampling phase) equals the
    # discrete 1 / Σ w_k² up to aliasing, which is negligible for this smooth RTD.
    unit = Unit.closed_closed(60.0, 30.0)
    dt = 1.0
    w = np.linspace(0.0, 3.0, 300001)
    spectrum = dt * np.sinc(w * dt / (2 * np.pi)) ** 2
    gain = np.asarray(unit.frequency_response(w)) ** 2
    spectral = np.pi / np.trapezoid(gain * spectrum, w)
    discrete = float(white_noise_variance_reduction_ratio(unit, dt, hold="zero"))
    assert discrete == pytest.approx(spectral, rel=1e-9)
    # Both tend to MODELS.md §8's 1 / (dt ∫E² dt) when dt is small against the spread.
    e = lambda t: float(unit.exit_age(np.array([t]))[0])  # noqa: E731
    integral = quad(lambda t: e(t) ** 2, 0.0, 400.0, limit=400)[0]
    assert discrete == pytest.approx(1.0 / (dt * integral), rel=1e-3)
    linear = float(white_noise_variance_reduction_ratio(unit, dt))
    assert linear == pytest.approx(1.0 / (dt * integral), rel=1e-3)


@pytest.mark.study
def test_series_vrr_of_simulated_white_noise_matches_the_linear_hold_formula():
    unit = Unit.tanks(20.0, 3.0)
    dt = 1.0
    times = np.arange(0.0, 200000.0, dt)
    trace = np.random.default_rng(11).normal(0.3, 0.05, times.size)
    measured = float(series_variance_reduction_ratio(unit, times, trace))
    predicted = float(white_noise_variance_reduction_ratio(unit, dt))
    # The outlet variance is estimated from 2e5 correlated samples (correlation time about
    # 20 samples): a relative standard error near 1.5 %; 4 standard errors allowed.
    assert measured == pytest.approx(predicted, rel=0.06)
