"""Open–open axial dispersion model (MODELS.md section 2): E, F and moments in closed form."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc, erfcx
from jax.typing import ArrayLike

from axialmix._validation import array_namespace, require_increasing_times, require_positive

__all__ = ["exit_age_open", "mean_open", "step_response_open", "variance_open"]


def _validate(t: ArrayLike, tau: ArrayLike, peclet: ArrayLike) -> None:
    require_increasing_times("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)


def exit_age_open(t: ArrayLike, tau: ArrayLike, peclet: ArrayLike) -> jax.Array:
    """Return the open–open exit-age density E(t) in closed form.

    ``E = sqrt(Pe / (4 pi theta)) e^{-Pe (1-theta)² / (4 theta)} / tau`` with ``theta = t/tau``
    (MODELS.md section 2).

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: space time ``L / v`` in the same unit (positive); the mean is ``(1 + 2/Pe) tau``.
    - `peclet`: Peclet number ``Pe = v L / D_z`` (dimensionless, positive).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    _validate(t, tau, peclet)
    tau = jnp.asarray(tau, float)
    theta = jnp.asarray(t, float) / tau
    peclet = jnp.asarray(peclet, float)
    positive = theta > 0
    theta = jnp.where(positive, theta, 1.0)
    exponent = -peclet * (1.0 - theta) ** 2 / (4.0 * theta)
    density = jnp.sqrt(peclet / (4.0 * jnp.pi * theta)) * jnp.exp(exponent)
    return jnp.where(positive, density, 0.0) / tau


def step_response_open(t: ArrayLike, tau: ArrayLike, peclet: ArrayLike) -> jax.Array:
    """Return the open–open cumulative residence time distribution F(t) in closed form.

    With ``theta = t/tau`` and ``r = sqrt(Pe/(4 theta))``,
    ``F = erfc(r (1-theta))/2 - e^{Pe} erfc(r (1+theta))/2``; the open–open E is the
    length-biased inverse Gaussian density, and this is its distribution function. The second
    term is evaluated as ``e^{-Pe (1-theta)²/(4 theta)} erfcx(r (1+theta)) / 2`` so that it
    cannot overflow.

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: space time ``L / v`` in the same unit (positive).
    - `peclet`: Peclet number (dimensionless, positive).

    **Returns:**

    ``F(t)`` (dimensionless), same shape as `t`.
    """
    _validate(t, tau, peclet)
    theta = jnp.asarray(t, float) / jnp.asarray(tau, float)
    peclet = jnp.asarray(peclet, float)
    positive = theta > 0
    theta = jnp.where(positive, theta, 1.0)
    scale = jnp.sqrt(peclet / (4.0 * theta))
    exponent = -peclet * (1.0 - theta) ** 2 / (4.0 * theta)
    cumulative = 0.5 * erfc(scale * (1.0 - theta)) - 0.5 * jnp.exp(exponent) * erfcx(
        scale * (1.0 + theta)
    )
    return jnp.where(positive, cumulative, 0.0)


def mean_open(tau: ArrayLike, peclet: ArrayLike) -> jax.Array | np.ndarray:
    """Return the open–open mean residence time ``(1 + 2/Pe) tau``.

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number (dimensionless, positive).

    **Returns:**

    The mean residence time in the unit of `tau`: NumPy (array or scalar) when both
    arguments are Python numbers or NumPy arrays (no JAX dispatch), a JAX array otherwise.
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    xp = array_namespace(tau, peclet)
    return xp.asarray(tau, float) * (1.0 + 2.0 / xp.asarray(peclet, float))


def variance_open(tau: ArrayLike, peclet: ArrayLike) -> jax.Array:
    """Return the open–open residence-time variance ``tau² (2/Pe + 8/Pe²)``.

    It is normalised by ``tau = L/v``, not by the mean (MODELS.md section 2).

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number (dimensionless, positive).

    **Returns:**

    The variance in (time unit)².
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    peclet = jnp.asarray(peclet, float)
    return jnp.asarray(tau, float) ** 2 * (2.0 / peclet + 8.0 / peclet**2)
