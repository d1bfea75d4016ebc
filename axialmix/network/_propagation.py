"""Propagation of network states to output times: matrix exponentials or matrix powers.

The states at output times are propagated from one time to the next with ``expm(K h)``
(continuous) or ``P^k`` (discrete): one matrix for a uniform grid (then a ``lax.scan`` of
matrix–vector products), one per interval otherwise.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from .._validation import concrete_value, require_increasing_times
from ._description import CompartmentNetwork
from ._expm import expm

__all__ = [
    "continuous_states",
    "discrete_states",
    "regular_grid",
    "step_indices",
    "times_array",
    "uniform_spacing",
]


#: Times per block when each interval has its own transition matrix (see :func:`_propagate`).
BLOCK = 4096


def uniform_spacing(increments: np.ndarray | None) -> bool:
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

        def step(state, matrix):
            new = matrix @ state
            return new, new

        def propagate(state, block_increments):
            return jax.lax.scan(step, state, jax.vmap(transition)(block_increments))

        count = increments.shape[0] - 1
        if count <= BLOCK:
            _, rest = propagate(first, increments[1:])
        else:
            # One matrix per time, all at once, keeps every exponential's intermediates for
            # reverse mode (5 kB per time for four compartments). In blocks, each recomputed
            # in the backward pass, memory stays that of one block. Padding increments are
            # zero: an identity step, after the last real time.
            blocks = -(-count // BLOCK)
            padded = jnp.pad(increments[1:], (0, blocks * BLOCK - count))
            _, rest = jax.lax.scan(jax.checkpoint(propagate), first,
                                   padded.reshape(blocks, BLOCK))
            rest = rest.reshape(blocks * BLOCK, *first.shape)[:count]
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


def times_array(times: ArrayLike) -> tuple[Array, np.ndarray | None, tuple[int, ...]]:
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


def continuous_states(
    generator: Array, start: Array, times: Array, concrete: np.ndarray | None,
    regular: bool | None = None,
) -> Array:
    """``expm(K t_j) start`` for increasing times (zero-clipped: t < 0 gives ``start``).

    `regular` says what traced times are (see :func:`regular_grid`); concrete times
    choose for themselves."""
    if concrete is not None:
        steps = np.diff(np.maximum(concrete, 0.0), prepend=0.0)
        return _exponential_states(generator, start, jnp.asarray(steps), uniform_spacing(steps))
    if regular is not None and not isinstance(regular, bool):
        raise ValueError(f"regular must be True, False or None, got {regular!r}.")
    return _traced_exponential_states(generator, start, times, regular)


#: Relative spread of traced intervals below which they are propagated as one uniform grid
#: (decimal times read from a file, 0.01 s apart up to 41 s, differ by about 1e-12 of the step).
TRACED_UNIFORM_TOLERANCE = 1e-9

#: Relative spread of a grid's concrete intervals below which :func:`regular_grid` calls it
#: regular: ten times tighter than the check the program makes on the times it is given.
REGULAR_GRID_TOLERANCE = 1e-10


def regular_grid(times: ArrayLike) -> bool:
    """Whether every row of concrete `times` is a regular grid (at least three times, one
    positive spacing within a relative 1e-10).

    A program traced for such rows may say so to the curves of a continuous network
    (``regular=True`` in :func:`exit_age`, :func:`cumulative_exit_age` and
    :func:`four_compartment_exit_age`): for traced times they then compile one propagation,
    not two (a fit of a network compiles in a quarter to a half less time). What
    ``regular`` says:

    - ``None`` (default): nothing; whether traced times are uniformly spaced is known only
      when the program runs, so both propagations are compiled and one is picked then.
    - ``True``: a regular grid, possibly shifted and clipped at zero (``max(t_j - s, 0)``
      for a grid ``t_j``, as a delay makes them): one matrix exponential for the first
      positive interval and one for the spacing. Times that break it give NaN, never a
      wrong value.
    - ``False``: any increasing times: one exponential per interval (exact for a regular
      grid too).

    Concrete times choose for themselves.

    **Arguments:** `times`: times (any unit), one-dimensional or rows ``(..., samples)``.

    **Returns:** a bool.
    """
    rows = np.asarray(times, dtype=float)
    if rows.ndim == 0 or rows.shape[-1] < 3:
        return False
    steps = np.diff(rows.reshape(-1, rows.shape[-1]), axis=-1)
    first = steps[:, :1]
    return bool(np.all(np.isfinite(steps)) and np.all(first > 0)
                and np.all(np.abs(steps - first) <= REGULAR_GRID_TOLERANCE * first))


def _regular_propagate(transition: Callable[[Array], Array], start: Array,
                       increments: Array, times: Array) -> Array:
    """States after each increment for increments ``0, ..., 0, a, h, h, ..., h`` (a regular
    grid shifted and clipped at zero): `start` before the first positive increment,
    ``T(a) start`` at it and ``T(h)^k T(a) start`` k increments after it, with ``h`` the
    increment after it (``T(a)^k start`` where ``a`` is a whole increment).
    Increments of any other pattern give NaN states."""
    n = increments.shape[0]
    index = jnp.arange(n)
    first = jnp.argmax(increments > 0)
    following = increments[jnp.minimum(first + 1, n - 1)]
    # The shift that clipping undoes rounds each time by up to a few ulps of the largest.
    slack = (TRACED_UNIFORM_TOLERANCE * jnp.abs(following)
             + 16 * jnp.finfo(increments.dtype).eps * jnp.max(jnp.abs(times)))
    # A grid from t = 0 (a first increment of zero, then whole ones) is propagated as a
    # uniform grid is in :func:`_propagate`, from the state before its first whole step: the
    # same products.
    whole = (first > 0) & (jnp.abs(increments[first] - following) <= slack)
    spacing = jnp.where(whole, increments[first], following)
    origin = jnp.where(whole, first - 1, first)
    initial = jnp.where(whole, start, transition(increments[first]) @ start)
    matrix = transition(spacing)

    def step(state, _):
        new = matrix @ state
        return new, new

    _, rest = jax.lax.scan(step, initial, None, length=n - 1)
    after = jnp.concatenate([initial[None], rest], axis=0)[jnp.maximum(index - origin, 0)]
    before = (index < origin).reshape((n,) + (1,) * start.ndim)
    states = jnp.where(before, start, after)
    kept = jnp.where(index < first, increments == 0,
                     (index == first) | (jnp.abs(increments - spacing) <= slack))
    return jnp.where(jnp.all(kept), states, jnp.nan)


@partial(jax.jit, static_argnames="regular")
def _traced_exponential_states(generator: Array, start: Array, times: Array,
                               regular: bool | None = None) -> Array:
    """States at traced times: whether they are uniformly spaced is known only when the
    program runs, so both strategies are compiled and a branch picks one (one matrix
    exponential and matrix–vector products for a uniform grid: 100 times faster for a
    histogram of 4,000 bins than one exponential per interval). Under ``vmap`` the branch
    becomes a select and both run. With `regular` said (see :func:`regular_grid`) only
    the propagation it names is compiled."""
    increments = jnp.diff(jnp.maximum(times, 0.0), prepend=0.0)
    if increments.shape[0] < 3:
        return _propagate(lambda h: expm(generator * h), start, increments, False)
    if regular is not None:
        if regular:
            return _regular_propagate(lambda h: expm(generator * h), start, increments, times)
        return _propagate(lambda h: expm(generator * h), start, increments, False)
    rest = increments[1:]
    uniform = jnp.all(jnp.abs(rest - rest[0])
                      <= TRACED_UNIFORM_TOLERANCE * jnp.maximum(jnp.abs(rest[0]), 1e-300))
    return jax.lax.cond(
        uniform,
        lambda: _propagate(lambda h: expm(generator * h), start, increments, True),
        lambda: _propagate(lambda h: expm(generator * h), start, increments, False))


# Jitted with the strategy static, so that eager calls reuse the compiled propagation.
@partial(jax.jit, static_argnames="uniform")
def _exponential_states(generator: Array, start: Array, increments: Array, uniform: bool) -> Array:
    return _propagate(
        lambda h: expm(generator * h), start, increments, uniform
    )


@partial(jax.jit, static_argnames="uniform")
def _power_states(step: Array, start: Array, increments: Array, uniform: bool) -> Array:
    return _propagate(lambda k: _matrix_power(step, k), start, increments, uniform)


def step_indices(network: CompartmentNetwork, concrete: np.ndarray | None) -> np.ndarray:
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


def discrete_states(step: Array, start: Array, steps: np.ndarray) -> Array:
    """``P^{k_j} start`` for non-decreasing step counts ``k_j >= 0``."""
    increments = np.diff(steps, prepend=0)
    return _power_states(
        step, start, jnp.asarray(increments), uniform_spacing(increments.astype(float))
    )

