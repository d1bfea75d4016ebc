"""The Levenberg–Marquardt loop for least squares: damped Gauss–Newton steps in the
unconstrained coordinates, solved by a Cholesky factorisation written in JAX, in a
:func:`jax.lax.while_loop`."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.solve.settings import SolverPlan
from fitting.solve.status import RUNNING


def _cholesky_solve(matrix, vector):
    """Solve ``matrix x = vector`` for a small symmetric positive definite `matrix`.

    A Cholesky factorisation and two triangular solves, each a ``fori_loop`` over columns:
    no LAPACK call (whose first use on the CPU imports SciPy), and a traced size that does
    not grow with the dimension. A matrix that is not positive definite gives NaN.
    """
    size = matrix.shape[0]
    index = jnp.arange(size)

    def factor_column(j, lower):
        column = matrix[:, j] - lower @ lower[j]
        pivot = jnp.sqrt(column[j])
        return lower.at[:, j].set(
            jnp.where(index > j, column / pivot, jnp.where(index == j, pivot, 0.0)))

    lower = jax.lax.fori_loop(0, size, factor_column, jnp.zeros_like(matrix))

    def forward(i, partial):
        return partial.at[i].set((vector[i] - lower[i] @ partial) / lower[i, i])

    partial = jax.lax.fori_loop(0, size, forward, jnp.zeros_like(vector))

    def backward(k, solution):
        i = size - 1 - k
        return solution.at[i].set((partial[i] - lower[:, i] @ solution) / lower[i, i])

    return jax.lax.fori_loop(0, size, backward, jnp.zeros_like(vector))


#: Levenberg-Marquardt's damping at the start (relative to the largest diagonal entry of JᵀJ).
_INITIAL_DAMPING = 1e-3
#: Damping past which no step can decrease the loss at float64 precision.
_MAX_DAMPING = 1e16
#: Accepted steps in a row, each changing the loss by less than ``ftol``, after which
#: Levenberg-Marquardt stops even though its steps are longer than ``xtol`` (a loss falling
#: ever more slowly towards a bound or along a flat valley); the post-check then decides.
_STALLED_STEPS = 3
#: Levenberg-Marquardt gives up (status SLOW) when the loss falls by less than _SLOW_FALL of
#: itself over _SLOW_STEPS iterations: a crawl along a curved valley (e.g. towards a rate of
#: zero) that it would follow only in hundreds of steps.
_SLOW_STEPS = 20
_SLOW_FALL = 1e-3
#: Largest change of an unconstrained coordinate in one Levenberg-Marquardt step (a factor
#: e for a positive parameter): a poorly determined parameter (e.g. a Peclet number whose
#: curve barely changes towards zero) does not leap across decades in one Gauss-Newton step
#: onto a plateau of the loss.
_MAX_STEP = 1.0


def weighted_residuals(predicted, jacobian, derivative, observed, root, used):
    """Levenberg–Marquardt's residuals and their Jacobian in the unconstrained coordinates.

    **Arguments:** the model's values and their Jacobian in the free values at a point, the
    derivative of the free values in their unconstrained coordinates there (one per
    coordinate: the transforms act coordinate by coordinate), the observed values, the
    square roots of the weights over the loss's size, and which points count.

    **Returns:** ``(r, J)``: ``root (m - y)`` and its Jacobian, zero where a point does not
    count.
    """
    residual = jnp.where(used, root * (predicted - observed), 0.0)
    scaled = jnp.where(used[:, None], root[:, None] * jacobian * derivative, 0.0)
    return residual, scaled


def weighted_evaluation(to_free: Callable, model_curve: Callable, observed, root, used
                        ) -> Callable:
    """``evaluate(u) -> (r, J, (m, dm/df))`` of a weighted least-squares fit, for
    :func:`lm_step`: the model curve `model_curve` of the free values ``to_free(u)`` and its
    forward-mode Jacobian, weighted by :func:`weighted_residuals`."""

    def evaluate(u):
        free_values = to_free(u)
        derivative = jax.jvp(to_free, (u,), (jnp.ones_like(u),))[1]

        def curve(f):
            value = model_curve(f)
            return value, value

        jacobian, predicted = jax.jacfwd(curve, has_aux=True)(free_values)
        residual, scaled = weighted_residuals(predicted, jacobian, derivative, observed, root,
                                              used)
        return residual, scaled, (predicted, jacobian)

    return evaluate


def lm_initial(u0, empty):
    """Levenberg–Marquardt's loop state before its first iteration (which only evaluates
    at `u0`); `empty`: zeros of the shapes of ``(r, J, aux)``. See :func:`lm_step`."""
    residual0, jacobian0, aux0 = empty
    return (u0, residual0, jacobian0, aux0, jnp.asarray(jnp.inf), jnp.asarray(_INITIAL_DAMPING),
            jnp.asarray(2.0), jnp.asarray(True), jnp.asarray(0), jnp.asarray(0),
            jnp.asarray(0), jnp.asarray(jnp.inf), jnp.asarray(RUNNING))


def lm_step(evaluate: Callable, carry, options: SolverPlan):
    """One Levenberg–Marquardt iteration on the loop state `carry` (see
    :func:`levenberg_marquardt`); its last entry is the status (``RUNNING`` until a
    stopping rule fires)."""
    (u, residual, jacobian, aux, value, damping, factor, first, count, evaluations, stalled,
     checkpoint, _) = carry
    curvature = jacobian.T @ jacobian
    gradient = jacobian.T @ residual
    size = jnp.maximum(jnp.max(jnp.diag(curvature)), 1e-300)
    move = _cholesky_solve(curvature + damping * size * jnp.eye(gradient.shape[0]),
                           -gradient)
    longest = jnp.max(jnp.abs(move))
    move = move * jnp.where(longest > _MAX_STEP, _MAX_STEP / longest, 1.0)
    trial = jnp.where(first, u, u + move)
    new_residual, new_jacobian, new_aux = evaluate(trial)
    new_value = new_residual @ new_residual
    finite = jnp.isfinite(new_value) & jnp.all(jnp.isfinite(new_jacobian))
    accept = finite & (first | (new_value < value))
    predicted_fall = -(2.0 * gradient @ move + move @ curvature @ move)
    ratio = (value - new_value) / jnp.where(predicted_fall > 0, predicted_fall, jnp.inf)
    damping_next = jnp.where(
        first, _INITIAL_DAMPING,
        jnp.where(accept, damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3),
                  damping * factor))
    factor_next = jnp.where(accept, 2.0, 2.0 * factor)
    relative_change = (value - new_value) / jnp.maximum(jnp.abs(value), 1e-300)
    small_change = accept & ~first & (relative_change <= options.ftol)
    stalled = jnp.where(small_change, stalled + 1, jnp.where(accept, 0, stalled))

    def keep(new, old):
        return jax.tree.map(lambda a, b: jnp.where(accept, a, b), new, old)

    u, residual, jacobian, aux, kept_value = keep(
        (trial, new_residual, new_jacobian, new_aux, new_value),
        (u, residual, jacobian, aux, value))
    count = count + jnp.where(first, 0, 1)
    gradient_norm = jnp.linalg.norm(2.0 * jacobian.T @ residual)
    # Every _SLOW_STEPS iterations: did the loss fall by at least _SLOW_FALL of itself?
    milestone = ~first & (count % _SLOW_STEPS == 0)
    slow = milestone & (checkpoint - kept_value <= _SLOW_FALL * checkpoint)
    checkpoint = jnp.where(first | milestone, kept_value, checkpoint)
    status = jnp.select(
        [
            first & ~finite,
            ~first & (gradient_norm <= options.tol) & (longest <= options.xtol),
            small_change & ((longest <= options.xtol) | (stalled >= _STALLED_STEPS)),
            damping_next > _MAX_DAMPING,
            count >= options.max_steps,
            slow,
        ],
        [4, 0, 1, 3, 2, 10],
        default=RUNNING,
    )
    return (u, residual, jacobian, aux, kept_value, damping_next, factor_next,
            jnp.asarray(False), count, evaluations + 1, stalled, checkpoint, status)


def levenberg_marquardt(evaluate: Callable, u0, empty, options: SolverPlan):
    """Minimise ``r(u)·r(u)`` from `u0` by Levenberg–Marquardt in a while_loop.

    `evaluate(u) -> (r, J, aux)`: residuals, their Jacobian in `u` and anything else wanted
    at the final point; `empty`: zeros of the shapes of ``(r, J, aux)``. The step solves
    ``(JᵀJ + λ m I) δ = -Jᵀr`` (``m`` the largest diagonal entry of ``JᵀJ``: Levenberg's
    damping in the unconstrained coordinates, so a poorly determined direction moves like
    gradient descent rather than by a huge Gauss–Newton step), is shortened to at most
    :data:`_MAX_STEP` in every coordinate, and λ follows Nielsen's update. The first
    iteration only evaluates at `u0`, so the program holds the model once.
    Returns ``(u, value, gradient, steps, evaluations, status, aux)``.
    """
    carry = jax.lax.while_loop(lambda c: c[-1] == RUNNING,
                               lambda c: lm_step(evaluate, c, options),
                               lm_initial(u0, empty))
    u, residual, jacobian, aux, value, _, _, _, count, evaluations, _, _, status = carry
    return u, value, 2.0 * jacobian.T @ residual, count, evaluations, status, aux
