"""Dead-zone, series and sampled-inlet models of axialmix.analytic against independent references.

The references (tests/analytic_references.py) share nothing with the saddle-point inversion under
test: a time-domain subordination integral over the plain closed–closed density, a Chebyshev
method-of-lines model with an immobile-zone ODE per node, and exact matrix exponentials of the
equivalent compartment networks.

Compiling each model's inversion takes seconds, so the default suite keeps one cross-check (tanks
with dead zones against their network) and the argument checks; the rest is an opt-in study
(``pytest --studies -s tests/test_analytic_exchange.py``, about a quarter of an hour on two cores).
"""

import itertools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from analytic_references import (
    ChebyshevADM,
    exchange_exit_age_subordinated,
    exchange_step_response_subordinated,
    network_inlet_response,
    network_responses,
    tanks_exchange_network,
)
from scipy import special, stats

import axialmix.analytic as analytic
from axialmix.analytic import (
    ClosedClosedADM,
    ExchangeZone,
    OpenOpenADM,
    Series,
    StirredTank,
    TanksInSeries,
)
from axialmix.analytic._contour import closed_closed_curves

# One time grid (in units of tau) for most checks, so that few programs are compiled.
THETA = np.concatenate([np.linspace(0.05, 3.0, 60), [3.5, 4.0, 5.0, 7.0, 10.0, 20.0, 50.0, 100.0]])


def _relative_to_peak(values, reference):
    return float(np.max(np.abs(np.asarray(values) - reference)) / np.max(np.abs(reference)))


def _central_difference(function, x, relative_step=1e-5):
    step = relative_step * abs(x)
    return (function(x + step) - function(x - step)) / (2.0 * step)


# --- plain units: the new inversion against the closed forms -----------------------------


@pytest.mark.study
@pytest.mark.parametrize("peclet", [0.1, 8.0, 1000.0])
def test_exchange_without_dead_zone_reproduces_closed_closed_to_round_off(peclet):
    tau = 20.0
    t = THETA * tau
    unit = ExchangeZone(ClosedClosedADM(tau, peclet), 0.0, 0.05)
    exit_age = np.asarray(analytic.exit_age(unit, t))
    reference = np.asarray(analytic.exit_age_closed(t, tau, peclet))
    error = _relative_to_peak(exit_age, reference)
    step = np.asarray(analytic.step_response(unit, t))
    step_error = float(
        np.max(np.abs(step - np.asarray(analytic.step_response_closed(t, tau, peclet))))
    )
    print(f"Pe={peclet:g}: beta=0 vs closed-closed: E {error:.1e} of peak, F {step_error:.1e}")
    assert error <= 1e-12
    assert step_error <= 1e-12


@pytest.mark.study
@pytest.mark.parametrize(
    ("unit", "exit_age", "step"),
    [
        (
            TanksInSeries(2.0, 0.6),
            stats.gamma(a=0.6, scale=2.0 / 0.6).pdf,
            stats.gamma(a=0.6, scale=2.0 / 0.6).cdf,
        ),
        (
            TanksInSeries(2.0, 40.0),
            stats.gamma(a=40, scale=2.0 / 40).pdf,
            stats.gamma(a=40, scale=2.0 / 40).cdf,
        ),
        (StirredTank(2.0), stats.expon(scale=2.0).pdf, stats.expon(scale=2.0).cdf),
        (
            OpenOpenADM(2.0, 30.0),
            lambda t: np.asarray(analytic.exit_age_open(t, 2.0, 30.0)),
            lambda t: np.asarray(analytic.step_response_open(t, 2.0, 30.0)),
        ),
    ],
)
def test_plain_units_match_their_closed_forms(unit, exit_age, step):
    t = THETA * 2.0
    assert _relative_to_peak(analytic.exit_age(unit, t), exit_age(t)) <= 1e-12
    assert np.max(np.abs(np.asarray(analytic.step_response(unit, t)) - step(t))) <= 1e-12


