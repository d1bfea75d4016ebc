"""Inlet disturbances and the outlet responses of units and lines (MODELS.md §8)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import (
    require_finite,
    require_increasing_times,
    require_positive,
)
from axialmix.line import _grid
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._unit import Unit, is_concrete

__all__ = ["Disturbance", "OutletResponse", "grid_curve", "has_grid", "outlet_response",
           "response_at", "response_on_grid"]

_UNIFORM_RTOL = 1e-9


def _vector(name: str, value: ArrayLike) -> Array:
    require_finite(name, value)
    if is_concrete(value):  # NumPy: building a disturbance runs no program
        return np.atleast_1d(np.asarray(value, float))
    return jnp.atleast_1d(jnp.asarray(value, float))


def _numbers(*values) -> tuple:
    """The values as NumPy floats when all are concrete, else as JAX arrays."""
    if is_concrete(values):
        return tuple(np.asarray(value, float) for value in values)
    return tuple(jnp.asarray(value, float) for value in values)


class Disturbance(eqx.Module):
    """A deviation ``δu(t)`` of the inlet content from its target: steps, pulses and traces.

    Build one with :meth:`step`, :meth:`pulse`, :meth:`square`, :meth:`ramp` or
    :meth:`trace`, and add disturbances with ``+``. A trace is the piecewise-linear
    interpolant of its samples, zero before the first sample and held at the last value after
    the last one (the convention of :func:`axialmix.adm.outlet_response`). Any value unit
    works (mass fraction, % of target): the outlet deviation comes in the same unit.

    **Arguments:**

    - `step_times`, `step_sizes`: times (time unit) and sizes (value unit) of steps.
    - `pulse_times`, `pulse_amounts`: times and amounts (value unit × time unit) of pulses.
    - `traces`: tuple of ``(times, values)`` pairs.
    - `value_unit`, `time_unit`: units, carried to the results.
    """

    step_times: Array
    step_sizes: Array
    pulse_times: Array
    pulse_amounts: Array
    traces: tuple[tuple[Array, Array], ...] = ()
    value_unit: str = eqx.field(static=True, default="")
    time_unit: str = eqx.field(static=True, default="s")

    def __check_init__(self) -> None:
        for times, sizes, what in (
            (self.step_times, self.step_sizes, "steps"),
            (self.pulse_times, self.pulse_amounts, "pulses"),
        ):
            if jnp.shape(times) != jnp.shape(sizes) or jnp.ndim(times) != 1:
                raise ValueError(f"the times and sizes of {what} must be 1-D of equal length.")
        for times, values in self.traces:
            require_increasing_times("trace times", times)
            require_finite("trace values", values)
            if jnp.shape(times) != jnp.shape(values) or jnp.ndim(times) != 1:
                raise ValueError(
                    f"a trace needs 1-D times and values of equal length, got "
                    f"{jnp.shape(times)} and {jnp.shape(values)}."
                )
            if jnp.shape(times)[0] < 2:
                raise ValueError("a trace needs at least two samples.")

    @classmethod
    def _make(cls, *, steps=((), ()), pulses=((), ()), traces=(), value_unit="", time_unit="s"):
        return cls(
            _vector("step times", steps[0]),
            _vector("step sizes", steps[1]),
            _vector("pulse times", pulses[0]),
            _vector("pulse amounts", pulses[1]),
            tuple(_numbers(t, v) for t, v in traces),
            value_unit,
            time_unit,
        )

    @classmethod
    def step(
        cls, magnitude: ArrayLike, start: ArrayLike = 0.0, *, value_unit: str = "",
        time_unit: str = "s",
    ) -> Disturbance:
        """A lasting change of the inlet content by `magnitude` from time `start` on."""
        return cls._make(steps=([start], [magnitude]), value_unit=value_unit, time_unit=time_unit)

    @classmethod
    def pulse(
        cls, amount: ArrayLike, at: ArrayLike = 0.0, *, value_unit: str = "",
        time_unit: str = "s",
    ) -> Disturbance:
        """An instantaneous excess ``amount · δ(t - at)`` (value unit × time unit)."""
        return cls._make(pulses=([at], [amount]), value_unit=value_unit, time_unit=time_unit)

    @classmethod
    def square(
        cls, magnitude: ArrayLike, duration: ArrayLike, start: ArrayLike = 0.0, *,
        value_unit: str = "", time_unit: str = "s",
    ) -> Disturbance:
        """A deviation `magnitude` lasting `duration` (positive) from `start`."""
        require_positive("duration", duration)
        start, duration, magnitude = _numbers(start, duration, magnitude)
        stack = np.stack if is_concrete((start, duration, magnitude)) else jnp.stack
        return cls._make(
            steps=(stack([start, start + duration]), stack([magnitude, -magnitude])),
            value_unit=value_unit,
            time_unit=time_unit,
        )

    @classmethod
    def ramp(
        cls, magnitude: ArrayLike, duration: ArrayLike, start: ArrayLike = 0.0, *,
        value_unit: str = "", time_unit: str = "s",
    ) -> Disturbance:
        """A linear change from 0 at `start` to `magnitude` after `duration`, then held."""
        require_positive("duration", duration)
        start, duration, magnitude = _numbers(start, duration, magnitude)
        stack = np.stack if is_concrete((start, duration, magnitude)) else jnp.stack
        times = stack([start, start + duration])
        values = stack([np.zeros(()), magnitude])
        return cls._make(traces=((times, values),), value_unit=value_unit, time_unit=time_unit)

    @classmethod
    def trace(
        cls, times: ArrayLike, values: ArrayLike, *, value_unit: str = "", time_unit: str = "s"
    ) -> Disturbance:
        """A sampled deviation (a feeder trace): linear between samples, zero before, held after.

        **Arguments:**

        - `times`: sample times (time unit), strictly increasing, at least 2.
        - `values`: deviations at `times` (value unit).
        - `value_unit`, `time_unit`: units.

        **Returns:**

        A :class:`Disturbance`.
        """
        return cls._make(traces=((times, values),), value_unit=value_unit, time_unit=time_unit)

    def __add__(self, other: Disturbance) -> Disturbance:
        if not isinstance(other, Disturbance):
            return NotImplemented
        if (other.value_unit, other.time_unit) != (self.value_unit, self.time_unit):
            raise ValueError("disturbances with different units cannot be added.")
        return Disturbance(
            jnp.concatenate([self.step_times, other.step_times]),
            jnp.concatenate([self.step_sizes, other.step_sizes]),
            jnp.concatenate([self.pulse_times, other.pulse_times]),
            jnp.concatenate([self.pulse_amounts, other.pulse_amounts]),
            self.traces + other.traces,
            self.value_unit,
            self.time_unit,
        )

    def value(self, t: ArrayLike) -> Array:
        """The inlet deviation δu(t) without its pulses (value unit), at times of any shape."""
        t = jnp.asarray(t, float)
        total = jnp.sum(
            jnp.where(t[..., None] >= self.step_times, self.step_sizes, 0.0), axis=-1
        )
        for times, values in self.traces:
            inside = jnp.interp(t, times, values)
            total = total + jnp.where(t < times[0], 0.0, inside)
        return total

    def event_times(self) -> Array:
        """All times at which something starts (time unit)."""
        parts = [self.step_times, self.pulse_times] + [times for times, _ in self.traces]
        return jnp.concatenate(parts)


class OutletResponse(eqx.Module):
    """The outlet deviation of a unit or line for an inlet disturbance.

    **Arguments:**

    - `times`: output times (time unit).
    - `inlet`: the inlet deviation at `times`, pulses left out (value unit).
    - `outlet`: the outlet deviation at `times` (value unit).
    - `time_unit`, `value_unit`: units.
    """

    times: Array
    inlet: Array
    outlet: Array
    time_unit: str = eqx.field(static=True, default="s")
    value_unit: str = eqx.field(static=True, default="")


def _trace_on_times(times: Array, trace: tuple[Array, Array]) -> bool:
    """True when concrete output times equal a concrete, uniformly sampled trace's times."""
    trace_times = trace[0]
    if not is_concrete(times, trace_times):
        return False
    out = np.asarray(times)
    sampled = np.asarray(trace_times)
    if out.shape != sampled.shape or out.size < 3:
        return False
    steps = np.diff(sampled)
    uniform = np.max(np.abs(steps - steps.mean())) <= _UNIFORM_RTOL * steps.mean()
    return bool(uniform and np.allclose(out, sampled, rtol=0.0, atol=1e-12 * steps.mean()))


