"""Tests of the cumulative-throughput clock (axialmix.line, MODELS.md §7)."""

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.sparse import diags

from axialmix.line import (
    Disturbance,
    FlowSchedule,
    Line,
    Unit,
    equivalent_time,
    exit_age_changing_throughput,
    outlet_response_changing_throughput,
    throughput_clock,
)

FLOW = FlowSchedule([0.3, 0.9, 1.6, 2.0], [1.0, 1.6, 1.6, 0.7], flow_unit="kg/s")
ADM = Unit.closed_closed(1.0, 20.0)


def _flow(t):
    return float(np.interp(t, [0.3, 0.9, 1.6, 2.0], [1.0, 1.6, 1.6, 0.7]))


def _method_of_lines(peclet, times, inlet, cells):
    """Outlet of the closed–closed ADM with v(t) and D(t) proportional to Q(t), in real time.

    Nodes x_i = i/cells, central differences (second order), Danckwerts inlet and closed
    outlet by ghost nodes; ``dc/dt = (Q(t) / V) [-dc/dx + (1/Pe) d²c/dx²]`` with V = 1 (the
    hold-up at the reference flow 1 and tau 1), integrated by scipy's BDF piece by piece
    between the inlet's jumps. Independent of the clock: no change of variable is used.
    """
    h = 1.0 / cells
    diffusive, convective = 1.0 / (peclet * h * h), 1.0 / (2.0 * h)
    matrix = diags(
        [np.full(cells, diffusive + convective), np.full(cells + 1, -2.0 * diffusive),
         np.full(cells, diffusive - convective)],
        [-1, 0, 1],
    ).tolil()
    ghost_in = diffusive + convective
    matrix[0, 1] += ghost_in
    matrix[0, 0] -= ghost_in * 2.0 * h * peclet
    matrix[cells, cells - 1] += diffusive - convective
    matrix = matrix.tocsr()
    source = np.zeros(cells + 1)
    source[0] = ghost_in * 2.0 * h * peclet
    state = np.zeros(cells + 1)
    outlet = np.zeros(times.size)
    jumps = sorted({0.0, *inlet.keys()}) + [times[-1]]
    level = 0.0
    for begin, end in zip(jumps[:-1], jumps[1:], strict=True):
        level = inlet.get(begin, level)
        inside = (times > begin) & (times <= end)
        solution = solve_ivp(
            lambda t, c, level=level: _flow(t) * (matrix @ c + source * level),
            (begin, end), state, method="BDF", rtol=1e-11, atol=1e-13,
            jac=lambda t, c: _flow(t) * matrix, t_eval=times[inside], dense_output=True,
        )
        outlet[inside] = solution.y[-1]
        state = solution.sol(end)
    return outlet


def test_throughput_is_the_exact_integral_of_the_flow_trace():
    t = np.array([-1.0, 0.0, 0.5, 1.2, 1.9, 3.0])
    expected = [quad(_flow, 0.0, x, points=[0.3, 0.9, 1.6, 2.0])[0] if x > 0
                else -1.0 * x * -1.0 * _flow(0.0) * (x < 0) for x in t]
    np.testing.assert_allclose(FLOW.throughput(t), expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(throughput_clock(FLOW, t, holdup=2.0), np.asarray(expected) / 2.0)
    assert FLOW.flow_unit == "kg/s"


def test_constant_flow_rescales_time():
    steady = FlowSchedule.constant(2.5)
    t = np.linspace(0.0, 2.0, 9)
    np.testing.assert_allclose(equivalent_time(steady, t, reference_flow=1.0), 2.5 * t)
    np.testing.assert_allclose(
        exit_age_changing_throughput(ADM, steady, t, reference_flow=1.0),
        2.5 * ADM.exit_age(2.5 * t), rtol=1e-13,
    )


def test_square_response_under_a_flow_trace_matches_the_method_of_lines():
    # A square is two steps, each answered exactly on the equivalent clock. The method of
    # lines is second order: with 200 and 400 nodes fine - coarse is 8e-5 (three times the
    # error of `fine`), and their extrapolation agrees with the clock to 2e-8 (measured).
    times = np.linspace(0.05, 3.0, 60)
    response = outlet_response_changing_throughput(
        ADM, Disturbance.square(0.5, 0.6, 0.2), FLOW, times, reference_flow=1.0
    )
    coarse = _method_of_lines(20.0, times, {0.2: 0.5, 0.8: 0.0}, 200)
    fine = _method_of_lines(20.0, times, {0.2: 0.5, 0.8: 0.0}, 400)
    assert np.abs(fine - coarse).max() > 1e-5
    np.testing.assert_allclose(response.outlet, (4.0 * fine - coarse) / 3.0, atol=1e-6)
    # At constant flow the same route gives the unit's own step responses.
    steady = outlet_response_changing_throughput(
        ADM, Disturbance.square(0.5, 0.6, 0.2), FlowSchedule.constant(1.0), times,
        reference_flow=1.0,
    )
    expected = 0.5 * (ADM.cumulative(times - 0.2) - ADM.cumulative(times - 0.8))
    np.testing.assert_allclose(steady.outlet, expected, atol=1e-15)


def test_exit_time_density_under_a_flow_trace_is_normalised_and_holds_the_holdup():
    # Material entering at t0 leaves after the throughput of one hold-up on average:
    # ∫ E(t) [Θ(t) - Θ(t0)] dt = mean of the RTD on the equivalent clock (tau = 1 here).
    line = Line(ADM, Unit.tanks(0.5, 2.0))
    t = np.linspace(0.0, 12.0, 6001)
    density = np.asarray(exit_age_changing_throughput(line, FLOW, t, reference_flow=1.0,
                                                      injection_time=0.4))
    clock = np.asarray(equivalent_time(FLOW, t, reference_flow=1.0))
    start = float(equivalent_time(FLOW, 0.4, reference_flow=1.0))
    # Trapezoid sums on the 2 ms grid: O(h²) errors of 3e-7 (measured).
    assert np.trapezoid(density, t) == pytest.approx(1.0, abs=2e-6)
    assert np.trapezoid(density * (clock - start), t) == pytest.approx(float(line.mean()),
                                                                       rel=2e-6)
    assert np.all(density[t < 0.4] == 0.0)


def test_schedule_rejects_bad_flows():
    with pytest.raises(ValueError, match="flows must be positive"):
        FlowSchedule([0.0, 1.0], [1.0, -1.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        FlowSchedule([1.0, 0.0], [1.0, 2.0])
