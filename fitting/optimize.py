"""Gradient fits of residence-time models with optax: bounds, fixed and tied parameters, starts.

The vocabulary is lmfit's: a :class:`Parameter` has a ``value``, optional bounds ``min`` and
``max``, ``vary`` (``False`` fixes it) and ``expr`` (ties it to other parameters, e.g.
``Parameter(1.0, expr="k_f")`` or ``expr="2*k_f"``). :func:`fit` returns a :class:`FitResult`
with values, standard errors, 95 % intervals, correlations and a printable report.

How a fit runs:

* The varying, untied parameters are mapped to unconstrained coordinates ``u``:
  ``p = min + exp(u)`` with only a lower bound (``log`` for positive parameters),
  ``p = max - exp(u)`` with only an upper bound, ``p = min + (max - min) sigmoid(u)`` with both,
  and ``p = s u`` with none (``s``: the power of ten nearest the start value). Bounds
  therefore hold exactly and the optimiser never sees a constraint.
* The loss (:mod:`fitting.objective`) is divided by its value for a zero model
  (``Σ w y²`` for least squares) so that it is of order one whatever the units; ``tol`` is a
  bound on the gradient norm of this scaled loss in ``u``.
* ``method='lbfgs'`` (default): :func:`optax.lbfgs` with its zoom line search (strong Wolfe
  conditions); the line search stores the value and gradient at the accepted point and the
  next iteration reuses them, as :func:`optax.value_and_grad_from_state` does — read directly
  from the state, because under ``vmap`` that helper's ``lax.cond`` turns into a select that
  re-evaluates the objective every iteration. ``method='adam'``: :func:`optax.adam` at a fixed
  learning rate (rough, many cheap steps).
* The whole loop is a :func:`jax.lax.while_loop` inside :func:`jax.jit`; the compiled solver
  is cached per model, parameter layout and options, so later fits of the same kind only run.
* Starts: by default (``n_starts=None``) a fit runs from the start values and, when those
  differ from the model's method-of-moments estimate, from that estimate too (a start whose
  model curve misses the data sits on a flat loss no local method can leave; the moment
  estimate always overlaps the data). ``n_starts=1`` runs the start values alone.
  ``n_starts > 1``: the first start is the given start value (the method-of-moments estimate
  by default), the second the moment estimate, the others are drawn at random (seeded):
  log-uniform within a factor of 10 of the start for one-sided bounds, uniform (log-uniform
  for wide positive ranges) inside two-sided bounds. Each random start is first moved
  ``warmup_steps`` Adam steps, then polished by L-BFGS. All starts run as ONE vmapped
  batch; the lowest loss wins.
* Stopping: gradient norm below ``tol`` (converged), relative loss change below ``ftol``
  (converged: no further decrease possible at this precision), the line search finding no
  decrease, a non-finite loss, or ``max_steps`` iterations (not converged).
* Checking (least squares): a stopped fit counts as converged only if one Gauss–Newton step
  from it is below ``xtol``. Where the Gauss–Newton curvature ``JᵀJ`` is singular (a
  direction the model curve does not change along to first order, e.g. the mirror line of
  the four-compartment model), that step is meaningless; the full Hessian then decides: if
  it is positive definite and Newton's method puts the minimum within
  :data:`SECOND_ORDER_DISTANCE` standard errors, the fit converged (status 8).
* ``relative_errors=True``: the data's errors are taken as proportional to the curve
  (multiplicative noise): after a first fit, the curve is fitted again from its result with
  weights ``1 / max(|model|, floor)²`` (``1 / max(|model|, floor)`` for the mean absolute
  error), ``floor`` being ``RELATIVE_FLOOR`` of the model's peak, and again, until the fitted
  values change by less than ``RELATIVE_CHANGE`` (iteratively reweighted least squares: the
  weights are then those of the fit's own curve).
* ``n_evaluations`` counts objective evaluations, each one value and gradient (one model
  evaluation plus its reverse pass), summed over all starts.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import json
import math
import operator
import time as _time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from fitting.io import Curve
from fitting.objective import LOSSES

if TYPE_CHECKING:
    from fitting.models import Model

__all__ = ["FitResult", "Parameter", "Parameters", "fit", "fit_many"]


# --- parameters ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Parameter:
    """One model parameter in lmfit's vocabulary: start value, bounds, fixed or tied.

    **Arguments:**

    - `value`: start value (the fitted value in a result), in the parameter's unit.
    - `min`, `max`: bounds (``None`` for none); kept exactly by transformation.
    - `vary`: ``False`` keeps the parameter fixed at `value`.
    - `expr`: ties the parameter to others: an arithmetic expression of parameter names and
      numbers with ``+ - * / **`` and parentheses, e.g. ``'k_f'``, ``'2*k_f'``,
      ``'0.5*(k_f + k_s)'``. A tied parameter is not fitted itself.
    """

    value: float
    min: float | None = None
    max: float | None = None
    vary: bool = True
    expr: str | None = None

    def __post_init__(self) -> None:
        value = float(self.value)
        object.__setattr__(self, "value", value)
        for bound in ("min", "max"):
            limit = getattr(self, bound)
            if limit is not None:
                limit = float(limit)
                if math.isnan(limit):
                    raise ValueError(f"Parameter {bound} is NaN")
                object.__setattr__(self, bound, None if math.isinf(limit) else limit)
        if math.isnan(value):
            raise ValueError("Parameter value is NaN")
        if self.min is not None and self.max is not None and not self.min < self.max:
            raise ValueError(f"Parameter min ({self.min:g}) must be below max ({self.max:g})")
        if self.expr is None and self.vary:
            if (self.min is not None and value < self.min) or (
                self.max is not None and value > self.max
            ):
                raise ValueError(
                    f"Parameter value {value:g} lies outside its bounds [{self.min}, {self.max}]"
                )
        if self.expr is not None:
            _parse_expression(self.expr)

    def replace(self, **changes: Any) -> Parameter:
        """A copy with some fields changed, e.g. ``p.replace(vary=False)``."""
        return dataclasses.replace(self, **changes)


class Parameters(dict):
    """Ordered mapping of parameter name to :class:`Parameter` (like lmfit's ``Parameters``)."""

    def add(
        self,
        name: str,
        value: float = 0.0,
        min: float | None = None,
        max: float | None = None,
        vary: bool = True,
        expr: str | None = None,
    ) -> Parameters:
        """Add (or replace) the parameter `name`; returns ``self`` so calls chain."""
        self[name] = Parameter(value, min=min, max=max, vary=vary, expr=expr)
        return self

    def valuesdict(self) -> dict[str, float]:
        """``{name: value}`` of all parameters."""
        return {name: p.value for name, p in self.items()}

    def copy(self) -> Parameters:
        return Parameters(self)


# --- tied-parameter expressions ----------------------------------------------------------------

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}


