"""The single-start solver: the pure function that fits one curve from one start (warm-up,
then the local method), and its compiled programs shared within the process."""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.losses import LOSSES
from fitting.parameters import Layout
from fitting.solve.first_order import adam_minimise, lbfgs_minimise
from fitting.solve.levenberg_marquardt import levenberg_marquardt, weighted_evaluation
from fitting.solve.programs import Program, export_key
from fitting.solve.settings import SolverPlan


def single_start_function(model, layout: Layout, options: SolverPlan) -> Callable:
    """The pure function that fits one curve from one start (see
    :class:`~fitting.solve.MultiStartSolver`).

    ``(u0, warm, base, time, observed, weights) -> dict``: `u0` the start in unconstrained
    coordinates, `warm` whether it first takes the Adam warm-up, `base` all parameter values
    (fixed ones used), the curve and its weights (zero weight: a point that does not count,
    whatever the model gives there).
    """
    loss_function = LOSSES[options.loss]

    def predict(free_values, base, time):
        return model(time, layout.all_values(free_values, base))

    def solve(u0, warm, base, time, observed, weights):
        used = weights > 0
        if options.loss == "sse":
            scale = jnp.sum(weights * observed**2)
        else:
            scale = jnp.sum(weights * jnp.abs(observed)) / jnp.sum(weights)
        scale = jnp.where(scale > 0, scale, 1.0)

        def objective(u):
            free_values = layout.physical_from_unconstrained(u)
            residual = jnp.where(used, predict(free_values, base, time) - observed, 0.0)
            return loss_function(residual, weights) / scale

        warm_evaluations = jnp.asarray(0)
        if options.warmup_steps > 0 and options.method != "adam":
            def warm_up(u):
                u_warm, _, _, _, evaluations, _ = adam_minimise(objective, u, options,
                                                        options.warmup_steps)
                return u_warm, evaluations

            u0, warm_evaluations = jax.lax.cond(warm, warm_up,
                                                lambda u: (u, jnp.asarray(0)), u0)
        if options.method == "lm":
            root = jnp.sqrt(weights / scale)

            evaluate = weighted_evaluation(layout.physical_from_unconstrained,
                                           lambda f: predict(f, base, time), observed, root,
                                           used)

            size, count = time.shape[0], u0.shape[0]
            empty = (jnp.zeros(size), jnp.zeros((size, count)),
                     (jnp.zeros(size), jnp.zeros((size, count))))
            u, value, grad, steps, evaluations, status, (predicted, jacobian) = (
                levenberg_marquardt(evaluate, u0, empty, options))
            free_values = layout.physical_from_unconstrained(u)
        else:
            if options.method == "adam":
                u, value, grad, steps, evaluations, status = adam_minimise(objective, u0, options,
                                                                   options.max_steps)
            else:
                u, value, grad, steps, evaluations, status = lbfgs_minimise(objective, u0, options)
            free_values = layout.physical_from_unconstrained(u)
            predicted = predict(free_values, base, time)
            jacobian = jax.jacfwd(predict)(free_values, base, time)
        all_from_free = jax.jacfwd(
            lambda f: jnp.stack(list(layout.all_values(f, base).values())))(free_values)
        return {
            "u": u,
            "free_values": free_values,
            "all_values": jnp.stack(list(layout.all_values(free_values, base).values())),
            "predicted": predicted,
            "jacobian": jacobian,
            "derivative": jax.jvp(layout.physical_from_unconstrained, (u,),
                                  (jnp.ones_like(u),))[1],
            "all_from_free": all_from_free,
            "scaled_loss": value,
            "scale": scale,
            "grad_norm": jnp.linalg.norm(grad),
            "steps": steps,
            "evaluations": evaluations + warm_evaluations,
            "status": status,
        }

    return solve


#: Solver programs of this process by (model, layout, plan), most recently used last.
_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
#: Solver programs kept at most (each holds its compiled executables).
_MAX_PROGRAMS = 64


def solver_program(model, layout: Layout, options: SolverPlan) -> Program:
    """The single-start program of a model, layout and plan, shared within the process.

    A plan without warm-up runs on the program of the same plan with a warm-up when this
    process has one (the warm-up is skipped at run time, ``warm`` false), so the one-start
    refits after a multi-start fit (relative or combined errors, profiles) compile and load
    nothing new.
    """
    key = (model, layout, options)
    program = _PROGRAMS.get(key)
    if program is None and options.warmup_steps == 0:
        program = next((found for (m, lay, plan), found in reversed(_PROGRAMS.items())
                        if m is model and lay == layout
                        and dataclasses.replace(plan, warmup_steps=0) == options), None)
    if program is None:
        program = Program(single_start_function(model, layout, options),
                           f"{'lbfgs' if options.method == 'lbfgs' else 'solve'}-{model.name}",
                           export_key(model, layout, options), times=3)
        _PROGRAMS[key] = program
        while len(_PROGRAMS) > _MAX_PROGRAMS:
            _PROGRAMS.popitem(last=False)
    else:
        _PROGRAMS.move_to_end(next(k for k, v in _PROGRAMS.items() if v is program))
    return program
