"""First-order minimisers of a scalar loss in a :func:`jax.lax.while_loop`: L-BFGS with a
zoom line search, and Adam at a fixed learning rate (also the random starts' warm-up)."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.solve.settings import SolverPlan
from fitting.solve.status import RUNNING


def lbfgs_minimise(objective: Callable, u0, options: SolverPlan):
    """Minimise `objective` from `u0` with optax L-BFGS + zoom line search in a while_loop."""
    import optax  # only L-BFGS and Adam need it (a fifth of a second to import)

    solver = optax.lbfgs(
        memory_size=options.memory_size,
        linesearch=optax.scale_by_zoom_linesearch(
            max_linesearch_steps=20, initial_guess_strategy="one"
        ),
    )
    value0, grad0 = jax.value_and_grad(objective)(u0)

    def step(carry):
        u, state, value, grad, count, evaluations, _ = carry
        updates, state = solver.update(
            grad, state, u, value=value, grad=grad, value_fn=objective
        )
        candidate = optax.apply_updates(u, updates)
        new_value = optax.tree.get(state, "value")
        new_grad = optax.tree.get(state, "grad")
        evaluations = evaluations + optax.tree.get(state, "num_linesearch_steps")
        finite = jnp.isfinite(new_value) & jnp.all(jnp.isfinite(new_grad))
        decreased = finite & (new_value <= value)
        u_next = jnp.where(decreased, candidate, u)
        value_next = jnp.where(decreased, new_value, value)
        grad_next = jnp.where(decreased, new_grad, grad)
        relative_change = (value - value_next) / jnp.maximum(jnp.abs(value), 1e-300)
        count = count + 1
        status = jnp.select(
            [
                ~jnp.isfinite(value_next),
                jnp.linalg.norm(grad_next) <= options.tol,
                ~decreased,
                relative_change <= options.ftol,
                count >= options.max_steps,
            ],
            [4, 0, 3, 1, 2],
            default=RUNNING,
        )
        return u_next, state, value_next, grad_next, count, evaluations, status

    initial_status = jnp.where(
        ~jnp.isfinite(value0), 4, jnp.where(jnp.linalg.norm(grad0) <= options.tol, 0, RUNNING)
    )
    carry = (u0, solver.init(u0), value0, grad0, jnp.asarray(0), jnp.asarray(1), initial_status)
    u, _, value, grad, count, evaluations, status = jax.lax.while_loop(
        lambda c: c[-1] == RUNNING, step, carry
    )
    return u, value, grad, count, evaluations, status


def adam_minimise(objective: Callable, u0, options: SolverPlan, max_steps: int):
    """Minimise `objective` with Adam for at most `max_steps`; returns the best point seen."""
    import optax  # only L-BFGS and Adam need it (a fifth of a second to import)

    solver = optax.adam(options.learning_rate)
    value_and_grad = jax.value_and_grad(objective)

    def step(carry):
        u, state, best_u, best_value, best_grad, count, _ = carry
        value, grad = value_and_grad(u)
        improved = jnp.isfinite(value) & (value < best_value)
        best_u = jnp.where(improved, u, best_u)
        best_grad = jnp.where(improved, grad, best_grad)
        best_value = jnp.where(improved, value, best_value)
        safe_grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        updates, state = solver.update(safe_grad, state, u)
        count = count + 1
        status = jnp.select(
            [jnp.linalg.norm(best_grad) <= options.tol, count >= max_steps],
            [0, 2],
            default=RUNNING,
        )
        return optax.apply_updates(u, updates), state, best_u, best_value, best_grad, count, status

    carry = (u0, solver.init(u0), u0, jnp.asarray(jnp.inf), jnp.full_like(u0, jnp.inf),
             jnp.asarray(0), jnp.asarray(RUNNING if max_steps > 0 else 2))
    _, _, u, value, grad, count, status = jax.lax.while_loop(
        lambda c: c[-1] == RUNNING, step, carry
    )
    status = jnp.where(jnp.isfinite(value), status, 4)
    return u, value, grad, count, count, status