def _mean_interval_cumulative(evaluator, lags: Array, widths: Array) -> Array:
    """``[R(lag) - R(lag - width)] / width``: the mean of F over ``[lag - width, lag]``."""
    return (evaluator.ramp_response(lags) - evaluator.ramp_response(lags - widths)) / widths


def _trace_response_dense(evaluator, times: Array, trace: tuple[Array, Array]) -> Array:
    # u(t) = u_0 H(t - t_0) + Σ_j (u_{j+1} - u_j) × (linear rise over [t_j, t_{j+1}]); the rise
    # over an interval of width h_j answers with the mean of F over the lag window, by parts.
    trace_times, values = trace
    widths = jnp.diff(trace_times)
    lags = times[:, None] - trace_times[None, :-1]
    means = _mean_interval_cumulative(evaluator, lags, widths[None, :])
    first = values[0] * evaluator.cumulative(times - trace_times[0])
    return first + means @ jnp.diff(values)


def _trace_response_uniform(evaluator, trace: tuple[Array, Array]) -> Array:
    """The same on the trace's own uniform times, as one FFT convolution over lags."""
    trace_times, values = trace
    n = trace_times.shape[0]
    width = (trace_times[-1] - trace_times[0]) / (n - 1)
    lags = jnp.arange(n) * width
    means = jnp.where(jnp.arange(n) >= 1, _mean_interval_cumulative(evaluator, lags, width), 0.0)
    increments = jnp.concatenate([jnp.diff(values), jnp.zeros(1)])
    return values[0] * evaluator.cumulative(lags) + _grid._fft_convolution(increments, means)


