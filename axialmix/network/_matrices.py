"""Rate (generator) and step matrices of a compartment network (MODELS.md §3).

Continuous time: ``dm/dt = K m + s u(t)`` with the generator ``K[j, i] = k_ij`` (i ≠ j),
``K[i, i] = -(sum_j k_ij + k_out_i)``, feed split ``s`` and outflow ``y = k_out · m``.
Discrete steps: ``m_{k+1} = P m_k`` with ``P = I + Q``, ``Q[j, i] = f_ij``,
``Q[i, i] = -(sum_j f_ij + q_i)`` (see :mod:`axialmix.network._responses` for the
conventions of time).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from .._validation import concrete_value, require_finite
from ._description import CompartmentNetwork

__all__ = ["generator_matrix", "outflow_vector", "rate_arrays", "require_open", "step_matrix"]


def rate_arrays(
    network: CompartmentNetwork, rates: ArrayLike | None, outflow_rates: ArrayLike | None
) -> tuple[Array, Array]:
    if rates is None:
        rates = network.rates
    if outflow_rates is None:
        outflow_rates = network.outflow_rates
    rates = jnp.asarray(rates, dtype=float)
    outflow_rates = jnp.asarray(outflow_rates, dtype=float)
    if rates.shape != (len(network.connections),):
        raise ValueError(
            f"rates must have shape ({len(network.connections)},), got {rates.shape}."
        )
    if outflow_rates.shape != (len(network.outlets),):
        raise ValueError(
            f"outflow_rates must have shape ({len(network.outlets)},), got {outflow_rates.shape}."
        )
    for name, value in (("rates", rates), ("outflow_rates", outflow_rates)):
        require_finite(name, value)
        array = concrete_value(value)
        if array is not None and (array < 0).any():
            raise ValueError(f"{name} must be non-negative, got {array.min():g}.")
    return rates, outflow_rates


def _assemble(
    network: CompartmentNetwork, rates: Array, outflow_rates: Array
) -> tuple[Array, Array]:
    """Transfer matrix with ``[j, i] = rate_ij`` and loss per compartment (rates + outflow)."""
    n = network.n_compartments
    transfer = jnp.zeros((n, n)).at[network.targets, network.sources].add(rates)
    loss = jnp.zeros(n).at[network.sources].add(rates)
    outflow = jnp.zeros(n).at[network.outlet_indices].add(outflow_rates)
    return transfer, loss + outflow


def generator_matrix(
    network: CompartmentNetwork,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Rate (generator) matrix ``K`` of ``dm/dt = K m + feed``: ``K[j, i] = k_ij``.

    Columns sum to minus the outflow rate of each compartment (zero for a closed network:
    mass conservation). For a discrete network the result is ``Q / dt``, the generator whose
    explicit Euler step of length dt is the network's step matrix.

    **Arguments:**

    - `network`: the structure (and default rates).
    - `rates`: connection rates in ``network.connections`` order (1/time, or per step for
      a discrete network), optional.
    - `outflow_rates`: outflow rates in ``network.outlets`` order, optional.

    **Returns:**

    Array ``(n, n)`` in 1/time.
    """
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    transfer, loss = _assemble(network, rates, outflow_rates)
    generator = transfer - jnp.diag(loss)
    return generator / network.time_step if network.is_discrete else generator


def step_matrix(
    network: CompartmentNetwork,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Expected-content step matrix ``P = I + Q`` of a discrete network: ``m_{k+1} = P m_k``.

    **Arguments:**

    - `network`: a discrete network (``time_step`` set).
    - `rates`, `outflow_rates`: per-step fractions, optional (see :func:`generator_matrix`).

    **Returns:**

    Array ``(n, n)``, dimensionless.
    """
    if not network.is_discrete:
        raise ValueError("step_matrix needs a discrete network; use network.discretised(dt).")
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    transfer, loss = _assemble(network, rates, outflow_rates)
    return jnp.eye(network.n_compartments) + transfer - jnp.diag(loss)


def outflow_vector(network: CompartmentNetwork, outflow_rates: Array) -> Array:
    """Outflow rate of every compartment (zero where there is no outlet)."""
    return jnp.zeros(network.n_compartments).at[network.outlet_indices].add(outflow_rates)


def require_open(network: CompartmentNetwork) -> None:
    """Raise unless the network has an inlet and an outlet."""
    if not network.inlets or not network.outlets:
        raise ValueError("This response needs an open network with an inlet and an outlet.")
