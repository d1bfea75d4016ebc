"""Funnel plots: the largest outlet deviation for square inlet disturbances (MODELS.md §8)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_positive
from axialmix.line._disturbance import grid_curve, has_grid
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._models import EMPIRICAL
from axialmix.line._programs import ProgramRunner, run_program
from axialmix.line._unit import Unit, is_concrete

__all__ = ["FunnelResult", "FunnelSettings", "funnel"]

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


class FunnelSettings(eqx.Module):
    """How the worst window of each duration is found (see :func:`funnel`).

    **Arguments:**

    - `grid_points`: candidate window starts on ``[0, reach]`` (at least 16).
    - `iterations`: golden-section steps refining the best candidate (at least 1; 40 shrink
      the two-cell bracket by 4e-9, which leaves the maximum exact to round-off since the
      error is quadratic in the position).
    - `reach_spreads`: the search covers window starts up to the mean plus this many
      standard deviations (a measured curve: up to its last sample).
    """

    grid_points: int = eqx.field(static=True, default=512)
    iterations: int = eqx.field(static=True, default=40)
    reach_spreads: float = eqx.field(static=True, default=10.0)

    def __check_init__(self) -> None:
        if not isinstance(self.grid_points, int) or self.grid_points < 16:
            raise ValueError(
                f"grid_points must be an integer of at least 16, got {self.grid_points!r}."
            )
        if not isinstance(self.iterations, int) or self.iterations < 1:
            raise ValueError(f"iterations must be a positive integer, got {self.iterations!r}.")
        if not (self.reach_spreads > 0):
            raise ValueError(f"reach_spreads must be positive, got {self.reach_spreads!r}.")


class FunnelResult(eqx.Module):
    """The funnel plot of a unit or line: largest outlet deviation per magnitude and duration.

    **Arguments:**

    - `durations`: durations of the square disturbances (time unit), ``(n_durations,)``.
    - `magnitudes`: their magnitudes (magnitude unit), ``(n_magnitudes,)``.
    - `max_deviation`: ``M · max_t [F(t) - F(t - d)]``, one row per magnitude and one column
      per duration (magnitude unit), ``(n_magnitudes, n_durations)``; signed like M.
    - `max_fraction`: ``max_t [F(t) - F(t - d)]`` per duration (dimensionless): the part of
      a disturbance that reaches the outlet at its worst moment.
    - `worst_time`: time after the disturbance starts at which that happens (time unit).
    - `time_unit`, `magnitude_unit`: units.
    - `mean_residence_time`: the mean residence time of the RTD (time unit), found with
      the funnel (its search reaches past it by `reach_spreads` standard deviations), or
      None.
    """

    durations: Array
    magnitudes: Array
    max_deviation: Array
    max_fraction: Array
    worst_time: Array
    time_unit: str = eqx.field(static=True, default="s")
    magnitude_unit: str = eqx.field(static=True, default="")
    mean_residence_time: Array | None = None

    def to_dict(self) -> dict:
        """Plain JSON-ready dict: ``max_deviation`` rows are magnitudes, columns durations."""
        return {
            "durations": np.asarray(self.durations).tolist(),
            "magnitudes": np.asarray(self.magnitudes).tolist(),
            "max_deviation": np.asarray(self.max_deviation).tolist(),
            "max_fraction": np.asarray(self.max_fraction).tolist(),
            "worst_time": np.asarray(self.worst_time).tolist(),
            "time_unit": self.time_unit,
            "magnitude_unit": self.magnitude_unit,
        }


def _reach(rtd: Unit | Line | TabulatedRTD, settings: FunnelSettings) -> Array:
    """Latest window start searched: mean + k sd, or the last sample of a measured curve."""
    if isinstance(rtd, Unit) and rtd.model == EMPIRICAL:
        return jnp.asarray(rtd.structure[-1], float)
    return rtd.mean() + settings.reach_spreads * jnp.sqrt(rtd.variance())


def _worst_window(evaluator, duration: Array, starts: Array, base: Array, iterations: int):
    """Largest ``F(u + d) - F(u)`` over window starts u >= 0 and its argument (one duration)."""

    def passed(u):
        return evaluator.cumulative(u + duration) - evaluator.cumulative(u)

    count = starts.shape[0]
    if has_grid(evaluator):  # F on the shifted grid of starts, propagated (a network)
        shifted = grid_curve(evaluator, "cumulative", duration, starts[1] - starts[0], count)
    else:
        shifted = evaluator.cumulative(starts + duration)
    candidates = shifted - base
    best = jnp.argmax(candidates)
    last = starts.shape[0] - 1
    low = starts[jnp.maximum(best - 1, 0)]
    high = starts[jnp.minimum(best + 1, last)]

    # Golden-section search for the maximum inside the bracket around the best candidate.
    def body(_, bracket):
        a, b = bracket
        c = b - _GOLDEN * (b - a)
        d = a + _GOLDEN * (b - a)
        keep_left = passed(c) > passed(d)
        return jnp.where(keep_left, a, c), jnp.where(keep_left, d, b)

    a, b = jax.lax.fori_loop(0, iterations, body, (low, high))
    refined = 0.5 * (a + b)
    refined_value = passed(refined)
    use_refined = refined_value >= candidates[best]
    value = jnp.where(use_refined, refined_value, candidates[best])
    start = jnp.where(use_refined, refined, starts[best])
    return value, start + duration


def _funnel_core(evaluator, durations: Array, reach: Array | None, grid_points: int,
                 iterations: int):
    """The worst fraction and its time for every duration (one program: the durations are
    vmapped); `reach` None: the mean plus `reach_spreads` standard deviations, here."""
    starts = jnp.linspace(0.0, reach, grid_points)
    if has_grid(evaluator):
        base = grid_curve(evaluator, "cumulative", 0.0, starts[1] - starts[0], grid_points)
    else:
        base = evaluator.cumulative(starts)
    return jax.vmap(
        lambda duration: _worst_window(evaluator, duration, starts, base, iterations)
    )(durations)


def _funnel_program(evaluator, durations, reach, settings: FunnelSettings):
    """The worst fractions and times and the RTD's mean, one program."""
    if reach is None:
        reach = _reach(evaluator, settings)
    fraction, worst_time = _funnel_core(evaluator, durations, reach, settings.grid_points,
                                        settings.iterations)
    return fraction, worst_time, evaluator.mean()


