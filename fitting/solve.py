"""The optimiser core: compiled multi-start solvers in pure JAX, their settings and status.

* The loss (:mod:`fitting.losses`) is divided by its value for a zero model (``Σ w y²`` for
  least squares) so that it is of order one whatever the units; ``tol`` is a bound on the
  gradient norm of this scaled loss in the unconstrained coordinates ``u``
  (:class:`fitting.parameters.Layout`).
* ``method='lbfgs'`` (default): :func:`optax.lbfgs` with its zoom line search (strong Wolfe
  conditions); the line search stores the value and gradient at the accepted point and the
  next iteration reuses them, as :func:`optax.value_and_grad_from_state` does — read directly
  from the state, because under ``vmap`` that helper's ``lax.cond`` turns into a select that
  re-evaluates the objective every iteration. ``method='adam'``: :func:`optax.adam` at a fixed
  learning rate (rough, many cheap steps).
* The whole loop is a :func:`jax.lax.while_loop` inside :func:`jax.jit`; the compiled solver
  is cached per model, parameter layout and settings, so later fits of the same kind only
  run; the compiled programs are also kept on disk between runs when the persistent
  compilation cache is on (:func:`enable_compilation_cache`).
* Starts (:func:`start_points`): the start value, the method-of-moments estimate, then random
  starts (seeded), each random start first moved ``warmup_steps`` Adam steps, then polished by
  L-BFGS. All starts run as ONE vmapped batch; the lowest loss wins.
* Stopping: gradient norm below ``tol`` (converged), relative loss change below ``ftol``
  (converged: no further decrease possible at this precision), the line search finding no
  decrease, a non-finite loss, or ``max_steps`` iterations (not converged); see
  :class:`Status`.
* Checking (least squares): a stopped fit counts as converged only if one Gauss–Newton step
  from it is below ``xtol``. Where the Gauss–Newton curvature ``JᵀJ`` is singular (a
  direction the model curve does not change along to first order, e.g. the mirror line of
  the four-compartment model), that step is meaningless; the full Hessian then decides
  (:func:`second_order_distance`).
"""

from __future__ import annotations

import enum
import functools
import math
import os
import time as _time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.losses import LOSSES
from fitting.parameters import Layout

__all__ = [
    "CONVERGED",
    "FIRST_ORDER_CONVERGED",
    "SECOND_ORDER_DISTANCE",
    "STATUS_MESSAGES",
    "MultiStart",
    "Optimiser",
    "SolverPlan",
    "Status",
    "compiled_curvature",
    "compiled_solver",
    "enable_compilation_cache",
    "make_plan",
    "run_solver",
    "second_order_distance",
    "start_points",
]


class Status(enum.IntEnum):
    """Why a fit stopped; the values are the status codes of earlier releases."""

    GRADIENT = 0
    LOSS_CHANGE = 1
    MAX_STEPS = 2
    NO_DECREASE = 3
    NOT_FINITE = 4
    PRECISION_LIMIT = 5
    FLAT = 6
    MISSES_DATA = 7
    SECOND_ORDER = 8
    ON_BOUND = 9

    @property
    def converged(self) -> bool:
        """Whether this stopping rule counts as convergence."""
        return self in CONVERGED

    @property
    def message(self) -> str:
        """The stopping rule in words."""
        return STATUS_MESSAGES[self]


#: Stopping codes of the optimisation loop and their messages.
STATUS_MESSAGES = {
    Status.GRADIENT: "converged: gradient norm below tol",
    Status.LOSS_CHANGE: "converged: relative loss change below ftol",
    Status.MAX_STEPS: "not converged: maximum number of steps reached",
    Status.NO_DECREASE: "not converged: the line search found no decrease",
    Status.NOT_FINITE: "not converged: the loss is not finite",
    Status.PRECISION_LIMIT: "converged: at the precision limit (no further decrease possible; "
    "Gauss-Newton step below xtol)",
    Status.FLAT: "not converged: a Gauss-Newton step from here is still large (flat loss: the "
    "model curve may miss the data; try other start values or n_starts > 1)",
    Status.MISSES_DATA: "not converged: the model curve misses the data (loss at least 99 % of "
    "that of a zero curve); try other start values or n_starts > 1",
    Status.SECOND_ORDER: "converged: a local minimum where the Gauss-Newton curvature is "
    "singular (the full Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors); a parameter combination is determined only at second "
    "order, see the identifiability report",
    Status.ON_BOUND: "converged: a minimum on the bound of {names} (the loss falls towards it; "
    "the other parameters' Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors)",
}
#: Status codes that count as converged.
CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT, Status.SECOND_ORDER,
             Status.ON_BOUND)