def response_at(evaluator, disturbance: Disturbance, times: Array, *, uniform_traces=()) -> Array:
    """Outlet deviation at times for an evaluator (a unit or a tabulated line); traceable.

    **Arguments:**

    - `evaluator`: a :class:`Unit` or :class:`TabulatedRTD` covering the lags needed.
    - `disturbance`: the inlet deviation.
    - `times`: output times, any shape (dense path for traces).
    - `uniform_traces`: indices of traces to evaluate by FFT on their own times (`times`
      must then be those times).

    **Returns:**

    The outlet deviation, the shape of `times`.
    """
    times = jnp.asarray(times, float)
    total = jnp.zeros(times.shape)
    # Empty step or pulse lists are skipped (static shapes): a network evaluates its curves by
    # propagating over the sorted lags and has nothing to propagate over an empty list.
    if disturbance.step_times.shape[0]:
        lags = times[..., None] - disturbance.step_times
        total = total + jnp.sum(disturbance.step_sizes * evaluator.cumulative(lags), axis=-1)
    if disturbance.pulse_times.shape[0]:
        pulse_lags = times[..., None] - disturbance.pulse_times
        total = total + jnp.sum(disturbance.pulse_amounts * evaluator.exit_age(pulse_lags),
                                axis=-1)
    flat = times.reshape(-1)
    for index, trace in enumerate(disturbance.traces):
        if index in uniform_traces:
            contribution = _trace_response_uniform(evaluator, trace)
        else:
            contribution = _trace_response_dense(evaluator, flat, trace)
        total = total + contribution.reshape(times.shape)
    return total


def has_grid(evaluator) -> bool:
    """Whether `evaluator` evaluates its curves on a uniform grid faster than time by time
    (a unit whose model gives them by propagation, :attr:`UnitModel.grid`)."""
    return isinstance(evaluator, Unit) and evaluator.model.grid is not None


def grid_curve(evaluator, kind: str, first: Array, step: Array, count: int) -> Array:
    """The curve `kind` (``"exit_age"``, ``"cumulative"`` or ``"ramp"``) of an evaluator at
    the uniformly spaced times ``first + j step``, ``j < count``: propagated along the grid
    where the evaluator has one (:func:`has_grid`), else evaluated at those times."""
    if has_grid(evaluator):
        return evaluator.model.grid(kind, first, step, count, evaluator.parameters,
                                    evaluator.structure)
    times = first + step * jnp.arange(count)
    if kind == "exit_age":
        return evaluator.exit_age(times)
    return evaluator.cumulative(times) if kind == "cumulative" else (
        evaluator.ramp_response(times))