@pytest.mark.study
def test_ramp_response_of_tanks_matches_its_closed_form():
    # ∫_0^t F = t P(n, n t/tau) - tau P(n + 1, n t/tau) for the gamma density.
    for n in [0.5, 3.0, 2000.0]:
        t = THETA * 2.0
        closed = t * special.gammainc(n, n * t / 2.0) - 2.0 * special.gammainc(n + 1, n * t / 2.0)
        ramp = np.asarray(analytic.ramp_response(TanksInSeries(2.0, n), t))
        assert np.max(np.abs(ramp - closed) / np.maximum(t, 1.0)) <= 1e-12


# --- the closed-closed ADM with a dead zone ----------------------------------------------

EXCHANGE_CASES = [
    # (Pe, beta, k_d tau): slow, intermediate and fast exchange; low and high Pe.
    (8.0, 1.0, 0.5),
    (1000.0, 5.0, 0.01),
    (1000.0, 0.2, 3.0),
    (1000.0, 1.0, 30.0),
    (100.0, 0.5, 100.0),
    (0.1, 5.0, 0.01),
    (0.1, 0.2, 100.0),
    # A nearly empty dead zone at high Pe: E came out 1.09e6 instead of 4.57 at theta 1.05
    # when the split was refused for G large on its circles, although e^{s t} makes up for it
    # at the times the split is used.
    (1000.0, 1e-6, 30.0),
    (300.0, 1e-4, 15.0),
]


@pytest.mark.study
@pytest.mark.parametrize(("peclet", "beta", "kappa"), EXCHANGE_CASES)
def test_exchange_exit_age_matches_subordination_integral(peclet, beta, kappa):
    exit_age = np.asarray(analytic.exit_age_exchange(THETA, 1.0, peclet, beta, kappa))
    reference = exchange_exit_age_subordinated(THETA, peclet, beta, kappa)
    error = _relative_to_peak(exit_age, reference)
    print(
        f"Pe={peclet:g} beta={beta:g} k_d tau={kappa:g}: max|E - E_ref| = {error:.1e} of the peak"
    )
    # Required: 1e-6 of the peak. Measured 1.4e-10 or better on the cases above.
    assert error <= 1e-8


@pytest.mark.study
@pytest.mark.parametrize(
    ("peclet", "beta", "kappa"),
    [
        (8.0, 1.0, 0.5),
        (1000.0, 5.0, 0.01),
        (300.0, 1.0, 3.0),
        (1000.0, 1e-6, 5.0),
        (70.0, 1e-6, 30.0),
        # Came out 8.5e4 where F is at most 1: the late form's saddle search read log(G - 1)
        # across its branch cut at real s > 0.
        (100.0, 2.0, 8.0),
        (300.0, 1.0, 10.0),
        # Outside the verified range of step responses (fast exchange at Pe above 70): it
        # warns, and loses digits here (0.13 where F is at most 1).
        pytest.param(
            100.0, 1e-6, 15.0,
            marks=pytest.mark.xfail(strict=True, reason="outside the verified range (warns)"),
        ),
    ],
)
def test_exchange_step_response_matches_subordination_integral(peclet, beta, kappa):
    theta = np.array([0.5, 0.9, 1.0, 1.1, 1.5, 2.0, 5.0, 20.0, 100.0])
    step = np.asarray(analytic.step_response_exchange(theta, 1.0, peclet, beta, kappa))
    reference = exchange_step_response_subordinated(theta, peclet, beta, kappa)
    error = float(np.max(np.abs(step - reference)))
    print(f"Pe={peclet:g} beta={beta:g} k_d tau={kappa:g}: max|F - F_ref| = {error:.1e}")
    assert error <= 1e-9


