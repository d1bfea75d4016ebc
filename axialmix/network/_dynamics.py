"""The mean-field (Markov) model of a compartment network, in JAX (MODELS.md §3).

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

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from .._validation import concrete_value, require_finite, require_increasing_times
from ._description import CompartmentNetwork

__all__ = [
    "compartment_amounts",
    "cumulative_exit_age",
    "exit_age",
    "four_compartment_exit_age",
    "four_compartment_generator",
    "generator_matrix",
    "outlet_response",
    "residence_time_moments",
    "species_fractions",
    "step_matrix",
]

# Scaling and squaring with the degree-13 Pade approximant (Higham 2005, the choice of
# scipy.linalg.expm for large norms), written without the degree-selecting branches of
# jax.scipy.linalg.expm: it compiles about a third faster, which matters because every new
# (compartments, output times) shape compiles the propagation once. Accuracy: relative error
# near 1e-15 for moderate norms (tested against scipy). Norms above THETA_13 * 2**24 (~9e7,
# e.g. a rate of 1e5 / s over 900 s in one interval) give NaN rather than a wrong answer.
_PADE_13 = (
    64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
    40840800.0, 960960.0, 16380.0, 182.0, 1.0,
)
_THETA_13 = 5.371920351148152
_MAX_SQUARINGS = 24


def _expm(matrix: Array) -> Array:
    """Matrix exponential (scaling and squaring, Pade 13); differentiable, jit/vmap clean."""
    b = _PADE_13
    norm = jnp.max(jnp.sum(jnp.abs(matrix), axis=0))
    squarings = jax.lax.stop_gradient(
        jnp.maximum(0.0, jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / _THETA_13)))
    )
    a1 = matrix / 2.0**squarings
    identity = jnp.eye(matrix.shape[0], dtype=matrix.dtype)
    a2 = a1 @ a1
    a4 = a2 @ a2
    a6 = a4 @ a2
    u = a1 @ (
        a6 @ (b[13] * a6 + b[11] * a4 + b[9] * a2)
        + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * identity
    )
    v = a6 @ (b[12] * a6 + b[10] * a4 + b[8] * a2) + b[6] * a6 + b[4] * a4 + b[2] * a2 + (
        b[0] * identity
    )
    result = jnp.linalg.solve(v - u, v + u)

    def square(current, index):
        return jnp.where(index < squarings, current @ current, current), None

    result, _ = jax.lax.scan(square, result, jnp.arange(_MAX_SQUARINGS, dtype=matrix.dtype))
    return jnp.where(squarings > _MAX_SQUARINGS, jnp.nan, result)


# ------------------------------------------------------------------ matrices
def _rate_arrays(
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


def _outflow_vector(network: CompartmentNetwork, outflow_rates: Array) -> Array:
    return jnp.zeros(network.n_compartments).at[network.outlet_indices].add(outflow_rates)


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
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
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
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    transfer, loss = _assemble(network, rates, outflow_rates)
    return jnp.eye(network.n_compartments) + transfer - jnp.diag(loss)


def four_compartment_generator(
    k_f: ArrayLike, k_r: ArrayLike, k_s: ArrayLike, k_out: ArrayLike
) -> Array:
    """Generator ``K`` of the four-compartment model (MODELS.md §3), rows C1 … C4.

    **Arguments:**

    - `k_f`, `k_r`, `k_s`, `k_out`: scalar rates (1/time).

    **Returns:**

    Array ``(4, 4)``; ``dm/dt = K m`` plus the feed into C1.
    """
    k_f, k_r, k_s, k_out = (jnp.asarray(x, dtype=float) for x in (k_f, k_r, k_s, k_out))
    zero = jnp.zeros_like(k_f)
    return jnp.stack(
        [
            jnp.stack([-(k_f + k_s), k_r, k_s, zero]),
            jnp.stack([k_f, -(k_r + k_s), zero, k_s]),
            jnp.stack([k_s, zero, -(k_f + k_s), k_r]),
            jnp.stack([zero, k_s, k_f, -(k_s + k_r + k_out)]),
        ]
    )


# ------------------------------------------------------------------ propagation
def _uniform_spacing(increments: np.ndarray | None) -> bool:
    if increments is None or increments.size < 3:
        return False
    rest = increments[1:]
    return bool(np.all(np.abs(rest - rest[0]) <= 1e-12 * max(abs(rest[0]), 1e-300)))


def _propagate(
    transition: Callable[[Array], Array],
    start: Array,
    increments: Array,
    uniform: bool,
) -> Array:
    """States after each increment: ``x_0 = T(inc_0) start``, ``x_j = T(inc_j) x_{j-1}``."""
    first = transition(increments[0]) @ start
    if increments.shape[0] == 1:
        return first[None]
    if uniform:
        matrix = transition(increments[1])

        def step(state, _):
            new = matrix @ state
            return new, new

        _, rest = jax.lax.scan(step, first, None, length=increments.shape[0] - 1)
    else:
        matrices = jax.vmap(transition)(increments[1:])

        def step(state, matrix):
            new = matrix @ state
            return new, new

        _, rest = jax.lax.scan(step, first, matrices)
    return jnp.concatenate([first[None], rest], axis=0)


def _matrix_power(matrix: Array, exponent: Array) -> Array:
    """``matrix ** exponent`` for a (possibly traced) non-negative integer, by squaring."""
    exponent = jnp.asarray(exponent, dtype=jnp.int64)

    def body(carry, _):
        result, base, k = carry
        result = jnp.where(k % 2 == 1, result @ base, result)
        return (result, base @ base, k // 2), None

    identity = jnp.eye(matrix.shape[0], dtype=matrix.dtype)
    (result, _, _), _ = jax.lax.scan(body, (identity, matrix, exponent), None, length=62)
    return result


def _times_array(times: ArrayLike) -> tuple[Array, np.ndarray | None, tuple[int, ...]]:
    """Times as a 1-D JAX array, as NumPy when concrete (None when traced), and their shape.

    The NumPy copy is taken before any JAX operation: inside ``jit`` every ``jnp`` result
    is a tracer, and the concrete times decide the propagation strategy.
    """
    concrete = concrete_value(times)
    if concrete is not None:
        concrete = np.atleast_1d(concrete.astype(float))
    array = jnp.atleast_1d(jnp.asarray(times, dtype=float))
    shape = np.shape(times) if concrete is not None else jnp.shape(times)
    if len(shape) > 1:
        raise ValueError(f"times must be a scalar or one-dimensional, got shape {shape}.")
    require_increasing_times("times", concrete if concrete is not None else array)
    return array, concrete, shape


def _continuous_states(
    generator: Array, start: Array, times: Array, concrete: np.ndarray | None
) -> Array:
    """``expm(K t_j) start`` for increasing times (zero-clipped: t < 0 gives ``start``)."""
    if concrete is not None:
        steps = np.diff(np.maximum(concrete, 0.0), prepend=0.0)
        return _exponential_states(generator, start, jnp.asarray(steps), _uniform_spacing(steps))
    return _exponential_states(
        generator, start, jnp.diff(jnp.maximum(times, 0.0), prepend=0.0), False
    )


# Jitted with the strategy static, so that eager calls reuse the compiled propagation.
@partial(jax.jit, static_argnames="uniform")
def _exponential_states(generator: Array, start: Array, increments: Array, uniform: bool) -> Array:
    return _propagate(
        lambda h: _expm(generator * h), start, increments, uniform
    )


@partial(jax.jit, static_argnames="uniform")
def _power_states(step: Array, start: Array, increments: Array, uniform: bool) -> Array:
    return _propagate(lambda k: _matrix_power(step, k), start, increments, uniform)


def _step_indices(network: CompartmentNetwork, concrete: np.ndarray | None) -> np.ndarray:
    if concrete is None:
        raise ValueError(
            "Times of a discrete network must be concrete (not traced): they select steps."
        )
    steps = concrete / network.time_step
    rounded = np.rint(steps)
    off = np.abs(steps - rounded) > 1e-9 * np.maximum(1.0, np.abs(steps))
    if np.any(off):
        raise ValueError(
            f"times must be multiples of the time step {network.time_step:g}; "
            f"got {concrete[np.argmax(off)]:g}."
        )
    return rounded.astype(np.int64)


def _discrete_states(step: Array, start: Array, steps: np.ndarray) -> Array:
    """``P^{k_j} start`` for non-decreasing step counts ``k_j >= 0``."""
    increments = np.diff(steps, prepend=0)
    return _power_states(
        step, start, jnp.asarray(increments), _uniform_spacing(increments.astype(float))
    )


# ------------------------------------------------------------------ responses
def exit_age(
    network: CompartmentNetwork,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Exit-age density ``E(t) = k_out · m(t)`` for a unit tracer pulse into the inlet(s) at t = 0.

    The pulse is split over the inlets by their feed fractions; with several outlets the
    outflows are summed. For a discrete network see the module conventions
    (``E(t_{k+1}) = q · P^k s / dt``).

    **Arguments:**

    - `network`: an open network (inlet and active outlet).
    - `times`: output times (time units), strictly increasing; E = 0 for t < 0.
    - `rates`, `outflow_rates`: optional rate arrays (see :func:`generator_matrix`).

    **Returns:**

    Array of E (1/time), the shape of `times`.
    """
    _require_open(network)
    times, concrete, shape = _times_array(times)
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    split = jnp.asarray(network.feed_split)
    if network.is_discrete:
        steps = _step_indices(network, concrete)
        step = step_matrix(network, rates, outflow_rates)
        states = _discrete_states(step, split, np.maximum(steps - 1, 0))
        outflow = states @ _outflow_vector(network, outflow_rates) / network.time_step
        values = jnp.where(jnp.asarray(steps) >= 1, outflow, 0.0)
    else:
        generator = generator_matrix(network, rates, outflow_rates)
        states = _continuous_states(generator, split, times, concrete)
        values = jnp.where(times >= 0, states @ _outflow_vector(network, outflow_rates), 0.0)
    return values.reshape(shape)