#: Status codes that count as converged without the second-order check (profile re-fits).
FIRST_ORDER_CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT)
#: Newton distance to a local minimum, in standard errors, below which a fit that stopped on
#: a singular Gauss-Newton curvature counts as converged (status 8).
SECOND_ORDER_DISTANCE = 1e-3
_RUNNING = -1
#: Scaled loss (1 = a zero model curve) at or above which a fit is reported as missing the data.
_PLATEAU = 0.99


class Optimiser(eqx.Module):
    """Settings of the local optimiser, immutable.

    **Arguments:**

    - `method`: ``'lbfgs'`` (default) or ``'adam'``.
    - `max_steps`: iteration limit per start; ``None``: 500 for L-BFGS, 5000 for Adam.
    - `tol`: gradient-norm tolerance on the scaled loss in transformed coordinates.
    - `ftol`: relative loss change below which the iteration stops.
    - `xtol`: a least-squares fit counts as converged only if one Gauss–Newton step from the
      result would move no transformed coordinate by more than `xtol` (for positive
      parameters: a relative change).
    - `learning_rate`: Adam's step size in transformed coordinates.
    - `memory_size`: L-BFGS history length.
    """

    method: str = eqx.field(default="lbfgs", static=True)
    max_steps: int | None = eqx.field(default=None, static=True)
    tol: float = eqx.field(default=1e-10, static=True)
    ftol: float = eqx.field(default=1e-10, static=True)
    xtol: float = eqx.field(default=1e-6, static=True)
    learning_rate: float = eqx.field(default=0.05, static=True)
    memory_size: int = eqx.field(default=10, static=True)

    def __check_init__(self):
        if self.method not in ("lbfgs", "adam"):
            raise ValueError(f"method must be 'lbfgs' or 'adam', got {self.method!r}")
        if self.max_steps is not None and not self.max_steps >= 1:
            raise ValueError(f"max_steps must be at least 1, got {self.max_steps}")
        if not (self.tol > 0 and self.xtol > 0 and self.ftol >= 0):
            raise ValueError("tol and xtol must be positive and ftol non-negative")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be positive, got {self.learning_rate}")
        if not self.memory_size >= 1:
            raise ValueError(f"memory_size must be at least 1, got {self.memory_size}")

    @property
    def steps(self) -> int:
        """The iteration limit in force."""
        if self.max_steps is not None:
            return int(self.max_steps)
        return 500 if self.method == "lbfgs" else 5000


class MultiStart(eqx.Module):
    """How many starts a fit makes and how random starts are drawn, immutable.

    **Arguments:**

    - `n_starts`: number of starts, run as one vmapped batch: the start value, then (for
      models with a moment estimate) the moment estimate, then random starts. ``None``
      (default): the model's default (the start value, plus the moment estimate when it
      differs, unless the model says otherwise).
    - `seed`: seed of the random starts.
    - `warmup_steps`: Adam steps applied to each random start before L-BFGS.
    """

    n_starts: int | None = eqx.field(default=None, static=True)
    seed: int = eqx.field(default=0, static=True)
    warmup_steps: int = eqx.field(default=100, static=True)

    def __check_init__(self):
        if self.n_starts is not None and not self.n_starts >= 1:
            raise ValueError(f"n_starts must be at least 1, got {self.n_starts}")
        if not self.warmup_steps >= 0:
            raise ValueError(f"warmup_steps must be non-negative, got {self.warmup_steps}")


@dataclass(frozen=True)
class SolverPlan:
    """The static settings one compiled solver is built for (hashable; see :func:`make_plan`)."""

    loss: str
    method: str
    max_steps: int
    tol: float
    ftol: float
    warmup_steps: int
    learning_rate: float
    memory_size: int
    xtol: float


