"""The four-compartment model of MODELS.md §3, defined once: its structure and fast kernels.

A 2 × 2 layout: compartments ``C1 C2`` (first row) and ``C3 C4`` (second row); forward
``k_f`` for C1→C2 and C3→C4, backward ``k_r`` for C2→C1 and C4→C3, side exchange ``k_s``
both ways for C1↔C3 and C2↔C4; feed into C1, outflow ``k_out`` from C4. The table
:data:`FOUR_COMPARTMENT_CONNECTIONS` is the one definition: the network preset
(:func:`axialmix.network.four_compartment`), its generator
(:func:`four_compartment_generator`) and its fast exit age (:func:`four_compartment_exit_age`)
are all built from it, and the particle preset from the network preset.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from .._validation import concrete_value, require_finite
from ._propagation import continuous_states, times_array

__all__ = [
    "FOUR_COMPARTMENTS",
    "FOUR_COMPARTMENT_CONNECTIONS",
    "FOUR_COMPARTMENT_INLET",
    "FOUR_COMPARTMENT_OUTLET",
    "FOUR_COMPARTMENT_RATES",
    "four_compartment_exit_age",
    "four_compartment_generator",
]

FOUR_COMPARTMENTS = ("C1", "C2", "C3", "C4")
"""Compartment names, in the order of the generator's rows and columns."""
FOUR_COMPARTMENT_RATES = ("k_f", "k_r", "k_s", "k_out")
"""Rate names, in the order of the functions' arguments."""
FOUR_COMPARTMENT_CONNECTIONS = (
    ("C1", "C2", "k_f"), ("C3", "C4", "k_f"),
    ("C2", "C1", "k_r"), ("C4", "C3", "k_r"),
    ("C1", "C3", "k_s"), ("C3", "C1", "k_s"),
    ("C2", "C4", "k_s"), ("C4", "C2", "k_s"),
)
"""``(source, target, rate name)`` of every connection."""
FOUR_COMPARTMENT_INLET = "C1"
FOUR_COMPARTMENT_OUTLET = "C4"

_SOURCES = np.array([FOUR_COMPARTMENTS.index(s) for s, _, _ in FOUR_COMPARTMENT_CONNECTIONS])
_TARGETS = np.array([FOUR_COMPARTMENTS.index(t) for _, t, _ in FOUR_COMPARTMENT_CONNECTIONS])
_RATE_INDEX = np.array(
    [FOUR_COMPARTMENT_RATES.index(k) for _, _, k in FOUR_COMPARTMENT_CONNECTIONS]
)
_OUTLET = FOUR_COMPARTMENTS.index(FOUR_COMPARTMENT_OUTLET)
_INLET = FOUR_COMPARTMENTS.index(FOUR_COMPARTMENT_INLET)


def four_compartment_generator(
    k_f: ArrayLike, k_r: ArrayLike, k_s: ArrayLike, k_out: ArrayLike
) -> Array:
    """Generator ``K`` of the four-compartment model (MODELS.md §3), rows C1 … C4.

    Built from :data:`FOUR_COMPARTMENT_CONNECTIONS`: ``K[j, i] = k_ij`` and
    ``K[i, i] = -(sum_j k_ij + k_out_i)``.

    **Arguments:**

    - `k_f`, `k_r`, `k_s`, `k_out`: scalar rates (1/time).

    **Returns:**

    Array ``(4, 4)``; ``dm/dt = K m`` plus the feed into C1.
    """
    rates = jnp.stack([jnp.asarray(x, dtype=float) for x in (k_f, k_r, k_s, k_out)])
    flows = rates[_RATE_INDEX]
    transfer = jnp.zeros((4, 4), dtype=float).at[_TARGETS, _SOURCES].add(flows)
    loss = jnp.zeros(4, dtype=float).at[_SOURCES].add(flows).at[_OUTLET].add(rates[3])
    return transfer - jnp.diag(loss)


def four_compartment_exit_age(
    t: ArrayLike, k_f: ArrayLike, k_r: ArrayLike, k_s: ArrayLike, k_out: ArrayLike,
    *, regular: bool | None = None,
) -> Array:
    """Exit age of the four-compartment model for a unit pulse into C1 (fast, for fitting).

    ``E(t) = k_out · [expm(K t) e_1]_4`` with ``K`` from :func:`four_compartment_generator`;
    the same curve as ``exit_age(four_compartment(k_f, k_r, k_s, k_out), t)`` without
    building a network, so it jits, differentiates and vmaps over the parameters. Rates may
    be zero (no validation error for an unreachable outlet: E is then 0).

    **Arguments:**

    - `t`: output times (time units), strictly increasing; E = 0 for t < 0.
    - `k_f`, `k_r`, `k_s`, `k_out`: scalar rates (1/time), non-negative.
    - `regular`: for traced times, whether they are a regular grid (possibly shifted and
      clipped at zero): see :func:`regular_grid`. Default: not said.

    **Returns:**

    Array of E (1/time), the shape of `t`.
    """
    for name, value in zip(FOUR_COMPARTMENT_RATES, (k_f, k_r, k_s, k_out), strict=True):
        require_finite(name, value)
        array = concrete_value(value)
        if array is not None and (array < 0).any():
            raise ValueError(f"{name} must be non-negative, got {array.min():g}.")
    times, concrete, shape = times_array(t)
    generator = four_compartment_generator(k_f, k_r, k_s, k_out)
    states = continuous_states(generator, jnp.zeros(4).at[_INLET].set(1.0), times, concrete,
                               regular)
    outflow = jnp.asarray(k_out, dtype=float) * states[:, _OUTLET]
    return jnp.where(times >= 0, outflow, 0.0).reshape(shape)
