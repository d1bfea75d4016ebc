"""One unit operation's residence time distribution: :class:`Unit`."""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import (
    concrete_value,
    require_finite,
    require_increasing_times,
    require_positive,
)
from axialmix.line import _grid
from axialmix.line._models import (
    CLOSED_CLOSED,
    CLOSED_CLOSED_EXCHANGE,
    CLOSED_CLOSED_TANK,
    EMPIRICAL,
    NETWORK,
    OPEN_OPEN,
    TANKS,
    TANKS_EXCHANGE,
    UnitModel,
    moments_from_transfer_function,
)
from axialmix.network import CompartmentNetwork
from axialmix.rtd import trapezoid

__all__ = ["Unit", "choose_intervals", "is_concrete"]

DEFAULT_INTERVALS = 2048
"""Grid intervals of a tabulation (Romberg ramp, lines) when the spread is not concrete."""
_POINTS_PER_SPREAD = 16
_MAX_INTERVALS = 1 << 17


def is_concrete(*values: object) -> bool:
    """True when no leaf of the values is a JAX tracer."""
    leaves = jax.tree_util.tree_leaves(values)
    return all(concrete_value(leaf) is not None for leaf in leaves)


def choose_intervals(horizon: ArrayLike, spread: ArrayLike, base: int) -> int:
    """Grid intervals over ``[0, horizon]``: `base`, or more so that h <= spread / 16.

    Only concrete values can raise the count (a power of two, at most 2**17); under a trace
    `base` is used.
    """
    if not is_concrete(horizon, spread):
        return base
    horizon = float(np.max(np.asarray(horizon)))
    spread = float(np.min(np.asarray(spread)))
    if not (horizon > 0 and spread > 0 and math.isfinite(horizon) and math.isfinite(spread)):
        return base
    needed = _POINTS_PER_SPREAD * horizon / spread
    intervals = base
    while intervals < needed and intervals < _MAX_INTERVALS:
        intervals *= 2
    return intervals


def _time_array(name: str, t: ArrayLike) -> Array:
    require_finite(name, t)
    return jnp.asarray(t, float)


