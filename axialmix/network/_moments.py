"""Exact moments of a network's exit-age distribution, by linear solves (MODELS.md §3)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ._description import CompartmentNetwork
from ._matrices import generator_matrix, outflow_vector, rate_arrays, require_open, step_matrix

__all__ = ["ResidenceTimeMoments", "residence_time_moments"]


class ResidenceTimeMoments(NamedTuple):
    """Exact moments of a network's exit-age distribution."""

    total: Array
    """∫ E dt: 1 when every tracer leaves through the outlets."""
    mean: Array
    """Mean residence time (time units)."""
    variance: Array
    """Variance of the residence time (time²)."""


def residence_time_moments(
    network: CompartmentNetwork,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> ResidenceTimeMoments:
    """Exact zeroth, first and central second moments of E(t), by linear solves.

    Continuous: with ``A = -K``, ``∫E = k·A⁻¹s``, ``mean = k·A⁻²s``, ``∫t²E = 2 k·A⁻³s``.
    Discrete (module conventions): ``∫E = q·(I-P)⁻¹s``, ``mean = dt q·(I-P)⁻²s``,
    ``∫t²E = dt² q·(I+P)(I-P)⁻³s``. In both, the mean equals total holdup / throughput for
    steady holdups.

    **Arguments:**

    - `network`: an open network.
    - `rates`, `outflow_rates`: optional rate arrays.

    **Returns:**

    :class:`ResidenceTimeMoments` ``(total, mean, variance)``.
    """
    require_open(network)
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    outflow = outflow_vector(network, outflow_rates)
    split = jnp.asarray(network.feed_split)
    if network.is_discrete:
        step = step_matrix(network, rates, outflow_rates)
        resolvent = jnp.eye(network.n_compartments) - step
        x1 = jnp.linalg.solve(resolvent, split)
        x2 = jnp.linalg.solve(resolvent, x1)
        x3 = jnp.linalg.solve(resolvent, x2)
        dt = network.time_step
        total = outflow @ x1
        mean = dt * outflow @ x2
        second = dt**2 * outflow @ (x3 + step @ x3)
    else:
        resolvent = -generator_matrix(network, rates, outflow_rates)
        x1 = jnp.linalg.solve(resolvent, split)
        x2 = jnp.linalg.solve(resolvent, x1)
        x3 = jnp.linalg.solve(resolvent, x2)
        total = outflow @ x1
        mean = outflow @ x2
        second = 2 * outflow @ x3
    return ResidenceTimeMoments(total, mean, second / total - (mean / total) ** 2)