def cumulative_exit_age(
    network: CompartmentNetwork,
    times: ArrayLike,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> Array:
    """Cumulative exit age ``F(t) = ∫_0^t E``: the outflow for a unit step of feed at t = 0.

    **Arguments:**

    - `network`: an open network.
    - `times`: output times, strictly increasing; F = 0 for t ≤ 0.
    - `rates`, `outflow_rates`: optional rate arrays.

    **Returns:**

    Array of F (dimensionless), the shape of `times`. For a discrete network,
    ``F(t_j) = sum_{i <= j} E(t_i) dt`` (the step response with the module's conventions).
    """
    _require_open(network)
    times, concrete, shape = _times_array(times)
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    outflow = _outflow_vector(network, outflow_rates)
    split = jnp.asarray(network.feed_split)
    n = network.n_compartments
    if network.is_discrete:
        steps = _step_indices(network, concrete)
        step = step_matrix(network, rates, outflow_rates)
        # Augmented state (sum_{i<k} P^i s, P^k s): after k steps the first block holds the
        # tracer of all past pulses, whose outflow sum is F.
        augmented = jnp.block([[jnp.eye(n), jnp.eye(n)], [jnp.zeros((n, n)), step]])
        start = jnp.concatenate([jnp.zeros(n), split])
        states = _discrete_states(augmented, start, steps)
        values = states[:, :n] @ outflow
    else:
        generator = generator_matrix(network, rates, outflow_rates)
        augmented = jnp.zeros((n + 1, n + 1)).at[:n, :n].set(generator).at[:n, n].set(split)
        start = jnp.zeros(n + 1).at[n].set(1.0)
        states = _continuous_states(augmented, start, times, concrete)
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
    _require_open(network)
    times, concrete, shape = _times_array(times)
    signal = jnp.atleast_1d(jnp.asarray(inlet_signal, dtype=float))
    if signal.shape != times.shape:
        raise ValueError(
            f"inlet_signal must have the shape of times {times.shape}, got {signal.shape}."
        )
    require_finite("inlet_signal", signal)
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    outflow = _outflow_vector(network, outflow_rates)
    split = jnp.asarray(network.feed_split)
    if network.is_discrete:
        steps = _step_indices(network, concrete)
        if np.any(np.diff(steps) != 1):
            raise ValueError("A discrete network needs one inlet sample per step.")
        step = step_matrix(network, rates, outflow_rates)
        feeds = split[None, :] * signal[:, None] * network.time_step
        values = _stepped_response(step, feeds, outflow / network.time_step)
        return values.reshape(shape)
    if times.shape[0] == 1:
        return jnp.zeros(shape)
    generator = generator_matrix(network, rates, outflow_rates)
    uniform = concrete is not None and _uniform_spacing(np.diff(concrete, prepend=concrete[0]))
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
    slopes = jnp.diff(signal) / intervals

    def transition(h):
        return _expm(augmented * h)[:n]

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
    times, concrete, shape = _times_array(times)
    if concrete is not None and (concrete < 0).any():
        raise ValueError(f"times must be non-negative, got {concrete.min():g}.")
    initial = jnp.asarray(initial_amounts, dtype=float)
    if initial.shape[:1] != (network.n_compartments,) or initial.ndim > 2:
        raise ValueError(
            f"initial_amounts must have shape ({network.n_compartments},) or "
            f"({network.n_compartments}, n_species), got {initial.shape}."
        )
    require_finite("initial_amounts", initial)
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    if network.is_discrete:
        states = _discrete_states(
            step_matrix(network, rates, outflow_rates), initial, _step_indices(network, concrete)
        )
    else:
        states = _continuous_states(
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
    _require_open(network)
    rates, outflow_rates = _rate_arrays(network, rates, outflow_rates)
    outflow = _outflow_vector(network, outflow_rates)
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


def four_compartment_exit_age(
    t: ArrayLike, k_f: ArrayLike, k_r: ArrayLike, k_s: ArrayLike, k_out: ArrayLike
) -> Array:
    """Exit age of the four-compartment model for a unit pulse into C1 (fast, for fitting).

    ``E(t) = k_out · [expm(K t) e_1]_4`` with ``K`` from :func:`four_compartment_generator`;
    the same curve as ``exit_age(four_compartment(k_f, k_r, k_s, k_out), t)`` without
    building a network, so it jits, differentiates and vmaps over the parameters. Rates may
    be zero (no validation error for an unreachable outlet: E is then 0).

    **Arguments:**

    - `t`: output times (time units), strictly increasing; E = 0 for t < 0.
    - `k_f`, `k_r`, `k_s`, `k_out`: scalar rates (1/time), non-negative.

    **Returns:**

    Array of E (1/time), the shape of `t`.
    """
    for name, value in (("k_f", k_f), ("k_r", k_r), ("k_s", k_s), ("k_out", k_out)):
        require_finite(name, value)
        array = concrete_value(value)
        if array is not None and (array < 0).any():
            raise ValueError(f"{name} must be non-negative, got {array.min():g}.")
    times, concrete, shape = _times_array(t)
    generator = four_compartment_generator(k_f, k_r, k_s, k_out)
    states = _continuous_states(generator, jnp.zeros(4).at[0].set(1.0), times, concrete)
    return jnp.where(times >= 0, jnp.asarray(k_out, dtype=float) * states[:, 3], 0.0).reshape(shape)


def _require_open(network: CompartmentNetwork) -> None:
    if not network.inlets or not network.outlets:
        raise ValueError("This response needs an open network with an inlet and an outlet.")
