"""From moments or physical quantities to model parameters: Peclet number, dispersion, tau."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from axialmix._validation import array_namespace, concrete_value, require_positive
from axialmix.analytic.closed import variance_ratio_closed

__all__ = [
    "approximate_peclet_from_variance_ratio",
    "peclet_from_moments",
    "peclet_from_physical",
    "peclet_from_variance_ratio",
    "sherritt_dispersion",
    "sherritt_peclet",
    "tau_from_physical",
    "transport_from_dimensionless",
]

# From the rational start below (within 5 % of the root) Newton reaches round-off in 4 steps
# for every Pe in [1e-6, 1e8]; two more are a margin and cost nothing noticeable.
_NEWTON_STEPS = 6


def _starting_peclet(ratio, xp=jnp):
    """Invert the rational fit ``(6 + 2 Pe) / (6 + 4 Pe + Pe²)`` of the variance ratio.

    The fit has the exact limits ``1 - Pe/3`` (Pe -> 0) and ``2/Pe - 2/Pe²`` (Pe -> ∞); its
    inverse is the positive root of ``r Pe² + (4r - 2) Pe + 6 r - 6 = 0``, written in the form
    without cancellation on each side of r = 1/2. `xp` is the array namespace (``jax.numpy``,
    or ``numpy`` for :func:`approximate_peclet_from_variance_ratio`; ``math`` for one number
    in (0, 1): the same operations on the side that is taken, without selects).
    """
    root = xp.sqrt(1.0 + 2.0 * ratio * (1.0 - ratio))
    if xp is math:
        if ratio < 0.5:
            return ((1.0 - 2.0 * ratio) + root) / ratio
        return 6.0 * (1.0 - ratio) / (root - (1.0 - 2.0 * ratio))
    low_ratio = ratio < 0.5
    r_low = xp.where(low_ratio, ratio, 0.25)
    r_high = xp.where(low_ratio, 0.75, ratio)
    from_low = ((1.0 - 2.0 * r_low) + xp.sqrt(1.0 + 2.0 * r_low * (1.0 - r_low))) / r_low
    from_high = 6.0 * (1.0 - r_high) / (root - (1.0 - 2.0 * r_high))
    return xp.where(low_ratio, from_low, from_high)


def approximate_peclet_from_variance_ratio(ratio: ArrayLike) -> np.ndarray:
    """Return a closed–closed Peclet number within 5 % of the one whose ``sigma²/tau²`` is `ratio`.

    The starting value of :func:`peclet_from_variance_ratio` (the inverse of a rational fit of
    the variance ratio with its exact limits at both ends), in NumPy: no JAX program is traced,
    so it suits start values computed once per curve in Python. Ratios outside (0, 1) give NaN.

    **Arguments:**

    - `ratio`: dimensionless variance ``sigma² / tau²`` (any shape).

    **Returns:**

    The approximate Peclet number (dimensionless), a NumPy array of the shape of `ratio`.
    """
    if type(ratio) is float or type(ratio) is np.float64:  # one number: no array operations
        return np.asarray(_starting_peclet(float(ratio), math) if 0.0 < ratio < 1.0 else
                          math.nan)
    ratio = np.asarray(ratio, float)
    valid = (ratio > 0.0) & (ratio < 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        peclet = _starting_peclet(np.where(valid, ratio, 0.5), np)
    return np.where(valid, peclet, np.nan)


@jax.custom_jvp
def peclet_from_variance_ratio(ratio: ArrayLike) -> jax.Array:
    """Return the closed–closed Peclet number whose ``sigma²/tau²`` equals ``ratio``.

    Solves ``2/Pe - 2/Pe² (1 - e^{-Pe}) = ratio`` by Newton's method in ``log Pe`` (a fixed
    number of steps, so it jits); the derivative comes from the implicit function theorem.
    Ratios outside (0, 1) give NaN; use :func:`peclet_from_moments` for checked input.

    **Arguments:**

    - `ratio`: dimensionless variance ``sigma² / tau²`` (any shape).

    **Returns:**

    The Peclet number (dimensionless), same shape as `ratio`.
    """
    ratio = jnp.asarray(ratio, float)
    valid = (ratio > 0.0) & (ratio < 1.0)
    ratio_safe = jnp.where(valid, ratio, 0.5)
    log_ratio = jnp.log(ratio_safe)

    def newton_step(_, log_peclet):
        peclet = jnp.exp(log_peclet)
        value, slope = jax.jvp(variance_ratio_closed, (peclet,), (peclet,))
        # d log f / d log Pe = Pe f'(Pe) / f(Pe)
        return log_peclet - (jnp.log(value) - log_ratio) * value / slope

    log_peclet = jax.lax.fori_loop(
        0, _NEWTON_STEPS, newton_step, jnp.log(_starting_peclet(ratio_safe))
    )
    return jnp.where(valid, jnp.exp(log_peclet), jnp.nan)


@peclet_from_variance_ratio.defjvp
def _peclet_from_variance_ratio_jvp(primals, tangents):
    (ratio,), (ratio_dot,) = primals, tangents
    peclet = peclet_from_variance_ratio(ratio)
    _, slope = jax.jvp(variance_ratio_closed, (peclet,), (jnp.ones_like(peclet),))
    return peclet, ratio_dot / slope


# Jitted, so that eager calls (reports evaluate it on plain numbers, many times a fit) reuse
# one compiled program instead of tracing the Newton loop again on every call.
peclet_from_variance_ratio = jax.jit(peclet_from_variance_ratio)


def peclet_from_moments(mean: ArrayLike, variance: ArrayLike) -> jax.Array:
    """Return the closed–closed Peclet number that reproduces a measured mean and variance.

    Inverts ``sigma²/tau² = 2/Pe - 2/Pe² (1 - e^{-Pe})`` (MODELS.md section 2) with
    ``tau = mean``; differentiable in both arguments.

    **Arguments:**

    - `mean`: mean residence time (any time unit, positive).
    - `variance`: residence-time variance in the same unit squared; ``variance / mean²``
      must lie in (0, 1), the range of the closed–closed model.

    **Returns:**

    The Peclet number (dimensionless); NaN for out-of-range traced input.
    """
    require_positive("mean", mean)
    require_positive("variance", variance)
    mean_value, variance_value = concrete_value(mean), concrete_value(variance)
    if mean_value is not None and variance_value is not None:
        ratio = variance_value / mean_value**2
        if (ratio >= 1.0).any():
            raise ValueError(
                "variance / mean² must be below 1 for the closed–closed model (1 is a single "
                f"stirred tank), got {ratio.max():g}"
            )
    mean = jnp.asarray(mean, float)
    return peclet_from_variance_ratio(jnp.asarray(variance, float) / mean**2)


def sherritt_dispersion(length: ArrayLike, mean: ArrayLike, variance: ArrayLike) -> jax.Array:
    """Return the large-Pe dispersion estimate ``D_z = L² sigma² / (2 <t>³)`` (Sherritt 2003).

    Exact for the inverse-Gaussian RTD; for the closed–closed model its relative error is
    O(1/Pe) (MODELS.md section 2).

    **Arguments:**

    - `length`: mixer length (any length unit, positive).
    - `mean`: mean residence time (time unit, positive).
    - `variance`: residence-time variance (time unit squared, positive).

    **Returns:**

    The axial dispersion coefficient in (length unit)²/(time unit).
    """
    require_positive("length", length)
    require_positive("mean", mean)
    require_positive("variance", variance)
    length, mean = jnp.asarray(length, float), jnp.asarray(mean, float)
    return length**2 * jnp.asarray(variance, float) / (2.0 * mean**3)


def sherritt_peclet(mean: ArrayLike, variance: ArrayLike) -> jax.Array:
    """Return the Peclet number of the Sherritt estimate, ``Pe = v L / D_z = 2 <t>² / sigma²``.

    It uses ``v = L / <t>`` with :func:`sherritt_dispersion`; the length cancels.

    **Arguments:**

    - `mean`: mean residence time (time unit, positive).
    - `variance`: residence-time variance (time unit squared, positive).

    **Returns:**

    The Peclet number (dimensionless).
    """
    require_positive("mean", mean)
    require_positive("variance", variance)
    return 2.0 * jnp.asarray(mean, float) ** 2 / jnp.asarray(variance, float)


def peclet_from_physical(
    velocity: ArrayLike, dispersion: ArrayLike, length: ArrayLike
) -> jax.Array:
    """Return the Peclet number ``Pe = v L / D_z``.

    **Arguments:**

    - `velocity`: mean axial velocity (length unit / time unit, positive).
    - `dispersion`: axial dispersion coefficient (length unit² / time unit, positive).
    - `length`: mixer length (length unit, positive).

    **Returns:**

    The Peclet number (dimensionless).
    """
    require_positive("velocity", velocity)
    require_positive("dispersion", dispersion)
    require_positive("length", length)
    velocity, length = jnp.asarray(velocity, float), jnp.asarray(length, float)
    return velocity * length / jnp.asarray(dispersion, float)


def tau_from_physical(velocity: ArrayLike, length: ArrayLike) -> jax.Array:
    """Return the space time ``tau = L / v``.

    **Arguments:**

    - `velocity`: mean axial velocity (length unit / time unit, positive).
    - `length`: mixer length (length unit, positive).

    **Returns:**

    ``tau`` in the time unit of `velocity`.
    """
    require_positive("velocity", velocity)
    require_positive("length", length)
    return jnp.asarray(length, float) / jnp.asarray(velocity, float)


def transport_from_dimensionless(
    tau: ArrayLike, peclet: ArrayLike, length: ArrayLike
) -> tuple[jax.Array, jax.Array] | tuple[np.ndarray, np.ndarray]:
    """Return the velocity and axial dispersion ``(v, D_z)`` behind ``tau`` and ``Pe``.

    The inverse of :func:`tau_from_physical` and :func:`peclet_from_physical`:
    ``v = L / tau`` and ``D_z = v L / Pe = L² / (tau Pe)`` (MODELS.md section 2). For the
    open–open model too, ``tau`` is ``L / v`` (not its mean residence time).

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number (dimensionless, positive).
    - `length`: mixer length (length unit, positive).

    **Returns:**

    ``(velocity, dispersion)`` in length unit / time unit and length unit² / time unit:
    NumPy (arrays or scalars) when every argument is a Python number or NumPy array (no JAX
    dispatch), JAX arrays otherwise.
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    require_positive("length", length)
    xp = array_namespace(tau, peclet, length)
    tau, length = xp.asarray(tau, float), xp.asarray(length, float)
    velocity = length / tau
    return velocity, velocity * length / xp.asarray(peclet, float)
