"""Diversion: when to divert out-of-specification material, and how much (MODELS.md §8).

Diversion starts when the predicted outlet content leaves the specification limits and ends
when it returns; the diverted amount is the flow integrated over that window. With several
excursions the window runs from the first exit to the last return (everything in between is
diverted, which is what a diverter valve does).

The uncertainty of a fitted RTD enters by sampling the fit's (normal or log-normal)
parameter distribution. Two conservative windows are offered:

* ``method="region"`` (default): the earliest start and the latest stop over parameter
  vectors filling the ``coverage`` confidence region of that distribution (the ellipsoid
  ``(p - p̂)ᵀ C⁻¹ (p - p̂) <= chi²_k(coverage)``, sampled on its surface and inside). Whenever
  the true parameters lie in the region the true window lies inside, so it is covered with
  at least the region's probability, whatever the shape of the map from parameters to window.
* ``method="quantile"``: from a low quantile of the sampled starts to a high quantile of the
  sampled stops (the miss rate split between the two ends). Tighter, and close to the stated
  coverage when the window ends move monotonically with the parameters, but not guaranteed:
  when both ends move together the two misses exclude each other and the coverage is just the
  nominal one, below it when the fit's covariance is itself too small.
"""

from __future__ import annotations

import concurrent.futures
import math
import os
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_increasing_times, require_positive
from axialmix.analytic.fourier import grid_inversion, truncation_estimates
from axialmix.line._disturbance import (
    Disturbance,
    has_grid,
    response_at,
    response_on_grid,
)
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._programs import ProgramRunner, compile_program, run_program
from axialmix.line._throughput import FlowSchedule
from axialmix.line._unit import Unit

__all__ = [
    "MAX_EVALUATIONS",
    "MAX_FAILED_SHARE",
    "SETTLED",
    "ConservativeDiversion",
    "DiversionRefused",
    "DiversionTooLarge",
    "DiversionWindow",
    "conservative_diversion_window",
    "diversion_window",
    "memory_budget",
    "sample_units",
]

_ROOT_STEPS = 24
#: Output times evaluated together (the scan of any number of times runs in chunks of these).
_CHUNK = 4096
#: Bytes held per scan time (times, outlet, excess and masks as float64, with room).
_BYTES_PER_TIME = 64
#: Largest number of model evaluations (output times × disturbance events, over the scan and
#: all samples) a diversion may ask for: about ten minutes at a microsecond each.
MAX_EVALUATIONS = 5e8
#: Largest share of covariance samples allowed to fail (no finite prediction, or an outlet
#: that has not settled by the end of the longest scan) before the conservative window is
#: refused: above it the window would be made of the samples that happened to work.
MAX_FAILED_SHARE = 0.01
#: The disturbance's effect counts as settled at the end of the scan when the share still to
#: come, ``1 - F(end - last event)``, is at most this.
SETTLED = 1e-4
#: Doublings of the scan's span allowed to reach a settled outlet.
_EXTENSIONS = 6
#: Samples evaluated together in a batch unless memory asks for fewer.
_BATCH = 64
#: Scan times of one covariance sample: every k-th time of the scan, at least this many.
SAMPLE_SCAN_POINTS = 256
#: Interval counts tried, coarsest first, for the table of F (and E) that the covariance
#: samples of a numerically inverted unit are evaluated on (each time of such a unit costs a
#: contour integral; a sample's scan and root finding ask for about 600 of them).
TABLE_INTERVALS = (64, 128, 256, 512, 1024)
#: Intervals of the table that the nominal window of a numerically inverted unit is computed
#: on, from the unit's exact F (and E) at its nodes; its error is estimated by the table of
#: every second node and reported with the window.
NOMINAL_TABLE_INTERVALS = 2048
#: The coarsest table is taken whose nominal outlet agrees with the exact one at every scan
#: time within this share of the limits' width; if none does, the samples use the exact unit.
TABLE_TOLERANCE = 1e-4
#: The samples' tables come from the Fourier series of :func:`~axialmix.analytic.fourier.
#: grid_inversion` (one FFT a sample instead of a contour a node) when its error, estimated
#: by the series of half the terms and measured against the exact inversion at
#: :data:`CHECK_NODES` nodes, is at most this (F, and E times the horizon); a sample beyond it
#: is tabulated by the exact inversion.
FOURIER_TOLERANCE = 1e-7
#: Nodes of each sample's table checked against the exact inversion (the samples' settle
#: check at the scan's candidate ends shares that program).
CHECK_NODES = 16
#: Most terms of a sample's Fourier series (above, the samples are inverted exactly).
MAX_FOURIER_TERMS = 2**18


