"""Losses that score a model curve against a measured one.

Residuals are ``r_i = y_model(t_i) - y_exp(t_i)``. Weights ``w_i >= 0`` multiply the squared
residuals (``w_i = 1 / sigma_i²`` for points with known standard deviations ``sigma_i``); a
zero weight drops a point (used to pad curves of different lengths to one array).

* ``'sse'``: least squares ``Σ w_i r_i²``, the loss with a statistical meaning (Gaussian
  errors), used for standard errors and intervals.
* ``'mae'``: the source work's mean absolute error ``(1/n) Σ |r_i|`` (weighted:
  ``Σ w_i |r_i| / Σ w_i``), kept to compare with its grid search. It is not smooth at zero
  residuals, so gradient methods converge on it less cleanly than on ``'sse'``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

import axialmix  # noqa: F401  (float64 before any JAX array is made)

__all__ = ["LOSSES", "mean_absolute_error", "residuals", "sum_of_squares"]


def residuals(predicted: ArrayLike, observed: ArrayLike) -> Array:
    """Model minus data at each sample time.

    **Arguments:**

    - `predicted`: model values ``y_model(t_i)``, shape ``(n,)``.
    - `observed`: measured values ``y_exp(t_i)``, shape ``(n,)``, same unit.

    **Returns:**

    ``y_model - y_exp``, shape ``(n,)``.
    """
    return jnp.asarray(predicted) - jnp.asarray(observed)


def sum_of_squares(
    residual: ArrayLike, weights: ArrayLike | None = None
) -> Array:
    """Weighted sum of squared residuals ``Σ w_i r_i²``.

    **Arguments:**

    - `residual`: residuals ``r_i``, shape ``(n,)``; unit U.
    - `weights`: ``w_i >= 0`` (default all one), shape ``(n,)``; unit 1/U² for ``1/sigma²``.

    **Returns:**

    The scalar loss; unit U² (dimensionless with ``1/sigma²`` weights).
    """
    residual = jnp.asarray(residual)
    squared = residual**2
    if weights is None:
        return jnp.sum(squared)
    return jnp.sum(jnp.asarray(weights) * squared)


def mean_absolute_error(
    residual: ArrayLike, weights: ArrayLike | None = None
) -> Array:
    """Mean absolute residual, the source's ``Error = (1/n) Σ |y_model - y_exp|``.

    **Arguments:**

    - `residual`: residuals ``r_i``, shape ``(n,)``; unit U.
    - `weights`: ``w_i >= 0`` (default all one); the weighted form is
      ``Σ w_i |r_i| / Σ w_i``.

    **Returns:**

    The scalar loss; unit U.
    """
    residual = jnp.abs(jnp.asarray(residual))
    if weights is None:
        return jnp.mean(residual)
    weights = jnp.asarray(weights)
    return jnp.sum(weights * residual) / jnp.sum(weights)


#: The losses :func:`fitting.fit.fit` accepts, by name.
LOSSES = {"sse": sum_of_squares, "mae": mean_absolute_error}