@functools.lru_cache(maxsize=256)
def _parse_expression(expr: str) -> ast.Expression:
    """Parse a tie expression, allowing only numbers, names, + - * / ** and parentheses."""
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError:
        raise ValueError(f"Parameter expr {expr!r} is not a valid expression") from None
    for node in ast.walk(tree):
        allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Name, ast.Load, ast.Constant,
                   *_BINARY, *_UNARY)
        if not isinstance(node, allowed):
            raise ValueError(
                f"Parameter expr {expr!r}: only numbers, parameter names, + - * / ** and "
                "parentheses are allowed"
            )
        if isinstance(node, ast.Constant) and not isinstance(node.value, int | float):
            raise ValueError(f"Parameter expr {expr!r}: {node.value!r} is not a number")
    return tree


def _expression_names(expr: str) -> set[str]:
    return {n.id for n in ast.walk(_parse_expression(expr)) if isinstance(n, ast.Name)}


def _evaluate(node: ast.AST, values: Mapping[str, Any]) -> Any:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, values)
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        return values[node.id]
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_evaluate(node.left, values), _evaluate(node.right, values))
    return _UNARY[type(node.op)](_evaluate(node.operand, values))


# --- the static layout of a fit ----------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """Which parameters are free, fixed or tied, and how free ones are transformed (static)."""

    names: tuple[str, ...]
    model_names: tuple[str, ...]
    free: tuple[str, ...]
    kinds: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    scale: tuple[float, ...]
    tied: tuple[tuple[str, str], ...]

    @property
    def free_index(self) -> tuple[int, ...]:
        return tuple(self.names.index(n) for n in self.free)

    def physical_from_unconstrained(self, u):
        """Free parameter values from unconstrained coordinates (JAX)."""
        values = []
        for j, kind in enumerate(self.kinds):
            if kind == "lower":
                values.append(self.lower[j] + jnp.exp(u[j]))
            elif kind == "upper":
                values.append(self.upper[j] - jnp.exp(u[j]))
            elif kind == "both":
                values.append(
                    self.lower[j] + (self.upper[j] - self.lower[j]) * jax.nn.sigmoid(u[j])
                )
            else:
                values.append(self.scale[j] * u[j])
        return jnp.stack(values)

    def unconstrained_from_physical(self, values: np.ndarray) -> np.ndarray:
        """Unconstrained coordinates of free parameter values (NumPy; values inside bounds)."""
        u = np.empty(len(self.free))
        for j, kind in enumerate(self.kinds):
            value = float(values[j])
            if kind == "lower":
                u[j] = math.log(max(value - self.lower[j], 1e-300))
            elif kind == "upper":
                u[j] = math.log(max(self.upper[j] - value, 1e-300))
            elif kind == "both":
                x = (value - self.lower[j]) / (self.upper[j] - self.lower[j])
                x = min(max(x, 1e-12), 1 - 1e-12)
                u[j] = math.log(x / (1 - x))
            else:
                u[j] = value / self.scale[j]
        return u

    def all_values(self, free_values, base) -> dict[str, Any]:
        """All parameter values: base (fixed) values, free values, then ties in order (JAX)."""
        values = {name: base[i] for i, name in enumerate(self.names)}
        for j, name in enumerate(self.free):
            values[name] = free_values[j]
        for name, expr in self.tied:
            values[name] = _evaluate(_parse_expression(expr), values)
        return values


def _layout(model: Model, params: Parameters) -> _Layout:
    names = tuple(model.parameter_names) + tuple(n for n in params if n not in
                                                 model.parameter_names)
    missing = [n for n in model.parameter_names if n not in params]
    if missing:
        raise ValueError(f"no value for parameter(s) {missing} of model {model.name!r}")
    free, kinds, lower, upper, scale = [], [], [], [], []
    pending = {}
    for name in names:
        p = params[name]
        if p.expr is not None:
            unknown = _expression_names(p.expr) - set(names)
            if unknown:
                raise ValueError(
                    f"parameter {name!r}: expr {p.expr!r} names unknown parameter(s) "
                    f"{sorted(unknown)}"
                )
            pending[name] = p.expr
        elif p.vary:
            free.append(name)
            has_low, has_high = p.min is not None, p.max is not None
            kinds.append({(True, True): "both", (True, False): "lower",
                          (False, True): "upper", (False, False): "none"}[(has_low, has_high)])
            lower.append(p.min if has_low else 0.0)
            upper.append(p.max if has_high else 0.0)
            # Unbounded parameters are scaled by the power of ten nearest their start value
            # (static, so nearby start values share one compiled solver).
            magnitude = abs(p.value) if kinds[-1] == "none" and p.value != 0 else 1.0
            scale.append(10.0 ** round(math.log10(magnitude)))
    tied = []
    resolved = set(names) - set(pending)
    while pending:
        ready = [n for n, e in pending.items() if _expression_names(e) <= resolved]
        if not ready:
            raise ValueError(f"parameter ties form a cycle: {sorted(pending)}")
        for name in ready:
            tied.append((name, pending.pop(name)))
            resolved.add(name)
    if not free:
        raise ValueError("nothing to fit: every parameter is fixed or tied")
    return _Layout(names, tuple(model.parameter_names), tuple(free), tuple(kinds),
                   tuple(lower), tuple(upper), tuple(scale), tuple(tied))


