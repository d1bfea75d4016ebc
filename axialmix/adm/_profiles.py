"""Concentration profiles c(z, t) inside the mixer from the finite-volume solver."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from axialmix._validation import concrete_value, require_increasing_times, require_positive
from axialmix.adm._config import SolverConfig
from axialmix.adm._curves import _grid_weights, _initial_state
from axialmix.adm._solver import _step, grid_operator

__all__ = ["profiles"]


def profiles(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    inlet: str = "pulse",
    config: SolverConfig | None = None,
    substeps: int | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Return the axial concentration profiles c(z, t) after a pulse or a step at the inlet.

    The cell averages of the coarse grid of `config` (Richardson-combined with the fine grid
    when `config.richardson`). Between consecutive requested times the solver takes
    `substeps` equal steps (from t = 0 to the first time as well).

    **Arguments:**

    - `t`: times (same unit as `tau`), non-negative and strictly increasing (1-D).
    - `tau`: space time ``L / v`` (positive scalar).
    - `peclet`: Peclet number ``v L / D_z`` (positive scalar).
    - `inlet`: ``"pulse"`` (unit ideal pulse) or ``"step"`` (unit step at t = 0).
    - `config`: solver settings; None uses ``SolverConfig.for_peclet(peclet)``, which needs
      a concrete `peclet`.
    - `substeps`: steps per interval (static); None chooses them from concrete times so that
      no step exceeds ``config.max_step`` (8 when the times are traced).

    **Returns:**

    ``(x, c)``: cell centres ``x = z / L`` (cells,) and concentrations (times, cells). For a
    pulse, c is scaled so that ``∫ c dx`` over ``0 < x < 1`` is the fraction of the tracer
    still inside and the outlet value is ``tau E(t)``; for a step it is relative to the
    inlet concentration.
    """
    require_increasing_times("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    if inlet not in ("pulse", "step"):
        raise ValueError(f"inlet must be 'pulse' or 'step', got {inlet!r}")
    times = concrete_value(t)
    if times is not None and (times.ndim != 1 or (times < 0).any()):
        raise ValueError("t must be a one-dimensional array of non-negative times")
    if config is None:
        pe = concrete_value(peclet)
        if pe is None:
            raise ValueError("config must be given when peclet is traced (jit, grad, vmap)")
        config = SolverConfig.for_peclet(float(pe))
    theta = jnp.asarray(t, float) / jnp.asarray(tau, float)
    if substeps is None:
        scale = concrete_value(tau)
        if times is not None and scale is not None:
            widest = float(np.max(np.diff(np.concatenate([[0.0], times / float(scale)]))))
            substeps = max(1, math.ceil(widest / config.max_step))
        else:
            substeps = 8
    lower, diagonal, upper = grid_operator(config.grids, jnp.asarray(peclet, float))
    intervals = jnp.diff(jnp.concatenate([jnp.zeros(1), theta]))

    def advance(state, interval):
        def substep(inner, _):
            return _step(lower, diagonal, upper, inner, interval / substeps), None

        state, _ = jax.lax.scan(substep, state, None, length=substeps)
        return state, state[:, 0]

    _, states = jax.lax.scan(advance, _initial_state(config, inlet), intervals)
    if inlet == "step":
        states = states + 1.0
    cells = config.cells
    if config.richardson:
        coarse = states[:, :cells]
        fine = states[:, cells:].reshape(states.shape[0], cells, 2).mean(axis=-1)
        weights = _grid_weights(config)
        concentration = weights[0] * coarse + weights[1] * fine
    else:
        concentration = states
    centres = (jnp.arange(cells) + 0.5) / cells
    return centres, concentration
