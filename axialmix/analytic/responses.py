"""Exit age, step, ramp and sampled-inlet responses of any transfer function (MODELS.md §2, §6).

Each response is one exact numerical Laplace inversion (:mod:`axialmix.analytic._laplace`):
E of ``G``, F of ``G / s``, the ramp response of ``G / s²``. A sampled inlet signal, taken
as piecewise linear, is a sum of steps and ramps, so its outlet signal is the matching sum of
exact step and ramp responses (:func:`inlet_response`).
"""

from __future__ import annotations

import warnings
from functools import partial

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from axialmix._validation import concrete_value, require_finite, require_increasing_times
from axialmix.analytic._laplace import DEFAULT_NODES, invert_single, invert_with_dead_zone
from axialmix.analytic.transfer import (
    ClosedClosedADM,
    ExchangeZone,
    OpenOpenADM,
    Series,
    StirredTank,
    TanksInSeries,
    TransferFunction,
)

__all__ = [
    "AccuracyWarning",
    "exit_age",
    "inlet_response",
    "ramp_response",
    "step_response",
    "unverified_parameters",
]


class AccuracyWarning(UserWarning):
    """A unit was evaluated outside the parameter range in which its accuracy was verified."""


# Ranges over which the inversion was checked against independent references (tests of
# axialmix.analytic and the studies in tests/test_analytic_exchange.py): the Peclet number of
# an ADM, the number of tanks, and for a dead zone its capacity ratio, its exchange number
# k_d times the mobile mean, and the Peclet number or tank count of the mobile unit.
_PECLET_RANGE = (1e-2, 1e4)
_TANKS_RANGE = (0.5, 2000.0)
_DEAD_ZONE_PECLET_RANGE = (0.1, 1000.0)
_DEAD_ZONE_TANKS_RANGE = (1.0, 100.0)
_CAPACITY_RANGE = (0.0, 5.0)
_EXCHANGE_NUMBER_RANGE = (0.01, 100.0)
# Step, ramp and inlet responses of a dead zone (G/s and G/s² inverted with the removed pole at
# 0): checked only up to this exchange number when the mobile unit's Peclet number (or tank
# count) is above the next value; beyond it some cases lose digits (Pe 80, beta 1e-6 and
# k_d tau 15: 5e-5; Pe 300 with k_d tau 30: every digit), where E itself is right.
_CUMULATIVE_EXCHANGE_NUMBER = 10.0
_CUMULATIVE_FAST_EXCHANGE_PECLET = 70.0
# A stirred tank in series with other units: its time over their mean.
_TANK_RATIO_RANGE = (1e-3, 10.0)


def _outside(name: str, value, bounds, owner: str) -> list[str]:
    array = concrete_value(value)
    if array is None or array.size == 0:
        return []
    low, high = bounds
    bad = (array < low) | (array > high)
    if not bad.any():
        return []
    worst = array[bad].flat[0]
    return [f"{owner} {name} {worst:g} is outside the verified range [{low:g}, {high:g}]"]


def _range_problems(
    unit: TransferFunction, in_zone: bool = False, cumulative: bool = False
) -> list[str]:
    name = type(unit).__name__
    if isinstance(unit, ClosedClosedADM | OpenOpenADM):
        bounds = _DEAD_ZONE_PECLET_RANGE if in_zone else _PECLET_RANGE
        return _outside("peclet", unit.peclet, bounds, name)
    if isinstance(unit, TanksInSeries):
        bounds = _DEAD_ZONE_TANKS_RANGE if in_zone else _TANKS_RANGE
        return _outside("n_tanks", unit.n_tanks, bounds, name)
    if isinstance(unit, ExchangeZone):
        problems = _range_problems(unit.unit, in_zone=True)
        problems += _outside("capacity_ratio", unit.capacity_ratio, _CAPACITY_RANGE, name)
        mean = concrete_value(unit.unit.mean())
        rate = concrete_value(unit.exchange_rate)
        if mean is not None and rate is not None:
            bounds = _EXCHANGE_NUMBER_RANGE
            mobile = unit.unit
            peclet = concrete_value(getattr(mobile, "peclet", getattr(mobile, "n_tanks", 0.0)))
            if cumulative and peclet is not None and bool(
                (peclet > _CUMULATIVE_FAST_EXCHANGE_PECLET).any()
            ):
                bounds = (_EXCHANGE_NUMBER_RANGE[0], _CUMULATIVE_EXCHANGE_NUMBER)
                name = f"{name} (step, ramp or inlet response, Pe or N above "\
                       f"{_CUMULATIVE_FAST_EXCHANGE_PECLET:g})"
            problems += _outside("exchange number k_d * mean", rate * mean, bounds, name)
        return problems
    if isinstance(unit, Series):
        problems = [p for part in unit.units for p in _range_problems(part, in_zone, cumulative)]
        for index, part in enumerate(unit.units):
            others = [u for i, u in enumerate(unit.units) if i != index]
            if isinstance(part, StirredTank) and others:
                rest = concrete_value(sum(u.mean() for u in others))
                tank = concrete_value(part.tau)
                if rest is not None and tank is not None:
                    problems += _outside(
                        "tau over the mean of the other units", tank / rest, _TANK_RATIO_RANGE, name
                    )
        return problems
    return []