def make_plan(loss: str, optimiser: Optimiser, multistart: MultiStart) -> SolverPlan:
    """The :class:`SolverPlan` of a loss and settings.

    A single start never warms up, so its solver has no Adam loop.

    **Arguments:** `loss`: a key of :data:`fitting.losses.LOSSES`; `optimiser`, `multistart`:
    the settings.

    **Returns:** the plan.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {sorted(LOSSES)}, got {loss!r}")
    n_starts = multistart.n_starts
    warmup = int(multistart.warmup_steps) if n_starts is None or n_starts > 1 else 0
    return SolverPlan(loss, optimiser.method, optimiser.steps, float(optimiser.tol),
                      float(optimiser.ftol), warmup, float(optimiser.learning_rate),
                      int(optimiser.memory_size), float(optimiser.xtol))


def enable_compilation_cache(folder: str | Path | None = None) -> Path:
    """Keep compiled solvers on disk, so later runs of the same fit skip compiling.

    **Arguments:**

    - `folder`: the cache folder; default ``$JAX_COMPILATION_CACHE_DIR`` if set, else
      ``$XDG_CACHE_HOME/axialmix/jax`` (``~/.cache/axialmix/jax`` without XDG_CACHE_HOME).

    **Returns:** the folder used.
    """
    if folder is None:
        folder = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if folder is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        folder = os.path.join(base, "axialmix", "jax")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    # Small programs too: a fit's solvers compile in well under the default one second.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def _lbfgs(objective: Callable, u0, options: SolverPlan):
    """Minimise `objective` from `u0` with optax L-BFGS + zoom line search in a while_loop."""
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
            default=_RUNNING,
        )
        return u_next, state, value_next, grad_next, count, evaluations, status

    initial_status = jnp.where(
        ~jnp.isfinite(value0), 4, jnp.where(jnp.linalg.norm(grad0) <= options.tol, 0, _RUNNING)
    )
    carry = (u0, solver.init(u0), value0, grad0, jnp.asarray(0), jnp.asarray(1), initial_status)
    u, _, value, grad, count, evaluations, status = jax.lax.while_loop(
        lambda c: c[-1] == _RUNNING, step, carry
    )
    return u, value, grad, count, evaluations, status


def _adam(objective: Callable, u0, options: SolverPlan, max_steps: int):
    """Minimise `objective` with Adam for at most `max_steps`; returns the best point seen."""
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
            default=_RUNNING,
        )
        return optax.apply_updates(u, updates), state, best_u, best_value, best_grad, count, status

    carry = (u0, solver.init(u0), u0, jnp.asarray(jnp.inf), jnp.full_like(u0, jnp.inf),
             jnp.asarray(0), jnp.asarray(_RUNNING if max_steps > 0 else 2))
    _, _, u, value, grad, count, status = jax.lax.while_loop(
        lambda c: c[-1] == _RUNNING, step, carry
    )
    status = jnp.where(jnp.isfinite(value), status, 4)
    return u, value, grad, count, count, status


@functools.lru_cache(maxsize=64)
def compiled_solver(model, layout: Layout, options: SolverPlan, batch: str):
    """The jitted multi-start solver for one model, layout and option set.

    `batch`: ``'curves'`` (vmapped over curves; one curve is a batch of one) or ``'bases'``
    (vmapped over fixed-parameter values, for profiles).
    """
    loss_function = LOSSES[options.loss]

    def predict(free_values, base, time):
        values = layout.all_values(free_values, base)
        return model(time, values)

    def objective(u, base, time, observed, weights, scale):
        free_values = layout.physical_from_unconstrained(u)
        residual = predict(free_values, base, time) - observed
        return loss_function(residual, weights) / scale

    def solve_one_start(u0, base, time, observed, weights, scale, warm):
        def bound(u):
            return objective(u, base, time, observed, weights, scale)

        if options.method == "adam":
            return _adam(bound, u0, options, options.max_steps)
        if options.warmup_steps > 0:
            u_warm, _, _, _, warm_evaluations, _ = _adam(bound, u0, options,
                                                         options.warmup_steps)
            u0 = jnp.where(warm, u_warm, u0)
            warm_evaluations = jnp.where(warm, warm_evaluations, 0)
        else:
            warm_evaluations = 0
        u, value, grad, count, evaluations, status = _lbfgs(bound, u0, options)
        return u, value, grad, count, evaluations + warm_evaluations, status

    def solve(starts, warm, base, time, observed, weights):
        if options.loss == "sse":
            scale = jnp.sum(weights * observed**2)
        else:
            scale = jnp.sum(weights * jnp.abs(observed)) / jnp.sum(weights)
        scale = jnp.where(scale > 0, scale, 1.0)
        u, value, grad, count, evaluations, status = jax.vmap(
            solve_one_start, in_axes=(0, None, None, None, None, None, 0)
        )(starts, base, time, observed, weights, scale, warm)
        ranked = jnp.where(jnp.isfinite(value), value, jnp.inf)
        best = jnp.argmin(ranked)
        free_values = layout.physical_from_unconstrained(u[best])
        status_best = status[best]
        if options.loss == "sse":
            # Distance to the optimum, estimated by one Gauss-Newton step in the transformed
            # coordinates (minimum-norm step: unidentifiable directions do not count).
            def weighted_residual(v):
                free = layout.physical_from_unconstrained(v)
                return jnp.sqrt(weights) * (predict(free, base, time) - observed)

            step = jnp.linalg.lstsq(jax.jacfwd(weighted_residual)(u[best]),
                                    -weighted_residual(u[best]), rcond=1e-10)[0]
            newton_step = jnp.max(jnp.abs(step))
            stopped = (status_best == 0) | (status_best == 1) | (status_best == 3)
            near = newton_step <= options.xtol
            status_best = jnp.where(
                stopped & near, jnp.where(status_best == 3, 5, status_best),
                jnp.where(stopped, 6, status_best),
            )
        else:
            newton_step = jnp.asarray(jnp.nan)
        # A model curve that explains (almost) nothing of the data sits on a plateau of the
        # loss where every stopping rule can fire; never call that converged.
        status_best = jnp.where(value[best] >= _PLATEAU, 7, status_best)
        predicted = predict(free_values, base, time)
        jacobian = jax.jacfwd(predict)(free_values, base, time)
        all_from_free = jax.jacfwd(
            lambda f: jnp.stack(list(layout.all_values(f, base).values()))
        )(free_values)
        return {
            "free_values": free_values,
            "all_values": jnp.stack(list(layout.all_values(free_values, base).values())),
            "predicted": predicted,
            "jacobian": jacobian,
            "all_from_free": all_from_free,
            "scaled_loss": value[best],
            "start_losses": value * scale,
            "grad_norm": jnp.linalg.norm(grad[best]),
            "steps": count[best],
            "evaluations": jnp.sum(evaluations),
            "status": status_best,
            "newton_step": newton_step,
        }

    if batch == "curves":
        return jax.jit(jax.vmap(solve, in_axes=(0, None, 0, 0, 0, 0)))
    return jax.jit(jax.vmap(solve, in_axes=(0, None, 0, None, None, None)))


#: Compiled executables by solver and argument shapes, so that timings exclude compilation.
_EXECUTABLES: dict = {}


def run_solver(solver: Callable, *arguments) -> tuple[dict, float, float]:
    """Run a jitted solver; returns its output, the run time and the compile time (s)."""
    arguments = tuple(jnp.asarray(a) for a in arguments)
    key = (solver, tuple((a.shape, a.dtype) for a in arguments))
    began = _time.perf_counter()
    executable = _EXECUTABLES.get(key)
    if executable is None:
        executable = _EXECUTABLES[key] = solver.lower(*arguments).compile()
    compiled = _time.perf_counter()
    out = jax.block_until_ready(executable(*arguments))
    return out, _time.perf_counter() - compiled, compiled - began


def start_points(
    layout: Layout, start: np.ndarray, anchor: np.ndarray | None, n_starts: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Start points in unconstrained coordinates, and which of them get the Adam warm-up.

    Row 0 is `start`; with `anchor` (the method-of-moments estimate) and ``n_starts >= 2``,
    row 1 is the anchor; the remaining rows are random: log-uniform within a factor of 10 of
    the anchor (or start) for one-sided bounds, uniform inside two-sided bounds (log-uniform
    when positive and wider than a factor 100), normal around it without bounds.
    """
    rng = np.random.default_rng(seed)
    u_start = layout.unconstrained_from_physical(start)
    starts = np.tile(u_start, (n_starts, 1))
    first_random = 1
    centre = u_start
    if anchor is not None and n_starts >= 2:
        centre = layout.unconstrained_from_physical(anchor)
        starts[1] = centre
        first_random = 2
    count = n_starts - first_random
    spread = math.log(10.0)
    for j, kind in enumerate(layout.kinds):
        if count <= 0:
            break
        if kind in ("lower", "upper"):
            starts[first_random:, j] = centre[j] + rng.uniform(-spread, spread, count)
        elif kind == "both":
            low, high = layout.lower[j], layout.upper[j]
            fraction = rng.uniform(0.02, 0.98, count)
            if low > 0 and high / low > 100:
                values = np.exp(np.log(low) + fraction * (np.log(high) - np.log(low)))
            else:
                values = low + fraction * (high - low)
            starts[first_random:, j] = np.log((values - low) / (high - values))
        else:
            starts[first_random:, j] = centre[j] + rng.normal(0.0, 1.0, count)
    warm = np.arange(n_starts) >= first_random
    return starts, warm