@pytest.mark.study
@pytest.mark.parametrize(
    ("peclet", "beta", "kappa"), [(10.0, 1.0, 0.3), (40.0, 5.0, 2.0), (3.0, 0.5, 20.0)]
)
def test_exchange_matches_chebyshev_method_of_lines(peclet, beta, kappa):
    step = 0.1
    theta = step * np.arange(1, 41)
    model = ChebyshevADM(peclet, beta, kappa, points=48)
    exit_age, cumulative = model.on_grid(step, theta.size)
    tau = 30.0  # dimensional: the exchange rate is k_d = kappa / tau
    t = theta * tau
    ours = np.asarray(analytic.exit_age_exchange(t, tau, peclet, beta, kappa / tau)) * tau
    ours_step = np.asarray(analytic.step_response_exchange(t, tau, peclet, beta, kappa / tau))
    error = _relative_to_peak(ours, exit_age)
    step_error = float(np.max(np.abs(ours_step - cumulative)))
    print(f"Pe={peclet:g} beta={beta:g}: method of lines E {error:.1e} of peak, F {step_error:.1e}")
    assert error <= 1e-8
    assert step_error <= 1e-8


@pytest.mark.study
def test_exchange_exit_age_integrates_to_one_with_the_exact_moments():
    peclet, beta, kappa = 20.0, 1.0, 1.0
    u = np.linspace(0.0, np.sqrt(60.0), 20001)
    theta = u**2
    weights = np.full(u.size, u[1] - u[0]) * 2.0 * u
    weights[[0, -1]] *= 0.5
    exit_age = np.asarray(analytic.exit_age_exchange(theta, 1.0, peclet, beta, kappa))
    area = np.sum(weights * exit_age)
    mean = np.sum(weights * theta * exit_age)
    variance = np.sum(weights * (theta - mean) ** 2 * exit_age)
    assert abs(area - 1.0) <= 1e-10
    assert mean == pytest.approx(float(analytic.mean_exchange(1.0, beta)), rel=1e-10)
    assert variance == pytest.approx(
        float(analytic.variance_exchange(1.0, peclet, beta, kappa)), rel=1e-9
    )


@pytest.mark.study
def test_step_response_reaches_one_after_a_slow_dead_zone_empties():
    # k_d tau = 0.01: the last tracer leaves the dead zone after thousands of tau.
    theta = np.array([1.0, 10.0, 100.0, 1000.0, 5000.0, 2e4])
    step = np.asarray(analytic.step_response_exchange(theta, 1.0, 1000.0, 5.0, 0.01))
    # Increasing until F is 1 to the accuracy of the inversion (a few 1e-14).
    assert np.all(np.diff(step) > -1e-13)
    assert step[-1] == pytest.approx(1.0, abs=1e-12)
    # About 1 - e^{-β k_d tau} = 4.9 % of the tracer visits the dead zone and leaves late.
    assert 0.04 < 1.0 - step[1] < 0.049
    reference = exchange_step_response_subordinated(theta[:4], 1000.0, 5.0, 0.01)
    assert np.max(np.abs(step[:4] - reference)) <= 1e-10


UNITS = {
    "adm-exchange": ExchangeZone(ClosedClosedADM(3.0, 40.0), 2.0, 0.2),
    "tanks-exchange": ExchangeZone(TanksInSeries(3.0, 4.5), 0.7, 1.5),
    "open-exchange": ExchangeZone(OpenOpenADM(3.0, 15.0), 1.0, 0.5),
    "series": Series(ExchangeZone(ClosedClosedADM(3.0, 40.0), 2.0, 0.2), StirredTank(0.4)),
    "tanks-series": Series(TanksInSeries(3.0, 6.0), StirredTank(1.0), ClosedClosedADM(2.0, 9.0)),
}


@pytest.mark.study
@pytest.mark.parametrize("name", sorted(UNITS))
def test_moments_are_the_taylor_coefficients_of_the_transfer_function(name):
    unit = UNITS[name]

    def cumulant(x):
        return jnp.real(unit.log_transfer(x.astype(complex)))

    slope = jax.grad(cumulant)(jnp.zeros(()))
    curvature = jax.grad(jax.grad(cumulant))(jnp.zeros(()))
    assert float(-slope) == pytest.approx(float(unit.mean()), rel=1e-12)
    assert float(curvature) == pytest.approx(float(unit.variance()), rel=1e-10)
    assert complex(unit.transfer(0.0)) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.study
