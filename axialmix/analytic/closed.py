"""Closed–closed (Danckwerts) axial dispersion model: E, F, transfer function and moments.

Formulas of MODELS.md section 2. E and F come from an exact numerical inversion of the
transfer function (see :mod:`axialmix.analytic._contour`), accurate to about 1e-13 of the
peak for every Peclet number from 1e-2 to 1e4 and every time, early times included; the
eigenfunction series in :mod:`axialmix.analytic.highprecision` is the test reference.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from axialmix._validation import (
    array_namespace,
    require_finite,
    require_increasing_times,
    require_positive,
)
from axialmix.analytic._contour import (
    DEFAULT_NODES,
    closed_closed_curves,
    closed_closed_exit_age,
    exprel,
)

__all__ = [
    "exit_age_closed",
    "mean_closed",
    "step_response_closed",
    "transfer_function_closed",
    "variance_closed",
    "variance_ratio_closed",
]


def _require_nodes(nodes: int) -> None:
    if not isinstance(nodes, int) or nodes < 8:
        raise ValueError(f"nodes must be an integer of at least 8, got {nodes!r}")


def exit_age_closed(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the exact closed–closed exit-age density E(t) of the axial dispersion model.

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: space time ``L / v`` in the same unit (positive); it is also the mean.
    - `peclet`: Peclet number ``Pe = v L / D_z`` (dimensionless, positive).
    - `nodes`: quadrature nodes of the Bromwich integral (static, at least 8; the default 24
      is exact to round-off for Pe from 1e-3 to 1e5: within 2.4e-15 of the peak of 48
      nodes' values).

    **Returns:**

    ``E(t)`` in 1/(time unit), same shape as `t`.
    """
    require_increasing_times("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    _require_nodes(nodes)
    tau = jnp.asarray(tau, float)
    return closed_closed_exit_age(jnp.asarray(t, float) / tau, peclet, nodes) / tau


def step_response_closed(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    nodes: int = DEFAULT_NODES,
) -> jax.Array:
    """Return the exact closed–closed cumulative residence time distribution F(t).

    **Arguments:**

    - `t`: times (any unit), strictly increasing; times ``<= 0`` give 0.
    - `tau`: space time ``L / v`` in the same unit (positive).
    - `peclet`: Peclet number (dimensionless, positive).
    - `nodes`: quadrature nodes of the Bromwich integral (static).

    **Returns:**

    ``F(t)`` (dimensionless, rising from 0 to 1), same shape as `t`.
    """
    require_increasing_times("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    _require_nodes(nodes)
    _, step_response = closed_closed_curves(
        jnp.asarray(t, float) / jnp.asarray(tau, float), peclet, nodes
    )
    return step_response


def transfer_function_closed(s: ArrayLike, peclet: ArrayLike) -> jax.Array:
    """Return the closed–closed transfer function G(s) in its overflow-safe form.

    ``G = 4 q e^{Pe(1-q)/2} / [(1+q)² - (1-q)² e^{-q Pe}]`` with ``q = sqrt(1 + 4 s / Pe)``
    (MODELS.md section 2), evaluated as ``4 e^{Pe(1-q)/2} / (4 + Pe (1-q)² (e^{-q Pe}-1)/(-q Pe))``,
    which is finite at ``q = 0`` too.

    **Arguments:**

    - `s`: Laplace variable in units of ``1/tau`` (real or complex, any shape).
    - `peclet`: Peclet number (dimensionless, positive).

    **Returns:**

    Complex ``G(s)``, same shape as `s`; ``G(0) = 1``.
    """
    require_finite("s", s)
    require_positive("peclet", peclet)
    s = jnp.asarray(s, complex)
    peclet = jnp.asarray(peclet, float)
    q = jnp.sqrt(1.0 + 4.0 * s / peclet)
    denominator = 4.0 + peclet * (1.0 - q) ** 2 * exprel(-q * peclet)
    return 4.0 * jnp.exp(0.5 * peclet * (1.0 - q)) / denominator


def variance_ratio_closed(peclet: ArrayLike) -> jax.Array:
    """Return the closed–closed dimensionless variance ``sigma²/tau² = 2/Pe - 2/Pe² (1 - e^{-Pe})``.

    Computed as ``2 (e^{-Pe} - 1 + Pe) / Pe²``, by its Taylor series below Pe = 1 to avoid
    cancellation (it tends to ``1 - Pe/3`` as Pe -> 0).

    **Arguments:**

    - `peclet`: Peclet number (dimensionless, positive; any shape).

    **Returns:**

    ``sigma² / tau²`` (dimensionless), in (0, 1).
    """
    peclet = jnp.asarray(peclet, float)
    small = peclet < 1.0
    small_pe = jnp.where(small, peclet, 0.5)
    large_pe = jnp.where(small, 2.0, peclet)
    # 2 (e^{-x} - 1 + x) / x² = Σ_k 2 (-x)^k / (k+2)!, summed by Horner; 18 terms reach 1e-17.
    series = jnp.zeros_like(small_pe)
    for k in range(18, -1, -1):
        series = series * (-small_pe) + 2.0 / _factorial(k + 2)
    direct = 2.0 * (jnp.expm1(-large_pe) + large_pe) / large_pe**2
    return jnp.where(small, series, direct)


def _factorial(n: int) -> float:
    result = 1.0
    for k in range(2, n + 1):
        result *= k
    return result


def mean_closed(tau: ArrayLike, peclet: ArrayLike) -> jax.Array | np.ndarray:
    """Return the mean residence time of the closed–closed model, which equals ``tau``.

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number (dimensionless, positive); the mean does not depend on it.

    **Returns:**

    The mean residence time in the unit of `tau`: NumPy (array or scalar) when both
    arguments are Python numbers or NumPy arrays (no JAX dispatch), a JAX array otherwise.
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    if type(tau) in (float, int) and type(peclet) in (float, int):
        return np.asarray(tau, float)  # two numbers broadcast to a 0-d array: no dispatch
    xp = array_namespace(tau, peclet)
    tau, _ = xp.broadcast_arrays(xp.asarray(tau, float), xp.asarray(peclet, float))
    return tau


def variance_closed(tau: ArrayLike, peclet: ArrayLike) -> jax.Array:
    """Return the residence-time variance of the closed–closed model.

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive).
    - `peclet`: Peclet number (dimensionless, positive).

    **Returns:**

    ``sigma² = tau² (2/Pe - 2/Pe² (1 - e^{-Pe}))`` in (time unit)².
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    return jnp.asarray(tau, float) ** 2 * variance_ratio_closed(peclet)
