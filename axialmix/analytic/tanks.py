"""Tanks in series with a real-valued number of tanks: the gamma residence time distribution."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.special import gammainc, gammaln
from jax.typing import ArrayLike

from axialmix._validation import require_increasing_times, require_positive

__all__ = ["exit_age_tanks", "mean_tanks", "step_response_tanks", "variance_tanks"]


def _validate(t: ArrayLike, tau: ArrayLike, n_tanks: ArrayLike) -> None:
    require_increasing_times("t", t)
    require_positive("tau", tau)
    require_positive("n_tanks", n_tanks)


def exit_age_tanks(t: ArrayLike, tau: ArrayLike, n_tanks: ArrayLike) -> jax.Array:
    """Return the exit-age density of n equal stirred tanks in series (gamma density).

    ``E(t) = (n/tau) (n theta)^{n-1} e^{-n theta} / Gamma(n)`` with ``theta = t/tau``,
    evaluated in log space (``gammaln``) so that large n neither overflows nor underflows;
    n may be any positive real. At ``t = 0`` the right limit is returned (0 for n > 1,
    ``1/tau`` for n = 1, infinity for n < 1); earlier times give 0.

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``< 0`` give 0.
    - `tau`: total mean residence time of the chain, same unit as `t` (positive).
    - `n_tanks`: number of tanks (positive real; 1 is a single stirred tank).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    _validate(t, tau, n_tanks)
    tau = jnp.asarray(tau, float)
    n = jnp.asarray(n_tanks, float)
    theta = jnp.asarray(t, float) / tau
    positive = theta > 0
    scaled = n * jnp.where(positive, theta, 1.0)
    log_density = jnp.log(n) + (n - 1.0) * jnp.log(scaled) - scaled - gammaln(n)
    at_zero = jnp.where(n > 1.0, 0.0, jnp.where(n == 1.0, 1.0, jnp.inf))
    density = jnp.where(positive, jnp.exp(log_density), jnp.where(theta == 0, at_zero, 0.0))
    return density / tau


def step_response_tanks(t: ArrayLike, tau: ArrayLike, n_tanks: ArrayLike) -> jax.Array:
    """Return the cumulative distribution of n tanks in series, ``P(n, n t / tau)``.

    ``P`` is the regularised lower incomplete gamma function.

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: total mean residence time, same unit as `t` (positive).
    - `n_tanks`: number of tanks (positive real).

    **Returns:**

    ``F(t)`` (dimensionless), same shape as `t`.
    """
    _validate(t, tau, n_tanks)
    n = jnp.asarray(n_tanks, float)
    theta = jnp.asarray(t, float) / jnp.asarray(tau, float)
    positive = theta > 0
    return jnp.where(positive, gammainc(n, n * jnp.where(positive, theta, 1.0)), 0.0)


def mean_tanks(tau: ArrayLike, n_tanks: ArrayLike) -> jax.Array:
    """Return the mean residence time of n tanks in series, which equals ``tau``.

    **Arguments:**

    - `tau`: total mean residence time (time unit, positive).
    - `n_tanks`: number of tanks (positive real); the mean does not depend on it.

    **Returns:**

    The mean residence time in the unit of `tau`.
    """
    require_positive("tau", tau)
    require_positive("n_tanks", n_tanks)
    tau, _ = jnp.broadcast_arrays(jnp.asarray(tau, float), jnp.asarray(n_tanks, float))
    return tau


def variance_tanks(tau: ArrayLike, n_tanks: ArrayLike) -> jax.Array:
    """Return the residence-time variance of n tanks in series, ``tau² / n``.

    **Arguments:**

    - `tau`: total mean residence time (time unit, positive).
    - `n_tanks`: number of tanks (positive real).

    **Returns:**

    The variance in (time unit)².
    """
    require_positive("tau", tau)
    require_positive("n_tanks", n_tanks)
    return jnp.asarray(tau, float) ** 2 / jnp.asarray(n_tanks, float)
