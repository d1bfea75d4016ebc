"""Tests of compartment networks with scheduled rates (axialmix.network, diffrax).

Named test_line_* because scheduled rates serve the changing-throughput part of the line
package (impeller speed ramps, feed steps).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from axialmix.network import (
    RateSchedule,
    ScheduleSolver,
    exit_age,
    four_compartment,
    generator_matrix,
    outlet_response,
    scheduled_amounts,
    scheduled_exit_age,
    scheduled_outlet_response,
)

NETWORK = four_compartment(2.125, 2.125, 0.625, 1.0)
TIMES = np.linspace(0.0, 20.0, 81)
KNOTS = np.array([0.0, 3.0, 7.0])
RATES = np.stack([NETWORK.rates, 1.7 * NETWORK.rates, 0.6 * NETWORK.rates])
OUTFLOW = np.array([[1.0], [1.5], [0.8]])
RAMP_TIMES = np.linspace(0.0, 12.0, 25)


def _piecewise_constant_exit_age(times, injection_time=0.0):
    """E by chained matrix exponentials (scipy) for the piecewise-constant schedule."""
    generators = [np.asarray(generator_matrix(NETWORK, r, o)) for r, o in zip(RATES, OUTFLOW,
                                                                              strict=True)]
    bounds = [*KNOTS, np.inf]
    values = []
    for t in times:
        if t < injection_time:
            values.append(0.0)
            continue
        amounts = np.asarray(NETWORK.feed_split, float)
        current = injection_time
        for k, generator in enumerate(generators):
            end = min(t, bounds[k + 1])
            if end > current:
                amounts = expm(generator * (end - current)) @ amounts
                current = end
        index = np.searchsorted(KNOTS, t, side="right") - 1
        values.append(OUTFLOW[max(index, 0), 0] * amounts[3])
    return np.array(values)


def test_constant_schedule_reproduces_the_matrix_exponential_solution():
    # Two knots with equal rates (the shape of the ramp below, so one compiled solve serves
    # both). Tsit5 at rtol 1e-9: 3e-11 of the peak measured.
    constant = RateSchedule(KNOTS[:2], np.stack([RATES[0], RATES[0]]),
                            np.stack([OUTFLOW[0], OUTFLOW[0]]))
    values = scheduled_exit_age(NETWORK, constant, RAMP_TIMES)
    np.testing.assert_allclose(values, exit_age(NETWORK, RAMP_TIMES), atol=1e-9)


def test_piecewise_constant_schedule_matches_chained_matrix_exponentials():
    schedule = RateSchedule(KNOTS, RATES, OUTFLOW, interpolation="previous")
    for injection in (0.0, 2.0):
        values = scheduled_exit_age(NETWORK, schedule, TIMES, injection_time=injection)
        expected = _piecewise_constant_exit_age(TIMES, injection)
        np.testing.assert_allclose(values, expected, atol=1e-9)


def test_ramped_schedule_matches_an_independent_ode_solution():
    # Rates linear between two knots, then held: scipy's DOP853 at rtol 1e-12 on the same
    # dm/dt = K(t) m, with K assembled here from the interpolated rates.
    ramp = RateSchedule(KNOTS[:2], RATES[:2], OUTFLOW[:2])
    values = np.asarray(scheduled_exit_age(NETWORK, ramp, RAMP_TIMES))

    # The generator is linear in the rates, so K(t) blends the two knots' generators.
    first, second = (np.asarray(generator_matrix(NETWORK, RATES[k], OUTFLOW[k])) for k in (0, 1))

    def weight(t):
        return np.clip(t / 3.0, 0.0, 1.0)

    def field(t, m):
        return (first + weight(t) * (second - first)) @ m

    solution = solve_ivp(field, (0.0, RAMP_TIMES[-1]), np.asarray(NETWORK.feed_split, float),
                         method="DOP853", rtol=1e-12, atol=1e-14, t_eval=RAMP_TIMES)
    outflow = OUTFLOW[0, 0] + weight(RAMP_TIMES) * (OUTFLOW[1, 0] - OUTFLOW[0, 0])
    expected = outflow * solution.y[3]
    np.testing.assert_allclose(values, expected, atol=1e-9)


def test_scheduled_results_differentiate_in_every_knot_rate():
    schedule_times = KNOTS[:2]

    @jax.jit
    def loss(rates, outflow):
        schedule = RateSchedule(schedule_times, rates, outflow)
        return jnp.sum(scheduled_exit_age(NETWORK, schedule, RAMP_TIMES) ** 2)

    gradient_rates, gradient_outflow = jax.grad(loss, argnums=(0, 1))(RATES[:2], OUTFLOW[:2])
    rng = np.random.default_rng(5)
    for _ in range(3):
        k, j = rng.integers(2), rng.integers(RATES.shape[1])
        step = 1e-5
        up, down = RATES[:2].copy(), RATES[:2].copy()
        up[k, j] += step
        down[k, j] -= step
        finite = (loss(up, OUTFLOW[:2]) - loss(down, OUTFLOW[:2])) / (2 * step)
        assert float(gradient_rates[k, j]) == pytest.approx(float(finite), rel=1e-5, abs=1e-9)
    up, down = OUTFLOW[:2].copy(), OUTFLOW[:2].copy()
    up[1, 0] += 1e-5
    down[1, 0] -= 1e-5
    finite = (loss(RATES[:2], up) - loss(RATES[:2], down)) / 2e-5
    assert float(gradient_outflow[1, 0]) == pytest.approx(float(finite), rel=1e-5)


def test_scheduled_outlet_response_and_amounts_match_the_constant_network():
    schedule = RateSchedule.constant(NETWORK)
    signal = np.sin(TIMES / 3.0) ** 2
    np.testing.assert_allclose(
        scheduled_outlet_response(NETWORK, schedule, TIMES, signal),
        outlet_response(NETWORK, TIMES, signal), atol=1e-9,
    )
    amounts = scheduled_amounts(NETWORK, schedule, np.array([0.0, 1.0, 0.0, 0.0]), TIMES)
    generator = np.asarray(generator_matrix(NETWORK))
    expected = np.array([expm(generator * t)[:, 1] for t in TIMES])
    np.testing.assert_allclose(amounts, expected, atol=1e-9)


def test_schedule_rejects_nonsense():
    with pytest.raises(ValueError, match="interpolation must be"):
        RateSchedule(KNOTS, RATES, OUTFLOW, interpolation="cubic")
    with pytest.raises(ValueError, match="rates must be non-negative"):
        RateSchedule(KNOTS, -RATES, OUTFLOW)
    with pytest.raises(ValueError, match="connection rates"):
        scheduled_exit_age(NETWORK, RateSchedule(KNOTS, RATES[:, :3], OUTFLOW), TIMES)
    with pytest.raises(ValueError, match="continuous network"):
        scheduled_exit_age(NETWORK.discretised(0.1), RateSchedule.constant(NETWORK), TIMES)
    with pytest.raises(ValueError, match="rtol"):
        ScheduleSolver(rtol=2.0)