def _merge_parameters(model: Model, params, curve: Curve | None) -> Parameters:
    """Model defaults (moment estimates as start values when a curve is given), then the user's.

    A number replaces only the start value; a :class:`Parameter` replaces the whole setting.
    """
    merged = model.parameters(curve)
    if params is None:
        return merged
    for name, setting in params.items():
        if isinstance(setting, Parameter):
            merged[name] = setting
        elif name in merged:
            merged[name] = merged[name].replace(value=float(setting))
        else:
            merged[name] = Parameter(float(setting))
    return merged


# --- the compiled solver -----------------------------------------------------------------------


@dataclass(frozen=True)
class _Options:
    loss: str
    method: str
    max_steps: int
    tol: float
    ftol: float
    warmup_steps: int
    learning_rate: float
    memory_size: int
    xtol: float


#: Stopping codes of the optimisation loop and their messages.
STATUS_MESSAGES = {
    0: "converged: gradient norm below tol",
    1: "converged: relative loss change below ftol",
    2: "not converged: maximum number of steps reached",
    3: "not converged: the line search found no decrease",
    4: "not converged: the loss is not finite",
    5: "converged: at the precision limit (no further decrease possible; Gauss-Newton step "
       "below xtol)",
    6: "not converged: a Gauss-Newton step from here is still large (flat loss: the model "
       "curve may miss the data; try other start values or n_starts > 1)",
    7: "not converged: the model curve misses the data (loss at least 99 % of that of a zero "
       "curve); try other start values or n_starts > 1",
    8: "converged: a local minimum where the Gauss-Newton curvature is singular (the full "
       "Hessian is positive definite and Newton's method puts the minimum within "
       "0.001 standard errors); a parameter combination is determined only at second order, "
       "see the identifiability report",
    9: "converged: a minimum on the bound of {names} (the loss falls towards it; the other "
       "parameters' Hessian is positive definite and Newton's method puts the minimum "
       "within 0.001 standard errors)",
}
#: Status codes that count as converged.
CONVERGED = (0, 1, 5, 8, 9)
#: Newton distance to a local minimum, in standard errors, below which a fit that stopped on
#: a singular Gauss-Newton curvature counts as converged (status 8).
SECOND_ORDER_DISTANCE = 1e-3
_RUNNING = -1
#: Scaled loss (1 = a zero model curve) at or above which a fit is reported as missing the data.
_PLATEAU = 0.99


def _lbfgs(objective: Callable, u0, options: _Options):
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


def _adam(objective: Callable, u0, options: _Options, max_steps: int):
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
def _compiled_solver(model: Model, layout: _Layout, options: _Options, batch: str):
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


def _run_solver(solver: Callable, *arguments) -> tuple[dict, float, float]:
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


