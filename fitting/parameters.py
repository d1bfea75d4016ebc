"""Fit parameters in lmfit's vocabulary: values, bounds, fixed and tied parameters.

A :class:`Parameter` has a ``value``, optional bounds ``min`` and ``max``, ``vary`` (``False``
fixes it) and ``expr`` (ties it to other parameters, e.g. ``Parameter(1.0, expr="k_f")`` or
``expr="2*k_f"``). A :class:`Layout` is the static plan of one fit: which parameters are
free, fixed or tied, and how each free one is mapped to an unconstrained coordinate ``u``:
``p = min + exp(u)`` with only a lower bound (``log`` for positive parameters),
``p = max - exp(u)`` with only an upper bound, ``p = min + (max - min) sigmoid(u)`` with
both, and ``p = s u`` with none (``s``: the power of ten nearest the start value). Bounds
therefore hold exactly and the optimiser never sees a constraint.
"""

from __future__ import annotations

import ast
import functools
import math
import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)

__all__ = [
    "PARAMETER_ALIASES",
    "Layout",
    "Parameter",
    "Parameters",
    "clip_into_bounds",
    "evaluate_expression",
    "expression_names",
    "canonical_name",
    "make_layout",
    "parse_expression",
]

#: Symbols accepted for parameter names on the command line (the files and tables always
#: use the name): the Peclet number's symbol, and the short names of the measurement model.
PARAMETER_ALIASES = {"Pe": "peclet", "t_d": "dead_time", "b": "baseline"}


def canonical_name(name: str) -> str:
    """The parameter name for `name` or its symbol (``"Pe"`` -> ``"peclet"``)."""
    return PARAMETER_ALIASES.get(name, name)



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
            parse_expression(self.expr)

    def replace(self, **changes: Any) -> Parameter:
        """A copy with some fields changed, e.g. ``p.replace(vary=False)``."""
        fields = {"value": self.value, "min": self.min, "max": self.max, "vary": self.vary,
                  "expr": self.expr}
        unknown = changes.keys() - fields.keys()
        if unknown:
            raise TypeError(f"Parameter has no field {sorted(unknown)[0]!r}")
        return Parameter(**(fields | changes))


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
def parse_expression(expr: str) -> ast.Expression:
    """Parse a tie expression, allowing only numbers, names, + - * / ** and parentheses.

    **Arguments:** `expr`: the expression text.

    **Returns:** the parsed tree (cached); a one-line ``ValueError`` for anything else.
    """
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


def expression_names(expr: str) -> set[str]:
    """The parameter names a tie expression reads."""
    return {n.id for n in ast.walk(parse_expression(expr)) if isinstance(n, ast.Name)}


def evaluate_expression(node: ast.AST, values: Mapping[str, Any]) -> Any:
    """Value of a parsed tie expression with parameter `values` (numbers or JAX scalars)."""
    if isinstance(node, ast.Expression):
        return evaluate_expression(node.body, values)
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        return values[node.id]
    if isinstance(node, ast.BinOp):
        left = evaluate_expression(node.left, values)
        return _BINARY[type(node.op)](left, evaluate_expression(node.right, values))
    return _UNARY[type(node.op)](evaluate_expression(node.operand, values))


# --- the static layout of a fit ----------------------------------------------------------------


@dataclass(frozen=True)
class Layout:
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
            values[name] = evaluate_expression(parse_expression(expr), values)
        return values


def make_layout(model_name: str, parameter_names: Sequence[str], params: Parameters) -> Layout:
    """The static layout of a fit of a model with `parameter_names` under settings `params`.

    **Arguments:**

    - `model_name`: the model's name (for messages).
    - `parameter_names`: the names the model reads, in order.
    - `params`: a setting for each of them (and possibly extra parameters used in ties).

    **Returns:** a :class:`Layout`; a one-line ``ValueError`` for a missing parameter, a
    name the model does not read that no tie uses, an unknown name in a tie, a cycle of
    ties, or nothing left to fit.
    """
    parameter_names = tuple(parameter_names)
    names = parameter_names + tuple(n for n in params if n not in parameter_names)
    missing = [n for n in parameter_names if n not in params]
    if missing:
        raise ValueError(f"no value for parameter(s) {missing} of model {model_name!r}")
    # A name the model does not read is kept only when a tie uses it (an extra parameter
    # that other ones are expressed in); otherwise it is a misspelling, refused.
    used = set()
    for n in params:
        if params[n].expr is not None:
            used |= expression_names(params[n].expr)
    unknown = [n for n in params if n not in parameter_names and n not in used
               and params[n].expr is None]
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown} for model {model_name!r} "
                         f"(its parameters: {', '.join(parameter_names)})")
    free, kinds, lower, upper, scale = [], [], [], [], []
    pending = {}
    for name in names:
        p = params[name]
        if p.expr is not None:
            unknown = expression_names(p.expr) - set(names)
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
        ready = [n for n, e in pending.items() if expression_names(e) <= resolved]
        if not ready:
            raise ValueError(f"parameter ties form a cycle: {sorted(pending)}")
        for name in ready:
            tied.append((name, pending.pop(name)))
            resolved.add(name)
    if not free:
        raise ValueError("nothing to fit: every parameter is fixed or tied")
    return Layout(names, parameter_names, tuple(free), tuple(kinds),
                   tuple(lower), tuple(upper), tuple(scale), tuple(tied))


def clip_into_bounds(value: float, parameter: Parameter) -> float:
    """Move a start value strictly inside the parameter's bounds.

    **Arguments:** `value`: a start value; `parameter`: the setting with the bounds.

    **Returns:** `value`, or the nearest point a little inside the bounds.
    """
    low = parameter.min if parameter.min is not None else -np.inf
    high = parameter.max if parameter.max is not None else np.inf
    if np.isfinite(low) and np.isfinite(high):
        margin = 1e-3 * (high - low)
        return float(np.clip(value, low + margin, high - margin))
    if np.isfinite(low) and value <= low:
        return float(low + max(abs(low), 1.0) * 1e-3)
    if np.isfinite(high) and value >= high:
        return float(high - max(abs(high), 1.0) * 1e-3)
    return float(value)