def test_series_means_and_variances_add():
    first = ExchangeZone(ClosedClosedADM(3.0, 40.0), 2.0, 0.2)
    second = StirredTank(0.4)
    both = Series(first, second)
    assert float(both.mean()) == pytest.approx(float(first.mean() + second.mean()), rel=1e-15)
    assert float(both.variance()) == pytest.approx(
        float(first.variance() + second.variance()), rel=1e-15
    )
    # And the curves: the numerical moments of the series' E are those sums.
    t = np.linspace(0.0, 400.0, 40001)
    exit_age = np.asarray(analytic.exit_age(both, t))
    mean = np.trapezoid(t * exit_age, t)
    assert np.trapezoid(exit_age, t) == pytest.approx(1.0, abs=1e-8)
    assert mean == pytest.approx(float(both.mean()), rel=1e-7)
    assert np.trapezoid((t - mean) ** 2 * exit_age, t) == pytest.approx(
        float(both.variance()), rel=1e-6
    )


def test_variance_of_the_dead_zone_model_matches_its_formula():
    tau, peclet, beta, rate = 7.0, 12.0, 0.8, 0.3
    expected = (1 + beta) ** 2 * float(
        analytic.variance_closed(tau, peclet)
    ) + 2 * beta * tau / rate
    assert float(analytic.variance_exchange(tau, peclet, beta, rate)) == pytest.approx(
        expected, rel=1e-14
    )
    assert float(analytic.mean_exchange(tau, beta)) == pytest.approx((1 + beta) * tau, rel=1e-15)
    assert float(analytic.variance_tanks_exchange(tau, 3.0, beta, rate)) == pytest.approx(
        (1 + beta) ** 2 * tau**2 / 3.0 + 2 * beta * tau / rate, rel=1e-14
    )


# --- tanks with dead zones: an exact compartment network ---------------------------------


def test_tanks_with_dead_zones_match_the_network_on_a_small_grid():
    # The default suite's one cross-check: 16 points, one compiled program.
    tau, t = 4.0, 0.25 * np.arange(1, 17) * 4.0
    exit_age, _, _ = network_responses(*tanks_exchange_network(3, tau, 5.0, 0.05), t)
    ours = analytic.exit_age(ExchangeZone(TanksInSeries(tau, 3.0), 5.0, 0.05), t)
    # Measured 2e-13 of the peak; the requirement is 1e-6.
    assert _relative_to_peak(ours, exit_age) <= 1e-10


@pytest.mark.study
@pytest.mark.parametrize(
    ("n_tanks", "beta", "rate"), [(1, 0.5, 2.0), (3, 5.0, 0.05), (12, 1.0, 0.4)]
)
def test_tanks_with_dead_zones_match_the_equivalent_network(n_tanks, beta, rate):
    tau = 4.0
    t = THETA * tau
    exit_age, step, ramp = network_responses(*tanks_exchange_network(n_tanks, tau, beta, rate), t)
    unit = ExchangeZone(TanksInSeries(tau, float(n_tanks)), beta, rate)
    errors = (
        _relative_to_peak(analytic.exit_age(unit, t), exit_age),
        float(np.max(np.abs(np.asarray(analytic.step_response(unit, t)) - step))),
        float(
            np.max(np.abs(np.asarray(analytic.ramp_response(unit, t)) - ramp) / np.maximum(t, 1.0))
        ),
    )
    print(f"n={n_tanks} beta={beta:g} k_d={rate:g}: E, F, R errors {errors}")
    assert max(errors) <= 1e-10


# --- series ------------------------------------------------------------------------------