def unverified_parameters(unit: TransferFunction, *, cumulative: bool = False) -> list[str]:
    """The parameters of `unit` outside the range where its inversion has been verified.

    The same check that makes :func:`exit_age` and the other responses warn with
    :class:`AccuracyWarning`, for callers that evaluate the unit inside compiled code (where
    no warning can look at the values), such as a fit reporting on its fitted parameters.

    **Arguments:**

    - `unit`: a :class:`~axialmix.analytic.TransferFunction` with concrete parameters.
    - `cumulative`: check the range of the step, ramp and inlet responses (narrower for a
      dead zone with fast exchange) instead of that of ``E``.

    **Returns:** one phrase per parameter outside its range (empty when all are inside).
    """
    _require_unit(unit)
    return _range_problems(unit, cumulative=cumulative)


def _warn_if_unverified(unit: TransferFunction, cumulative: bool = False) -> None:
    problems = unverified_parameters(unit, cumulative=cumulative)
    if problems:
        warnings.warn(
            "; ".join(problems) + ": the result may be inaccurate", AccuracyWarning, stacklevel=3
        )


def _require_unit(unit: object) -> None:
    if not isinstance(unit, TransferFunction):
        raise ValueError(
            f"unit must be a TransferFunction (e.g. ClosedClosedADM), got {type(unit).__name__}"
        )


def _require_nodes(nodes: int) -> None:
    if not isinstance(nodes, int) or nodes < 8:
        raise ValueError(f"nodes must be an integer of at least 8, got {nodes!r}")


def _inverse(unit: TransferFunction, t: jax.Array, power: int, nodes: int) -> jax.Array:
    """Return the inverse transform of ``G(s) / s**power`` at times ``t`` (any shape)."""
    fixed = jax.lax.stop_gradient(unit)
    positive = t > 0
    theta = jnp.where(positive, t, 1.0)
    zones = fixed.exchange_zones()
    if not zones:
        value = invert_single(
            unit.log_transfer,
            fixed.log_transfer,
            fixed.rightmost_singularity(),
            unit.mean(),
            theta,
            power,
            nodes,
        )
    else:
        (zone,) = zones
        rate = jnp.asarray(zone.exchange_rate, float)
        value = invert_with_dead_zone(
            unit.log_transfer,
            fixed.surrogate_log_transfer,
            zone.near_log_transfer(),
            fixed.rightmost_singularity(),
            fixed.far_singularity(),
            zone.near_singularity(),
            -rate,
            jnp.sqrt(jnp.asarray(zone.capacity_ratio, float)) * rate,
            unit.mean(),
            theta,
            power,
            nodes,
        )
    return jnp.where(positive, value, 0.0)


@partial(jax.jit, static_argnames=("power", "nodes"))
def _response(unit: TransferFunction, t: jax.Array, power: int, nodes: int) -> jax.Array:
    return _inverse(unit, t, power, nodes)


def _checked_times(unit: object, t: ArrayLike, nodes: int, cumulative: bool) -> jax.Array:
    _require_unit(unit)
    _require_nodes(nodes)
    require_increasing_times("t", t)
    _warn_if_unverified(unit, cumulative)
    return jnp.asarray(t, float)