def memory_budget() -> int:
    """Bytes a diversion may hold at once: a quarter of the machine's memory, at most 2 GiB."""
    try:
        physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        physical = 8 * 2**30
    return int(min(2 * 2**30, physical // 4))


class DiversionTooLarge(ValueError):
    """A diversion whose scan or samples would exceed the memory or evaluation bounds.

    `option` is ``"points"`` or ``"samples"``: what to reduce."""

    def __init__(self, option: str, message: str):
        super().__init__(message)
        self.option = option


class DiversionRefused(ValueError):
    """A conservative window refused because too many covariance samples failed.

    **Attributes:** `failed` (samples without a finite prediction or a settled outlet),
    `nonfinite`, `unsettled`, `samples` (drawn)."""

    def __init__(self, message: str, failed: int, nonfinite: int, unsettled: int,
                 samples: int):
        super().__init__(message)
        self.failed, self.nonfinite, self.unsettled, self.samples = (
            failed, nonfinite, unsettled, samples)


class DiversionWindow(eqx.Module):
    """When diversion starts and stops, and the amount diverted, for one RTD.

    **Arguments:**

    - `start`: time the outlet content first leaves the limits (time unit; NaN when it never
      does; the first output time when it is already out there).
    - `stop`: time it last returns (time unit; NaN when it never leaves; +inf when it is
      still out at the last output time).
    - `diverted_amount`: ``∫_start^stop Q dt`` (amount unit; 0 or +inf as above).
    - `diverts`: whether the content leaves the limits at any output time.
    - `times`, `outlet`: the output times and the predicted outlet content there.
    - `lower`, `upper`: the specification limits (content unit).
    - `time_unit`, `content_unit`, `amount_unit`: units.
    - `table_error`: NaN when the window was located on the model itself (to round-off);
      for a numerically inverted unit, located on a table of its exact F (and E) at
      :data:`NOMINAL_TABLE_INTERVALS` intervals, the estimate of the outlet's error (content
      unit: the largest difference to the table of every second node over the scan).
    """

    start: Array
    stop: Array
    diverted_amount: Array
    diverts: Array
    times: Array
    outlet: Array
    lower: Array
    upper: Array
    time_unit: str = eqx.field(static=True, default="s")
    content_unit: str = eqx.field(static=True, default="")
    amount_unit: str = eqx.field(static=True, default="")
    table_error: float = eqx.field(static=True, default=float("nan"))

    def to_dict(self) -> dict:
        """Plain JSON-ready dict of the window (NaN and infinities as None and "inf")."""
        return {
            "diverts": bool(self.diverts),
            "start": _number(self.start),
            "stop": _number(self.stop),
            "diverted_amount": _number(self.diverted_amount),
            "lower": _number(self.lower),
            "upper": _number(self.upper),
            "time_unit": self.time_unit,
            "content_unit": self.content_unit,
            "amount_unit": self.amount_unit,
            "table_error": _number(self.table_error),
        }


def _number(value) -> float | str | None:
    number = float(value)
    if np.isnan(number):
        return None
    if np.isinf(number):
        return "inf" if number > 0 else "-inf"
    return number


def _amount(flow, start: Array, stop: Array) -> Array:
    if isinstance(flow, FlowSchedule):
        return flow.throughput(stop) - flow.throughput(start)
    return jnp.asarray(flow, float) * (stop - start)


def _crossing(excess, low: Array, high: Array) -> Array:
    """The sign changes of `excess` in the brackets [low, high] (1-D arrays of brackets whose
    ends differ in sign), to round-off.

    Illinois' regula falsi: the bracket is kept, and an end that stays twice has its value
    halved, so convergence is superlinear (about 1e-15 of the bracket after a dozen steps
    for a smooth excess). At most :data:`_ROOT_STEPS` steps, fewer once every bracket has
    closed to a few units of round-off or landed on a zero (under ``vmap`` the loop runs
    until the last lane is done; the others keep their values).
    """
    # One evaluation site for both ends (and, in the loop, one for the guesses): the model's
    # program appears twice in the compiled code, not four times.
    ends = excess(jnp.concatenate([low, high]))
    f_low, f_high = ends[: low.shape[0]], ends[low.shape[0]:]

    def closed(a, b, fa, fb):
        width = 4.0 * jnp.finfo(float).eps * jnp.maximum(jnp.abs(a), jnp.abs(b))
        return (b - a <= width) | (fa == 0) | (fb == 0) | ~jnp.isfinite(fa + fb)

    def running(state):
        step, a, b, fa, fb, _ = state
        return (step < _ROOT_STEPS) & ~jnp.all(closed(a, b, fa, fb))

    def body(state):
        step, a, b, fa, fb, side = state
        guess = jnp.clip(b - fb * (b - a) / jnp.where(fb != fa, fb - fa, 1.0), a, b)
        guess = jnp.where(jnp.isfinite(guess) & (fb != fa), guess, 0.5 * (a + b))
        fg = excess(guess)
        same_as_a = (fg > 0) == (fa > 0)
        # Replace the end on the guess's side; halve the other end's value if it stays twice.
        new_a = jnp.where(same_as_a, guess, a)
        new_b = jnp.where(same_as_a, b, guess)
        new_fa = jnp.where(same_as_a, fg, jnp.where(side == -1, fa / 2, fa))
        new_fb = jnp.where(same_as_a, jnp.where(side == 1, fb / 2, fb), fg)
        return step + 1, new_a, new_b, new_fa, new_fb, jnp.where(same_as_a, 1, -1)

    _, a, b, fa, fb, _ = jax.lax.while_loop(
        running, body, (0, low, high, f_low, f_high, jnp.zeros(low.shape, int))
    )
    return jnp.where(jnp.abs(fa) < jnp.abs(fb), a, b)


def _excess(content, lower, upper):
    return jnp.maximum(content - upper, lower - content)


def _outlet(evaluator, disturbance, times):
    """The outlet deviation on 1-D `times`, in chunks of :data:`_CHUNK` times (bounded memory
    for any number of times; one program)."""
    n = times.shape[0]
    if n <= _CHUNK:
        return response_at(evaluator, disturbance, times)
    chunks = -(-n // _CHUNK)
    padded = jnp.concatenate([times, jnp.full(chunks * _CHUNK - n, times[-1])])
    values = jax.lax.map(lambda part: response_at(evaluator, disturbance, part),
                         padded.reshape(chunks, _CHUNK))
    return values.reshape(-1)[:n]


def _uniform_count(times: np.ndarray) -> int:
    """How many leading times of a concrete scan lie on one uniform grid (to 1e-9 of its
    spacing): all of them, all but the last (a scan that ends on the given end, off its
    stride), or none."""
    times = np.asarray(times, float)

    def on_grid(count):
        if count < 3:
            return False
        step = (times[count - 1] - times[0]) / (count - 1)
        grid = times[0] + step * np.arange(count)
        return step > 0 and bool(np.max(np.abs(times[:count] - grid)) <= 1e-9 * step)

    for count in (times.shape[0], times.shape[0] - 1):
        if on_grid(count):
            return count
    return 0


def _scan_outlet(evaluator, disturbance, times, uniform: int):
    """The outlet deviation on the scan: its first `uniform` times as one grid
    (:func:`response_on_grid`) when the evaluator propagates along grids, the rest time by
    time."""
    if uniform < 3 or not has_grid(evaluator):
        return _outlet(evaluator, disturbance, times)
    step = (times[uniform - 1] - times[0]) / (uniform - 1)
    head = response_on_grid(evaluator, disturbance, times[0], step, uniform)
    if uniform == times.shape[0]:
        return head
    return jnp.concatenate([head, response_at(evaluator, disturbance, times[uniform:])])


def _window(evaluator, disturbance, times, target, lower, upper, flow, uniform: int = 0):
    """Start, stop, amount, diverts and the outlet content on the times (traceable; the first
    `uniform` times uniformly spaced, see :func:`_uniform_count`)."""
    outlet = target + _scan_outlet(evaluator, disturbance, times, uniform)

    def excess_at(t):
        return _excess(target + response_at(evaluator, disturbance, t), lower, upper)

    out = _excess(outlet, lower, upper) > 0
    diverts = jnp.any(out)
    last_index = times.shape[0] - 1
    first = jnp.argmax(out)
    last = last_index - jnp.argmax(out[::-1])
    # The exit and the return, located together (vectorised over the two brackets).
    roots = _crossing(
        excess_at,
        jnp.stack([times[jnp.maximum(first - 1, 0)], times[last]]),
        jnp.stack([times[first], times[jnp.minimum(last + 1, last_index)]]),
    )
    start = jnp.where(first == 0, times[0], roots[0])
    stop = jnp.where(last == last_index, jnp.inf, roots[1])
    amount = jnp.where(stop == jnp.inf, jnp.inf, _amount(flow, start, jnp.where(
        stop == jnp.inf, start, stop)))
    start = jnp.where(diverts, start, jnp.nan)
    stop = jnp.where(diverts, stop, jnp.nan)
    amount = jnp.where(diverts, amount, 0.0)
    return start, stop, amount, diverts, outlet


def _unsettled(evaluator, disturbance, end):
    """``1 - F(end - last event)``: the share of the disturbance's effect still to come at
    the end of the scan (0 for a disturbance without events)."""
    events = disturbance.event_times()
    if events.shape[0] == 0:
        return jnp.asarray(0.0)
    lag = end - jnp.max(events)
    return jnp.where(lag > 0, 1.0 - evaluator.cumulative(jnp.maximum(lag, 0.0)), 1.0)


def _window_program(evaluator, disturbance, times, target, lower, upper, flow, uniform):
    """The window on a scan and the share of the effect still to come at its end."""
    window = _window(evaluator, disturbance, times, target, lower, upper, flow, uniform)
    return (*window, _unsettled(evaluator, disturbance, times[-1]))


def _candidate_ends(times: np.ndarray) -> np.ndarray:
    """The ends of the scan doubled 0 to :data:`_EXTENSIONS` times."""
    span = float(times[-1] - times[0])
    return times[0] + span * 2.0 ** np.arange(_EXTENSIONS + 1)


def _settle_program(evaluator, disturbance, ends):
    """``1 - F`` at the lag from the last event to each candidate end."""
    return jax.vmap(lambda end: _unsettled(evaluator, disturbance, end))(ends)


def _event_times_host(disturbance: Disturbance) -> np.ndarray:
    """:meth:`Disturbance.event_times` of a concrete disturbance, in NumPy (no program)."""
    parts = [np.asarray(disturbance.step_times, float), np.asarray(disturbance.pulse_times, float),
             *(np.asarray(times, float) for times, _ in disturbance.traces)]
    return np.concatenate(parts)


def _lag_horizon_host(disturbance: Disturbance, times: np.ndarray) -> float:
    """:func:`lag_horizon` of a concrete disturbance and times, in NumPy (no program)."""
    events = _event_times_host(disturbance)
    latest = float(np.max(times))
    if events.size == 0:
        return latest
    return max(latest - float(events.min()), float(np.finfo(float).tiny))


def _sample_settle(unit_factory, parameters, disturbance, ends, horizon, batch):
    """``1 - F`` at each candidate end for each sample ``(samples, ends)``, in batches."""

    def one(vector):
        evaluator = as_evaluator(unit_factory(vector), horizon)
        return jax.vmap(lambda end: _unsettled(evaluator, disturbance, end))(ends)

    return jax.lax.map(one, parameters, batch_size=batch)


def _extended(times: np.ndarray, factor: float = 2.0) -> np.ndarray:
    """`times` continued at their last spacing to `factor` times their span."""
    step = float(times[-1] - times[-2])
    span = float(times[-1] - times[0])
    extra = max(1, int(np.ceil((factor - 1.0) * span / step)))
    return np.concatenate([times, times[-1] + step * np.arange(1, extra + 1)])


def _scan_budget(points: int, lags: int, what: str) -> None:
    """Refuse a scan whose arrays or model evaluations exceed the stated bounds."""
    memory = points * _BYTES_PER_TIME
    if memory > memory_budget():
        raise DiversionTooLarge(
            "points", f"{what} of {points:,} times needs about {memory / 2**30:.3g} GiB, "
            f"more than the {memory_budget() / 2**30:.3g} GiB allowed")
    if points * lags > MAX_EVALUATIONS:
        raise DiversionTooLarge(
            "points", f"{what} of {points:,} times needs about {points * lags:.3g} model "
            f"evaluations, more than the {MAX_EVALUATIONS:.3g} allowed")


def _lags(disturbance: Disturbance) -> int:
    """Model evaluations per output time of a disturbance's response."""
    return max(1, int(disturbance.step_times.shape[0] + disturbance.pulse_times.shape[0]
                      + sum(trace[0].shape[0] for trace in disturbance.traces)))


def _check(rtd, disturbance, times, target, lower, upper, flow):
    require_increasing_times("times", times)
    for name, value in (("target", target), ("lower", lower), ("upper", upper)):
        require_finite(name, value)
    if np.ndim(times) != 1 or np.shape(times)[0] < 2:
        raise ValueError("times must be one-dimensional with at least two samples.")
    if not isinstance(disturbance, Disturbance):
        raise ValueError(f"disturbance must be a Disturbance, got {type(disturbance).__name__}.")
    if disturbance.time_unit != rtd.time_unit:
        raise ValueError(
            f"the disturbance is in {disturbance.time_unit!r} but the RTD in {rtd.time_unit!r}."
        )
    if not isinstance(flow, FlowSchedule):
        require_positive("flow", flow)
    if (
        np.ndim(lower) == 0
        and np.ndim(upper) == 0
        and not isinstance(lower, jax.core.Tracer)
        and not isinstance(upper, jax.core.Tracer)
        and not float(lower) < float(upper)
    ):
        raise ValueError(f"lower ({float(lower):g}) must be below upper ({float(upper):g}).")


def diversion_window(
    rtd: Unit | Line | TabulatedRTD,
    disturbance: Disturbance,
    times: ArrayLike,
    *,
    target: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    flow: ArrayLike | FlowSchedule = 1.0,
    content_unit: str = "",
    amount_unit: str = "",
    extend: bool = True,
    programs: ProgramRunner | None = None,
) -> DiversionWindow:
    """When to start and stop diverting after a disturbance, and how much material that is.

    The outlet content ``target + E ⊗ δu`` (:func:`outlet_response`) is scanned on `times`;
    the first exit from ``[lower, upper]`` and the last return are then located exactly by
    root finding on the model between the neighbouring times (to round-off). A unit whose
    every time is a numerical inversion (``UnitModel.numerical``: the exchange models) is
    evaluated on a table of its exact F (and E) at :data:`NOMINAL_TABLE_INTERVALS`
    intervals instead, and the window carries the estimate of that table's error
    (`table_error`).

    **Arguments:**

    - `rtd`: a :class:`Unit`, :class:`Line` or :class:`TabulatedRTD`.
    - `disturbance`: the inlet deviation (in content units, e.g. a feeder trace).
    - `times`: scan times (time unit), strictly increasing; fine enough that no excursion
      falls between two of them.
    - `target`: the content at steady state (content unit).
    - `lower`, `upper`: specification limits (content unit), e.g. ``0.95 × target`` and
      ``1.05 × target`` for ±5 %.
    - `flow`: the outlet flow, a number (amount per time unit) or a
      :class:`~axialmix.line.FlowSchedule`.
    - `content_unit`, `amount_unit`: units carried to the result.
    - `extend`: continue the scan past ``times[-1]`` (at its last spacing, doubling its span,
      at most six times) until the disturbance's effect has settled: ``1 - F`` at the lag from
      its last event to the end of the scan at most :data:`SETTLED`. Then the outlet content
      no longer changes, so a window open at the end stays open (``stop = inf``) and none
      starts later; a window is never cut by the end of `times`. A ValueError says when the
      outlet has not settled after the doublings.
    - `programs`: how the compiled programs are run (:data:`ProgramRunner`: a cache across
      processes, say); None: compiled in this process.

    **Returns:**

    A :class:`DiversionWindow` (its `times` are the scan's, extended or not).

    **Raises:** :class:`DiversionTooLarge` for a scan of more than
    :data:`MAX_EVALUATIONS` model evaluations or more memory than :func:`memory_budget`.
    """
    _check(rtd, disturbance, times, target, lower, upper, flow)
    times = np.asarray(times, float)
    target, lower, upper = (np.asarray(x, float) for x in (target, lower, upper))
    flow = flow if isinstance(flow, FlowSchedule) else np.asarray(flow, float)
    lags = _lags(disturbance)
    inverted = _inverted_unit(rtd)
    if extend:
        # The end the scan needs, found first (one small program over the candidate ends),
        # so that the window's program is compiled once, for the scan it runs on.
        ends = _candidate_ends(times)
        if inverted is not None:
            unsettled = _inverted_unsettled(inverted, disturbance, ends, programs)
        else:
            evaluator = as_evaluator(rtd, _lag_horizon_host(disturbance, ends))
            unsettled = np.asarray(run_program(programs, "divert-settle", _settle_program,
                                               evaluator, disturbance, ends))
        settled = np.flatnonzero(unsettled <= SETTLED)
        if settled.size == 0:
            raise ValueError(
                f"the outlet has not settled by {ends[-1]:g} {rtd.time_unit} "
                f"({float(unsettled[-1]):.2g} of the disturbance's effect still to come after "
                f"{_EXTENSIONS} doublings of the scan); give later times")
        times = _extended(times, 2.0 ** int(settled[0])) if settled[0] else times
    _scan_budget(times.shape[0], lags, "a scan")
    table_error = float("nan")
    if inverted is not None:
        # Each time of such a unit is a contour integral: the window is located on a fine
        # table of its exact values (one program), whose error is estimated and returned.
        evaluator, _, table_error = _nominal_table(inverted, disturbance, times, programs)
    else:
        evaluator = as_evaluator(rtd, _lag_horizon_host(disturbance, times))
    start, stop, amount, diverts, outlet, _ = run_program(
        programs, "divert-window", _window_program, evaluator, disturbance, times, target,
        lower, upper, flow, _uniform_count(times))
    return DiversionWindow(
        start, stop, amount, diverts, times, outlet, lower, upper,
        rtd.time_unit, content_unit, amount_unit, table_error,
    )


# ------------------------------------------------------------------ uncertainty
def _distribution(values, covariance, scale):
    """The checked values and a square root of the covariance (NumPy)."""
    values = np.atleast_1d(np.asarray(values, float))
    covariance = np.atleast_2d(np.asarray(covariance, float))
    require_finite("values", values)
    require_finite("covariance", covariance)
    p = values.shape[0]
    if values.ndim != 1 or covariance.shape != (p, p):
        raise ValueError(f"covariance must have shape ({p}, {p}), got {covariance.shape}.")
    if scale not in ("linear", "log"):
        raise ValueError(f"scale must be 'linear' or 'log', got {scale!r}.")
    if scale == "log":
        require_positive("values", values)
    eigenvalues, vectors = np.linalg.eigh(covariance)
    if eigenvalues.min() < -1e-10 * max(eigenvalues.max(), 1e-300):
        raise ValueError("covariance must be positive semi-definite.")
    return values, vectors * np.sqrt(np.clip(eigenvalues, 0.0, None))


def _regularized_gamma(a: float, x: float) -> float:
    """The regularized lower incomplete gamma function ``P(a, x)`` (series below ``a + 1``,
    Lentz's continued fraction of ``1 - P`` above), to about 1e-16."""
    if x <= 0.0:
        return 0.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        denominator = a
        while abs(term) > 1e-17 * abs(total):
            denominator += 1.0
            term *= x / denominator
            total += term
        return total * math.exp(log_front)
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    fraction = d
    for i in range(1, 10_000):
        a_i = -i * (i - a)
        b += 2.0
        d = a_i * d + b
        d = tiny if abs(d) < tiny else d
        c = b + a_i / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        fraction *= d * c
        if abs(d * c - 1.0) <= 1e-17:
            break
    return 1.0 - math.exp(log_front) * fraction


def chi_square_quantile(dof: int, probability: float) -> float:
    """The `probability` quantile of the chi-square distribution with `dof` degrees of
    freedom (``2 P^{-1}(dof / 2, probability)``), by bisection to round-off (SciPy's
    ``chi2.ppf`` without importing SciPy).

    **Arguments:** `dof`: degrees of freedom (positive); `probability`: in (0, 1).

    **Returns:** the quantile (dimensionless).
    """
    a = dof / 2.0
    low, high = 0.0, max(1.0, a)
    while _regularized_gamma(a, high) < probability:
        low, high = high, 2.0 * high
    while True:
        middle = 0.5 * (low + high)
        if middle in (low, high):
            break
        if _regularized_gamma(a, middle) < probability:
            low = middle
        else:
            high = middle
    return 2.0 * middle


def _draw_arguments(values, covariance, samples, seed, scale, region) -> tuple:
    """The arguments of :func:`_draw_program` (checked)."""
    if not isinstance(samples, int) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}.")
    values, root = _distribution(values, covariance, scale)
    radius = None
    if region is not None:
        radius = math.sqrt(chi_square_quantile(values.shape[0], region))
    return values, root, np.asarray(seed, np.int64), samples, scale, radius


def _draw(values, covariance, samples, seed, scale, region, programs=None):
    """Parameter vectors: normal draws, or (region) points filling the confidence ellipsoid."""
    return run_program(programs, "divert-draw", _draw_program,
                       *_draw_arguments(values, covariance, samples, seed, scale, region))


def _drawn_settle(draw: tuple, unit_factory, disturbance, ends, horizon, batch):
    """The draws and ``1 - F`` of each at the candidate ends (one program: the samples'
    settle check right after they are drawn)."""
    parameters = _draw_program(*draw)
    padding = -parameters.shape[0] % batch
    padded = jnp.concatenate([parameters, jnp.repeat(parameters[:1], padding, axis=0)])
    return parameters, _sample_settle(unit_factory, padded, disturbance, ends, horizon, batch)


def _draw_program(values, root, seed, samples, scale, radius):
    p = values.shape[0]
    centre = jnp.log(values) if scale == "log" else values
    key_direction, key_radius = jax.random.split(jax.random.PRNGKey(seed))
    normal = jax.random.normal(key_direction, (samples, p))
    if radius is not None:
        # Half of the points on the surface of the region (radius sqrt(chi²_p(region)) in
        # whitened coordinates, where the extremes of a monotone map lie), half uniformly
        # inside it, and the centre.
        directions = normal / jnp.linalg.norm(normal, axis=1, keepdims=True)
        uniform = jax.random.uniform(key_radius, (samples,))
        inside = jnp.arange(samples) % 2 == 1
        radii = radius * jnp.where(inside, uniform ** (1.0 / p), 1.0)
        normal = (directions * radii[:, None]).at[0].set(0.0)
    drawn = centre + normal @ root.T
    return jnp.exp(drawn) if scale == "log" else drawn


def sample_units(
    unit_factory: Callable[[Array], Unit | Line],
    values: ArrayLike,
    covariance: ArrayLike,
    samples: int,
    *,
    seed: int = 0,
    scale: str = "linear",
) -> tuple[Unit | Line, Array]:
    """Units (or lines) for samples of a fitted parameter vector: the hook for fit results.

    Parameter vectors are drawn from ``N(values, covariance)`` (``scale="linear"``) or,
    for positive parameters, ``log p ~ N(log values, covariance)`` with the covariance of
    the logarithms (``scale="log"``, the relative-error form of a fit's covariance), and
    mapped through `unit_factory` under ``jax.vmap``.

    **Arguments:**

    - `unit_factory`: function of one parameter vector ``(p,)`` returning a :class:`Unit`
      or :class:`Line` (it must be traceable: build units from the array entries).
    - `values`: the fitted values ``(p,)``.
    - `covariance`: their covariance ``(p, p)`` (of the logarithms for ``scale="log"``),
      symmetric positive semi-definite.
    - `samples`: number of draws.
    - `seed`: random seed.
    - `scale`: ``"linear"`` or ``"log"``.

    **Returns:**

    ``(units, parameters)``: a batched Unit or Line whose leaves carry a leading axis of
    length `samples` (use it with ``jax.vmap``), and the drawn parameters ``(samples, p)``.
    """
    parameters = _draw(values, covariance, samples, seed, scale, None)
    return jax.vmap(unit_factory)(parameters), parameters


class SampleTables(eqx.Module):
    """How the samples' tables of a numerically inverted unit were made.

    - `intervals`: the table's intervals.
    - `terms`: terms of the Fourier series (None: every sample inverted exactly).
    - `exact`: samples tabulated by the exact inversion (their series missed
      :data:`FOURIER_TOLERANCE`, or no series was used).
    - `error`: the largest error of the series tables used (their estimate and the
      difference from the exact inversion at :data:`CHECK_NODES` nodes; F, and E times the
      horizon; dimensionless), NaN when none was used.
    """

    intervals: int = eqx.field(static=True)
    terms: int | None = eqx.field(static=True)
    exact: int = eqx.field(static=True)
    error: float = eqx.field(static=True)


class ConservativeDiversion(eqx.Module):
    """A diversion window with its uncertainty, from samples of a fit's parameters.

    **Arguments:**

    - `nominal`: the :class:`DiversionWindow` at the fitted values.
    - `start`, `stop`, `diverted_amount`: the conservative window (time unit, amount unit),
      NaN start and stop (amount 0) when no sample calls for diversion.
    - `coverage`: the stated probability.
    - `method`: ``"region"`` or ``"quantile"`` (see :mod:`axialmix.line`'s diversion notes
      and :func:`conservative_diversion_window`).
    - `sample_parameters`: the parameter vectors used ``(samples, p)``.
    - `sample_starts`, `sample_stops`: their windows (``+inf``/``-inf`` for vectors that do
      not divert, NaN for vectors whose prediction is not finite).
    - `diverting_fraction`: share of the valid samples that divert.
    - `valid_samples`: samples with a finite prediction whose outlet settled within the scan.
    - `failed_samples`: the others (at most :data:`MAX_FAILED_SHARE` of the samples, or the
      window is refused), left out of the window and counted here.
    - `scan_end`: the end of the scan of the samples (time unit; past the given times when
      the outlet had not settled there).
    - `time_unit`, `amount_unit`: units.
    - `table_intervals`: None when the samples were evaluated on the unit itself; otherwise
      the intervals of the table of F (and E) each sample was evaluated on (a numerically
      inverted unit, see :data:`TABLE_INTERVALS`).
    - `table_difference`: the largest difference between the nominal outlet from such a table
      and the exact one over the nominal scan (content unit; at most
      :data:`TABLE_TOLERANCE` of the limits' width).
    - `tables`: how those tables were made (:class:`SampleTables`), or None.
    """

    nominal: DiversionWindow
    start: Array
    stop: Array
    diverted_amount: Array
    coverage: float = eqx.field(static=True)
    method: str = eqx.field(static=True)
    sample_parameters: Array
    sample_starts: Array
    sample_stops: Array
    diverting_fraction: Array
    valid_samples: int = eqx.field(static=True)
    failed_samples: int = eqx.field(static=True, default=0)
    scan_end: float = eqx.field(static=True, default=float("nan"))
    time_unit: str = eqx.field(static=True, default="s")
    amount_unit: str = eqx.field(static=True, default="")
    table_intervals: int | None = eqx.field(static=True, default=None)
    table_difference: float = eqx.field(static=True, default=float("nan"))
    tables: SampleTables | None = None

    def to_dict(self) -> dict:
        """Plain JSON-ready dict: the nominal and the conservative window and how it was made."""
        return {
            "nominal": self.nominal.to_dict(),
            "conservative": {
                "start": _number(self.start),
                "stop": _number(self.stop),
                "diverted_amount": _number(self.diverted_amount),
            },
            "coverage": self.coverage,
            "method": self.method,
            "samples": int(self.sample_parameters.shape[0]),
            "valid_samples": self.valid_samples,
            "failed_samples": self.failed_samples,
            "scan_end": _number(self.scan_end),
            "diverting_fraction": float(self.diverting_fraction),
            "sample_table": None if self.table_intervals is None else {
                "intervals": self.table_intervals,
                "nominal_outlet_difference": _number(self.table_difference),
                **({} if self.tables is None else {
                    "method": "exact" if self.tables.terms is None else "fourier series",
                    "series_terms": self.tables.terms,
                    "exact_samples": self.tables.exact,
                    "series_error": _number(self.tables.error)}),
            },
            "time_unit": self.time_unit,
            "amount_unit": self.amount_unit,
        }


def _needs(disturbance: Disturbance) -> bool:
    """Whether a response to `disturbance` uses E (pulses; traces, through the ramp)."""
    return bool(disturbance.pulse_times.shape[0]) or len(disturbance.traces) > 0


def _inverted_unit(rtd) -> Unit | None:
    """The unit of `rtd` when its every time is a numerical inversion, else None."""
    if isinstance(rtd, Line) and len(rtd.units) == 1:
        rtd = rtd.units[0]
    return rtd if isinstance(rtd, Unit) and rtd.model.numerical else None


def _exact_curves_program(unit, times, exit_age):
    return (unit._curve("cumulative", times),
            unit._curve("exit_age", times) if exit_age else None)


def _exact_curves(unit, times, exit_age, programs=None):
    """F (and E, or None) of `unit` at 1-D `times`: the one exact program of an inverted
    unit's diversion (its tables' nodes and its settle checks share its shape)."""
    return run_program(programs, "divert-exact-curves", _exact_curves_program, unit,
                       np.asarray(times, float), exit_age)


def _exact_sample_curves_program(unit_factory, parameters, times, exit_age, batch):
    return jax.lax.map(lambda vector: _exact_curves_program(
        _inverted_unit(unit_factory(vector)), times, exit_age), parameters, batch_size=batch)


def _exact_sample_curves(unit_factory, parameters, times, exit_age, batch, programs=None):
    """:func:`_exact_curves` of every sample's unit ``(samples, times)``, in batches of
    `batch` (the last filled with copies of the first vector, whose results are dropped),
    on the CPU as one call per core at once (:func:`_cpu_parts`; each sample's numbers
    those of one call); NumPy arrays."""
    parameters = np.asarray(parameters)
    count = parameters.shape[0]
    times = np.asarray(times, float)
    calls = [(unit_factory, vectors, times, exit_age, batch) for (vectors,) in _row_calls(
        (parameters,), count, batch, _cpu_parts(-(-count // batch)))]
    compiled = compile_program(programs, "divert-exact-sample-curves",
                               _exact_sample_curves_program, calls[0])
    return _run_calls(compiled, calls, count)


def _padded(times: np.ndarray, size: int) -> np.ndarray:
    """`times` padded with zeros to `size` (a settle check borrows a table's program)."""
    return np.concatenate([times, np.zeros(size - times.shape[0])])


def _table(step, cumulative, exit_age, unit):
    return TabulatedRTD.from_values(step, cumulative, exit_age, unit.mean(), unit.variance(),
                                    unit.time_unit, ramp=exit_age is not None)


def _unsettled_from(cumulative, lags):
    """``1 - F`` at the lags from the last event (1 where the lag is not positive; NumPy)."""
    return np.where(np.asarray(lags) > 0, 1.0 - np.asarray(cumulative), 1.0)


def _sample_windows(unit_factory, parameters, disturbance, times, target, lower, upper, flow,
                    horizon, tables, uniform, batch):
    """Window ends, diverts, finite and unsettled share of each sample, in batches of `batch`
    vectors (one program: ``lax.map`` over batches of a vmapped window). `tables` is None
    (each sample's unit itself) or ``(step, F, E)``: each sample's exact node values
    ``(samples, N + 1)`` of an inverted unit (E None when the disturbance needs none)."""

    def one(item):
        vector, cumulative, density = item
        rtd = unit_factory(vector)
        if tables is None:
            evaluator = as_evaluator(rtd, horizon)
        else:
            evaluator = _table(tables[0], cumulative, density, _inverted_unit(rtd))
        start, stop, _, diverts, outlet = _window(
            evaluator, disturbance, times, target, lower, upper, flow, uniform
        )
        unsettled = _unsettled(evaluator, disturbance, times[-1])
        return start, stop, diverts, jnp.all(jnp.isfinite(outlet)), unsettled

    items = (parameters, None, None) if tables is None else (parameters, *tables[1:])
    return jax.lax.map(one, items, batch_size=batch)


def _sample_step(given: int) -> int:
    """k of the samples' scan: every k-th time of a scan of `given` times keeps at least
    :data:`SAMPLE_SCAN_POINTS` of them (the same k over an extended scan: its spacing stays)."""
    return max(1, (given - 1) // (SAMPLE_SCAN_POINTS - 1))


def _sample_scan(times: np.ndarray, step: int) -> np.ndarray:
    """Every `step`-th time of the scan, and its last."""
    picked = times[::step]
    return picked if picked[-1] == times[-1] else np.append(picked, times[-1])


def _cpu_parts(batches: int) -> int:
    """How many concurrent calls a program over `batches` batches of samples is run as.

    On the CPU one call runs on one core, and calls made at once from several threads run
    on as many cores: one call per core this process may use, each of two batches or more
    (a call of one batch is compiled without its loop over batches, which XLA removes,
    and rounds some samples' numbers differently in the last place; from two batches on,
    each sample's numbers are those of one call over all). On an accelerator, which runs a
    call's lanes in parallel itself: one call."""
    if jax.default_backend() != "cpu":
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, batches // 2))


def _padded_rows(rows, size: int):
    """`rows` with copies of their first row up to `size` rows (NumPy)."""
    rows = np.asarray(rows)
    return np.concatenate([rows, np.repeat(rows[:1], size - rows.shape[0], axis=0)])


def _row_calls(arrays, count: int, batch: int, parts: int) -> list[tuple]:
    """Each call's rows of `arrays` (arrays of `count` rows, or None): padded with copies of
    their first row to whole batches of `batch`, the same number a call, for `parts` calls."""
    rows = batch * -(-count // (batch * parts))
    padded = [None if a is None else _padded_rows(a, rows * parts) for a in arrays]
    return [tuple(None if a is None else a[k * rows:(k + 1) * rows] for a in padded)
            for k in range(parts)]


def _run_calls(compiled, calls: list[tuple], count: int):
    """`compiled` run on each call's arguments, the calls at once (a thread each); the
    outputs joined along their rows and cut to `count` rows (NumPy; a None output stays
    None)."""
    if len(calls) == 1:
        results = [jax.device_get(compiled(*calls[0]))]
    else:
        with concurrent.futures.ThreadPoolExecutor(len(calls)) as pool:
            results = list(pool.map(lambda call: jax.device_get(compiled(*call)), calls))
    return jax.tree_util.tree_map(lambda *outputs: np.concatenate(outputs)[:count], *results)


def _evaluate_samples(unit_factory, parameters, disturbance, times, target, lower, upper,
                      flow, horizon, tables=None, programs=None):
    """Run the sample program on every sample: batches of vectors whose temporary memory
    stays within :func:`memory_budget`, split into whole batches among one call per CPU
    core (:func:`_cpu_parts`; the calls run at once, each on its own thread). A sample's
    batch and its place in it do not depend on the split, and each sample's numbers are
    those of one call over all samples (bit for bit: tested)."""
    parameters = np.asarray(parameters)
    count = parameters.shape[0]
    batch = min(_BATCH, count)
    budget = memory_budget()
    parts = _cpu_parts(-(-count // batch))
    while True:
        # Whole batches only (a remainder would be a second copy of the program): the last
        # batches are filled with copies of the first vector, whose results are dropped.
        calls = [(unit_factory, vectors, disturbance, times, target, lower, upper, flow,
                  horizon, None if tables is None else (tables[0], cumulative, density),
                  _uniform_count(times), batch)
                 for vectors, cumulative, density in _row_calls(
                     (parameters, *((None, None) if tables is None else tables[1:])),
                     count, batch, parts)]
        compiled = compile_program(programs, "divert-samples", _sample_windows, calls[0])
        temp = compiled.temporary_bytes()
        if temp * parts <= budget:
            break
        if batch > 1:
            batch = max(1, int(batch * budget / (temp * parts)))
        elif parts > 1:  # one sample a batch: fewer calls at once
            parts = max(1, min(parts - 1, budget // max(temp, 1)))
        else:
            raise DiversionTooLarge(
                "points", f"one covariance sample over {times.shape[0]:,} scan times needs "
                f"about {temp / 2**30:.3g} GiB, more than the {budget / 2**30:.3g} GiB "
                "allowed")
    return tuple(_run_calls(compiled, calls, count))


def _table_outlets_program(unit, step, cumulative, exit_age, disturbance, times, strides):
    return jnp.stack([response_at(_table(
        step * stride, cumulative[::stride], None if exit_age is None else exit_age[::stride],
        unit), disturbance, times) for stride in strides])


def _table_outlets(unit, step, cumulative, exit_age, disturbance, times, strides,
                   programs=None):
    """The outlet deviation on `times` from the tables of every `stride`-th of the exact node
    values ``(step, cumulative, exit_age)`` (one row per stride)."""
    return run_program(programs, "divert-table-outlets", _table_outlets_program, unit,
                       np.asarray(step, float), cumulative, exit_age, disturbance,
                       np.asarray(times, float), strides)


def _nominal_table(unit: Unit, disturbance: Disturbance, times: np.ndarray, programs=None):
    """The table an inverted unit's nominal window is computed on, with the node values, its
    step and the estimate of its outlet error on `times` (the difference to the table of
    every second node, content unit; the table's own error is smaller, by about 2⁶ for a
    smooth curve)."""
    horizon = _lag_horizon_host(disturbance, times)
    step = horizon / NOMINAL_TABLE_INTERVALS
    cumulative, density = _exact_curves(
        unit, step * np.arange(NOMINAL_TABLE_INTERVALS + 1), _needs(disturbance), programs)
    outlets = np.asarray(_table_outlets(unit, step, cumulative, density, disturbance,
                                        times, (1, 2), programs))
    error = float(np.max(np.abs(outlets[0] - outlets[1])))
    return _table(step, cumulative, density, unit), (step, cumulative, density), error


def _inverted_unsettled(unit: Unit, disturbance: Disturbance, ends: np.ndarray,
                        programs=None) -> np.ndarray:
    """``1 - F(end - last event)`` of an inverted unit at the candidate `ends`, exactly, by the
    program of its nominal table."""
    events = _event_times_host(disturbance)
    if events.size == 0:
        return np.zeros(ends.shape)
    lags = ends - events.max()
    cumulative, _ = _exact_curves(unit, _padded(
        np.maximum(lags, 0.0), NOMINAL_TABLE_INTERVALS + 1), _needs(disturbance), programs)
    return _unsettled_from(np.asarray(cumulative)[: ends.shape[0]], lags)


def _choose_table(unit: Unit, nominal: DiversionWindow, disturbance: Disturbance, target,
                  lower, upper, programs=None):
    """The coarsest interval count of :data:`TABLE_INTERVALS` whose table's nominal outlet
    agrees with the nominal window's within :data:`TABLE_TOLERANCE` of the limits' width on
    the nominal scan, the table's step (time unit) and that difference (content unit); the
    count is None when no table is close enough."""
    _, (step, cumulative, density), _ = _nominal_table(unit, disturbance,
                                                       np.asarray(nominal.times), programs)
    strides = tuple(NOMINAL_TABLE_INTERVALS // n for n in TABLE_INTERVALS)
    outlets = np.asarray(_table_outlets(unit, step, cumulative, density, disturbance,
                                        nominal.times, strides, programs))
    differences = np.max(np.abs(outlets - (np.asarray(nominal.outlet) - float(target))),
                         axis=1)
    allowed = TABLE_TOLERANCE * float(upper - lower)
    for intervals, stride, difference in zip(TABLE_INTERVALS, strides, differences,
                                             strict=True):
        if difference <= allowed:
            return intervals, step * stride, float(difference)
    return None, float("nan"), float("nan")


def _sample_grid(disturbance: Disturbance, scan: np.ndarray, step: float):
    """Spacing, interval count and horizon of the samples' tables over the lags of `scan`:
    spacing at most `step`, the count a power of two (extended scans keep the spacing)."""
    horizon = _lag_horizon_host(disturbance, scan)
    intervals = 1 << max(0, math.ceil(math.log2(horizon / step - 1e-9)))
    return horizon / intervals, intervals, horizon


def _pad_rows(parameters, batch: int):
    """`parameters` with copies of their first row up to a whole number of batches (NumPy)."""
    count = np.shape(parameters)[0]
    return _padded_rows(parameters, count + -count % batch)


def _unit_transfer(unit: Unit):
    return lambda s: unit.model.transfer_function(s, unit.parameters, unit.structure)


def _fourier_estimates(unit, horizon, intervals, max_terms, exit_age):
    return truncation_estimates(_unit_transfer(unit), horizon, intervals, max_terms,
                                exit_age=exit_age)


def _fourier_terms(unit: Unit, horizon: float, intervals: int, exit_age: bool,
                   programs=None) -> int | None:
    """Terms of the samples' Fourier series: twice the fewest whose estimate on the nominal
    unit is a tenth of :data:`FOURIER_TOLERANCE` (a margin for the samples' spread), or None
    when :data:`MAX_FOURIER_TERMS` do not reach it."""
    estimates = np.asarray(run_program(programs, "divert-fourier-estimates",
                                       _fourier_estimates, unit, float(horizon), intervals,
                                       MAX_FOURIER_TERMS // 2, exit_age))
    good = np.flatnonzero(estimates <= 0.1 * FOURIER_TOLERANCE)
    return None if good.size == 0 else 8 * intervals * 2 ** int(good[0])


def _fourier_sample_curves(unit_factory, parameters, horizon, intervals, terms, exit_age,
                           batch):
    """Each sample's Fourier-series table ``(F, E, estimate)``, in batches."""
    return jax.lax.map(lambda vector: grid_inversion(
        _unit_transfer(_inverted_unit(unit_factory(vector))), horizon, intervals, terms,
        exit_age=exit_age), parameters, batch_size=batch)


def _fourier_batch(terms: int) -> int:
    """Samples a batch of series of `terms` terms may hold within :func:`memory_budget`
    (about twenty complex arrays of the terms a sample)."""
    return int(max(1, min(_BATCH, memory_budget() // (20 * 16 * terms))))


def _check_nodes(intervals: int) -> np.ndarray:
    return np.unique(np.round(np.linspace(1, intervals, CHECK_NODES)).astype(int))


def _sample_tables(unit_factory, parameters, disturbance, scan, step: float, batch: int,
                   unit: Unit, programs=None):
    """Each sample's node values on the grid of :func:`_sample_grid`: ``(step, F, E)`` with
    ``(samples, N + 1)`` arrays, the horizon and the :class:`SampleTables` record. The
    values come from the Fourier series where it is verified, else from the exact
    inversion."""
    grid, intervals, horizon = _sample_grid(disturbance, scan, step)
    count = parameters.shape[0]
    needs = _needs(disturbance)
    nodes = grid * np.arange(intervals + 1)
    terms = _fourier_terms(unit, grid * intervals, intervals, needs, programs)
    if terms is None:
        cumulative, density = _exact_sample_curves(
            unit_factory, parameters, nodes, needs, batch, programs)
        return ((grid, cumulative[:count], None if density is None else density[:count]),
                horizon, SampleTables(intervals, None, count, float("nan")))
    fbatch = min(_fourier_batch(terms), count)
    cumulative, density, estimate = run_program(
        programs, "divert-fourier-sample-curves", _fourier_sample_curves, unit_factory,
        _pad_rows(parameters, fbatch), grid * intervals, intervals, terms, needs, fbatch)
    cumulative, estimate = np.array(cumulative[:count]), np.asarray(estimate[:count])
    density = None if density is None else np.array(density[:count])
    checked = _check_nodes(intervals)
    exact_f, exact_e = _exact_sample_curves(
        unit_factory, parameters, _padded(nodes[checked], CHECK_NODES), needs, batch,
        programs)
    exact_f = np.asarray(exact_f[:count, : checked.size])
    difference = np.abs(cumulative[:, checked] - exact_f).max(axis=1)
    finite = np.isfinite(exact_f).all(axis=1)
    if density is not None:
        exact_e = np.asarray(exact_e[:count, : checked.size])
        difference = np.maximum(difference, grid * intervals * np.abs(
            density[:, checked] - exact_e).max(axis=1))
        finite &= np.isfinite(exact_e).all(axis=1)
    error = np.maximum(estimate, difference)
    # Samples whose series missed the tolerance are inverted exactly; those whose exact
    # inversion is not finite fail later whatever their table holds.
    redo = np.flatnonzero(finite & ~(error <= FOURIER_TOLERANCE))
    if redo.size:
        exact_cumulative, exact_density = _exact_sample_curves(
            unit_factory, parameters[redo], nodes, needs, batch, programs)
        cumulative[redo] = np.asarray(exact_cumulative[: redo.size])
        if density is not None:
            density[redo] = np.asarray(exact_density[: redo.size])
    used = finite.copy()
    used[redo] = False
    cumulative[~finite] = np.nan
    worst = float(error[used].max()) if used.any() else float("nan")
    return ((grid, jnp.asarray(cumulative), None if density is None else jnp.asarray(density)),
            horizon, SampleTables(intervals, terms, int(redo.size), worst))


def _sample_settle_exact(unit_factory, parameters, disturbance, ends, batch: int,
                         programs=None) -> np.ndarray:
    """``1 - F(end - last event)`` of each sample at the candidate `ends` ``(samples, ends)``,
    by the exact inversion (the program of the tables' check nodes: the lags padded to
    :data:`CHECK_NODES`)."""
    events = _event_times_host(disturbance)
    count = parameters.shape[0]
    if events.size == 0:
        return np.zeros((count, ends.shape[0]))
    lags = ends - events.max()
    cumulative, _ = _exact_sample_curves(
        unit_factory, parameters, _padded(np.maximum(lags, 0.0), CHECK_NODES),
        _needs(disturbance), batch, programs)
    return _unsettled_from(np.asarray(cumulative)[:count, : ends.shape[0]], lags)


def _refuse_if_failing(nonfinite: int, nonfinite_reason: str, unsettled: int, end: float,
                       samples: int, max_failed_share: float, time_unit: str) -> None:
    """Raise :class:`DiversionRefused` when more than `max_failed_share` of the samples fail:
    `nonfinite` of them for `nonfinite_reason`, `unsettled` not settled by `end`."""
    failed = nonfinite + unsettled
    if failed <= max_failed_share * samples:
        return
    reasons = []
    if nonfinite:
        reasons.append(f"{nonfinite} {nonfinite_reason}")
    if unsettled:
        reasons.append(f"{unsettled} have not settled by {end:g} {time_unit}")
    raise DiversionRefused(
        f"{failed} of {samples} samples ({failed / samples:.1%}, more than the "
        f"{max_failed_share:.0%} allowed) fail: {' and '.join(reasons)}; the parameter "
        "distribution reaches values where the model has no usable prediction, so no "
        "conservative window is given", failed, nonfinite, unsettled, samples)


def _refuse_never_settling(settle: np.ndarray, ends: np.ndarray, samples: int,
                           max_failed_share: float, time_unit: str) -> None:
    """Refuse before the samples' scan when too many samples have settled at none of the
    candidate `ends` (``settle``: their ``1 - F`` there, ``(samples, ends)``): no finite value
    at any, or above :data:`SETTLED` at all of them, the last being 2^_EXTENSIONS times the
    nominal scan's span, the longest scan there is. F does not decrease, so such a sample
    has not settled by the end of any scan: the scan (which for these samples would run to
    its longest) would end in this refusal."""
    never = ~(settle <= SETTLED).any(axis=1)
    nothing = never & ~np.isfinite(settle).any(axis=1)
    _refuse_if_failing(int(nothing.sum()), "give no finite F at any scan end",
                       int((never & ~nothing).sum()), float(ends[-1]), samples,
                       max_failed_share, time_unit)


def _settled_scan(settle: np.ndarray, full: np.ndarray, scan: np.ndarray, step: int,
                  samples: int, lags: int) -> np.ndarray:
    """The samples' scan doubled (at its spacing) to the latest candidate end at which every
    sample with finite values has settled, within :data:`MAX_EVALUATIONS` (later samples then
    count as not settled)."""
    reaches = settle <= SETTLED
    needed = np.where(reaches.any(axis=1), np.argmax(reaches, axis=1), _EXTENSIONS)
    doublings = int(needed[np.isfinite(settle).all(axis=1)].max(initial=0))
    while doublings and samples * _sample_scan(
            _extended(full, 2.0 ** doublings), step).shape[0] * lags > MAX_EVALUATIONS:
        doublings -= 1
    return _sample_scan(_extended(full, 2.0 ** doublings), step) if doublings else scan


def conservative_diversion_window(
    unit_factory: Callable[[Array], Unit | Line],
    values: ArrayLike,
    covariance: ArrayLike,
    disturbance: Disturbance,
    times: ArrayLike,
    *,
    target: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    flow: ArrayLike | FlowSchedule = 1.0,
    coverage: float = 0.95,
    method: str = "region",
    samples: int = 1000,
    seed: int = 0,
    scale: str = "linear",
    content_unit: str = "",
    amount_unit: str = "",
    max_failed_share: float = MAX_FAILED_SHARE,
    programs: ProgramRunner | None = None,
) -> ConservativeDiversion:
    """A diversion window that covers the true one with a stated probability, by sampling.

    ``method="region"`` (default) fills the `coverage` confidence region of the parameter
    distribution (normal, or log-normal with ``scale="log"``) with `samples` vectors, half on
    its surface, and returns the earliest start and the latest stop among them: it contains
    the true window whenever the true parameters lie in the region, i.e. with probability at
    least `coverage` under the fit's distribution. ``method="quantile"`` draws from the
    distribution itself and returns the ``(1 - coverage)/2`` quantile of the starts and the
    ``(1 + coverage)/2`` quantile of the stops: tighter, about the stated coverage when the
    ends move monotonically with the parameters, not guaranteed. Vectors that do not divert
    count as windows from +inf to -inf. Sampling rather than first-order propagation through
    JAX derivatives is used because a window need not exist for every parameter vector and
    its ends are not smooth where an excursion appears or merges with another.

    **Arguments:**

    - `unit_factory`: function of a parameter vector returning a :class:`Unit` or :class:`Line`
      (traceable; it is vmapped).
    - `values`, `covariance`: the fit's parameter vector and covariance (see `scale`).
    - `disturbance`, `times`, `target`, `lower`, `upper`, `flow`: as in
      :func:`diversion_window`.
    - `coverage`: the probability to cover (between 0 and 1).
    - `method`: ``"region"`` or ``"quantile"``.
    - `samples`: number of parameter vectors.
    - `seed`: random seed.
    - `scale`: ``"linear"`` or ``"log"`` (see :func:`sample_units`).
    - `content_unit`, `amount_unit`: units of the content and of the diverted amount.
    - `max_failed_share`: largest share of samples allowed to fail (no finite prediction, or
      an outlet not settled at the end of the longest scan); above it the window is refused.
    - `programs`: how the compiled programs are run (see :func:`diversion_window`).

    The nominal window's scan is extended until its outlet has settled (see
    :func:`diversion_window`); the samples are scanned on every k-th of its times (k such that
    the given `times` keep at least :data:`SAMPLE_SCAN_POINTS`; their crossings are then
    located exactly on the model), and the scan is extended further, at the same spacing,
    while some sample has not settled. Samples run in batches
    whose memory, measured from the compiled program before any work, stays within
    :func:`memory_budget`. A unit whose every time is a numerical inversion (the exchange
    models, ``UnitModel.numerical``) is evaluated, sample by sample, on a table of its F
    (and E) at the coarsest grid of :data:`TABLE_INTERVALS` whose nominal outlet agrees
    with the nominal window's (itself on a table of :data:`NOMINAL_TABLE_INTERVALS`
    intervals of exact values) within :data:`TABLE_TOLERANCE` of the limits' width (the
    result says which grid and how close); without such a grid the samples use the unit
    itself. Each sample's table comes from the damped Fourier series of
    :func:`~axialmix.analytic.fourier.grid_inversion` (one FFT a sample), whose error, its
    own estimate and the difference from the exact inversion at :data:`CHECK_NODES` nodes,
    must be at most :data:`FOURIER_TOLERANCE`; samples that miss it are tabulated by the
    exact inversion, and the result counts them (``tables``).

    **Returns:**

    A :class:`ConservativeDiversion`, with the failed samples counted.

    **Raises:** :class:`DiversionRefused` when more than `max_failed_share` of the samples
    fail (the window is never made of the samples that happened to work);
    :class:`DiversionTooLarge` when the samples and scan would exceed
    :data:`MAX_EVALUATIONS` model evaluations or the memory budget (before any work).
    """
    if not 0.0 < coverage < 1.0:
        raise ValueError(f"coverage must lie between 0 and 1, got {coverage!r}.")
    if method not in ("region", "quantile"):
        raise ValueError(f"method must be 'region' or 'quantile', got {method!r}.")
    if not 0.0 <= max_failed_share < 1.0:
        raise ValueError(f"max_failed_share must lie in [0, 1), got {max_failed_share!r}.")
    nominal_rtd = unit_factory(np.atleast_1d(np.asarray(values, float)))
    nominal = diversion_window(
        nominal_rtd, disturbance, times,
        target=target, lower=lower, upper=upper, flow=flow, content_unit=content_unit,
        amount_unit=amount_unit, programs=programs,
    )
    lags = _lags(disturbance)
    step = _sample_step(np.shape(times)[0])
    scan = _sample_scan(np.asarray(nominal.times), step)
    if isinstance(samples, int) and samples * scan.shape[0] * lags > MAX_EVALUATIONS:
        raise DiversionTooLarge(
            "samples", f"{samples:,} samples over {scan.shape[0]:,} scan times need about "
            f"{samples * scan.shape[0] * lags:.3g} model evaluations, more than the "
            f"{MAX_EVALUATIONS:.3g} allowed")
    draw = _draw_arguments(values, covariance, samples, seed, scale,
                           coverage if method == "region" else None)
    target, lower, upper = (np.asarray(x, float) for x in (target, lower, upper))
    flow = flow if isinstance(flow, FlowSchedule) else np.asarray(flow, float)
    full = np.asarray(nominal.times)
    batch = min(_BATCH, samples)
    inverted = _inverted_unit(nominal_rtd)
    ends = _candidate_ends(full)
    if inverted is None:
        # The draws and the end each sample needs, first (a small program: F at the
        # candidate ends), then the windows of all samples on one scan to the latest end
        # any of them needs.
        parameters, settle = run_program(
            programs, "divert-draw-settle", _drawn_settle, draw, unit_factory, disturbance,
            ends, _lag_horizon_host(disturbance, ends), batch)
        parameters, settle = np.asarray(parameters), np.asarray(settle)[:samples]
    else:
        parameters = np.asarray(run_program(programs, "divert-draw", _draw_program, *draw))
    table_intervals = table_step = table_record = None
    table_difference = float("nan")
    if inverted is not None:
        table_intervals, table_step, table_difference = _choose_table(
            inverted, nominal, disturbance, target, lower, upper, programs)
    if table_intervals is not None:
        # Each sample is evaluated on a table of its values, on the scan to the latest end
        # any of them needs (found first, exactly).
        settle = _sample_settle_exact(unit_factory, parameters, disturbance, ends, batch,
                                      programs)
        _refuse_never_settling(settle, ends, samples, max_failed_share, nominal.time_unit)
        scan = _settled_scan(settle, full, scan, step, samples, lags)
        tables, horizon, table_record = _sample_tables(
            unit_factory, parameters, disturbance, scan, table_step, batch, inverted, programs)
        starts, stops, diverts, finite, unsettled = _evaluate_samples(
            unit_factory, parameters, disturbance, scan, target, lower, upper, flow,
            horizon, tables, programs)
    else:
        if inverted is not None:  # an inverted unit without a close enough table
            settle = np.asarray(run_program(
                programs, "divert-sample-settle", _sample_settle, unit_factory,
                _pad_rows(parameters, batch), disturbance, ends,
                _lag_horizon_host(disturbance, ends), batch))[:samples]
        _refuse_never_settling(settle, ends, samples, max_failed_share, nominal.time_unit)
        scan = _settled_scan(settle, full, scan, step, samples, lags)
        starts, stops, diverts, finite, unsettled = _evaluate_samples(
            unit_factory, parameters, disturbance, scan, target, lower, upper, flow,
            _lag_horizon_host(disturbance, scan),  # static: a measured grid
            None, programs)
    late = finite & ~(unsettled <= SETTLED)
    nonfinite, unsettled_count = int((~finite).sum()), int(late.sum())
    failed = nonfinite + unsettled_count
    _refuse_if_failing(nonfinite, "give no finite outlet prediction", unsettled_count,
                       float(scan[-1]), samples, max_failed_share, nominal.time_unit)
    valid = finite & ~late
    starts = np.where(valid, np.where(diverts, starts, np.inf), np.nan)
    stops = np.where(valid, np.where(diverts, stops, -np.inf), np.nan)
    kept_starts = starts[valid]
    kept_stops = stops[valid]
    if method == "region":
        start, stop = kept_starts.min(), kept_stops.max()
    else:
        miss = (1.0 - coverage) / 2.0
        start = np.quantile(kept_starts, miss, method="lower")
        stop = np.quantile(kept_stops, 1.0 - miss, method="higher")
    if not np.isfinite(start) or not stop >= start:
        start = stop = np.nan
        amount = np.asarray(0.0)
    elif np.isinf(stop):
        amount = np.asarray(np.inf)
    elif isinstance(flow, FlowSchedule):
        amount = _amount(flow, jnp.asarray(start), jnp.asarray(stop))
    else:
        amount = np.asarray(flow * (stop - start))
    # Host values stay NumPy arrays (turning them into JAX arrays would run a program each).
    return ConservativeDiversion(
        nominal,
        np.asarray(start),
        np.asarray(stop),
        amount,
        float(coverage),
        method,
        parameters,
        starts,
        stops,
        np.asarray(np.asarray(diverts)[valid].mean()),
        int(valid.sum()),
        failed,
        float(scan[-1]),
        nominal.time_unit,
        amount_unit,
        table_intervals,
        table_difference,
        table_record,
    )
