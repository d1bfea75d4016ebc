"""Responses of the mean-field (Markov) model of a compartment network, in JAX (MODELS.md §3).

Continuous time: ``dm/dt = K m + s u(t)`` with the generator ``K[j, i] = k_ij`` (i ≠ j),
``K[i, i] = -(sum_j k_ij + k_out_i)``, feed split ``s`` and outflow ``y = k_out · m``.
Solutions use the matrix exponential: the states at output times are propagated from one
time to the next with ``expm(K h)``, one matrix for a uniform grid (then a ``lax.scan`` of
matrix–vector products), one per interval otherwise. An arbitrary inlet signal is
integrated *exactly* for its piecewise-linear interpolant, by the exponential of the
augmented matrix ``[[K, s, 0], [0, 0, 1], [0, 0, 0]]`` (first-order hold). This was chosen
over an ODE solver (diffrax): it has no step-size control or tolerance, costs one
exponential for uniformly sampled signals, is exact where the signal is linear between
samples (the convention of :mod:`axialmix.rtd`'s convolution), and its gradients are exact.

Discrete steps (the source's convention, ``network.time_step = dt``): every connection
moves the fraction ``f_ij`` of the content of i at the start of a step, and the outlet the
fraction ``q_i``, simultaneously, so the expected contents obey ``m_{k+1} = P m_k`` with
``P = I + Q``, ``Q[j, i] = f_ij``, ``Q[i, i] = -(sum_j f_ij + q_i)``. This is exactly the
expectation of the particle process, since each particle of i is moved with probability
``f_ij`` whatever happens to the others. Conventions (a particle's residence time is the
number of steps it took part in, times ``dt``):

* ``m_k`` is the content at ``t_k = k dt``, the start of step k; feed sampled at ``t_k``
  (``u(t_k) dt``) is added at ``t_k``, after the moves of step k - 1:
  ``m_k = P m_{k-1} + s u(t_k) dt``;
* what leaves during step k is reported as an outflow rate at ``t_{k+1}``:
  ``y(t_{k+1}) = q · m_k / dt``. A unit pulse at t = 0 gives ``m_0 = s`` and
  ``E(t_{k+1}) = q · P^k s / dt``, ``E(0) = 0``; then ``y = sum_i E(t - t_i) u(t_i) dt``.

With these, the mean residence time is total holdup / throughput in both conventions.
Times of a discrete network must be concrete multiples of ``dt``.

Rates: every function reads the rates from the network unless ``rates`` (one per
connection, in ``network.connections`` order) and/or ``outflow_rates`` (one per outlet)
are given; pass them to differentiate, jit or vmap over rates.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from .._validation import require_finite
from ._description import CompartmentNetwork
from ._expm import expm
from ._matrices import generator_matrix, outflow_vector, rate_arrays, require_open, step_matrix
from ._propagation import (
    continuous_states,
    discrete_states,
    step_indices,
    times_array,
    uniform_spacing,
)

__all__ = [
    "compartment_amounts",
    "cumulative_exit_age",
    "exit_age",
    "outlet_response",
    "species_fractions",
]


def exit_age(
    network: CompartmentNetwork,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
    *,
    regular: bool | None = None,
) -> Array:
    """Exit-age density ``E(t) = k_out · m(t)`` for a unit tracer pulse into the inlet(s) at t = 0.

    The pulse is split over the inlets by their feed fractions; with several outlets the
    outflows are summed. For a discrete network see the module conventions
    (``E(t_{k+1}) = q · P^k s / dt``).

    **Arguments:**

    - `network`: an open network (inlet and active outlet).
    - `times`: output times (time units), strictly increasing; E = 0 for t < 0.
    - `rates`, `outflow_rates`: optional rate arrays (see :func:`generator_matrix`).
    - `regular`: for traced times of a continuous network, whether they are a regular grid
      (possibly shifted and clipped at zero): see :func:`regular_grid`. Default: not said.

    **Returns:**

    Array of E (1/time), the shape of `times`.
    """
    require_open(network)
    times, concrete, shape = times_array(times)
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    split = jnp.asarray(network.feed_split)
    if network.is_discrete:
        steps = step_indices(network, concrete)
        step = step_matrix(network, rates, outflow_rates)
        states = discrete_states(step, split, np.maximum(steps - 1, 0))
        outflow = states @ outflow_vector(network, outflow_rates) / network.time_step
        values = jnp.where(jnp.asarray(steps) >= 1, outflow, 0.0)
    else:
        generator = generator_matrix(network, rates, outflow_rates)
        states = continuous_states(generator, split, times, concrete, regular)
        values = jnp.where(times >= 0, states @ outflow_vector(network, outflow_rates), 0.0)
    return values.reshape(shape)


def cumulative_exit_age(
    network: CompartmentNetwork,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
    *,
    regular: bool | None = None,
) -> Array:
    """Cumulative exit age ``F(t) = ∫_0^t E``: the outflow for a unit step of feed at t = 0.

    **Arguments:**

    - `network`: an open network.
    - `times`: output times, strictly increasing; F = 0 for t ≤ 0.
    - `rates`, `outflow_rates`: optional rate arrays.
    - `regular`: for traced times of a continuous network, whether they are a regular grid
      (possibly shifted and clipped at zero): see :func:`regular_grid`. Default: not said.

    **Returns:**

    Array of F (dimensionless), the shape of `times`. For a discrete network,
    ``F(t_j) = sum_{i <= j} E(t_i) dt`` (the step response with the module's conventions).
    """
    require_open(network)
    times, concrete, shape = times_array(times)
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    outflow = outflow_vector(network, outflow_rates)
    split = jnp.asarray(network.feed_split)
    n = network.n_compartments
    if network.is_discrete:
        steps = step_indices(network, concrete)
        step = step_matrix(network, rates, outflow_rates)
        # Augmented state (sum_{i<k} P^i s, P^k s): after k steps the first block holds the
        # tracer of all past pulses, whose outflow sum is F.
        augmented = jnp.block([[jnp.eye(n), jnp.eye(n)], [jnp.zeros((n, n)), step]])
        start = jnp.concatenate([jnp.zeros(n), split])
        states = discrete_states(augmented, start, steps)
        values = states[:, :n] @ outflow
    else:
        generator = generator_matrix(network, rates, outflow_rates)
        augmented = jnp.zeros((n + 1, n + 1)).at[:n, :n].set(generator).at[:n, n].set(split)
        start = jnp.zeros(n + 1).at[n].set(1.0)
        states = continuous_states(augmented, start, times, concrete, regular)
        values = jnp.where(times > 0, states[:, :n] @ outflow, 0.0)
    return values.reshape(shape)


def outlet_response(
    network: CompartmentNetwork,
    times: ArrayLike,
    inlet_signal: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Outlet tracer signal for an arbitrary sampled inlet tracer signal (``y = E * u``).

    The network starts empty at ``times[0]``. Continuous networks integrate the
    piecewise-linear interpolant of the samples exactly (augmented matrix exponential).
    Discrete networks take one sample per step (``times`` consecutive multiples of dt).
    By linearity the signal may be a tracer feed rate (the result is the outlet tracer
    flow) or an inlet concentration (the result is the outlet concentration).

    **Arguments:**

    - `network`: an open network.
    - `times`: sample times, strictly increasing.
    - `inlet_signal`: inlet signal at `times`.
    - `rates`, `outflow_rates`: optional rate arrays.

    **Returns:**

    Array, outlet signal at `times` (same units as the inlet signal).
    """
    require_open(network)
    times, concrete, shape = times_array(times)
    signal = jnp.atleast_1d(jnp.asarray(inlet_signal, dtype=float))
    if signal.shape != times.shape:
        raise ValueError(
            f"inlet_signal must have the shape of times {times.shape}, got {signal.shape}."
        )
    require_finite("inlet_signal", signal)
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    outflow = outflow_vector(network, outflow_rates)
    split = jnp.asarray(network.feed_split)
    if network.is_discrete:
        steps = step_indices(network, concrete)
        if np.any(np.diff(steps) != 1):
            raise ValueError("A discrete network needs one inlet sample per step.")
        step = step_matrix(network, rates, outflow_rates)
        feeds = split[None, :] * signal[:, None] * network.time_step
        values = _stepped_response(step, feeds, outflow / network.time_step)
        return values.reshape(shape)
    if times.shape[0] == 1:
        return jnp.zeros(shape)
    generator = generator_matrix(network, rates, outflow_rates)
    uniform = concrete is not None and uniform_spacing(np.diff(concrete, prepend=concrete[0]))
    values = _first_order_hold_response(generator, split, outflow, times, signal, uniform)
    return values.reshape(shape)


@jax.jit
def _stepped_response(step: Array, feeds: Array, outflow: Array) -> Array:
    """Outflow rates for ``m_k = P m_{k-1} + feed_k``; the outflow of step k is at t_{k+1}."""

    def advance(state, feed):
        state = step @ state + feed
        return state, state

    _, later = jax.lax.scan(advance, feeds[0], feeds[1:])
    states = jnp.concatenate([feeds[:1], later])
    return jnp.concatenate([jnp.zeros(1), states[:-1] @ outflow])


@partial(jax.jit, static_argnames="uniform")
def _first_order_hold_response(
    generator: Array, split: Array, outflow: Array, times: Array, signal: Array, uniform: bool
) -> Array:
    """Exact outflow for a piecewise-linear feed, by the augmented matrix exponential.

    On an interval of length h with feed ``u_k + g (t - t_k)``, the state ``(m, u, g)``
    obeys ``d/dt (m, u, g) = [[K, s, 0], [0, 0, 1], [0, 0, 0]] (m, u, g)``.
    """
    n = generator.shape[0]
    augmented = (
        jnp.zeros((n + 2, n + 2))
        .at[:n, :n].set(generator)
        .at[:n, n].set(split)
        .at[n, n + 1].set(1.0)
    )
    intervals = jnp.diff(times)
    # A zero-length interval (a repeated traced time) carries no slope; dividing by it would
    # give NaN and poison every later state.
    spread = intervals > 0
    slopes = jnp.where(spread, jnp.diff(signal) / jnp.where(spread, intervals, 1.0), 0.0)

    def transition(h):
        return expm(augmented * h)[:n]

    def advance(state, inputs):
        block, sample, slope = inputs
        state = block[:, :n] @ state + block[:, n] * sample + block[:, n + 1] * slope
        return state, state

    if uniform:
        block = transition(intervals[0])

        def advance_uniform(state, inputs):
            return advance(state, (block, *inputs))

        _, states = jax.lax.scan(advance_uniform, jnp.zeros(n), (signal[:-1], slopes))
    else:
        blocks = jax.vmap(transition)(intervals)
        _, states = jax.lax.scan(advance, jnp.zeros(n), (blocks, signal[:-1], slopes))
    return jnp.concatenate([jnp.zeros(1), states @ outflow])


def compartment_amounts(
    network: CompartmentNetwork,
    initial_amounts: ArrayLike,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Expected amounts in each compartment over time, without feed (batch mixing, wash-out).

    Every species obeys the same linear dynamics, so `initial_amounts` may carry a trailing
    species axis.

    **Arguments:**

    - `network`: any network (closed for a batch blender).
    - `initial_amounts`: ``(n,)`` or ``(n, n_species)`` amounts at t = 0.
    - `times`: output times ≥ 0, strictly increasing (multiples of dt if discrete).
    - `rates`, `outflow_rates`: optional rate arrays.

    **Returns:**

    Array ``(len(times), n[, n_species])`` of amounts (units of `initial_amounts`).
    """
    times, concrete, shape = times_array(times)
    if concrete is not None and (concrete < 0).any():
        raise ValueError(f"times must be non-negative, got {concrete.min():g}.")
    initial = jnp.asarray(initial_amounts, dtype=float)
    if initial.shape[:1] != (network.n_compartments,) or initial.ndim > 2:
        raise ValueError(
            f"initial_amounts must have shape ({network.n_compartments},) or "
            f"({network.n_compartments}, n_species), got {initial.shape}."
        )
    require_finite("initial_amounts", initial)
    rates, outflow_rates = rate_arrays(network, rates, outflow_rates)
    if network.is_discrete:
        states = discrete_states(
            step_matrix(network, rates, outflow_rates), initial, step_indices(network, concrete)
        )
    else:
        states = continuous_states(
            generator_matrix(network, rates, outflow_rates), initial, times, concrete
        )
    return states.reshape(shape + initial.shape)


def species_fractions(
    network: CompartmentNetwork,
    initial_amounts: ArrayLike,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Expected fraction of each species in each compartment over time (batch mixing).

    **Arguments:**

    - `network`: usually a closed network (e.g. :func:`v_blender`).
    - `initial_amounts`: ``(n, n_species)`` amounts at t = 0 (e.g. from
      :func:`loading_amounts`).
    - `times`: output times ≥ 0 (multiples of dt if discrete).
    - `rates`, `outflow_rates`: optional rate arrays.

    **Returns:**

    Array ``(len(times), n, n_species)``: amount of each species / total in the compartment.
    """
    initial = jnp.asarray(initial_amounts, dtype=float)
    if initial.ndim != 2:
        raise ValueError(f"initial_amounts must be (n, n_species), got shape {initial.shape}.")
    amounts = compartment_amounts(network, initial, times, rates, outflow_rates)
    amounts = amounts.reshape((-1,) + initial.shape)
    fractions = amounts / amounts.sum(axis=-1, keepdims=True)
    return fractions.reshape(jnp.shape(jnp.asarray(times)) + initial.shape)
