"""Outlet curves of the dimensionless ADM at the solver's time nodes, and their interpolation."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from axialmix.adm._config import SolverConfig, default_configs, peclet_level_bounds
from axialmix.adm._solver import grid_operator, propagate

__all__ = ["dimensionless_curves", "node_curves"]

_TINY = 1e-300


def _grid_weights(config: SolverConfig) -> tuple[float, ...]:
    """Weights of the grid solutions: Richardson ``(4 E_2N - E_N) / 3`` or the single grid."""
    return (-1.0 / 3.0, 4.0 / 3.0) if config.richardson else (1.0,)


def _initial_state(config: SolverConfig, inlet: str) -> jax.Array:
    """Initial state of the stacked grids: pulse ``e_1 / h`` or step deviation ``-1``."""
    parts = []
    for cells in config.grids:
        if inlet == "pulse":
            parts.append(jnp.zeros(cells).at[0].set(float(cells)))
        else:
            parts.append(-jnp.ones(cells))
    return jnp.concatenate(parts)[:, None]


@partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def node_curves(config: SolverConfig, inlet: str, peclet: jax.Array):
    """Outlet value and its theta-derivative at the time nodes of `config`.

    The Peclet derivative is computed in forward mode inside the JVP rule (with a unit
    tangent, alongside the solve), so reverse mode keeps only the sensitivities at the nodes
    instead of the states of every step (and of every resolution level under ``lax.switch``).

    **Arguments:**

    - `config`: the solver settings (static).
    - `inlet`: ``"pulse"`` (exit age E) or ``"step"`` (cumulative F).
    - `peclet`: the Peclet number (scalar).

    **Returns:**

    ``(values, slopes)`` at ``config.time_nodes()``: E and dE/dtheta, or F and dF/dtheta.
    """
    return _node_curves(config, inlet, peclet)


def _node_curves(config: SolverConfig, inlet: str, peclet: jax.Array):
    lower, diagonal, upper = grid_operator(config.grids, peclet)
    weights = _grid_weights(config)
    ends = np.cumsum(config.grids) - 1  # index of each grid's outlet cell
    upwind = [(0.5 + cells / peclet) * cells for cells in config.grids]

    def observe(state):
        value = sum(w * state[end, 0] for w, end in zip(weights, ends, strict=True))
        slope = sum(
            w * a * (state[end - 1, 0] - state[end, 0])
            for w, a, end in zip(weights, upwind, ends, strict=True)
        )
        return value, slope

    nodes = config.time_nodes()
    values, slopes = propagate(
        lower,
        diagonal,
        upper,
        _initial_state(config, inlet).astype(diagonal.dtype),
        np.diff(nodes),
        observe,
    )
    if inlet == "step":
        values = values + 1.0
    return values, slopes


@node_curves.defjvp
def _node_curves_jvp(config, inlet, primals, tangents):
    (peclet,), (peclet_dot,) = primals, tangents
    curves, sensitivities = _complex_step(lambda pe: _node_curves(config, inlet, pe), peclet)
    return curves, jax.tree.map(lambda s: s * peclet_dot, sensitivities)


def _complex_step(function, peclet):
    """Values and Peclet derivatives of a real-analytic `function` from one complex solve.

    ``f(Pe + i h) = f(Pe) + i h f'(Pe) + O(h^2)``: with h = 1e-20 Pe the real part is f and
    the imaginary part over h is f' to round-off, with no cancellation (complex-step
    differentiation). One complex pass has the operation count of one real solve.
    """
    step = 1e-20 * peclet
    shifted = function(peclet + 1j * step)
    values = jax.tree.map(jnp.real, shifted)
    derivatives = jax.tree.map(lambda z: jnp.imag(z) / step, shifted)
    return values, derivatives


def _locate(nodes: np.ndarray, theta: jax.Array):
    """Interval index, its width and the local coordinate in [0, 1] of each theta."""
    nodes = jnp.asarray(nodes)
    index = jnp.clip(jnp.searchsorted(nodes, theta, side="right") - 1, 0, nodes.shape[-1] - 2)
    left = nodes[index]
    width = jnp.diff(nodes)[index]
    local = jnp.clip((theta - left) / width, 0.0, 1.0)
    return index, width, local


def _hermite(nodes, values, slopes, theta):
    """Cubic Hermite interpolation of (values, slopes) given at `nodes`."""
    index, width, s = _locate(nodes, theta)
    y0, y1 = values[index], values[index + 1]
    m0, m1 = slopes[index] * width, slopes[index + 1] * width
    return (
        (1 + 2 * s) * (1 - s) ** 2 * y0
        + s * (1 - s) ** 2 * m0
        + s**2 * (3 - 2 * s) * y1
        + s**2 * (s - 1) * m1
    )


def _hermite_integral(nodes, values, slopes, theta):
    """Integral from 0 to theta of the cubic Hermite interpolant."""
    widths = jnp.diff(jnp.asarray(nodes))
    pieces = widths * (values[:-1] + values[1:]) / 2 + widths**2 * (slopes[:-1] - slopes[1:]) / 12
    cumulative = jnp.concatenate([jnp.zeros(1), jnp.cumsum(pieces)])
    index, width, s = _locate(nodes, theta)
    y0, y1 = values[index], values[index + 1]
    m0, m1 = slopes[index] * width, slopes[index + 1] * width
    partial = width * (
        (s - s**3 + s**4 / 2) * y0
        + (s**2 / 2 - 2 * s**3 / 3 + s**4 / 4) * m0
        + (s**3 - s**4 / 2) * y1
        + (s**4 / 4 - s**3 / 3) * m1
    )
    return cumulative[index] + partial


def _decay_rate(amount, rate_of_loss):
    """``rate_of_loss / amount`` where both are positive, else 0 (and a validity mask)."""
    valid = (amount > _TINY) & (rate_of_loss > 0)
    return jnp.where(valid, rate_of_loss / jnp.where(valid, amount, 1.0), 0.0), valid


def _safe_exprel_integral(rate, span):
    """``(1 - exp(-rate span)) / rate``, equal to ``span`` at rate 0."""
    small = rate * span < 1e-8
    safe_rate = jnp.where(small, 1.0, rate)
    return jnp.where(small, span, -jnp.expm1(-safe_rate * span) / safe_rate)


def _evaluate(config: SolverConfig, kinds: tuple[str, ...], thetas, peclet: jax.Array):
    """The dimensionless curves `kinds` (exit_age, step, ramp) at `thetas` for one config."""
    nodes = config.time_nodes()
    inlets = _inlets(kinds)
    curves = {inlet: node_curves(config, inlet, peclet) for inlet in inlets}
    return _interpolate(nodes, float(nodes[-1]), curves, kinds, thetas)


def _inlets(kinds: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(sorted({"pulse" if kind == "exit_age" else "step" for kind in kinds}))


def _interpolate(nodes, horizon, curves, kinds, thetas):
    """Evaluate the node curves at `thetas`, continuing them beyond the horizon."""
    results = []
    for kind, theta in zip(kinds, thetas, strict=True):
        values, slopes = curves["pulse" if kind == "exit_age" else "step"]
        inside = jnp.clip(theta, 0.0, horizon)
        beyond = jnp.maximum(theta - horizon, 0.0)
        last, last_slope = values[-1], slopes[-1]
        if kind == "exit_age":
            # After the horizon the slowest mode is left: E decays exponentially at its rate.
            rate, valid = _decay_rate(last, -last_slope)
            tail = jnp.where(valid, last * jnp.exp(-rate * beyond), 0.0)
            curve = jnp.where(theta > horizon, tail, _hermite(nodes, values, slopes, inside))
        elif kind == "step":
            remaining = 1.0 - last  # 1 - F at the horizon, decaying like E
            rate, valid = _decay_rate(remaining, last_slope)
            tail = 1.0 - jnp.where(valid, remaining * jnp.exp(-rate * beyond), 0.0)
            curve = jnp.where(theta > horizon, tail, _hermite(nodes, values, slopes, inside))
        else:
            remaining = 1.0 - last
            rate, valid = _decay_rate(remaining, last_slope)
            total = _hermite_integral(nodes, values, slopes, inside)
            lagging = jnp.where(valid, remaining, 0.0) * _safe_exprel_integral(rate, beyond)
            curve = total + beyond - lagging
        results.append(jnp.where(theta > 0, curve, 0.0))
    return tuple(results)


# -- default resolution chosen at run time from a traced Peclet number ----------------------
#
# Every level's node curves are padded to a common length, so one program holds them all.
# Under jit and grad, lax.switch runs only the selected level. Under vmap a switch would run
# every level for every element; the custom batching rule below runs each level once for the
# whole batch and skips (lax.cond on an unbatched predicate) the levels no element needs.
# The Peclet derivative comes from a custom JVP whose sensitivities are computed in forward
# mode by the same dispatch, so reverse mode stores no solver states.


def _padded_nodes(config: SolverConfig, length: int) -> np.ndarray:
    nodes = config.time_nodes()
    extra = nodes[-1] + np.arange(1, length - nodes.size + 1)
    return np.concatenate([nodes, extra])


def _level_table():
    configs = default_configs()
    length = max(config.time_nodes().size for config in configs)
    nodes = np.stack([_padded_nodes(config, length) for config in configs])
    horizons = np.asarray([config.time_nodes()[-1] for config in configs])
    return configs, length, nodes, horizons


def _level_index(peclet):
    bounds = jnp.asarray(peclet_level_bounds())
    return jnp.searchsorted(bounds, peclet, side="left")


def _level_solution(config, length, inlets, peclet, with_sensitivity):
    """Padded node curves of one level (and their Peclet derivatives when asked)."""

    def solve(pe):
        out = []
        for inlet in inlets:
            values, slopes = _node_curves(config, inlet, pe)
            pad = length - values.shape[0]
            out.append(jnp.pad(values, (0, pad), mode="edge"))
            out.append(jnp.pad(slopes, (0, pad), mode="edge"))
        return tuple(out)

    if not with_sensitivity:
        return solve(peclet)
    curves, sensitivities = _complex_step(solve, peclet)
    return curves + sensitivities


def _make_dispatch(inlets: tuple[str, ...], with_sensitivity: bool):
    configs, length, _, _ = _level_table()
    branches = [
        partial(_level_solution, config, length, inlets, with_sensitivity=with_sensitivity)
        for config in configs
    ]

    @jax.custom_batching.custom_vmap
    def dispatch(peclet):
        return jax.lax.switch(_level_index(peclet), branches, peclet)

    @dispatch.def_vmap
    def dispatch_batched(axis_size, in_batched, peclet):
        (batched,) = in_batched
        if not batched:
            out = jax.lax.switch(_level_index(peclet), branches, peclet)
            return out, tuple(False for _ in out)
        index = _level_index(peclet)
        shapes = jax.eval_shape(branches[0], peclet[0])
        out = tuple(jnp.zeros((axis_size, *s.shape), s.dtype) for s in shapes)
        for level, branch in enumerate(branches):
            chosen = index == level
            solved = jax.lax.cond(
                jnp.any(chosen),
                lambda pe, branch=branch: jax.vmap(branch)(pe),
                lambda pe: tuple(jnp.zeros((axis_size, *s.shape), s.dtype) for s in shapes),
                peclet,
            )
            out = tuple(
                jnp.where(chosen[:, None], new, old) for new, old in zip(solved, out, strict=True)
            )
        return out, tuple(True for _ in out)

    return dispatch


_DISPATCH = {}


def _dispatch(inlets: tuple[str, ...], with_sensitivity: bool):
    key = (inlets, with_sensitivity)
    if key not in _DISPATCH:
        _DISPATCH[key] = _make_dispatch(inlets, with_sensitivity)
    return _DISPATCH[key]


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _default_curves(inlets, peclet):
    return _dispatch(inlets, False)(peclet)


@_default_curves.defjvp
def _default_curves_jvp(inlets, primals, tangents):
    (peclet,), (peclet_dot,) = primals, tangents
    both = _dispatch(inlets, True)(peclet)
    half = len(both) // 2
    return both[:half], tuple(s * peclet_dot for s in both[half:])


def dimensionless_curves(
    kinds: tuple[str, ...], thetas: tuple[jax.Array, ...], peclet: jax.Array, config
) -> tuple[jax.Array, ...]:
    """Dimensionless exit age, step response or ramp response curves at given theta.

    With an explicit `config` that config is used. Otherwise a concrete `peclet` selects its
    default resolution level in Python, and a traced one selects it at run time (see the
    dispatch above: only the needed levels run, under jit, grad and vmap alike).

    **Arguments:**

    - `kinds`: each ``"exit_age"`` (tau E), ``"step"`` (F) or ``"ramp"`` (integral of F).
    - `thetas`: for each kind, the dimensionless times ``t / tau`` (arrays).
    - `peclet`: the Peclet number (scalar, possibly traced).
    - `config`: the solver settings, or None for the defaults.

    **Returns:**

    The curves, each of the shape of its theta.
    """
    thetas = tuple(thetas)
    if config is not None:
        return _evaluate(config, kinds, thetas, peclet)
    if not isinstance(peclet, jax.core.Tracer):
        index = int(np.searchsorted(peclet_level_bounds(), float(peclet), side="left"))
        return _evaluate(default_configs()[index], kinds, thetas, peclet)
    _, _, all_nodes, horizons = _level_table()
    index = _level_index(peclet)
    inlets = _inlets(kinds)
    flat = _default_curves(inlets, peclet)
    curves = {inlet: (flat[2 * i], flat[2 * i + 1]) for i, inlet in enumerate(inlets)}
    nodes = jnp.asarray(all_nodes)[index]
    horizon = jnp.asarray(horizons)[index]
    return _interpolate(nodes, horizon, curves, kinds, thetas)