@pytest.mark.study
@pytest.mark.parametrize(
    ("peclet", "beta", "kappa", "tank"), [(10.0, 0.0, 1.0, 0.3), (25.0, 1.0, 0.5, 0.05)]
)
def test_adm_then_stirred_tank_matches_method_of_lines(peclet, beta, kappa, tank):
    step = 0.1
    theta = step * np.arange(1, 41)
    exit_age, cumulative = ChebyshevADM(peclet, beta, kappa, points=48, tank=tank).on_grid(
        step, theta.size
    )
    unit = Series(ExchangeZone(ClosedClosedADM(1.0, peclet), beta, kappa), StirredTank(tank))
    error = _relative_to_peak(analytic.exit_age(unit, theta), exit_age)
    step_error = float(np.max(np.abs(np.asarray(analytic.step_response(unit, theta)) - cumulative)))
    print(
        f"Pe={peclet:g} beta={beta:g} k_d tau={kappa:g} tank={tank:g}: method of lines "
        f"E {error:.1e} of peak, F {step_error:.1e}"
    )
    assert error <= 1e-8
    assert step_error <= 1e-8


@pytest.mark.study
@pytest.mark.parametrize(("peclet", "tank"), [(1000.0, 0.01), (1000.0, 0.1), (200.0, 2.0)])
def test_adm_then_stirred_tank_matches_convolution_at_high_peclet(peclet, tank):
    # E(t) = ∫_0^t E_cc(u) e^{-(t-u)/tank} / tank du, by composite Gauss–Legendre.
    theta = np.array([0.8, 0.95, 1.0, 1.05, 1.2, 1.5, 2.0, 3.0])
    x, w = np.polynomial.legendre.leggauss(20)
    reference = []
    for t in theta:
        edges = np.unique(
            np.concatenate([np.linspace(0, t, 401), np.clip(1 + np.linspace(-0.3, 0.3, 301), 0, t)])
        )
        a, b = edges[:-1], edges[1:]
        u = (0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * x).ravel()
        weights = (0.5 * (b - a)[:, None] * w).ravel()
        e0 = np.asarray(closed_closed_curves(u, peclet)[0])
        reference.append(np.sum(weights * e0 * np.exp(-(t - u) / tank) / tank))
    reference = np.array(reference)
    unit = Series(ClosedClosedADM(1.0, peclet), StirredTank(tank))
    error = _relative_to_peak(analytic.exit_age(unit, theta), reference)
    print(f"Pe={peclet:g} tank={tank:g}: {error:.1e} of the peak")
    assert error <= 1e-9


# --- sampled inlet -----------------------------------------------------------------------

INLET_TIMES = np.array([0.0, 0.13, 0.3, 0.32, 0.55, 0.7, 0.9, 1.2])
INLET_SIGNAL = np.array([0.0, 1.4, 2.5, 2.6, 1.1, 0.4, 0.05, 0.0])


@pytest.mark.study
@pytest.mark.parametrize("after", ["zero", "hold"])
def test_inlet_response_of_tanks_with_dead_zones_matches_the_network(after):
    tau, beta, rate = 4.0, 1.5, 0.3
    inlet_times = INLET_TIMES * tau
    signal = INLET_SIGNAL + (0.7 if after == "hold" else 0.0)
    t = np.concatenate([[-1.0, 0.0], np.linspace(0.1, 6.0, 23) * tau])
    network = tanks_exchange_network(3, tau, beta, rate)
    reference = network_inlet_response(*network, inlet_times, signal, t, hold=after == "hold")
    unit = ExchangeZone(TanksInSeries(tau, 3.0), beta, rate)
    ours = np.asarray(analytic.inlet_response(unit, t, inlet_times, signal, after=after))
    error = _relative_to_peak(ours, reference)
    print(f"after={after}: inlet response vs network {error:.1e} of the peak")
    assert error <= 1e-10