def response_on_grid(evaluator, disturbance: Disturbance, first: Array, step: Array,
                     count: int) -> Array:
    """Outlet deviation at the uniformly spaced times ``first + j step``, ``j < count``, as
    :func:`response_at` gives it there (traceable; `count` static).

    Each event of the disturbance sees the output times as a uniform grid of lags, on which
    an evaluator with :func:`has_grid` (a network) propagates its curves instead of
    evaluating them time by time; other evaluators are evaluated at the grid's times.

    **Arguments:**

    - `evaluator`: a :class:`Unit` or :class:`TabulatedRTD` covering the lags needed.
    - `disturbance`: the inlet deviation.
    - `first`, `step`: the first output time and the spacing (time unit, step > 0).
    - `count`: the number of output times.

    **Returns:**

    The outlet deviation ``(count,)``.
    """
    first, step = jnp.asarray(first, float), jnp.asarray(step, float)

    def curves(kind, origins):
        return jax.vmap(lambda origin: grid_curve(evaluator, kind, first - origin, step,
                                                   count))(origins)

    total = jnp.zeros(count)
    if disturbance.step_times.shape[0]:
        total = total + disturbance.step_sizes @ curves("cumulative", disturbance.step_times)
    if disturbance.pulse_times.shape[0]:
        total = total + disturbance.pulse_amounts @ curves("exit_age", disturbance.pulse_times)
    for trace_times, values in disturbance.traces:
        # As _trace_response_dense: the rise over [t_k, t_k+1] answers with the mean of F
        # over the lag window, [R(t - t_k) - R(t - t_k+1)] / (t_k+1 - t_k).
        ramps = curves("ramp", trace_times)
        means = (ramps[:-1] - ramps[1:]) / jnp.diff(trace_times)[:, None]
        total = (total + values[0] * curves("cumulative", trace_times[:1])[0]
                 + jnp.diff(values) @ means)
    return total


@eqx.filter_jit
def _response(evaluator, disturbance, times, uniform_traces):
    return response_at(evaluator, disturbance, times, uniform_traces=uniform_traces)


def lag_horizon(disturbance: Disturbance, times: Array) -> Array:
    """The longest lag between an event of the disturbance and an output time."""
    events = disturbance.event_times()
    if events.shape[0] == 0:
        return jnp.max(times)
    return jnp.maximum(jnp.max(times) - jnp.min(events), jnp.finfo(float).tiny)


def outlet_response(
    rtd: Unit | Line | TabulatedRTD, disturbance: Disturbance, times: ArrayLike
) -> OutletResponse:
    """Outlet deviation ``δc = E ⊗ δu`` of a unit or line for an inlet disturbance (MODELS.md §8).

    Steps answer with F, pulses with E, and traces (ramps included) exactly for their
    piecewise-linear interpolant, through the ramp response ``R = ∫F`` (a sampled trace on
    the output times, uniformly sampled, is convolved by FFT; otherwise the cost is
    ``times × samples``). For a unit with closed-form curves the result is exact; a line's
    curves come from its grid (see :class:`Line`).

    **Arguments:**

    - `rtd`: a :class:`Unit`, :class:`Line` or :class:`TabulatedRTD`.
    - `disturbance`: the inlet deviation (:class:`Disturbance`), in the rtd's time unit.
    - `times`: output times (time unit), 1-D; the system is at target before every event.

    **Returns:**

    An :class:`OutletResponse` with the inlet and outlet deviations at `times`.
    """
    require_finite("times", times)
    times = jnp.asarray(times, float)
    if times.ndim != 1:
        raise ValueError(f"times must be one-dimensional, got shape {times.shape}.")
    if not isinstance(disturbance, Disturbance):
        raise ValueError(f"disturbance must be a Disturbance, got {type(disturbance).__name__}.")
    if disturbance.time_unit != rtd.time_unit:
        raise ValueError(
            f"the disturbance is in {disturbance.time_unit!r} but the RTD in {rtd.time_unit!r}."
        )
    uniform = tuple(
        index for index, trace in enumerate(disturbance.traces) if _trace_on_times(times, trace)
    )
    evaluator = as_evaluator(rtd, lag_horizon(disturbance, times))
    outlet = _response(evaluator, disturbance, times, uniform)
    return OutletResponse(
        times, disturbance.value(times), outlet, rtd.time_unit, disturbance.value_unit
    )

