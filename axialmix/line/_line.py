"""Unit operations in series: :class:`Line`, and the tabulated curves it computes."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import concrete_value, require_finite
from axialmix.line import _grid
from axialmix.line._models import EMPIRICAL, TANKS
from axialmix.line._unit import DEFAULT_INTERVALS, Unit, choose_intervals, is_concrete

__all__ = ["Line", "LineSettings", "TabulatedRTD", "as_evaluator"]

_UNIFORM_RTOL = 1e-9


class LineSettings(eqx.Module):
    """How a line's curves are computed on a grid (see :mod:`axialmix.line`).

    **Arguments:**

    - `intervals`: grid intervals over ``[0, horizon]`` when the line holds no measured
      curve (at least 16; raised on concrete input until the step is at most 1/16 of the
      smallest unit's standard deviation).
    - `subdivisions`: grid steps per sample step of the measured curves in the line (at
      least 1; raised likewise).
    """

    intervals: int = eqx.field(static=True, default=DEFAULT_INTERVALS)
    subdivisions: int = eqx.field(static=True, default=4)

    def __check_init__(self) -> None:
        if not isinstance(self.intervals, int) or self.intervals < 16:
            raise ValueError(
                f"intervals must be an integer of at least 16, got {self.intervals!r}."
            )
        if not isinstance(self.subdivisions, int) or self.subdivisions < 1:
            raise ValueError(
                f"subdivisions must be a positive integer, got {self.subdivisions!r}."
            )


class TabulatedRTD(eqx.Module):
    """E, F and the ramp response of an RTD on the grid ``k h`` over ``[0, horizon]``.

    Values between nodes are interpolated (six-point Lagrange). Beyond the horizon the RTD is
    taken as finished: E = 0, F = F(horizon), R grows with slope F(horizon).

    **Arguments:**

    - `step`: grid spacing h (time unit).
    - `exit_age_values`, `cumulative_values`, `ramp_values`: node values ``(N + 1,)``.
    - `mean_value`, `variance_value`: exact moments of the RTD (time, time²).
    - `time_unit`: unit of time.
    """

    step: Array
    exit_age_values: Array
    cumulative_values: Array
    ramp_values: Array
    mean_value: Array
    variance_value: Array
    time_unit: str = eqx.field(static=True, default="s")

    @classmethod
    def from_unit(cls, unit: Unit, horizon: ArrayLike, intervals: int, *,
                  exit_age: bool = True, ramp: bool = True) -> TabulatedRTD:
        """Tabulate a unit's exact curves on ``k h``, ``h = horizon / intervals`` (traceable).

        F (and E where asked) are the unit's exact values at the ``intervals + 1`` nodes; the
        ramp response is integrated from them interval by interval with the cubic Hermite
        rule ``h (F_k + F_k+1)/2 + h² (E_k - E_k+1)/12`` (fourth order). Use it where one
        unit is evaluated at many times and each costs a numerical inversion; the table's
        error is that of six-point Lagrange interpolation on the grid (check it against the
        unit: :func:`axialmix.line.conservative_diversion_window` does).

        **Arguments:**

        - `unit`: the unit.
        - `horizon`: last node (time unit).
        - `intervals`: number of grid intervals (static, at least 5).
        - `exit_age`: tabulate E (needed for pulses and for the ramp response).
        - `ramp`: tabulate the ramp response (needed for traces); implies `exit_age`.

        **Returns:**

        A :class:`TabulatedRTD`; a curve not tabulated is NaN, so a use of it cannot pass
        unnoticed.
        """
        if not isinstance(intervals, int) or intervals < 5:
            raise ValueError(f"intervals must be an integer of at least 5, got {intervals!r}.")
        step = jnp.asarray(horizon, float) / intervals
        nodes = step * jnp.arange(intervals + 1)
        density = unit._curve("exit_age", nodes) if (exit_age or ramp) else None
        return cls.from_values(step, unit._curve("cumulative", nodes), density,
                               unit.mean(), unit.variance(), unit.time_unit, ramp=ramp)

    @classmethod
    def from_values(cls, step: ArrayLike, cumulative: Array, exit_age: Array | None,
                    mean: ArrayLike, variance: ArrayLike, time_unit: str = "s", *,
                    ramp: bool = True) -> TabulatedRTD:
        """A table from exact node values ``F(k h)`` (and ``E(k h)``) (traceable).

        **Arguments:**

        - `step`: grid spacing h (time unit).
        - `cumulative`: F at the nodes ``(N + 1,)``.
        - `exit_age`: E at the nodes (1/time unit), or None (then E and the ramp are NaN).
        - `mean`, `variance`: the RTD's exact moments (time, time²).
        - `time_unit`: unit of time.
        - `ramp`: integrate the ramp response (cubic Hermite rule; needs `exit_age`).

        **Returns:**

        A :class:`TabulatedRTD`.
        """
        step = jnp.asarray(step, float)
        nan = jnp.full(cumulative.shape, jnp.nan)
        density = nan if exit_age is None else exit_age
        if ramp and exit_age is not None:
            pieces = (step / 2 * (cumulative[:-1] + cumulative[1:])
                      + step**2 / 12 * (density[:-1] - density[1:]))
            integral = jnp.concatenate([jnp.zeros(1), jnp.cumsum(pieces)])
        else:
            integral = nan
        return cls(step, density, cumulative, integral, jnp.asarray(mean, float),
                   jnp.asarray(variance, float), time_unit)

    @property
    def horizon(self) -> Array:
        """Last tabulated time (time unit)."""
        return self.step * (self.exit_age_values.shape[-1] - 1)

    def exit_age(self, t: ArrayLike) -> Array:
        """E(t), interpolated; zero before 0 and after the horizon (1/time unit)."""
        return _table_exit_age(self, jnp.asarray(t, float))

    def cumulative(self, t: ArrayLike) -> Array:
        """F(t), interpolated; zero up to 0, held after the horizon (dimensionless)."""
        return _table_cumulative(self, jnp.asarray(t, float))

    def ramp_response(self, t: ArrayLike) -> Array:
        """``∫_0^t F``, interpolated; continued linearly after the horizon (time unit)."""
        return _table_ramp(self, jnp.asarray(t, float))

    def _exit_age(self, t: Array) -> Array:
        # The horizon is step × N, which may round just below the latest time asked for.
        inside = (t >= 0) & (t <= self.horizon + 1e-9 * self.step)
        return jnp.where(inside, _grid.interpolate(self.step, self.exit_age_values, t), 0.0)

    def _cumulative(self, t: Array) -> Array:
        return jnp.where(t > 0, _grid.interpolate(self.step, self.cumulative_values, t), 0.0)

    def _ramp_response(self, t: Array) -> Array:
        inside = _grid.interpolate(self.step, self.ramp_values, t)
        beyond = self.ramp_values[-1] + (t - self.horizon) * self.cumulative_values[-1]
        return jnp.where(
            t <= 0, 0.0, jnp.where(t > self.horizon + 1e-9 * self.step, beyond, inside)
        )

    def mean(self) -> Array:
        """Mean residence time (time unit)."""
        return self.mean_value

    def variance(self) -> Array:
        """Residence-time variance (time unit squared)."""
        return self.variance_value


@eqx.filter_jit
def _table_exit_age(table: TabulatedRTD, t: Array) -> Array:
    return table._exit_age(t)


@eqx.filter_jit
def _table_cumulative(table: TabulatedRTD, t: Array) -> Array:
    return table._cumulative(t)


@eqx.filter_jit
def _table_ramp(table: TabulatedRTD, t: Array) -> Array:
    return table._ramp_response(t)


class Line(eqx.Module):
    """Unit operations in series (immutable, a JAX pytree).

    Transfer functions multiply and means and variances add, exactly. E, F and the ramp
    response of a line of several units are computed on a uniform grid from 0 to the latest
    time asked for: the units' curves are convolved exactly as piecewise-linear curves
    (a measured curve is one, so it is convolved exactly), on three grids h, h/2, h/4
    combined by Richardson extrapolation (sixth order; about 1e-12 of the peak for smooth
    units at the default grid), and interpolated between nodes.

    **Arguments:**

    - `*units`: :class:`Unit` or :class:`Line` objects, in flow order (lines are
      flattened). All share one time unit; tanks in series need ``n_tanks >= 1`` (E must
      be finite at t = 0). Measured curves must be sampled uniformly, with one common step,
      from a time that is a multiple of it.
    - `settings`: :class:`LineSettings`.
    - `name`: label used in plots.
    """

    units: tuple[Unit, ...]
    settings: LineSettings
    name: str = eqx.field(static=True)

    def __init__(self, *units: Unit | Line, settings: LineSettings | None = None,
                 name: str = "line"):
        flat: list[Unit] = []
        for item in units:
            if isinstance(item, Line):
                flat.extend(item.units)
            elif isinstance(item, Unit):
                flat.append(item)
            else:
                raise ValueError(f"a line is made of units, got {type(item).__name__}.")
        self.units = tuple(flat)
        self.settings = LineSettings() if settings is None else settings
        self.name = name

    def __check_init__(self) -> None:
        if not self.units:
            raise ValueError("a line needs at least one unit.")
        time_units = {unit.time_unit for unit in self.units}
        if len(time_units) > 1:
            raise ValueError(
                f"the units of a line must share one time unit, got {sorted(time_units)}."
            )
        for unit in self.units:
            if unit.model == TANKS:
                n = concrete_value(unit.parameters["n_tanks"])
                if n is not None and (n < 1).any():
                    raise ValueError(
                        "tanks in a line need n_tanks >= 1 (E is infinite at t = 0), "
                        f"got {n.min():g}."
                    )
        self._sample_step()

    @property
    def time_unit(self) -> str:
        """The unit of time of the line."""
        return self.units[0].time_unit

    # ------------------------------------------------------------------ exact composition
    def mean(self) -> Array:
        """Mean residence time of the line: the sum of the units' means (time unit)."""
        return sum(unit.mean() for unit in self.units)

    def variance(self) -> Array:
        """Variance of the line: the sum of the units' variances (time unit squared)."""
        return sum(unit.variance() for unit in self.units)

    def transfer_function(self, s: ArrayLike) -> Array:
        """Transfer function of the line: the product of its units' transfer functions.

        **Arguments:**

        - `s`: Laplace variable (1/time unit), real or complex, any shape.

        **Returns:**

        Complex G, the shape of `s`.
        """
        result = self.units[0].transfer_function(s)
        for unit in self.units[1:]:
            result = result * unit.transfer_function(s)
        return result

    def frequency_response(self, omega: ArrayLike) -> Array:
        """Amplitude ratio ``|G(i omega)|`` of the line.

        **Arguments:**

        - `omega`: angular frequencies (rad per time unit), any shape.

        **Returns:**

        ``|G(i omega)|`` (dimensionless), the shape of `omega`.
        """
        require_finite("omega", omega)
        return jnp.abs(self.transfer_function(1j * jnp.asarray(omega, float)))

    # ------------------------------------------------------------------ curves
    def exit_age(self, t: ArrayLike) -> Array:
        """Exit-age density E(t) of the line, computed on a grid over ``[0, max t]``.

        **Arguments:**

        - `t`: times (time unit), any shape; concrete if the line holds a measured curve.

        **Returns:**

        E (1/time unit), the shape of `t`.
        """
        return self._curve("exit_age", t)

    def cumulative(self, t: ArrayLike) -> Array:
        """Cumulative distribution F(t) of the line, computed on a grid over ``[0, max t]``.

        **Arguments:**

        - `t`: times (time unit), any shape; concrete if the line holds a measured curve.

        **Returns:**

        F (dimensionless), the shape of `t`.
        """
        return self._curve("cumulative", t)

    def ramp_response(self, t: ArrayLike) -> Array:
        """Response ``∫_0^t F`` of the line to an inlet ramp of unit slope from t = 0.

        **Arguments:**

        - `t`: times (time unit), any shape; concrete if the line holds a measured curve.

        **Returns:**

        R (time unit), the shape of `t`.
        """
        return self._curve("ramp", t)

    def _curve(self, kind: str, t: ArrayLike) -> Array:
        require_finite("t", t)
        t = jnp.asarray(t, float)
        if len(self.units) == 1:
            unit = self.units[0]
            return {"exit_age": unit.exit_age, "cumulative": unit.cumulative,
                    "ramp": unit.ramp_response}[kind](t)
        table = self.tabulate(jnp.max(t))
        return {"exit_age": table.exit_age, "cumulative": table.cumulative,
                "ramp": table.ramp_response}[kind](t)

    def tabulate(self, horizon: ArrayLike) -> TabulatedRTD:
        """Compute E, F and the ramp response of the line on a grid over ``[0, horizon]``.

        **Arguments:**

        - `horizon`: last time needed (time unit, positive). It may be traced unless the
          line holds a measured curve (its grid follows the curve's samples).

        **Returns:**

        A :class:`TabulatedRTD` (evaluate it at many times without recomputing the line).
        """
        require_finite("horizon", horizon)
        concrete = concrete_value(horizon)
        if concrete is not None:  # stays concrete inside a trace (a measured curve needs it)
            horizon = np.maximum(np.asarray(concrete, float), np.finfo(float).tiny)
        else:
            horizon = jnp.maximum(jnp.asarray(horizon, float), jnp.finfo(float).tiny)
        step, intervals = self._grid(horizon)
        exit_age, cumulative, ramp = _tabulate(self.units, step, intervals)
        return TabulatedRTD(
            jnp.asarray(step, float),
            exit_age,
            cumulative,
            ramp,
            self.mean(),
            self.variance(),
            self.time_unit,
        )

    # ------------------------------------------------------------------ grid
    def _sample_step(self) -> float | None:
        """The common sample step of the measured curves in the line, or None."""
        steps = []
        for unit in self.units:
            if unit.model != EMPIRICAL:
                continue
            knots = np.asarray(unit.structure)
            differences = np.diff(knots)
            step = differences.mean()
            if np.max(np.abs(differences - step)) > _UNIFORM_RTOL * step:
                raise ValueError(
                    f"the measured curve {unit.name!r} is not uniformly sampled; resample it "
                    "(numpy.interp) to use it in a line."
                )
            offset = knots[0] / step
            if abs(offset - round(offset)) > 1e-6:
                raise ValueError(
                    f"the measured curve {unit.name!r} starts at {knots[0]:g}, not a multiple "
                    f"of its step {step:g}; resample it to use it in a line."
                )
            steps.append(step)
        if not steps:
            return None
        if max(steps) - min(steps) > _UNIFORM_RTOL * max(steps):
            raise ValueError(
                f"the measured curves of a line must share one sample step, got {sorted(steps)}."
            )
        return float(steps[0])

    def _grid(self, horizon: Array) -> tuple[float | Array, int]:
        spreads = [unit._spread() for unit in self.units if unit.model != EMPIRICAL]
        smallest = jnp.min(jnp.stack(spreads)) if spreads else None
        sample_step = self._sample_step()
        if sample_step is None:
            intervals = choose_intervals(horizon, smallest, self.settings.intervals)
            return horizon / intervals, intervals
        if not is_concrete(horizon):
            raise ValueError(
                "a line with a measured curve needs concrete times (its grid follows the "
                "curve's samples)."
            )
        subdivisions = self.settings.subdivisions
        if smallest is not None and is_concrete(smallest):
            while sample_step / subdivisions > float(smallest) / 16 and subdivisions < 1024:
                subdivisions *= 2
        step = sample_step / subdivisions
        needed = max(16, math.ceil(float(horizon) / step - 1e-9))
        # A power of two: the FFTs pad to one anyway, and nearby horizons share one compiled
        # tabulation.
        return step, 1 << (needed - 1).bit_length()


@eqx.filter_jit
def _tabulate(units: tuple[Unit, ...], step, intervals: int) -> tuple[Array, Array, Array]:
    # The nodes of the grids h and h/2 are every fourth and every second node of the grid
    # h/4, so every curve is evaluated once, on the finest grid.
    finest = 2 ** (_grid.LEVELS - 1)
    fine_step = step / finest
    fine_pieces = [unit._interval_values(fine_step, intervals * finest) for unit in units]
    fine_cumulative = units[0]._curve(
        "cumulative", _grid.grid_nodes(fine_step, intervals * finest)
    )
    levels: dict[str, list[Array]] = {"exit_age": [], "cumulative": [], "ramp": []}
    for level in range(_grid.LEVELS):
        stride = finest // 2**level
        h = fine_step * stride
        pieces = [(start[::stride], end[stride - 1 :: stride]) for start, end in fine_pieces]
        first_cumulative = fine_cumulative[::stride]
        # E and F pass through the same chain of convolutions, stacked.
        first = (
            jnp.stack([pieces[0][0], first_cumulative[:-1]]),
            jnp.stack([pieces[0][1], first_cumulative[1:]]),
        )
        exit_age, cumulative = _chain(h, first, pieces[1:])
        levels["exit_age"].append(exit_age)
        levels["cumulative"].append(cumulative)
        levels["ramp"].append(_grid.cumulative_trapezoid(h, cumulative))
    return tuple(_grid.richardson(levels[key]) for key in ("exit_age", "cumulative", "ramp"))


def _chain(step, first, rest) -> Array:
    """Node values of ``first ⊗ rest[0] ⊗ rest[1] ⊗ …`` (all given as interval values)."""
    start, end = first
    values = jnp.concatenate([start, end[..., -1:]], axis=-1)
    for piece in rest:
        values = _grid.interval_convolution(step, (start, end), piece)
        start, end = values[..., :-1], values[..., 1:]
    return values


def as_evaluator(rtd: Unit | Line | TabulatedRTD, horizon: ArrayLike):
    """The object whose E, F and ramp response cover ``[0, horizon]``: a unit or a table."""
    if isinstance(rtd, Line):
        if len(rtd.units) == 1:
            return rtd.units[0]
        return rtd.tabulate(horizon)
    if isinstance(rtd, Unit | TabulatedRTD):
        return rtd
    raise ValueError(f"expected a Unit or a Line, got {type(rtd).__name__}.")