@pytest.mark.study
def test_inlet_response_of_the_adm_matches_quadrature_of_the_convolution():
    peclet, tau = 300.0, 10.0
    inlet_times = INLET_TIMES * tau * 0.3
    t = np.linspace(5.0, 25.0, 21)
    x, w = np.polynomial.legendre.leggauss(20)
    reference = []
    for time in t:
        # ∫ E(time - t') u(t') dt' over the inlet's support, panels on its knots.
        edges = np.unique(
            np.concatenate([np.linspace(inlet_times[0], inlet_times[-1], 301), inlet_times])
        )
        edges = np.append(edges[edges < time], min(time, inlet_times[-1]))
        a, b = edges[:-1], edges[1:]
        s = (0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * x).ravel()
        weights = (0.5 * (b - a)[:, None] * w).ravel()
        e = np.asarray(closed_closed_curves((time - s) / tau, peclet)[0]) / tau
        reference.append(np.sum(weights * e * np.interp(s, inlet_times, INLET_SIGNAL)))
    reference = np.array(reference)
    ours = np.asarray(
        analytic.inlet_response(ClosedClosedADM(tau, peclet), t, inlet_times, INLET_SIGNAL)
    )
    error = _relative_to_peak(ours, reference)
    print(f"inlet response vs quadrature: {error:.1e} of the peak")
    assert error <= 1e-10


@pytest.mark.study
def test_held_unit_step_inlet_gives_the_step_response():
    unit = ExchangeZone(ClosedClosedADM(5.0, 50.0), 1.0, 0.1)
    t = np.linspace(-1.0, 40.0, 30)
    ours = analytic.inlet_response(unit, t, [0.0, 1.0], [1.0, 1.0], after="hold")
    np.testing.assert_allclose(ours, analytic.step_response(unit, t), atol=1e-12)


# --- differentiation, transformations ----------------------------------------------------

GRADIENT_CASES = {
    # dimensional: tau in s, k_d in 1/s; the first is split into mobile and dead-zone parts,
    # the second inverted on one contour.
    "slow exchange": (30.0, 200.0, 1.5, 0.005),
    "fast exchange": (30.0, 8.0, 0.7, 0.2),
}


@pytest.mark.study
@pytest.mark.parametrize("case", sorted(GRADIENT_CASES))
@pytest.mark.parametrize("curve", [analytic.exit_age_exchange, analytic.step_response_exchange])
def test_exchange_gradients_match_central_differences(case, curve):
    parameters = GRADIENT_CASES[case]
    t = jnp.linspace(0.0, 150.0, 61)

    def total(*p):
        return jnp.sum(jnp.cos(0.07 * t) * curve(t, *p))

    gradient = jax.grad(total, argnums=(0, 1, 2, 3))(*parameters)
    for index, value in enumerate(parameters):

        def along(x, index=index):
            shifted = list(parameters)
            shifted[index] = x
            return float(total(*shifted))

        finite = _central_difference(along, value)
        assert float(gradient[index]) == pytest.approx(finite, rel=1e-6, abs=1e-9)


@pytest.mark.study
def test_tanks_exchange_and_series_gradients_match_central_differences():
    t = jnp.linspace(0.0, 40.0, 41)

    def total(tau, n, beta, rate, tank):
        unit = Series(ExchangeZone(TanksInSeries(tau, n), beta, rate), StirredTank(tank))
        return jnp.sum(jnp.sin(0.2 * t) * analytic.exit_age(unit, t))

    parameters = (6.0, 3.5, 0.9, 0.25, 1.3)
    gradient = jax.grad(total, argnums=tuple(range(5)))(*parameters)
    for index, value in enumerate(parameters):

        def along(x, index=index):
            shifted = list(parameters)
            shifted[index] = x
            return float(total(*shifted))

        assert float(gradient[index]) == pytest.approx(_central_difference(along, value), rel=1e-6)


@pytest.mark.study
def test_inlet_response_gradients_match_central_differences():
    inlet_times = INLET_TIMES * 12.0
    t = jnp.linspace(5.0, 80.0, 16)

    def total(tau, peclet, beta, rate, delay, signal):
        unit = ExchangeZone(ClosedClosedADM(tau, peclet), beta, rate)
        outlet = analytic.inlet_response(unit, t - delay, inlet_times, signal)
        return jnp.sum(jnp.cos(0.1 * t) * outlet)

    parameters = (20.0, 60.0, 1.2, 0.02, 2.5)
    signal = jnp.asarray(INLET_SIGNAL)
    gradient = jax.grad(total, argnums=(0, 1, 2, 3, 4, 5))(*parameters, signal)
    for index, value in enumerate(parameters):

        def along(x, index=index):
            shifted = list(parameters)
            shifted[index] = x
            return float(total(*shifted, signal))

        assert float(gradient[index]) == pytest.approx(_central_difference(along, value), rel=1e-6)
    # Linear in the inlet samples: the gradient is the response to each hat function.
    bump = jnp.zeros_like(signal).at[3].set(1.0)
    assert float(gradient[5][3]) == pytest.approx(float(total(*parameters, bump)), rel=1e-12)


