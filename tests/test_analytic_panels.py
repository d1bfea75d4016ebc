"""The closed–closed E from Chebyshev panels of exact values (axialmix.analytic.panels): the
same curve as the exact E to 1e-10 of the peak for Pe 0.1 to 1000, narrow peaks included; its
derivatives those of the exact E; the self-check and its fall-back; the 'adm' model's use."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from axialmix.analytic import exit_age_closed, panels
from axialmix.analytic.panels import (
    CHECK_TOLERANCE,
    LONG_CURVE,
    closed_panel_check,
    closed_panel_deviation,
    closed_support,
    exit_age_closed_panels,
)

#: The promise of a fit on panels: within this share of the peak of the exact E.
TOLERANCE = 1e-10
PECLETS = [0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0]
#: Space times over a sampled span of 0 to 100 (time unit): a peak narrow compared with the
#: span (tau 2: at Pe 1000 its width is 0.09, a thousandth of the span), mid-span, near and
#: past the end.
TAUS = [2.0, 20.0, 95.0, 150.0]


@pytest.mark.parametrize("peclet", PECLETS)
def test_panels_reproduce_the_exact_curve_to_1e_10_of_the_peak(peclet):
    # 20,001 samples over the span plus a log-spaced set from deep in the early rise to far
    # in the tail, where the cut-off support ends.
    t = np.unique(np.concatenate([np.linspace(0.0, 100.0, 20001), np.geomspace(1e-4, 1e4, 4001)]))
    for tau in TAUS:
        exact = np.asarray(exit_age_closed(t, tau, peclet))
        fast = np.asarray(exit_age_closed_panels(t, tau, peclet))
        lo, hi = (float(x) for x in closed_support(peclet))
        peak = np.max(np.asarray(exit_age_closed(tau * np.geomspace(lo, hi, 4001), tau, peclet)))
        assert np.max(np.abs(fast - exact)) <= TOLERANCE * peak, (peclet, tau)
        # The curve's own check is below its tolerance: the interpolant was used.
        assert closed_panel_check(tau, peclet) <= CHECK_TOLERANCE


def test_narrow_peak_sampled_coarsely_and_finely():
    # Pe 1000 at tau 1 over 0 to 100: the peak (width 0.045) holds a few samples of a
    # 100,000-sample curve, and none of a coarse one's but its flanks.
    for count in (100_001, 2_001):
        t = np.linspace(0.0, 100.0, count)
        exact = np.asarray(exit_age_closed(t, 1.0, 1000.0))
        fast = np.asarray(exit_age_closed_panels(t, 1.0, 1000.0))
        largest, peak = closed_panel_deviation(t, 1.0, 1000.0)
        assert peak >= np.max(exact)  # the peak of the curve, not of the samples
        assert largest == pytest.approx(np.max(np.abs(fast - exact)), abs=1e-300)
        assert largest <= TOLERANCE * peak


def test_support_ends_where_the_exact_curve_is_negligible():
    for peclet in [0.05, 0.1, 1.0, 10.0, 100.0, 1000.0, 2000.0]:
        lo, hi = (float(x) for x in closed_support(peclet))
        inside = np.geomspace(lo, hi, 2001)
        peak = np.max(np.asarray(exit_age_closed(inside, 1.0, peclet)))
        outside = np.concatenate([np.geomspace(lo * 1e-3, lo, 200), np.geomspace(hi, hi * 10, 200)])
        assert np.max(np.asarray(exit_age_closed(outside, 1.0, peclet))) <= 1e-14 * peak


def _jacobian(function, t, tau, peclet, dead_time=0.0):
    """d/d(tau, Pe, dead time) of ``function(t - dead_time, tau, Pe)``, forward mode."""

    def curve(q):
        return function(t - q[2], q[0], q[1])

    return np.asarray(jax.jacfwd(curve)(jnp.array([tau, peclet, dead_time])))


@pytest.mark.parametrize("peclet", [0.1, 1.0, 10.0, 100.0, 1000.0])
def test_derivatives_are_those_of_the_exact_curve(peclet):
    t = np.linspace(0.0, 100.0, 30001)
    tau = 20.0
    fast = _jacobian(lambda t, a, b: exit_age_closed_panels(t, a, b), t, tau, peclet, 0.3)
    exact = _jacobian(lambda t, a, b: exit_age_closed(t, a, b), t, tau, peclet, 0.3)
    for column in range(3):
        scale = np.max(np.abs(exact[:, column]))
        assert np.max(np.abs(fast[:, column] - exact[:, column])) <= 1e-10 * scale, column


def test_gradient_matches_central_differences():
    t = np.linspace(0.5, 60.0, 20001)
    weights = np.cos(t / 7.0)  # a loss that weighs every part of the curve

    def loss(q):
        return jnp.sum(weights * exit_age_closed_panels(t - q[2], q[0], q[1]))

    point = np.array([12.0, 25.0, 0.2])
    gradient = np.asarray(jax.grad(loss)(jnp.asarray(point)))
    for k in range(3):
        step = 1e-5 * max(abs(point[k]), 1.0)
        up, down = point.copy(), point.copy()
        up[k] += step
        down[k] -= step
        difference = (float(loss(jnp.asarray(up))) - float(loss(jnp.asarray(down)))) / (2 * step)
        assert gradient[k] == pytest.approx(difference, rel=1e-6, abs=1e-9 * np.abs(gradient).max())


def test_a_failed_check_falls_back_to_the_exact_curve_on_every_point():
    # Two panels of degree 2 cannot follow the curve: the check says so, and the evaluation
    # is the exact one (the same numbers), values and derivatives.
    t = np.linspace(0.0, 100.0, 5001)
    assert closed_panel_check(20.0, 10.0, panels=2, degree=2) > CHECK_TOLERANCE
    coarse = np.asarray(exit_age_closed_panels(t, 20.0, 10.0, panels=2, degree=2))
    exact = np.asarray(exit_age_closed(t, 20.0, 10.0))
    np.testing.assert_allclose(coarse, exact, rtol=1e-14, atol=1e-16 * exact.max())
    unchecked = np.asarray(exit_age_closed_panels(t, 20.0, 10.0, panels=2, degree=2, check=False))
    assert np.max(np.abs(unchecked - exact)) > 1e-6 * exact.max()
    derivative = _jacobian(lambda t, a, b: exit_age_closed_panels(t, a, b, panels=2, degree=2),
                           t, 20.0, 10.0)
    exact_derivative = _jacobian(lambda t, a, b: exit_age_closed(t, a, b), t, 20.0, 10.0)
    np.testing.assert_allclose(derivative, exact_derivative, rtol=1e-12,
                               atol=1e-14 * np.abs(exact_derivative).max())


def test_panels_trace_under_jit_with_traced_parameters():
    t = np.linspace(0.0, 50.0, 4001)
    jitted = jax.jit(lambda t, tau, peclet: exit_age_closed_panels(t, tau, peclet))
    np.testing.assert_allclose(jitted(t, 10.0, 30.0), exit_age_closed(t, 10.0, 30.0),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("kwargs, message", [
    ({"panels": 0}, "panels"), ({"degree": 1}, "degree"),
])
def test_bad_layouts_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        exit_age_closed_panels(np.linspace(0, 1, 5), 1.0, 1.0, **kwargs)


def test_negative_and_zero_times_give_zero():
    values = np.asarray(exit_age_closed_panels(np.array([-5.0, 0.0, 1e-9]), 1.0, 10.0))
    np.testing.assert_array_equal(values, 0.0)


def test_adm_model_uses_the_panels_only_for_long_curves():
    from fitting.models import get_model

    model = get_model("adm")
    params = {"tau": 20.0, "peclet": 10.0}
    short = np.linspace(0.0, 100.0, LONG_CURVE - 1)
    long = np.linspace(0.0, 100.0, LONG_CURVE)
    # Shorter curves: the exact E itself.
    np.testing.assert_array_equal(np.asarray(model(short, params)),
                                  np.asarray(exit_age_closed(short, 20.0, 10.0)))
    # Long curves: the panels, within their tolerance, measured on every point by the hook.
    values = np.asarray(model(long, params))
    np.testing.assert_array_equal(values, np.asarray(exit_age_closed_panels(long, 20.0, 10.0)))
    largest, peak = model.long_curve_check(long, params)
    # The check's exact E is compiled inside its own program, where t / tau may be rounded
    # differently from the eager evaluation's: equal to a few units in the last place of
    # the peak (the deviation itself is about 1e-14 of the peak).
    assert largest == pytest.approx(
        np.max(np.abs(values - np.asarray(exit_age_closed(long, 20.0, 10.0)))),
        abs=1e-15 * peak)
    assert largest <= TOLERANCE * peak
    # The response to a sampled inlet stays on the exact E.
    assert model.inlet_response is not None


def test_layout_constants_are_those_documented():
    assert panels.PANELS * (2 * panels.DEGREE + 1) < LONG_CURVE / 10
