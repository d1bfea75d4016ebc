"""The full Hessian of least squares: its compiled program, Newton's polish where
Levenberg–Marquardt stops on a singular Gauss–Newton curvature, and the second-order
distance to a minimum that decides whether such a fit converged."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.parameters import Layout
from fitting.solve.padding import pad_curve, padded_length
from fitting.solve.programs import Program, export_key, run_program
from fitting.solve.status import SECOND_ORDER_DISTANCE


@functools.lru_cache(maxsize=64)
def curvature_program(model, layout: Layout) -> Program:
    """The program of ``(value, gradient, Hessian)`` of ``Σ w r²`` in the free parameters
    (zero weights: points that do not count), the model held once."""

    def sse(free_values, base, time, observed, weights):
        values = layout.all_values(free_values, base)
        residual = jnp.where(weights > 0, model(time, values) - observed, 0.0)
        return jnp.sum(weights * residual**2)

    def gradient_and_value(*arguments):
        value, gradient = jax.value_and_grad(sse)(*arguments)
        return gradient, (value, gradient)

    def curvature(*arguments):
        hessian, (value, gradient) = jax.jacfwd(gradient_and_value, has_aux=True)(*arguments)
        return value, gradient, hessian

    return Program(curvature, f"curvature-{model.name}", export_key(model, layout), times=2)


@functools.lru_cache(maxsize=64)
def compiled_curvature(model, layout: Layout) -> Callable:
    """``(value, gradient, Hessian)`` of ``Σ w r²`` in the free parameters, compiled.

    **Arguments:** the model and its layout.

    **Returns:** a function of ``(free_values, base, time, observed, weights)`` returning NumPy
    arrays (the curve padded like the solver's, with zero weights).
    """

    program = curvature_program(model, layout)

    def run(free_values, base, time, observed, weights):
        size = np.asarray(time).shape[0]
        arguments = (np.asarray(free_values, dtype=float), np.asarray(base, dtype=float),
                     *pad_curve(time, observed, weights, padded_length(size)))
        executable, _ = program.executable(arguments)
        return jax.device_get(executable(*arguments))

    return run


#: Newton iterations (full Hessian) at most, where Levenberg–Marquardt stops on a singular
#: Gauss–Newton curvature.
_NEWTON_STEPS = 10


def _inside(layout: Layout, free_values: np.ndarray) -> bool:
    """Whether free parameter values lie strictly inside their bounds."""
    for j, kind in enumerate(layout.kinds):
        if kind in ("lower", "both") and not free_values[j] > layout.lower[j]:
            return False
        if kind in ("upper", "both") and not free_values[j] < layout.upper[j]:
            return False
    return True


def newton_polish(model, layout: Layout, solver: Program, out: dict, base, padded,
                  times: list[float]) -> dict | None:
    """Newton's method with the full Hessian from `out`'s end, then Levenberg–Marquardt
    again from there (for its outputs); ``None`` where the Hessian is not positive
    definite at the start. Its evaluations and steps include the Newton iterations.

    **Arguments:** the model and its layout; `solver`: their single-start program (see
    :func:`fitting.solve.single_start.solver_program`); `out`: the outputs of the start to
    polish; `base`: all parameter values (fixed ones used); `padded`: the curve's times,
    observed values and weights, padded (:func:`~fitting.solve.padding.pad_curve`);
    `times`: the run and compile seconds so far, added to.

    **Returns:** the outputs of `solver` from the polished point, or ``None``.
    """
    program = curvature_program(model, layout)
    free = np.asarray(out["free_values"], dtype=float)
    value, gradient, hessian = run_program(program, (free, base, *padded), times)
    evaluations = iterations = 1
    while iterations <= _NEWTON_STEPS:
        if not (np.isfinite(value) and np.all(np.isfinite(gradient))
                and np.all(np.isfinite(hessian))):
            break
        hessian = 0.5 * (hessian + hessian.T)
        eigenvalues = np.linalg.eigvalsh(hessian)
        if eigenvalues[0] <= 1e-12 * max(eigenvalues[-1], 1e-300):
            if iterations == 1:
                return None
            break
        step = -np.linalg.solve(hessian, gradient)
        if -float(gradient @ step) <= 1e-15 * value:  # at the precision of the loss
            break
        for _ in range(30):  # halve into the bounds and onto a decrease
            candidate = free + step
            if _inside(layout, candidate):
                new = run_program(program, (candidate, base, *padded), times)
                evaluations += 1
                if new[0] <= value:
                    break
            step = 0.5 * step
        else:
            break
        free, (value, gradient, hessian) = candidate, new
        iterations += 1
    u = layout.unconstrained_from_physical(free)
    again = run_program(solver, (u, np.asarray(False), base, *padded), times)
    again["evaluations"] = int(again["evaluations"]) + evaluations
    again["steps"] = int(again["steps"]) + iterations
    return again


def second_order_distance(model, layout: Layout, free_values, base, time, observed, weights,
                          sse: float, dof: float) -> tuple[float, tuple[str, ...]]:
    """Newton's distance to the nearest minimum in standard errors, and the bounds it lies on.

    Near a minimum ``SSE(p) ≈ SSE* + ½ (p - p*)ᵀ H (p - p*)``, so Newton's method predicts
    ``SSE - SSE* = ½ gᵀ H⁻¹ g``; divided by ``s² = SSE / dof`` this is the squared distance
    to the minimum in the metric of the standard errors (exact for a linear model). A
    parameter whose gradient pushes it onto a bound it (nearly) sits on — Newton's step in
    that parameter alone (``|g_j| / H_jj``) reaches the bound, and the loss falls by less
    than ``SECOND_ORDER_DISTANCE² s²`` when it goes there — is taken as on that bound: it
    adds that fall, and the others are checked on their own.

    **Arguments:** the model and layout of a fit, the free values at its end, the base
    (fixed) values, the data (`time`, `observed`, `weights`), its ``Σ w r²`` and degrees of
    freedom.

    **Returns:** ``(distance, names on a bound)``; ``(inf, ())`` when the free parameters'
    Hessian is not positive definite.
    """
    _, gradient, hessian = compiled_curvature(model, layout)(free_values, base, time,
                                                             observed, weights)
    gradient, hessian = np.asarray(gradient), np.asarray(hessian)
    values = np.asarray(free_values, dtype=float)
    if not (np.all(np.isfinite(gradient)) and np.all(np.isfinite(hessian))):
        return math.inf, ()
    variance = sse / dof
    small = SECOND_ORDER_DISTANCE**2 * variance
    on_bound, fall = [], 0.0
    for j, kind in enumerate(layout.kinds):
        if kind in ("lower", "both") and gradient[j] > 0:
            reach = values[j] - layout.lower[j]
        elif kind in ("upper", "both") and gradient[j] < 0:
            reach = layout.upper[j] - values[j]
        else:
            continue
        gain = abs(gradient[j]) * reach
        if gain <= small and abs(gradient[j]) >= hessian[j, j] * reach:
            on_bound.append(j)
            fall += gain
    inside = [j for j in range(values.size) if j not in on_bound]
    if inside:
        block = hessian[np.ix_(inside, inside)]
        block = 0.5 * (block + block.T)
        eigenvalues = np.linalg.eigvalsh(block)
        if eigenvalues[0] <= 1e-12 * max(eigenvalues[-1], 1e-300):
            return math.inf, ()
        fall += 0.5 * float(gradient[inside] @ np.linalg.solve(block, gradient[inside]))
    return math.sqrt(max(fall, 0.0) / variance), tuple(layout.free[j] for j in on_bound)