@pytest.mark.study
def test_exchange_curves_jit_and_vmap_over_parameters():
    t = jnp.linspace(0.0, 100.0, 41)
    taus = jnp.array([20.0, 25.0, 30.0])
    peclets = jnp.array([5.0, 80.0, 600.0])
    betas = jnp.array([0.0, 1.0, 4.0])
    rates = jnp.array([0.5, 0.01, 0.002])
    batched = jax.jit(jax.vmap(analytic.exit_age_exchange, in_axes=(None, 0, 0, 0, 0)))(
        t, taus, peclets, betas, rates
    )
    for row, parameters in zip(batched, zip(taus, peclets, betas, rates, strict=True), strict=True):
        np.testing.assert_allclose(
            row, analytic.exit_age_exchange(t, *parameters), rtol=1e-12, atol=1e-15
        )


# --- range and arguments -----------------------------------------------------------------


@pytest.mark.study
@pytest.mark.parametrize(
    ("unit", "message"),
    [
        (ExchangeZone(ClosedClosedADM(1.0, 10.0), 8.0, 1.0), "capacity_ratio"),
        (ExchangeZone(ClosedClosedADM(1.0, 10.0), 1.0, 500.0), "exchange"),
        (ExchangeZone(ClosedClosedADM(1.0, 5000.0), 1.0, 1.0), "peclet"),
    ],
)
def test_parameters_outside_the_verified_range_warn(unit, message):
    with pytest.warns(analytic.AccuracyWarning, match=message):
        analytic.exit_age(unit, np.array([0.5, 1.0]))


