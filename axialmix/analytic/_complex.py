"""Small overflow-safe complex helpers shared by the transfer functions and their inversion."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def log_expm1(ell: jax.Array) -> jax.Array:
    """Return ``log(e^ell - 1)`` for complex ell without overflow (any branch of the log).

    For ``Re ell > 0`` it is ``ell + log(1 - e^-ell)``, whose derivatives do not overflow
    either (forward-mode second derivatives of ``log(expm1(ell))`` meet ``e^{2 ell}``).
    """
    large = jnp.real(ell) > 0
    safe_large = jnp.where(large, ell, 1.0)
    safe_small = jnp.where(large, -1.0, ell)
    return jnp.where(
        large,
        safe_large + jnp.log(-jnp.expm1(-safe_large)),
        jnp.log(jnp.expm1(safe_small)),
    )