def funnel(
    rtd: Unit | Line | TabulatedRTD,
    durations: ArrayLike,
    magnitudes: ArrayLike,
    *,
    magnitude_unit: str = "",
    settings: FunnelSettings | None = None,
    programs: ProgramRunner | None = None,
) -> FunnelResult:
    """Funnel plot: the largest outlet deviation for each square disturbance (MODELS.md §8).

    A square inlet disturbance of magnitude M and duration d leaves the unit as
    ``M [F(t) - F(t - d)]``; its largest value is ``M · max_u [F(u + d) - F(u)]`` over the
    age u of the window start (Garcia-Munoz et al. 2018). For every duration at once (vmap)
    the exact F is scanned on `grid_points` window starts and the best one is refined by
    golden-section search, so the maximum is exact to round-off for any RTD whose
    ``F(u + d) - F(u)`` has a single peak within a grid cell of the best candidate.

    **Arguments:**

    - `rtd`: a :class:`Unit`, :class:`Line` or :class:`TabulatedRTD`.
    - `durations`: positive durations (time unit), 1-D.
    - `magnitudes`: magnitudes (any unit, any sign), 1-D.
    - `magnitude_unit`: their unit, carried to the result.
    - `settings`: :class:`FunnelSettings`.
    - `programs`: how the compiled program is run (a :data:`~axialmix.line.ProgramRunner`:
      a cache across processes, say); None: compiled in this process.

    **Returns:**

    A :class:`FunnelResult` whose ``max_deviation`` has one row per magnitude and one column
    per duration.
    """
    settings = FunnelSettings() if settings is None else settings
    require_positive("durations", durations)
    require_finite("magnitudes", magnitudes)
    # Concrete grids stay NumPy (a JAX array made of each would be a program of its own).
    array = np.asarray if is_concrete(durations, magnitudes) else jnp.asarray
    durations = array(durations, float).reshape(-1) if np.ndim(durations) == 0 else array(
        durations, float)
    magnitudes = array(magnitudes, float).reshape(-1) if np.ndim(magnitudes) == 0 else array(
        magnitudes, float)
    if durations.ndim != 1 or magnitudes.ndim != 1:
        raise ValueError("durations and magnitudes must be one-dimensional.")
    if isinstance(rtd, Line) and len(rtd.units) > 1:
        # A line is tabulated to the reach it needs (a concrete horizon), then scanned.
        reach = _reach(rtd, settings)
        evaluator = as_evaluator(rtd, reach + jnp.max(durations))
    else:  # the reach is found inside the program
        reach, evaluator = None, as_evaluator(rtd, 0.0)
    fraction, worst_time, mean = run_program(programs, "funnel", _funnel_program, evaluator,
                                             durations, reach, settings)
    if array is np.asarray and is_concrete(fraction):
        fraction, worst_time, mean = np.asarray(fraction), np.asarray(worst_time), np.asarray(
            mean)
    return FunnelResult(
        durations,
        magnitudes,
        magnitudes[:, None] * fraction[None, :],
        fraction,
        worst_time,
        rtd.time_unit,
        magnitude_unit,
        mean,
    )