def test_step_and_ramp_responses_warn_where_only_e_is_verified():
    fast = ExchangeZone(ClosedClosedADM(1.0, 100.0), 1.0, 15.0)
    times = np.array([0.5, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        analytic.exit_age(fast, times)
        analytic.step_response(ExchangeZone(ClosedClosedADM(1.0, 70.0), 1.0, 15.0), times)
        analytic.step_response(ExchangeZone(ClosedClosedADM(1.0, 100.0), 1.0, 10.0), times)
    for response in (analytic.step_response, analytic.ramp_response):
        with pytest.warns(analytic.AccuracyWarning, match="step, ramp or inlet response"):
            response(fast, times)


@pytest.mark.study
def test_parameters_inside_the_verified_range_do_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        analytic.exit_age(ExchangeZone(ClosedClosedADM(1.0, 10.0), 5.0, 100.0), np.array([1.0]))


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: ExchangeZone(ClosedClosedADM(1.0, 10.0), -1.0, 1.0),
            "capacity_ratio must be zero or positive",
        ),
        (
            lambda: ExchangeZone(ClosedClosedADM(1.0, 10.0), 1.0, 0.0),
            "exchange_rate must be positive",
        ),
        (lambda: ExchangeZone(1.0, 1.0, 1.0), "unit must be a TransferFunction"),
        (lambda: Series(), "at least one unit"),
        (
            lambda: Series(
                ExchangeZone(StirredTank(1.0), 1.0, 1.0), ExchangeZone(StirredTank(1.0), 1.0, 1.0)
            ),
            "at most one ExchangeZone",
        ),
        (
            lambda: ExchangeZone(ExchangeZone(StirredTank(1.0), 1.0, 1.0), 1.0, 1.0),
            "dead zone itself",
        ),
        (lambda: ClosedClosedADM(-1.0, 10.0), "tau must be positive"),
    ],
)
def test_bad_units_are_rejected_with_one_sentence(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_bad_response_arguments_are_rejected():
    unit = StirredTank(1.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        analytic.exit_age(unit, np.array([1.0, 0.5]))
    with pytest.raises(ValueError, match="after must be"):
        analytic.inlet_response(unit, np.array([1.0]), [0.0, 1.0], [1.0, 0.0], after="linear")
    with pytest.raises(ValueError, match="inlet_times needs at least two"):
        analytic.inlet_response(unit, np.array([1.0]), [0.0], [1.0])
    with pytest.raises(ValueError, match="inlet_times must be strictly increasing"):
        analytic.inlet_response(unit, np.array([1.0]), [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="unit must be a TransferFunction"):
        analytic.exit_age("adm", np.array([1.0]))


# --- study: the whole verified range ------------------------------------------------------


@pytest.mark.study
def test_study_exchange_exit_age_over_the_verified_range():
    theta = np.concatenate(
        [np.linspace(0.05, 3.0, 60), [3.5, 4, 5, 6, 7, 10, 15, 20, 30, 50, 100, 200, 400]]
    )
    worst = (0.0, None)
    for peclet, beta, kappa in itertools.product(
        [0.1, 0.3, 1, 3, 10, 30, 100, 300, 1000],
        [1e-6, 1e-4, 1e-3, 1e-2, 0.2, 1.0, 5.0],
        [0.01, 0.03, 0.1, 0.3, 1, 3, 10, 15, 30, 60, 100],
    ):
        exit_age = np.asarray(analytic.exit_age_exchange(theta, 1.0, peclet, beta, kappa))
        error = _relative_to_peak(
            exit_age, exchange_exit_age_subordinated(theta, peclet, beta, kappa)
        )
        worst = max(worst, (error, (peclet, beta, kappa)))
    print(f"worst max|E - E_ref| / max E_ref: {worst[0]:.1e} at (Pe, beta, k_d tau) = {worst[1]}")
    assert worst[0] <= 1e-7


@pytest.mark.study
def test_study_exchange_step_response_over_its_verified_range():
    """F against the integral of E (E checked against the subordination integral above):
    composite 20-point Gauss-Legendre panels of 0.005 up to 3 mobile means, geometric to 100."""
    theta = np.array([0.3, 0.5, 0.8, 0.9, 1.0, 1.1, 1.3, 1.5, 2.0, 3.0, 5.0, 10.0, 20.0, 100.0])
    x, w = np.polynomial.legendre.leggauss(20)
    edges = np.unique(np.concatenate([np.linspace(0, 3, 601), np.geomspace(3, 100, 400), theta]))
    low, high = edges[:-1], edges[1:]
    nodes = (0.5 * (high - low)[:, None] * x + 0.5 * (high + low)[:, None]).ravel()
    weights = (0.5 * (high - low)[:, None] * w).ravel()
    order = np.argsort(nodes)
    worst = (0.0, None)
    for peclet, beta, kappa in itertools.product(
        [0.1, 1, 10, 30, 70, 100, 300, 1000],
        [1e-6, 1e-4, 1e-2, 0.2, 1.0, 2.0, 5.0],
        [0.01, 0.1, 1, 3, 8, 10, 15, 30, 60, 100],
    ):
        if kappa > 10 and peclet > 70:
            continue  # outside the verified range of step responses (it warns there)
        exit_age = np.empty_like(nodes)
        exit_age[order] = analytic.exit_age_exchange(nodes[order], 1.0, peclet, beta, kappa)
        reference = np.array([np.sum((weights * exit_age)[nodes <= t]) for t in theta])
        step = np.asarray(analytic.step_response_exchange(theta, 1.0, peclet, beta, kappa))
        worst = max(worst, (float(np.max(np.abs(step - reference))), (peclet, beta, kappa)))
    print(f"worst max|F - F_ref|: {worst[0]:.1e} at (Pe, beta, k_d tau) = {worst[1]}")
    assert worst[0] <= 1e-9
