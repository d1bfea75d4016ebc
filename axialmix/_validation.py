"""Argument checks that run only on concrete values, so jit, grad and vmap keep working.

Every public model validates its inputs with these helpers. A check looks at the value only
when it is concrete (a Python number, a numpy array, or a JAX array outside a trace); inside
``jax.jit``, ``jax.grad`` or ``jax.vmap`` the argument is a tracer, and the check is skipped
silently: the model then returns NaN or zeros for nonsense input instead of raising. Each
failure is one ``ValueError`` sentence that names the argument.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "array_namespace",
    "concrete_value",
    "require_finite",
    "require_increasing_times",
    "require_positive",
]

#: Python numbers (not bool, which the array path refuses as not numeric).
_PLAIN_NUMBERS = (float, int)

_TRACER_ERRORS = (
    jax.errors.TracerArrayConversionError,
    jax.errors.ConcretizationTypeError,
    jax.errors.TracerIntegerConversionError,
    jax.errors.TracerBoolConversionError,
)


def array_namespace(*values: Any):
    """``numpy`` when every value is a Python number or NumPy array, else ``jax.numpy``.

    Closed-form quantities evaluated on plain numbers (a fit's record, once per curve) then
    cost NumPy operations instead of JAX dispatches, and stay JAX arrays inside a trace or
    when given JAX arrays.
    """
    if all(type(v) in _PLAIN_NUMBERS for v in values):
        return np
    return jnp if any(isinstance(v, jax.Array) for v in values) else np


def concrete_value(value: Any) -> np.ndarray | None:
    """Return ``value`` as a numpy array, or None when it is a JAX tracer.

    **Arguments:**

    - `value`: a number, array-like or JAX array.

    **Returns:**

    A numpy array, or ``None`` when the value is only known at run time (inside a trace).
    """
    if isinstance(value, jax.core.Tracer):
        return None
    try:
        return np.asarray(value)
    except _TRACER_ERRORS:
        return None


def require_finite(name: str, value: Any) -> None:
    """Raise ValueError when a concrete ``value`` holds NaN or an infinity.

    **Arguments:**

    - `name`: the argument name used in the message.
    - `value`: the argument.
    """
    if type(value) in _PLAIN_NUMBERS:  # a Python number: the same checks without an array
        if math.isnan(value):
            raise ValueError(f"{name} must not be NaN")
        if math.isinf(value):
            raise ValueError(f"{name} must be finite, got an infinity")
        return
    array = concrete_value(value)
    if array is None:
        return
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got {array.dtype}")
    if np.isnan(array).any():
        raise ValueError(f"{name} must not be NaN")
    if np.isinf(array).any():
        raise ValueError(f"{name} must be finite, got an infinity")


def require_positive(name: str, value: Any) -> None:
    """Raise ValueError when a concrete ``value`` is NaN, infinite, zero or negative.

    **Arguments:**

    - `name`: the argument name used in the message.
    - `value`: the argument (scalar or array; every element is checked).
    """
    require_finite(name, value)
    if type(value) in _PLAIN_NUMBERS:
        if value <= 0:
            raise ValueError(f"{name} must be positive, got {value:g}")
        return
    array = concrete_value(value)
    if array is None:
        return
    if (array <= 0).any():
        worst = array.min()
        raise ValueError(f"{name} must be positive, got {worst:g}")


def require_increasing_times(name: str, times: Any) -> None:
    """Raise ValueError when concrete ``times`` are NaN, infinite or not strictly increasing.

    Scalars are accepted; arrays must be one-dimensional. Negative times are allowed (a
    response is zero before the injection at t = 0).

    **Arguments:**

    - `name`: the argument name used in the message.
    - `times`: the time array.
    """
    require_finite(name, times)
    array = concrete_value(times)
    if array is None or array.ndim == 0:
        return
    if array.ndim != 1:
        raise ValueError(f"{name} must be a one-dimensional array, got shape {array.shape}")
    steps = np.diff(array)
    if (steps <= 0).any():
        index = int(np.argmax(steps <= 0))
        raise ValueError(
            f"{name} must be strictly increasing, but {name}[{index + 1}] = "
            f"{array[index + 1]:g} follows {array[index]:g}"
        )