def exit_age(unit: TransferFunction, t: ArrayLike, *, nodes: int = DEFAULT_NODES) -> jax.Array:
    """Return the exact exit-age density E(t) of a unit, by inverting its transfer function.

    **Arguments:**

    - `unit`: a :class:`~axialmix.analytic.TransferFunction` (for example
      ``ExchangeZone(ClosedClosedADM(tau, Pe), beta, k_d)``), parameters in one time unit.
    - `t`: times (same unit), strictly increasing; times ``<= 0`` give 0.
    - `nodes`: trapezoidal nodes of the contour integral (static, at least 8).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    return _response(unit, _checked_times(unit, t, nodes, False), 0, nodes)


def step_response(unit: TransferFunction, t: ArrayLike, *, nodes: int = DEFAULT_NODES) -> jax.Array:
    """Return the exact cumulative residence-time distribution F(t) of a unit.

    **Arguments:**

    - `unit`: a :class:`~axialmix.analytic.TransferFunction`.
    - `t`: times (its time unit), strictly increasing; times ``<= 0`` give 0.
    - `nodes`: trapezoidal nodes of the contour integral (static, at least 8).

    **Returns:**

    ``F(t)`` (dimensionless, from 0 to 1), same shape as `t`.
    """
    return _response(unit, _checked_times(unit, t, nodes, True), 1, nodes)


def ramp_response(unit: TransferFunction, t: ArrayLike, *, nodes: int = DEFAULT_NODES) -> jax.Array:
    """Return the exact response to a unit ramp inlet ``u = t`` (for t > 0), ``∫_0^t F``.

    **Arguments:**

    - `unit`: a :class:`~axialmix.analytic.TransferFunction`.
    - `t`: times (its time unit), strictly increasing; times ``<= 0`` give 0.
    - `nodes`: trapezoidal nodes of the contour integral (static, at least 8).

    **Returns:**

    The outlet signal in (time unit) per unit slope of the inlet, same shape as `t`; it
    approaches ``t - mean`` at late times.
    """
    return _response(unit, _checked_times(unit, t, nodes, True), 2, nodes)


_AFTER = ("zero", "hold")


@partial(jax.jit, static_argnames=("after", "nodes", "batch"))
def _inlet_response(unit, t, inlet_times, inlet_signal, after, nodes, batch):
    intervals = jnp.diff(inlet_times)
    slopes = jnp.diff(inlet_signal) / intervals
    padded = jnp.concatenate([jnp.zeros(1), slopes, jnp.zeros(1)])
    kinks = jnp.diff(padded)
    last = inlet_signal[-1] if after == "zero" else 0.0
    jump_times = jnp.stack([inlet_times[0], inlet_times[-1]])
    jumps = jnp.stack([inlet_signal[0], -last])

    def row(time):
        ramps = _inverse(unit, time - inlet_times, 2, nodes)
        steps = _inverse(unit, time - jump_times, 1, nodes)
        return jnp.sum(kinks * ramps) + jnp.sum(jumps * steps)

    return jax.lax.map(jax.checkpoint(row), t, batch_size=batch)


def inlet_response(
    unit: TransferFunction,
    t: ArrayLike,
    inlet_times: ArrayLike,
    inlet_signal: ArrayLike,
    *,
    after: str = "zero",
    nodes: int = DEFAULT_NODES,
    batch: int = 8,
) -> jax.Array:
    """Return the outlet signal ``(E ⊗ u)(t)`` of a unit for a sampled inlet signal u.

    The inlet is zero before ``inlet_times[0]`` and linear between samples (a jump at the
    first sample when ``inlet_signal[0] != 0``); after the last sample it drops to zero
    (``after="zero"``, for pulses) or keeps its last value (``after="hold"``, for steps). Such
    a signal is ``Σ_j J_j H(t - t_j) + Σ_j C_j (t - t_j)_+`` with jumps ``J_j`` and slope
    changes ``C_j``, so the outlet is ``Σ_j J_j F(t - t_j) + Σ_j C_j R(t - t_j)`` with the exact
    step response F and ramp response R: exact for the piecewise-linear signal, whatever the
    sampling. Output times need not coincide with the inlet samples, so a dead time is a shift
    of `t`.

    **Arguments:**

    - `unit`: a :class:`~axialmix.analytic.TransferFunction`.
    - `t`: output times (its time unit), any order, any real values.
    - `inlet_times`: inlet sample times (same unit), strictly increasing, at least two.
    - `inlet_signal`: inlet samples at `inlet_times` (any unit U).
    - `after`: ``"zero"`` or ``"hold"`` (static): the inlet after its last sample.
    - `nodes`: trapezoidal nodes of each contour integral (static, at least 8).
    - `batch`: output times evaluated together (static); memory grows with
      ``batch * len(inlet_times) * nodes``.

    **Returns:**

    The outlet signal in U, same shape as `t` (for an inlet concentration, the outlet
    concentration; for a normalised inlet of unit area, a density in 1/(time unit)).
    """
    _require_unit(unit)
    _require_nodes(nodes)
    _warn_if_unverified(unit, cumulative=True)
    if after not in _AFTER:
        raise ValueError(f"after must be 'zero' or 'hold', got {after!r}")
    if not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be a positive integer, got {batch!r}")
    require_finite("t", t)
    require_increasing_times("inlet_times", inlet_times)
    require_finite("inlet_signal", inlet_signal)
    inlet_times = jnp.atleast_1d(jnp.asarray(inlet_times, float))
    inlet_signal = jnp.atleast_1d(jnp.asarray(inlet_signal, float))
    if inlet_times.ndim != 1 or inlet_times.shape[0] < 2:
        raise ValueError(f"inlet_times needs at least two samples, got shape {inlet_times.shape}")
    if inlet_signal.shape != inlet_times.shape:
        raise ValueError(
            f"inlet_signal must have the shape of inlet_times {inlet_times.shape}, "
            f"got {inlet_signal.shape}"
        )
    t = jnp.asarray(t, float)
    values = _inlet_response(unit, t.reshape(-1), inlet_times, inlet_signal, after, nodes, batch)
    return values.reshape(t.shape)
