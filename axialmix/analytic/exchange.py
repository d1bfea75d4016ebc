"""Axial dispersion and tanks in series with a dead (stagnant) zone (MODELS.md §6).

The flowing (mobile) material exchanges tracer with a stagnant zone of ``β`` times its hold-up
at the first-order rate ``k_d``: in Laplace space the mobile unit sees
``s' = s (1 + β k_d / (s + k_d))`` instead of s. These are shortcuts for
``ExchangeZone(ClosedClosedADM(tau, peclet), β, k_d)`` and
``ExchangeZone(TanksInSeries(tau, n), β, k_d)`` with :func:`~axialmix.analytic.exit_age` and
:func:`~axialmix.analytic.step_response`; ``tau`` is the mobile space time, the mean residence
time is ``(1 + β) tau``. Everything is JAX, float64 and differentiable in every parameter.
"""

from __future__ import annotations

import jax
from jax.typing import ArrayLike

from axialmix.analytic._laplace import DEFAULT_NODES
from axialmix.analytic.responses import exit_age, step_response
from axialmix.analytic.transfer import ClosedClosedADM, ExchangeZone, TanksInSeries

__all__ = [
    "exit_age_exchange",
    "exit_age_tanks_exchange",
    "mean_exchange",
    "mean_tanks_exchange",
    "step_response_exchange",
    "step_response_tanks_exchange",
    "transfer_function_exchange",
    "variance_exchange",
    "variance_tanks_exchange",
]


def _adm(tau, peclet, capacity_ratio, exchange_rate) -> ExchangeZone:
    return ExchangeZone(ClosedClosedADM(tau, peclet), capacity_ratio, exchange_rate)


def _tanks(tau, n_tanks, capacity_ratio, exchange_rate) -> ExchangeZone:
    return ExchangeZone(TanksInSeries(tau, n_tanks), capacity_ratio, exchange_rate)


def transfer_function_exchange(
    s: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    capacity_ratio: ArrayLike,
    exchange_rate: ArrayLike,
) -> jax.Array:
    """Return the transfer function of the closed–closed ADM with a dead zone, ``G_cc(s')``.

    **Arguments:**

    - `s`: Laplace variable in 1/(time unit), real or complex, any shape.
    - `tau`: mobile space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number of the mobile phase (dimensionless, positive).
    - `capacity_ratio`: ``β``, immobile to mobile hold-up (dimensionless, >= 0).
    - `exchange_rate`: ``k_d`` (1/time unit, positive).

    **Returns:**

    Complex ``G(s)``, same shape as `s`; ``G(0) = 1``.
    """
    return _adm(tau, peclet, capacity_ratio, exchange_rate).transfer(s)


def exit_age_exchange(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    capacity_ratio: ArrayLike,
    exchange_rate: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the exit-age density E(t) of the closed–closed ADM with a dead zone.

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: mobile space time ``L / v`` in the same unit (positive).
    - `peclet`: Peclet number of the mobile phase (dimensionless, positive).
    - `capacity_ratio`: ``β``, immobile to mobile hold-up (dimensionless, >= 0).
    - `exchange_rate`: ``k_d``, exchange rate (1/time unit, positive).
    - `nodes`: trapezoidal nodes of each contour integral (static, at least 8).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    return exit_age(_adm(tau, peclet, capacity_ratio, exchange_rate), t, nodes=nodes)


def step_response_exchange(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    capacity_ratio: ArrayLike,
    exchange_rate: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the cumulative distribution F(t) of the closed–closed ADM with a dead zone.

    **Arguments:** as :func:`exit_age_exchange`.

    **Returns:**

    ``F(t)`` (dimensionless, from 0 to 1), same shape as `t`.
    """
    return step_response(_adm(tau, peclet, capacity_ratio, exchange_rate), t, nodes=nodes)


def mean_exchange(tau: ArrayLike, capacity_ratio: ArrayLike) -> jax.Array:
    """Return the mean residence time ``(1 + β) tau`` of a unit with a dead zone.

    **Arguments:**

    - `tau`: mobile space time (time unit, positive); the mobile unit's mean.
    - `capacity_ratio`: ``β`` (dimensionless, >= 0).

    **Returns:**

    The mean residence time in the unit of `tau`.
    """
    return _adm(tau, 1.0, capacity_ratio, 1.0).mean()


def variance_exchange(
    tau: ArrayLike, peclet: ArrayLike, capacity_ratio: ArrayLike, exchange_rate: ArrayLike
) -> jax.Array:
    """Return the residence-time variance of the closed–closed ADM with a dead zone.

    ``(1 + β)² tau² (2/Pe - 2/Pe² (1 - e^{-Pe})) + 2 β tau / k_d``, from the Taylor series of
    ``log G`` (see :class:`~axialmix.analytic.ExchangeZone`).

    **Arguments:** as :func:`transfer_function_exchange` without `s`.

    **Returns:**

    The variance in (time unit)².
    """
    return _adm(tau, peclet, capacity_ratio, exchange_rate).variance()


def exit_age_tanks_exchange(
    t: ArrayLike,
    tau: ArrayLike,
    n_tanks: ArrayLike,
    capacity_ratio: ArrayLike,
    exchange_rate: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the exit-age density of n tanks in series, each with a dead zone.

    ``G(s) = (1 + s' tau / n)^-n``; for whole n it is exactly a network of n flowing tanks,
    each exchanging with its own stagnant tank (``β tau / n`` hold-up, rate ``k_d``).

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: mobile mean residence time of the chain (time unit, positive).
    - `n_tanks`: number of tanks (positive real).
    - `capacity_ratio`: ``β`` (dimensionless, >= 0).
    - `exchange_rate`: ``k_d`` (1/time unit, positive).
    - `nodes`: trapezoidal nodes of each contour integral (static, at least 8).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    return exit_age(_tanks(tau, n_tanks, capacity_ratio, exchange_rate), t, nodes=nodes)


def step_response_tanks_exchange(
    t: ArrayLike,
    tau: ArrayLike,
    n_tanks: ArrayLike,
    capacity_ratio: ArrayLike,
    exchange_rate: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the cumulative distribution F(t) of n tanks in series with dead zones.

    **Arguments:** as :func:`exit_age_tanks_exchange`.

    **Returns:**

    ``F(t)`` (dimensionless), same shape as `t`.
    """
    return step_response(_tanks(tau, n_tanks, capacity_ratio, exchange_rate), t, nodes=nodes)


def mean_tanks_exchange(tau: ArrayLike, capacity_ratio: ArrayLike) -> jax.Array:
    """Return the mean residence time ``(1 + β) tau`` of tanks with dead zones.

    **Arguments:**

    - `tau`: mobile mean residence time (time unit, positive).
    - `capacity_ratio`: ``β`` (dimensionless, >= 0).

    **Returns:**

    The mean residence time in the unit of `tau`.
    """
    return _tanks(tau, 1.0, capacity_ratio, 1.0).mean()


def variance_tanks_exchange(
    tau: ArrayLike, n_tanks: ArrayLike, capacity_ratio: ArrayLike, exchange_rate: ArrayLike
) -> jax.Array:
    """Return the variance ``(1 + β)² tau² / n + 2 β tau / k_d`` of tanks with dead zones.

    **Arguments:**

    - `tau`: mobile mean residence time (time unit, positive).
    - `n_tanks`: number of tanks (positive real).
    - `capacity_ratio`: ``β`` (dimensionless, >= 0).
    - `exchange_rate`: ``k_d`` (1/time unit, positive).

    **Returns:**

    The variance in (time unit)².
    """
    return _tanks(tau, n_tanks, capacity_ratio, exchange_rate).variance()