@functools.lru_cache(maxsize=64)
def compiled_curvature(model, layout: Layout) -> Callable:
    """Jitted ``(gradient, Hessian)`` of ``Σ w r²`` in the free parameters."""

    def sse(free_values, base, time, observed, weights):
        values = layout.all_values(free_values, base)
        return jnp.sum(weights * (model(time, values) - observed) ** 2)

    return jax.jit(lambda *a: (jax.grad(sse)(*a), jax.hessian(sse)(*a)))


def second_order_distance(model, layout: Layout, free_values, base, time, observed, weights,
                          sse: float, dof: float) -> tuple[float, tuple[str, ...]]:
    """Newton's distance to the nearest minimum in standard errors, and the bounds it lies on.

    Near a minimum ``SSE(p) ≈ SSE* + ½ (p - p*)ᵀ H (p - p*)``, so Newton's method predicts
    ``SSE - SSE* = ½ gᵀ H⁻¹ g``; divided by ``s² = SSE / dof`` this is the squared distance
    to the minimum in the metric of the standard errors (exact for a linear model). A
    parameter whose gradient pushes it onto a bound it (nearly) sits on, the rest of the
    loss falling by less than ``SECOND_ORDER_DISTANCE² s²`` when it goes there, is taken as
    on that bound: it adds that fall, and the others are checked on their own.

    **Arguments:** the model and layout of a fit, the free values at its end, the base
    (fixed) values, the data (`time`, `observed`, `weights`), its ``Σ w r²`` and degrees of
    freedom.

    **Returns:** ``(distance, names on a bound)``; ``(inf, ())`` when the free parameters'
    Hessian is not positive definite.
    """
    gradient, hessian = compiled_curvature(model, layout)(
        jnp.asarray(free_values), jnp.asarray(base), jnp.asarray(time),
        jnp.asarray(observed), jnp.asarray(weights))
    gradient, hessian = np.asarray(gradient), np.asarray(hessian)
    values = np.asarray(free_values, dtype=float)
    if not (np.all(np.isfinite(gradient)) and np.all(np.isfinite(hessian))):
        return math.inf, ()
    variance = sse / dof
    small = SECOND_ORDER_DISTANCE**2 * variance
    on_bound, fall = [], 0.0
    for j, kind in enumerate(layout.kinds):
        if kind in ("lower", "both") and gradient[j] > 0:
            gain = gradient[j] * (values[j] - layout.lower[j])
        elif kind in ("upper", "both") and gradient[j] < 0:
            gain = -gradient[j] * (layout.upper[j] - values[j])
        else:
            continue
        if gain <= small:
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
