"""How accurate a finite-volume result is: the difference to the same solve on a refined grid."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from axialmix._validation import concrete_value
from axialmix.adm._config import SolverConfig
from axialmix.adm._outlet import exit_age, outlet_response, step_response

__all__ = ["FVErrorEstimate", "error_estimate", "refined_config"]

_RESPONSES = ("exit_age", "step", "inlet")


class FVErrorEstimate(eqx.Module):
    """A finite-volume curve with the estimate of its error from the solver's own convergence.

    The curve is solved twice: with `config` (the settings the solver uses by default) and
    on the grid of :func:`refined_config` (twice the cells, half the time steps). The solver
    is fourth order in space after its Richardson step and fifth order in time, so the
    refined curve is about 16 times more accurate and ``|values - refined|`` estimates the
    error of `values` itself (the estimate is measured against the exact solution in
    ``tests/test_adm_accuracy.py``).

    **Arguments:**

    - `values`: the curve with `config`: what :func:`~axialmix.adm.exit_age`,
      :func:`~axialmix.adm.step_response` or :func:`~axialmix.adm.outlet_response` return.
    - `refined`: the same curve on the refined grid.
    - `max_error`: ``max |values - refined|`` over the times, in the curve's unit.
    - `relative_error`: `max_error` divided by the largest ``|refined|`` (dimensionless).
    - `response`: ``"exit_age"`` (E, 1/time unit), ``"step"`` (F, dimensionless) or
      ``"inlet"`` (the outlet for a sampled inlet, the inlet's unit).
    - `cells`, `refined_cells`: the coarse grid's cells of the two solves.
    """

    values: jax.Array
    refined: jax.Array
    max_error: jax.Array
    relative_error: jax.Array
    response: str = eqx.field(static=True)
    cells: int = eqx.field(static=True)
    refined_cells: int = eqx.field(static=True)

    def to_dict(self) -> dict:
        """JSON-ready summary: the estimate, the method and the grids (no curves)."""
        return {
            "max_error": float(self.max_error),
            "relative_error": float(self.relative_error),
            "response": self.response,
            "method": "difference to the same solve on a refined grid (2x cells, "
                      "half the time steps)",
            "cells": self.cells,
            "refined_cells": self.refined_cells,
        }


def refined_config(config: SolverConfig) -> SolverConfig:
    """The settings of the refined solve of :func:`error_estimate`: twice the cells and half
    the time steps (same horizon, growth and Richardson step).

    **Arguments:** `config`: the settings to refine.

    **Returns:** a new :class:`SolverConfig`.
    """
    return SolverConfig(cells=2 * config.cells, max_step=config.max_step / 2,
                        first_step=config.first_step / 2, horizon=config.horizon,
                        richardson=config.richardson, growth=config.growth)


def error_estimate(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    response: str = "exit_age",
    inlet_times: ArrayLike | None = None,
    inlet_values: ArrayLike | None = None,
    config: SolverConfig | None = None,
) -> FVErrorEstimate:
    """A finite-volume curve and its error, estimated from the solver's own convergence.

    Solves the curve with `config` and on the grid of :func:`refined_config` and returns
    both with ``max |values - refined|`` (see :class:`FVErrorEstimate`). For reports after
    a fit or a solve: `peclet` must be concrete (not traced), and the refined solve costs
    several times a default one.

    **Arguments:**

    - `t`: times (a strictly increasing 1-D array or a scalar; the unit of `tau`).
    - `tau`: space time ``L / v`` (positive scalar).
    - `peclet`: Peclet number ``v L / D_z`` (positive concrete scalar).
    - `response`: ``"exit_age"`` (E), ``"step"`` (F) or ``"inlet"`` (with `inlet_times`
      and `inlet_values`, as :func:`~axialmix.adm.outlet_response`).
    - `config`: the settings whose accuracy is estimated; None: the default for `peclet`
      (:meth:`SolverConfig.for_peclet`, which is what the solver uses by default).

    **Returns:** an :class:`FVErrorEstimate`.
    """
    if response not in _RESPONSES:
        raise ValueError(f"response must be one of {', '.join(_RESPONSES)}, got {response!r}")
    value = concrete_value(peclet)
    if value is None:
        raise ValueError("peclet must be concrete for an error estimate (not traced)")
    if config is None:
        exit_age(jnp.ones(1), 1.0, peclet)  # the default's own range check, with its message
        config = SolverConfig.for_peclet(float(value))
    if response == "inlet" and (inlet_times is None or inlet_values is None):
        raise ValueError("response 'inlet' needs inlet_times and inlet_values")
    finer = refined_config(config)

    def solve(settings: SolverConfig) -> jax.Array:
        if response == "exit_age":
            return exit_age(t, tau, peclet, config=settings)
        if response == "step":
            return step_response(t, tau, peclet, config=settings)
        return outlet_response(t, tau, peclet, inlet_times, inlet_values, config=settings)

    values, refined = solve(config), solve(finer)
    max_error = jnp.max(jnp.abs(values - refined))
    peak = jnp.max(jnp.abs(refined))
    relative = jnp.where(peak > 0, max_error / jnp.where(peak > 0, peak, 1.0), np.nan)
    return FVErrorEstimate(values, refined, max_error, relative, response, config.cells,
                           finer.cells)