def _start_points(
    layout: _Layout, start: np.ndarray, anchor: np.ndarray | None, n_starts: int, seed: int
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


# --- the result ------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FitResult:
    """The outcome of a fit: values, uncertainty, convergence and the fitted curve.

    Attributes (units are those of the model's parameters and of the data):

    - `values`: fitted value of every parameter (free, fixed and tied), by name.
    - `stderr`: standard error by name (``None`` for fixed parameters; tied ones by
      propagation through their expression); from the Gauss–Newton curvature, see
      :mod:`fitting.uncertainty`.
    - `ci95`: ``(low, high)`` 95 % interval by name (Student t with ``n - p`` degrees of
      freedom), ``None`` for fixed parameters.
    - `correlation`, `covariance`: matrices over `free_names`.
    - `loss`: the minimised loss, unscaled (``Σ w r²`` or the mean absolute error).
    - `sse`: ``Σ w r²`` at the optimum whatever the loss (for AIC/BIC and errors).
    - `dof`: degrees of freedom of ``sse``, ``n - p`` (not a whole number for relative-error
      fits, where weights capped at the floor count less); `sigma`: ``sqrt(sse / dof)``.
    - `n_evaluations`: objective evaluations (value and gradient), all starts together.
    - `wall_time`: seconds the compiled solver ran (its share, for :func:`fit_many`);
      `compile_time`: seconds spent compiling it first (0 when reused).
    - `success`: converged with a finite loss; `converged`: a convergence test was met;
      `status` and `message`: which stopping rule ended the fit.
    - `model`, `params` (:class:`Parameters` with fitted values), `time`, `observed`,
      `weights`, `predicted`, `residuals` (model - data), `jacobian` (d predicted / d free).
    """

    model: Model
    params: Parameters
    init_params: Parameters
    free_names: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float | None]
    ci95: dict[str, tuple[float, float] | None]
    covariance: np.ndarray
    correlation: np.ndarray
    loss: float
    loss_name: str
    sse: float
    n_points: int
    dof: float
    sigma: float
    aic: float
    bic: float
    n_evaluations: int
    n_steps: int
    n_starts: int
    start_losses: np.ndarray
    grad_norm: float
    newton_step: float
    wall_time: float
    success: bool
    converged: bool
    status: int
    message: str
    method: str
    time: np.ndarray = field(repr=False)
    observed: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    predicted: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)
    jacobian: np.ndarray = field(repr=False)
    name: str = ""
    compile_time: float = 0.0

    def __repr__(self) -> str:
        values = ", ".join(f"{n}={v:.6g}" for n, v in self.values.items())
        return (f"FitResult({self.model.name}: {values}; loss={self.loss:.4g}, "
                f"converged={self.converged})")

    def report(self, correlation_threshold: float = 0.1) -> str:
        """A readable fit report (like lmfit's): statistics, values ± errors, correlations."""
        lines = [f"[[Model]] {self.model.name}: {self.model.description}"]
        if self.name:
            lines.append(f"    data: {self.name}")
        lines += [
            "[[Fit statistics]]",
            f"    method             = {self.method}, {self.n_starts} start(s)",
            f"    status             = {self.message}",
            f"    gradient norm      = {self.grad_norm:.3g} (scaled loss, transformed "
            "parameters)",
            f"    Gauss-Newton step  = {self.newton_step:.3g} (distance to the optimum, "
            "transformed parameters)",
            f"    steps              = {self.n_steps}",
            f"    evaluations        = {self.n_evaluations} (value + gradient)",
            f"    wall time          = {self.wall_time:.4g} s (+ {self.compile_time:.3g} s "
            "compiling)",
            f"    data points        = {self.n_points}",
            f"    variables          = {len(self.free_names)}",
            f"    degrees of freedom = {self.dof:.4g}",
            f"    loss ({self.loss_name})         = {self.loss:.6g}",
            f"    sum of squares     = {self.sse:.6g}",
            f"    residual std (s)   = {self.sigma:.6g}",
            f"    AIC                = {self.aic:.4f}",
            f"    BIC                = {self.bic:.4f}",
            "[[Variables]]",
        ]
        width = max(len(n) for n in self.values)
        for name, value in self.values.items():
            setting = self.init_params[name]
            label = f"    {name + ':':<{width + 1}} {value:<14.7g}"
            if setting.expr is not None:
                error = self.stderr[name]
                error_text = f" +/- {error:.4g}" if error is not None else ""
                lines.append(f"{label}{error_text} == '{setting.expr}'")
            elif not setting.vary:
                lines.append(f"{label}(fixed)")
            else:
                error = self.stderr[name]
                low, high = self.ci95[name] if self.ci95[name] else (math.nan, math.nan)
                relative = abs(error / value) * 100 if value else math.inf
                lines.append(
                    f"{label}+/- {error:<11.4g}({relative:.2f}%)  95% CI [{low:.6g}, {high:.6g}]"
                    f"  (init = {setting.value:.6g})"
                )
        pairs = [
            (abs(self.correlation[i, j]), self.free_names[i], self.free_names[j],
             self.correlation[i, j])
            for i in range(len(self.free_names))
            for j in range(i + 1, len(self.free_names))
            if abs(self.correlation[i, j]) > correlation_threshold
        ]
        if pairs:
            lines.append(
                f"[[Correlations]] (unreported correlations are < {correlation_threshold})"
            )
            for _, a, b, r in sorted(pairs, reverse=True):
                lines.append(f"    C({a}, {b}) = {r:+.4f}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (plain floats, ``None`` for undefined numbers)."""

        def number(x):
            return float(x) if x is not None and np.isfinite(x) else None

        parameters = {}
        for name, value in self.values.items():
            setting = self.init_params[name]
            interval = self.ci95[name]
            parameters[name] = {
                "value": number(value),
                "stderr": number(self.stderr[name]),
                "ci95": [number(interval[0]), number(interval[1])] if interval else None,
                "vary": bool(setting.vary and setting.expr is None),
                "expr": setting.expr,
                "min": setting.min,
                "max": setting.max,
                "init": setting.value,
            }
        return {
            "model": self.model.name,
            "data": self.name,
            "parameters": parameters,
            "correlation": {
                "names": list(self.free_names),
                "matrix": [[number(x) for x in row] for row in self.correlation],
            },
            "loss": number(self.loss),
            "loss_name": self.loss_name,
            "sse": number(self.sse),
            "aic": number(self.aic),
            "bic": number(self.bic),
            "n_points": self.n_points,
            "dof": self.dof,
            "converged": self.converged,
            "success": self.success,
            "message": self.message,
            "method": self.method,
            "n_starts": self.n_starts,
            "n_evaluations": self.n_evaluations,
            "n_steps": self.n_steps,
            "wall_time": self.wall_time,
            "compile_time": self.compile_time,
        }

    def restart_parameters(self) -> Parameters:
        """This fit's settings with the fitted values as start values (kept inside bounds),
        to start another fit from this one."""
        start = Parameters()
        for name, setting in self.init_params.items():
            if name in self.free_names:
                value = self.values[name]
                if setting.min is not None:
                    value = max(value, setting.min)
                if setting.max is not None:
                    value = min(value, setting.max)
                setting = setting.replace(value=value)
            start[name] = setting
        return start

    def identifiability(self):
        """Poorly determined parameter combinations (see :mod:`fitting.uncertainty`)."""
        from fitting.uncertainty import identifiability

        return identifiability(self)

    def profile(self, name: str, values: Sequence[float] | None = None, **options: Any):
        """Profile of the loss along `name` (:func:`fitting.uncertainty.profile_likelihood`)."""
        from fitting.uncertainty import profile_likelihood

        return profile_likelihood(self, name, values, **options)

    def to_json(self, **kwargs: Any) -> str:
        """:meth:`to_dict` as a JSON string."""
        return json.dumps(self.to_dict(), **kwargs)


# --- entry points ----------------------------------------------------------------------------


def _as_curve(data: Curve | tuple) -> Curve:
    if isinstance(data, Curve):
        return data
    try:
        time, value = data
    except (TypeError, ValueError):
        raise ValueError("data must be a Curve or a (time, values) pair") from None
    return Curve(name="", time=np.asarray(time, dtype=float), value=np.asarray(value, float))


def _check_data(curve: Curve, weights: np.ndarray) -> None:
    label = f"curve {curve.name!r}: " if curve.name else ""
    if len(curve) < 2:
        raise ValueError(f"{label}need at least two data points")
    if not (np.all(np.isfinite(curve.time)) and np.all(np.isfinite(curve.value))):
        raise ValueError(f"{label}time and values must be finite (no NaN or inf)")
    if not np.all(np.diff(curve.time) > 0):
        raise ValueError(f"{label}times must be strictly increasing")
    if weights.shape != curve.time.shape:
        raise ValueError(f"{label}weights have shape {weights.shape}, data {curve.time.shape}")
    if not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise ValueError(f"{label}weights must be finite and non-negative")


def _options(loss, method, max_steps, tol, ftol, xtol, warmup_steps, learning_rate,
             n_starts) -> _Options:
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {sorted(LOSSES)}, got {loss!r}")
    if method not in ("lbfgs", "adam"):
        raise ValueError(f"method must be 'lbfgs' or 'adam', got {method!r}")
    if max_steps is None:
        max_steps = 500 if method == "lbfgs" else 5000
    if max_steps < 1:
        raise ValueError(f"max_steps must be at least 1, got {max_steps}")
    if not tol > 0 or not ftol >= 0 or not xtol > 0:
        raise ValueError("tol and xtol must be positive and ftol non-negative")
    if n_starts is not None and n_starts < 1:
        raise ValueError(f"n_starts must be at least 1, got {n_starts}")
    # A single start never warms up: leave the Adam loop out of the compiled solver (and
    # see _without_idle_warmup for starts that are not random).
    warmup_steps = int(warmup_steps) if n_starts is None or n_starts > 1 else 0
    return _Options(loss, method, int(max_steps), float(tol), float(ftol), warmup_steps,
                    float(learning_rate), 10, float(xtol))


@dataclass(frozen=True, eq=False)
class _Prepared:
    """One curve made ready for the solver: merged settings, layout, weights, starts."""

    model: Model
    curve: Curve
    params: Parameters
    layout: _Layout
    weights: np.ndarray
    base: np.ndarray
    starts: np.ndarray
    warm: np.ndarray


def _without_idle_warmup(options: _Options, prepared: Sequence[_Prepared]) -> _Options:
    """Drop the Adam warm-up from the compiled solver when no start is random."""
    if options.warmup_steps > 0 and not any(p.warm.any() for p in prepared):
        return dataclasses.replace(options, warmup_steps=0)
    return options


def _prepare(model, curve: Curve, params, weights, n_starts: int | None,
             seed: int) -> _Prepared:
    from fitting.models import _clip, get_model

    model = get_model(model)
    merged = _merge_parameters(model, params, curve)
    layout = _layout(model, merged)
    weights = np.ones(len(curve)) if weights is None else np.asarray(weights, dtype=float)
    _check_data(curve, weights)
    n_used = int(np.count_nonzero(weights))
    if n_used <= len(layout.free):
        raise ValueError(
            f"{n_used} weighted data points cannot determine {len(layout.free)} free parameters"
        )
    base = np.array([merged[n].value for n in layout.names])
    start = base[list(layout.free_index)]
    anchor = None
    if model.initial_guess is not None and (n_starts is None or n_starts > 1):
        guess = model.parameters(curve)
        anchor = np.array([_clip(guess[n].value, merged[n]) if n in guess else merged[n].value
                           for n in layout.free])
    if n_starts is None:
        # The start values, and the moment estimate when it differs from them.
        same = anchor is None or np.allclose(anchor, start, rtol=1e-9, atol=0.0)
        n_starts = 1 if same else 2
    starts, warm = _start_points(layout, start, anchor, n_starts, seed)
    return _Prepared(model, curve, merged, layout, weights, base, starts, warm)


def _interval(value: float, half_width: float, setting: Parameter) -> tuple[float, float]:
    """95 % interval ``value ± half_width``; for a positive parameter with a lower bound of
    zero or more, symmetric in ``ln p`` instead (the coordinate the fit uses), so that it
    stays positive: ``value · exp(±half_width / value)``. The two agree when the relative
    error is small."""
    if setting.min is not None and setting.min >= 0 and value > 0:
        if not half_width / value <= LOG_INTERVAL_LIMIT:
            return (0.0, math.inf)  # not bounded at all (or an undefined error)
        factor = math.exp(half_width / value)
        return (value / factor, value * factor)
    return (value - half_width, value + half_width)


#: Half-width in ln p beyond which a positive parameter's interval is reported as (0, inf):
#: a factor of 1e20 either way bounds nothing.
LOG_INTERVAL_LIMIT = math.log(1e20)


@functools.lru_cache(maxsize=64)
def _compiled_curvature(model: Model, layout: _Layout) -> Callable:
    """Jitted ``(gradient, Hessian)`` of ``Σ w r²`` in the free parameters."""

    def sse(free_values, base, time, observed, weights):
        values = layout.all_values(free_values, base)
        return jnp.sum(weights * (model(time, values) - observed) ** 2)

    return jax.jit(lambda *a: (jax.grad(sse)(*a), jax.hessian(sse)(*a)))


def _second_order_check(prepared: _Prepared, layout: _Layout, free_values, sse: float,
                        dof: int) -> tuple[float, tuple[str, ...]]:
    """Newton's distance to the nearest minimum in standard errors, and the bounds it lies on.

    Near a minimum ``SSE(p) ≈ SSE* + ½ (p - p*)ᵀ H (p - p*)``, so Newton's method predicts
    ``SSE - SSE* = ½ gᵀ H⁻¹ g``; divided by ``s² = SSE / dof`` this is the squared distance
    to the minimum in the metric of the standard errors (exact for a linear model). A
    parameter whose gradient pushes it onto a bound it (nearly) sits on, the rest of the
    loss falling by less than ``SECOND_ORDER_DISTANCE² s²`` when it goes there, is taken as
    on that bound: it adds that fall, and the others are checked on their own. Returns
    ``(inf, ())`` when the free parameters' Hessian is not positive definite.
    """
    curve = prepared.curve
    gradient, hessian = _compiled_curvature(prepared.model, layout)(
        jnp.asarray(free_values), jnp.asarray(prepared.base), jnp.asarray(curve.time),
        jnp.asarray(curve.value), jnp.asarray(prepared.weights))
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


def _result(prepared: _Prepared, layout: _Layout, options: _Options, out: dict,
            wall_time: float, compile_time: float) -> FitResult:
    from fitting.uncertainty import gauss_newton_uncertainty, information_criteria

    curve, merged, weights = prepared.curve, prepared.params, prepared.weights
    # Distinct starts (fit_many pads a batch of curves to a common number of starts).
    n_starts = len(np.unique(prepared.starts, axis=0))
    out = {k: np.asarray(v) for k, v in out.items()}
    residual = out["predicted"] - curve.value
    n_points = int(np.count_nonzero(weights))
    sse = float(np.sum(weights * residual**2))
    loss = float(LOSSES[options.loss](residual, weights))
    uncertainty = gauss_newton_uncertainty(out["jacobian"], residual, weights,
                                           out["all_from_free"])
    values = dict(zip(layout.names, out["all_values"].tolist(), strict=True))
    stderr: dict[str, float | None] = {}
    ci95: dict[str, tuple[float, float] | None] = {}
    for i, name in enumerate(layout.names):
        setting = merged[name]
        if setting.expr is None and not setting.vary:
            stderr[name], ci95[name] = None, None
            continue
        error = float(uncertainty.all_stderr[i])
        stderr[name] = error
        ci95[name] = _interval(values[name], uncertainty.t_quantile * error, setting)
    status = int(out["status"])
    message = STATUS_MESSAGES[status]
    if status == 6 and options.loss == "sse" and uncertainty.dof > 0 and sse > 0:
        distance, on_bound = _second_order_check(prepared, layout, out["free_values"], sse,
                                                 uncertainty.dof)
        if distance <= SECOND_ORDER_DISTANCE:
            status = 9 if on_bound else 8
            message = STATUS_MESSAGES[status].replace("{names}", ", ".join(on_bound))
            message = f"{message} (distance {distance:.1g} standard errors)"
    converged = status in CONVERGED
    aic, bic = information_criteria(sse, n_points, len(layout.free))
    fitted = Parameters({n: merged[n].replace(value=values[n]) for n in layout.names})
    if options.method == "adam":
        method = "adam"
    elif options.warmup_steps > 0:
        method = f"lbfgs ({options.warmup_steps} adam steps first from random starts)"
    else:
        method = "lbfgs"
    return FitResult(
        model=prepared.model, params=fitted, init_params=merged, free_names=layout.free,
        values=values, stderr=stderr, ci95=ci95, covariance=uncertainty.covariance,
        correlation=uncertainty.correlation, loss=loss, loss_name=options.loss, sse=sse,
        n_points=n_points, dof=uncertainty.dof, sigma=uncertainty.sigma, aic=aic, bic=bic,
        n_evaluations=int(out["evaluations"]), n_steps=int(out["steps"]), n_starts=n_starts,
        start_losses=out["start_losses"], grad_norm=float(out["grad_norm"]),
        newton_step=float(out["newton_step"]), wall_time=wall_time, compile_time=compile_time,
        success=converged and bool(np.isfinite(loss)), converged=converged, status=status,
        message=message, method=method, time=curve.time,
        observed=curve.value, weights=weights, predicted=out["predicted"], residuals=residual,
        jacobian=out["jacobian"], name=curve.name,
    )


def fit(
    model: Model | str,
    data: Curve | tuple,
    params: Mapping[str, Parameter | float] | None = None,
    *,
    loss: str = "sse",
    weights: Sequence[float] | np.ndarray | None = None,
    method: str = "lbfgs",
    n_starts: int | None = None,
    seed: int = 0,
    max_steps: int | None = None,
    tol: float = 1e-10,
    ftol: float = 1e-10,
    xtol: float = 1e-6,
    warmup_steps: int = 100,
    learning_rate: float = 0.05,
    relative_errors: bool = False,
) -> FitResult:
    """Fit a residence-time model to one curve by gradient descent; see the module docstring.

    **Arguments:**

    - `model`: a :class:`~fitting.models.Model` or a built-in name (``'adm'``, ``'adm-fv'``,
      ``'adm-open'``, ``'tanks'``, ``'four-compartment'``).
    - `data`: a :class:`~fitting.io.Curve` or a ``(time, values)`` pair (time strictly
      increasing, unit T; values E in 1/T).
    - `params`: start values and settings overriding the model's defaults: name ->
      :class:`Parameter` (whole setting) or number (start value only). Unset start values
      come from the model's method-of-moments guess when it has one.
    - `loss`: ``'sse'`` (least squares, default) or ``'mae'`` (the source's mean absolute
      error); see :mod:`fitting.objective`.
    - `weights`: ``w_i >= 0`` multiplying the squared (or absolute) residuals, e.g.
      ``1/sigma_i²``; zero drops a point.
    - `method`: ``'lbfgs'`` (default) or ``'adam'``.
    - `n_starts`: number of starts, run as one vmapped batch: the start value, then (for
      models with a moment estimate) the moment estimate, then random starts. ``None``
      (default): the start value, plus the moment estimate when it differs.
    - `seed`: seed of the random starts.
    - `max_steps`: iteration limit per start (default 500 for L-BFGS, 5000 for Adam).
    - `tol`: gradient-norm tolerance on the scaled loss in transformed coordinates.
    - `ftol`: relative loss change below which the iteration stops.
    - `xtol`: a least-squares fit counts as converged only if one Gauss–Newton step from the
      result would move no transformed coordinate by more than `xtol` (for positive
      parameters: a relative change); guards against stopping on a flat loss.
    - `warmup_steps`: Adam steps applied to each random start before L-BFGS.
    - `learning_rate`: Adam's step size in transformed coordinates.
    - `relative_errors`: treat the data's errors as proportional to the curve (multiplicative
      noise): fit, then refit with weights ``1 / max(|model|, floor)²`` from the latest
      model curve until consistent (see the module docstring). Not combined with `weights`.

    **Returns:**

    A :class:`FitResult`.
    """
    if relative_errors:
        return fit_many(model, [data], params, loss=loss,
                        weights=None if weights is None else [weights], method=method,
                        n_starts=n_starts, seed=seed, max_steps=max_steps, tol=tol, ftol=ftol,
                        xtol=xtol, warmup_steps=warmup_steps, learning_rate=learning_rate,
                        relative_errors=True)[0]
    curve = _as_curve(data)
    options = _options(loss, method, max_steps, tol, ftol, xtol, warmup_steps, learning_rate,
                       n_starts)
    prepared = _prepare(model, curve, params, weights, n_starts, seed)
    options = _without_idle_warmup(options, [prepared])
    # One curve is a batch of one: fit and fit_many share the compiled solver.
    solver = _compiled_solver(prepared.model, prepared.layout, options, "curves")
    out, wall_time, compile_time = _run_solver(
        solver, prepared.starts[None], prepared.warm, prepared.base[None], curve.time[None],
        curve.value[None], prepared.weights[None],
    )
    out = {k: v[0] for k, v in out.items()}
    return _result(prepared, prepared.layout, options, out, wall_time, compile_time)


def fit_many(
    model: Model | str,
    curves: Sequence[Curve | tuple],
    params: Mapping[str, Parameter | float] | Sequence[Mapping | None] | None = None,
    *,
    loss: str = "sse",
    weights: Sequence[Sequence[float] | None] | None = None,
    method: str = "lbfgs",
    n_starts: int | None = None,
    seed: int = 0,
    max_steps: int | None = None,
    tol: float = 1e-10,
    ftol: float = 1e-10,
    xtol: float = 1e-6,
    warmup_steps: int = 100,
    learning_rate: float = 0.05,
    relative_errors: bool = False,
) -> list[FitResult]:
    """Fit one model to many curves in a single vmapped, jitted call.

    Curves of different lengths are padded to the longest with zero-weight points (times
    continuing the last spacing), so they need not share a grid. Start values come from each
    curve's moments (or `params`); the free/fixed/tied layout and the bounds are shared.

    **Arguments:**

    - `model`, `loss`, `method`, `n_starts`, `seed`, `max_steps`, `tol`, `ftol`, `xtol`,
      `warmup_steps`, `learning_rate`: as in :func:`fit` (curve i uses seed ``seed + i``).
    - `params`: as in :func:`fit`, for all curves, or a list with one setting per curve.
    - `curves`: :class:`~fitting.io.Curve` objects or ``(time, values)`` pairs.
    - `weights`: one weight array (or ``None``) per curve, or ``None``.
    - `relative_errors`: as in :func:`fit`; both passes are one vmapped call each.

    **Returns:**

    One :class:`FitResult` per curve, in order; `wall_time` is each curve's share of the call.
    """
    settings = dict(loss=loss, method=method, seed=seed, max_steps=max_steps, tol=tol,
                    ftol=ftol, xtol=xtol, warmup_steps=warmup_steps,
                    learning_rate=learning_rate)
    if relative_errors:
        if weights is not None:
            raise ValueError("relative_errors sets the weights itself; pass weights=None")
        curves = [_as_curve(c) for c in curves]
        first = fit_many(model, curves, params, n_starts=n_starts, **settings)
        return _refit_with_relative_errors(model, curves, first, settings)
    curves = [_as_curve(c) for c in curves]
    if not curves:
        raise ValueError("fit_many needs at least one curve")
    options = _options(loss, method, max_steps, tol, ftol, xtol, warmup_steps, learning_rate,
                       n_starts)
    per_curve_weights = weights if weights is not None else [None] * len(curves)
    if len(per_curve_weights) != len(curves):
        raise ValueError(f"{len(per_curve_weights)} weight arrays for {len(curves)} curves")
    per_curve_params = (params if isinstance(params, Sequence) and not isinstance(params, str)
                        else [params] * len(curves))
    if len(per_curve_params) != len(curves):
        raise ValueError(f"{len(per_curve_params)} parameter settings for {len(curves)} curves")
    def prepare_all(count):
        return [_prepare(model, c, p, w, count, seed + i)
                for i, (c, p, w) in enumerate(zip(curves, per_curve_params, per_curve_weights,
                                                  strict=True))]

    prepared = prepare_all(n_starts)
    counts = {p.starts.shape[0] for p in prepared}
    if len(counts) > 1:
        # Default starts differ in number between curves: one batch needs one number.
        prepared = prepare_all(max(counts))
    options = _without_idle_warmup(options, prepared)
    layout = prepared[0].layout
    for other in prepared[1:]:
        if dataclasses.replace(other.layout, scale=layout.scale) != layout:
            raise ValueError("fit_many: every curve must have the same free, fixed and tied "
                             "parameters and bounds")
    length = max(len(c) for c in curves)
    times, values, padded_weights, starts = [], [], [], []
    for p in prepared:
        curve, extra = p.curve, length - len(p.curve)
        step = curve.time[-1] - curve.time[-2]
        times.append(np.concatenate([curve.time, curve.time[-1] + step * np.arange(1, extra + 1)]))
        values.append(np.concatenate([curve.value, np.zeros(extra)]))
        padded_weights.append(np.concatenate([p.weights, np.zeros(extra)]))
        # Layouts differ at most in the scale of unbounded parameters: re-express the starts.
        free = p.layout.physical_from_unconstrained(jnp.asarray(p.starts.T)).T
        starts.append(np.stack([layout.unconstrained_from_physical(np.asarray(row))
                                for row in free]))
    solver = _compiled_solver(prepared[0].model, layout, options, "curves")
    out, wall_time, compile_time = _run_solver(
        solver, np.stack(starts), prepared[0].warm, np.stack([p.base for p in prepared]),
        np.stack(times), np.stack(values), np.stack(padded_weights),
    )
    share = wall_time / len(curves)
    results = []
    for i, p in enumerate(prepared):
        n = len(p.curve)
        single = {k: np.asarray(v[i]) for k, v in out.items()}
        single["predicted"] = single["predicted"][:n]
        single["jacobian"] = single["jacobian"][:n]
        results.append(_result(p, layout, options, single, share,
                               compile_time / len(curves)))
    return results


#: Floor of the relative-error weights, as a fraction of the model curve's peak: points where
#: the model is below it are weighted as if it were this large (a measurement's error never
#: vanishes, and an unbounded weight would let one point near zero decide the fit).
RELATIVE_FLOOR = 1e-3


#: Most reweighting passes of a relative-error fit, and the relative change of every fitted
#: value between passes below which the weights count as consistent with the fit.
RELATIVE_MAX_PASSES, RELATIVE_CHANGE = 10, 1e-8


def _relative_weights(result: FitResult, loss: str) -> np.ndarray:
    size = np.abs(np.asarray(result.predicted, dtype=float))
    size = np.maximum(size, RELATIVE_FLOOR * max(float(size.max(initial=0.0)), 1e-300))
    return 1.0 / (size**2 if loss == "sse" else size)


def _refit_with_relative_errors(model, curves: Sequence[Curve], first: Sequence[FitResult],
                                settings: dict) -> list[FitResult]:
    """Iteratively reweighted fits: weights from the previous pass's model curves, until the
    fitted values stop changing (the weights are then those of the fit's own curve)."""
    results, passes = list(first), 1
    evaluations = np.array([r.n_evaluations for r in first])
    wall = np.array([r.wall_time for r in first])
    compile_time = np.array([r.compile_time for r in first])
    for _ in range(RELATIVE_MAX_PASSES - 1):
        starts = [r.restart_parameters() for r in results]
        weights = [_relative_weights(r, settings["loss"]) for r in results]
        new = fit_many(model, curves, starts, weights=weights, n_starts=1, **settings)
        passes += 1
        evaluations += [r.n_evaluations for r in new]
        wall += [r.wall_time for r in new]
        compile_time += [r.compile_time for r in new]
        change = max(abs(b.values[n] / a.values[n] - 1) if a.values[n] else abs(b.values[n])
                     for a, b in zip(results, new, strict=True) for n in a.free_names)
        results = new
        if change <= RELATIVE_CHANGE:
            break
    method = f"relative errors: reweighted by 1/model^2 until consistent ({passes} passes)"
    return [
        _with_effective_dof(dataclasses.replace(
            r, n_evaluations=int(e), wall_time=float(w), compile_time=float(c),
            method=f"{r.method}; {method}", n_starts=f.n_starts, init_params=f.init_params,
        ))
        for r, f, e, w, c in zip(results, first, evaluations, wall, compile_time, strict=True)
    ]


def _with_effective_dof(result: FitResult) -> FitResult:
    """Residual variance of a relative-error least-squares fit, counting floored points right.

    With variance ``σ² m_i²`` and weights ``w_i = 1 / max(m_i, floor)²``, the expected
    ``Σ w r²`` is ``σ² Σ a_i (1 - h_i)`` with ``a_i = w_i m_i²`` (1, or below 1 where the
    floor caps the weight) and ``h_i`` the leverages of the weighted fit: these are the
    degrees of freedom (``n - p`` when no weight is capped). A point far below the floor
    holds almost no residual, and counting it as a full degree of freedom would understate
    ``s``. Standard errors, intervals and ``dof`` (then not a whole number) are rescaled.
    """
    if result.loss_name != "sse" or result.dof <= 0:
        return result
    from fitting.uncertainty import effective_degrees_of_freedom

    model_size = np.abs(np.asarray(result.predicted, dtype=float))
    dof = effective_degrees_of_freedom(result.jacobian, result.weights,
                                       result.weights * model_size**2)
    if not (math.isfinite(dof) and dof > 0):
        return result
    factor = math.sqrt(result.dof / dof)
    from scipy import stats

    t_quantile = float(stats.t.ppf(0.975, dof))
    stderr, ci95 = {}, {}
    for name, error in result.stderr.items():
        if error is None:
            stderr[name], ci95[name] = None, None
            continue
        stderr[name] = error * factor
        ci95[name] = _interval(result.values[name], t_quantile * stderr[name],
                               result.init_params[name])
    return dataclasses.replace(result, stderr=stderr, ci95=ci95,
                               covariance=result.covariance * factor**2,
                               sigma=result.sigma * factor, dof=dof)
