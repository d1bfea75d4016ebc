"""Changing throughput at constant hold-up: the cumulative-throughput clock (MODELS.md §7).

A vessel whose hold-up V stays constant while the flow Q(t) changes behaves, in the clock
``θ(t) = ∫_0^t Q(s) ds / V``, exactly as it does at constant flow: for the ADM the velocity
and the dispersion coefficient both scale with Q (the Peclet number is a property of the
vessel), for a compartment network every rate scales with Q. A unit described at a reference
flow ``Q_ref`` (its E in real time at that flow) therefore follows any flow trace through the
equivalent time ``T(t) = ∫_0^t Q / Q_ref = θ(t) V / Q_ref``: an RTD in real time is
``E_ref(T(t) - T(t_0)) Q(t) / Q_ref`` for material entering at ``t_0``, and a step in the
inlet content answers with ``F_ref(T(t) - T(t_step))``, exactly.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_increasing_times, require_positive
from axialmix.line._disturbance import Disturbance, OutletResponse, lag_horizon, response_at
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._unit import Unit

__all__ = [
    "FlowSchedule",
    "equivalent_time",
    "exit_age_changing_throughput",
    "outlet_response_changing_throughput",
    "throughput_clock",
]


class FlowSchedule(eqx.Module):
    """A flow-rate trace Q(t): linear between samples, constant before the first and after the last.

    **Arguments:**

    - `times`: sample times (time unit), strictly increasing (one sample: a constant flow).
    - `flows`: flow rates at `times` (flow unit, e.g. kg/h), positive.
    - `flow_unit`, `time_unit`: units; the throughput ``∫Q dt`` is in flow unit × time unit.
    """

    times: Array = eqx.field(converter=lambda x: jnp.atleast_1d(jnp.asarray(x, float)))
    flows: Array = eqx.field(converter=lambda x: jnp.atleast_1d(jnp.asarray(x, float)))
    flow_unit: str = eqx.field(static=True, default="")
    time_unit: str = eqx.field(static=True, default="s")

    def __check_init__(self) -> None:
        require_increasing_times("times", self.times)
        require_positive("flows", self.flows)
        if self.times.shape != self.flows.shape or self.times.ndim != 1:
            raise ValueError(
                f"times and flows must be 1-D of equal length, got {self.times.shape} and "
                f"{self.flows.shape}."
            )

    @classmethod
    def constant(cls, flow: ArrayLike, *, flow_unit: str = "", time_unit: str = "s"):
        """A constant flow rate."""
        return cls(jnp.zeros(1), jnp.atleast_1d(jnp.asarray(flow, float)), flow_unit, time_unit)

    def flow(self, t: ArrayLike) -> Array:
        """Q(t) at times of any shape (flow unit)."""
        return jnp.interp(jnp.asarray(t, float), self.times, self.flows)

    def _cumulative_from_first(self, t: Array) -> Array:
        """``∫_{times[0]}^t Q`` (negative before the first sample), exact."""
        times, flows = self.times, self.flows
        if times.shape[0] == 1:
            return flows[0] * (t - times[0])
        widths = jnp.diff(times)
        at_knots = jnp.concatenate(
            [jnp.zeros(1), jnp.cumsum(widths * (flows[1:] + flows[:-1]) / 2)]
        )
        index = jnp.clip(jnp.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
        x = jnp.clip(t - times[index], 0.0, widths[index])
        slope = (flows[index + 1] - flows[index]) / widths[index]
        inside = at_knots[index] + flows[index] * x + slope * x**2 / 2
        before = flows[0] * (t - times[0])
        after = at_knots[-1] + flows[-1] * (t - times[-1])
        return jnp.where(t < times[0], before, jnp.where(t > times[-1], after, inside))

    def throughput(self, t: ArrayLike) -> Array:
        """Cumulative throughput ``∫_0^t Q(s) ds`` at times of any shape (exact)."""
        return _throughput(self, jnp.asarray(t, float))


@eqx.filter_jit
def _throughput(schedule: FlowSchedule, t: Array) -> Array:
    return schedule._cumulative_from_first(t) - schedule._cumulative_from_first(jnp.zeros(()))


def throughput_clock(schedule: FlowSchedule, times: ArrayLike, *, holdup: ArrayLike) -> Array:
    """The cumulative-throughput clock ``θ(t) = ∫_0^t Q ds / V`` (MODELS.md §7).

    **Arguments:**

    - `schedule`: the flow trace.
    - `times`: times (time unit), any shape.
    - `holdup`: hold-up V (flow unit × time unit, positive).

    **Returns:**

    θ (dimensionless), the shape of `times`.
    """
    require_positive("holdup", holdup)
    require_finite("times", times)
    return schedule.throughput(times) / jnp.asarray(holdup, float)


def equivalent_time(
    schedule: FlowSchedule, times: ArrayLike, *, reference_flow: ArrayLike
) -> Array:
    """Time at the reference flow with the same throughput: ``T(t) = ∫_0^t Q ds / Q_ref``.

    **Arguments:**

    - `schedule`: the flow trace.
    - `times`: times (time unit), any shape.
    - `reference_flow`: the flow at which the unit's RTD was described (flow unit, positive).

    **Returns:**

    T (time unit), the shape of `times`.
    """
    require_positive("reference_flow", reference_flow)
    require_finite("times", times)
    return schedule.throughput(times) / jnp.asarray(reference_flow, float)


def _check_units(rtd, schedule: FlowSchedule) -> None:
    if schedule.time_unit != rtd.time_unit:
        raise ValueError(
            f"the flow schedule is in {schedule.time_unit!r} but the RTD in {rtd.time_unit!r}."
        )


def exit_age_changing_throughput(
    rtd: Unit | Line | TabulatedRTD,
    schedule: FlowSchedule,
    times: ArrayLike,
    *,
    reference_flow: ArrayLike,
    injection_time: ArrayLike = 0.0,
) -> Array:
    """Exit-time density of material entering at `injection_time` while the flow changes.

    ``E(t) = E_ref(T(t) - T(t_0)) Q(t) / Q_ref`` with the equivalent time T of
    :func:`equivalent_time`; exact at constant hold-up (MODELS.md §7). It integrates to one
    over t.

    **Arguments:**

    - `rtd`: the unit or line as described at `reference_flow`.
    - `schedule`: the flow trace Q(t).
    - `times`: output times (time unit), 1-D.
    - `reference_flow`: flow of the RTD's description (flow unit).
    - `injection_time`: entry time ``t_0`` (time unit).

    **Returns:**

    E in 1/time unit at `times` (0 before `injection_time`).
    """
    _check_units(rtd, schedule)
    require_finite("injection_time", injection_time)
    require_finite("times", times)
    require_positive("reference_flow", reference_flow)
    times = jnp.asarray(times, float)
    reference_flow = jnp.asarray(reference_flow, float)
    injection_time = jnp.asarray(injection_time, float)
    lags = _lags(schedule, times, injection_time, reference_flow)
    evaluator = as_evaluator(rtd, jnp.max(lags))
    return _real_time_density(evaluator, schedule, times, lags, reference_flow)


@eqx.filter_jit
def _lags(schedule, times, injection_time, reference_flow):
    return (schedule._cumulative_from_first(times)
            - schedule._cumulative_from_first(injection_time)) / reference_flow


@eqx.filter_jit
def _real_time_density(evaluator, schedule, times, lags, reference_flow):
    return evaluator.exit_age(lags) * schedule.flow(times) / reference_flow


def _retimed(disturbance: Disturbance, schedule: FlowSchedule, reference_flow) -> Disturbance:
    """The disturbance on the equivalent-time clock (pulses keep their mass)."""

    def clock(t):
        return equivalent_time(schedule, t, reference_flow=reference_flow)

    amounts = disturbance.pulse_amounts * schedule.flow(disturbance.pulse_times) / reference_flow
    traces = tuple((clock(times), values) for times, values in disturbance.traces)
    return Disturbance(
        clock(disturbance.step_times),
        disturbance.step_sizes,
        clock(disturbance.pulse_times),
        amounts,
        traces,
        disturbance.value_unit,
        disturbance.time_unit,
    )


@eqx.filter_jit
def _retimed_with_clock(disturbance, schedule, reference_flow, times):
    return (_retimed(disturbance, schedule, reference_flow),
            equivalent_time(schedule, times, reference_flow=reference_flow))


@eqx.filter_jit
def _response_on_clock(evaluator, disturbance, clock):
    return response_at(evaluator, disturbance, clock)


def outlet_response_changing_throughput(
    rtd: Unit | Line | TabulatedRTD,
    disturbance: Disturbance,
    schedule: FlowSchedule,
    times: ArrayLike,
    *,
    reference_flow: ArrayLike,
) -> OutletResponse:
    """Outlet deviation for an inlet disturbance while the flow follows a trace Q(t).

    The response is computed on the equivalent-time clock (:func:`equivalent_time`): steps
    and pulses exactly; a trace (or ramp) is taken as linear between its samples on that
    clock, which is exact where the flow is constant between samples and second order in the
    sample spacing otherwise.

    **Arguments:**

    - `rtd`: the unit or line as described at `reference_flow`.
    - `disturbance`: the inlet deviation in real time.
    - `schedule`: the flow trace.
    - `times`: output times (time unit), 1-D.
    - `reference_flow`: flow of the RTD's description (flow unit).

    **Returns:**

    An :class:`~axialmix.line.OutletResponse` at `times` (real time).
    """
    _check_units(rtd, schedule)
    require_positive("reference_flow", reference_flow)
    require_finite("times", times)
    times = jnp.asarray(times, float)
    reference_flow = jnp.asarray(reference_flow, float)
    retimed, clock = _retimed_with_clock(disturbance, schedule, reference_flow, times)
    evaluator = as_evaluator(rtd, lag_horizon(retimed, clock))
    outlet = _response_on_clock(evaluator, retimed, clock)
    return OutletResponse(
        times, disturbance.value(times), outlet, rtd.time_unit, disturbance.value_unit
    )