class Unit(eqx.Module):
    """The residence time distribution of one unit operation (immutable, a JAX pytree).

    Build one with :meth:`closed_closed`, :meth:`open_open`, :meth:`tanks`,
    :meth:`closed_closed_exchange`, :meth:`tanks_exchange`, :meth:`closed_closed_tank`,
    :meth:`network`, :meth:`empirical` or, for any other model, :meth:`from_model`. The
    parameters are array leaves, so units can be made inside ``jax.vmap`` (for example from
    samples of a fit's parameter distribution, :func:`axialmix.line.sample_units`) and
    differentiated.

    **Arguments:**

    - `model`: the :class:`UnitModel` that evaluates it (static).
    - `parameters`: dict of parameter arrays (names in ``model.parameter_names``).
    - `structure`: static structure of the model (a network, the sample times of a measured
      curve), or None.
    - `name`: label used in plots and reports.
    - `time_unit`: the unit of time of every time argument and parameter (default ``"s"``).
    """

    model: UnitModel = eqx.field(static=True)
    parameters: dict[str, Array]
    structure: Hashable = eqx.field(static=True, default=None)
    name: str = eqx.field(static=True, default="")
    time_unit: str = eqx.field(static=True, default="s")

    def __check_init__(self) -> None:
        if not isinstance(self.model, UnitModel):
            raise ValueError(f"model must be a UnitModel, got {type(self.model).__name__}.")
        names = set(self.parameters)
        expected = set(self.model.parameter_names)
        if names != expected:
            raise ValueError(
                f"a {self.model.name} unit needs parameters {sorted(expected)}, "
                f"got {sorted(names)}."
            )
        for name in self.model.parameter_names:
            require_finite(name, self.parameters[name])
        for name in self.model.positive:
            require_positive(name, self.parameters[name])

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_model(
        cls,
        model: UnitModel,
        parameters: Mapping[str, ArrayLike],
        *,
        structure: Hashable = None,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """Make a unit from any :class:`UnitModel` (the hook for models added later).

        **Arguments:**

        - `model`: the model's functions.
        - `parameters`: its parameters (arrays or numbers).
        - `structure`, `name`, `time_unit`: see :class:`Unit`.

        **Returns:**

        A :class:`Unit`.
        """
        params = {key: jnp.asarray(value, float) for key, value in parameters.items()}
        return cls(model, params, structure, name or model.name, time_unit)

    @classmethod
    def closed_closed(
        cls, tau: ArrayLike, peclet: ArrayLike, *, name: str = "", time_unit: str = "s"
    ) -> Unit:
        """A closed–closed (Danckwerts) axial dispersion unit (MODELS.md §2).

        **Arguments:**

        - `tau`: space time ``L / v`` (time unit, positive); the mean residence time.
        - `peclet`: Peclet number ``v L / D_z`` (positive).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` with exact E, F and G.
        """
        return cls.from_model(
            CLOSED_CLOSED, {"tau": tau, "peclet": peclet}, name=name, time_unit=time_unit
        )

    @classmethod
    def open_open(
        cls, tau: ArrayLike, peclet: ArrayLike, *, name: str = "", time_unit: str = "s"
    ) -> Unit:
        """An open–open axial dispersion unit; its mean is ``(1 + 2/Pe) tau`` (MODELS.md §2).

        **Arguments:**

        - `tau`: ``L / v`` (time unit, positive).
        - `peclet`: Peclet number (positive).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit`.
        """
        return cls.from_model(
            OPEN_OPEN, {"tau": tau, "peclet": peclet}, name=name, time_unit=time_unit
        )

    @classmethod
    def tanks(
        cls, tau: ArrayLike, n_tanks: ArrayLike, *, name: str = "", time_unit: str = "s"
    ) -> Unit:
        """Equal stirred tanks in series (gamma RTD; ``n_tanks`` may be any positive real).

        **Arguments:**

        - `tau`: total mean residence time (time unit, positive).
        - `n_tanks`: number of tanks (positive; 1 is one stirred tank).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit`.
        """
        return cls.from_model(
            TANKS, {"tau": tau, "n_tanks": n_tanks}, name=name, time_unit=time_unit
        )

    @classmethod
    def closed_closed_exchange(
        cls,
        tau: ArrayLike,
        peclet: ArrayLike,
        beta: ArrayLike,
        k_d: ArrayLike,
        *,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """A closed–closed ADM whose flowing material exchanges with a dead zone (MODELS.md §6).

        **Arguments:**

        - `tau`: space time of the flowing material (time unit, positive); the mean residence
          time is ``(1 + beta) tau``.
        - `peclet`: Peclet number (positive).
        - `beta`: dead-zone to flowing hold-up (dimensionless, >= 0).
        - `k_d`: exchange rate (1/time unit, positive).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` with exact E, F, ramp response and G.
        """
        return cls.from_model(
            CLOSED_CLOSED_EXCHANGE, {"tau": tau, "peclet": peclet, "beta": beta, "k_d": k_d},
            name=name, time_unit=time_unit,
        )

    @classmethod
    def tanks_exchange(
        cls,
        tau: ArrayLike,
        n_tanks: ArrayLike,
        beta: ArrayLike,
        k_d: ArrayLike,
        *,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """Tanks in series whose flowing material exchanges with a dead zone (MODELS.md §6).

        **Arguments:**

        - `tau`: mean residence time of the flowing material (time unit, positive).
        - `n_tanks`: number of tanks (positive real).
        - `beta`: dead-zone to flowing hold-up (dimensionless, >= 0).
        - `k_d`: exchange rate (1/time unit, positive).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` with exact E, F, ramp response and G.
        """
        return cls.from_model(
            TANKS_EXCHANGE, {"tau": tau, "n_tanks": n_tanks, "beta": beta, "k_d": k_d},
            name=name, time_unit=time_unit,
        )

    @classmethod
    def closed_closed_tank(
        cls,
        tau: ArrayLike,
        peclet: ArrayLike,
        tau_tank: ArrayLike,
        *,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """A closed–closed ADM followed by a stirred tank, as one unit (exact product of G).

        **Arguments:**

        - `tau`: space time of the dispersed section (time unit, positive).
        - `peclet`: its Peclet number (positive).
        - `tau_tank`: mean residence time of the tank (time unit, positive).
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` whose mean is ``tau + tau_tank``.
        """
        return cls.from_model(
            CLOSED_CLOSED_TANK, {"tau": tau, "peclet": peclet, "tau_tank": tau_tank},
            name=name, time_unit=time_unit,
        )

    @classmethod
    def network(
        cls,
        network: CompartmentNetwork,
        rates: ArrayLike | None = None,
        outflow_rates: ArrayLike | None = None,
        *,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """A continuous compartment network (MODELS.md §3) with exact E, F and G.

        **Arguments:**

        - `network`: an open, continuous :class:`~axialmix.network.CompartmentNetwork`.
        - `rates`, `outflow_rates`: rate arrays (1/time) in the network's order; default
          the network's own.
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` whose parameters are the two rate arrays.
        """
        if not isinstance(network, CompartmentNetwork):
            raise ValueError(f"network must be a CompartmentNetwork, got {type(network).__name__}.")
        if network.is_discrete:
            raise ValueError("a unit needs a continuous network; use network.continuous().")
        if not network.inlets or not network.outlets:
            raise ValueError("a unit needs an open network with an inlet and an outlet.")
        rates = network.rates if rates is None else rates
        outflow_rates = network.outflow_rates if outflow_rates is None else outflow_rates
        for label, value, size in (
            ("rates", rates, len(network.connections)),
            ("outflow_rates", outflow_rates, len(network.outlets)),
        ):
            if jnp.shape(value) != (size,):
                raise ValueError(f"{label} must have shape ({size},), got {jnp.shape(value)}.")
            array = concrete_value(value)
            if array is not None and (array < 0).any():
                raise ValueError(f"{label} must be non-negative, got {array.min():g}.")
        return cls.from_model(
            NETWORK,
            {"rates": rates, "outflow_rates": outflow_rates},
            structure=network,
            name=name or (network.description or "network"),
            time_unit=time_unit,
        )

    @classmethod
    def empirical(
        cls,
        time: ArrayLike,
        exit_age: ArrayLike,
        *,
        normalise: bool = True,
        name: str = "",
        time_unit: str = "s",
    ) -> Unit:
        """A measured exit-age curve used as it is: linear between samples, zero outside.

        E, F, the ramp response, the moments and the transfer function are those of the
        piecewise-linear interpolant, integrated exactly. In a :class:`Line`, measured
        curves must be sampled uniformly from a time that is a multiple of the step.

        **Arguments:**

        - `time`: sample times (time unit), strictly increasing, non-negative, at least 2.
        - `exit_age`: E (or any tracer signal) at `time`; small negative noise is allowed.
        - `normalise`: divide by the area (exact trapezoid), so that F ends at 1.
        - `name`, `time_unit`: label and unit of time.

        **Returns:**

        A :class:`Unit` whose structure is the tuple of sample times.
        """
        require_increasing_times("time", time)
        require_finite("exit_age", exit_age)
        times = np.asarray(concrete_value(time), dtype=float) if is_concrete(time) else None
        if times is None:
            raise ValueError("the sample times of a measured curve must be concrete (not traced).")
        values = jnp.asarray(exit_age, float)
        if times.ndim != 1 or times.size < 2:
            raise ValueError(f"time needs at least two samples, got shape {times.shape}.")
        if values.shape != times.shape:
            raise ValueError(
                f"exit_age must have the shape of time {times.shape}, got {values.shape}."
            )
        if times[0] < 0:
            raise ValueError(f"time must be non-negative (residence times), got {times[0]:g}.")
        if normalise:
            area = trapezoid(values, times)
            concrete_area = concrete_value(area)
            if concrete_area is not None and not concrete_area > 0:
                raise ValueError(f"the measured curve has no positive area ({concrete_area:g}).")
            values = values / area
        return cls.from_model(
            EMPIRICAL,
            {"exit_age": values},
            structure=tuple(float(x) for x in times),
            name=name or "measured",
            time_unit=time_unit,
        )

    # ------------------------------------------------------------------ curves
    def exit_age(self, t: ArrayLike) -> Array:
        """Exit-age density E(t) of the unit, exact.

        **Arguments:**

        - `t`: times (time unit), any shape and order.

        **Returns:**

        E (1/time unit), the shape of `t`; 0 before t = 0.
        """
        return _exit_age(self, _time_array("t", t))

    def cumulative(self, t: ArrayLike) -> Array:
        """Cumulative residence time distribution F(t) of the unit, exact.

        **Arguments:**

        - `t`: times (time unit), any shape and order.

        **Returns:**

        F (dimensionless), the shape of `t`; 0 up to t = 0.
        """
        return _cumulative(self, _time_array("t", t))

    def ramp_response(self, t: ArrayLike) -> Array:
        """Outlet response ``R(t) = ∫_0^t F`` to an inlet ramp of unit slope starting at t = 0.

        Exact where the model gives it (tanks, networks, measured curves); otherwise F is
        integrated on a grid over ``[0, max t]`` by Romberg's method (sixth order, typically
        1e-12 of ``max t``).

        **Arguments:**

        - `t`: times (time unit), any shape and order.

        **Returns:**

        R (time unit), the shape of `t`; 0 up to t = 0, ``t - mean`` once the RTD has ended.
        """
        t = _time_array("t", t)
        intervals = choose_intervals(jnp.max(t), self._spread(), DEFAULT_INTERVALS)
        return _ramp(self, t, intervals)

    def transfer_function(self, s: ArrayLike) -> Array:
        """Transfer function ``G(s) = ∫ E(t) e^{-st} dt`` of the unit.

        **Arguments:**

        - `s`: Laplace variable (1/time unit), real or complex, any shape.

        **Returns:**

        Complex G, the shape of `s`; ``G(0) = 1``.
        """
        if self.model.transfer_function is None:
            raise ValueError(f"the {self.model.name} model has no transfer function.")
        require_finite("s", s)
        return _transfer(self, jnp.asarray(s, complex))

    def frequency_response(self, omega: ArrayLike) -> Array:
        """Amplitude ratio ``|G(i omega)|``: the share of a feed oscillation that passes.

        **Arguments:**

        - `omega`: angular frequencies (rad per time unit), any shape.

        **Returns:**

        ``|G(i omega)|`` (dimensionless, 1 at omega = 0), the shape of `omega`.
        """
        require_finite("omega", omega)
        return jnp.abs(self.transfer_function(1j * jnp.asarray(omega, float)))

    def mean(self) -> Array:
        """Mean residence time (time unit), exact."""
        return self._moments()[0]

    def variance(self) -> Array:
        """Residence-time variance (time unit squared), exact."""
        return self._moments()[1]

    def _moments(self) -> tuple[Array, Array]:
        if self.model.moments is not None:
            return self.model.moments(self.parameters, self.structure)
        if self.model.transfer_function is None:
            raise ValueError(
                f"the {self.model.name} model gives neither moments nor a transfer function."
            )
        return moments_from_transfer_function(
            self.model.transfer_function, self.parameters, self.structure
        )

    def _spread(self) -> Array:
        """Residence-time standard deviation, used to size grids (time unit)."""
        return jnp.sqrt(self.variance())

    # ------------------------------------------------------------------ internal
    def _curve(self, kind: str, t: Array) -> Array:
        """E, F or R at traced times of any shape (no validation)."""
        if kind == "exit_age":
            return self.model.exit_age(t, self.parameters, self.structure)
        if kind == "cumulative":
            return self.model.cumulative(t, self.parameters, self.structure)
        if self.model.ramp is not None:
            return self.model.ramp(t, self.parameters, self.structure)
        return _romberg_ramp(self, t, DEFAULT_INTERVALS)

    def _interval_values(self, step: Array, intervals: int) -> tuple[Array, Array]:
        """E at the start and end of each grid interval (one-sided at a measured curve's ends)."""
        if self.model == EMPIRICAL:
            return _empirical_interval_values(self, step, intervals)
        values = self.model.exit_age(
            _grid.grid_nodes(step, intervals), self.parameters, self.structure
        )
        return values[:-1], values[1:]


def _empirical_interval_values(unit: Unit, step: Array, intervals: int) -> tuple[Array, Array]:
    """Exact interval values of a measured curve whose samples lie on grid nodes."""
    knots = np.asarray(unit.structure)
    h = float(step)
    positions = (knots - knots[0]) / h
    ratio = int(round(positions[1]))
    first = int(round(knots[0] / h))
    nodes = np.arange(intervals + 1)
    relative = (nodes - first) / ratio
    index = np.clip(np.floor(relative).astype(int), 0, knots.size - 2)
    fraction = relative - index
    inside = (relative >= 0) & (relative <= knots.size - 1)
    values = unit.parameters["exit_age"]
    node_values = jnp.where(
        inside, values[index] * (1 - fraction) + values[index + 1] * fraction, 0.0
    )
    start, end = node_values[:-1], node_values[1:]
    last = first + ratio * (knots.size - 1)
    if last < intervals:
        start = start.at[last].set(0.0)
    if first >= 1:
        end = end.at[first - 1].set(0.0)
    return start, end


def _romberg_ramp(unit: Unit, t: Array, intervals: int) -> Array:
    """``∫_0^t F`` by the cumulative trapezoid rule on grids h, h/2, h/4 and extrapolation."""
    horizon = jnp.maximum(jnp.max(t), jnp.finfo(float).tiny)
    step = horizon / intervals
    levels = []
    for level in range(_grid.LEVELS):
        fine = step / 2**level
        nodes = _grid.grid_nodes(fine, intervals * 2**level)
        levels.append(_grid.cumulative_trapezoid(fine, unit._curve("cumulative", nodes)))
    values = _grid.richardson(levels)
    return jnp.where(t > 0, _grid.interpolate(step, values, t), 0.0)


@eqx.filter_jit
def _exit_age(unit: Unit, t: Array) -> Array:
    return unit._curve("exit_age", t)


@eqx.filter_jit
def _cumulative(unit: Unit, t: Array) -> Array:
    return unit._curve("cumulative", t)


@eqx.filter_jit
def _ramp(unit: Unit, t: Array, intervals: int) -> Array:
    if unit.model.ramp is not None:
        return unit.model.ramp(t, unit.parameters, unit.structure)
    return _romberg_ramp(unit, t, intervals)


@eqx.filter_jit
def _transfer(unit: Unit, s: Array) -> Array:
    return unit.model.transfer_function(s, unit.parameters, unit.structure)
