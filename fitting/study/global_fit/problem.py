"""A study's joint least-squares problem, ready for the solver
(:func:`~fitting.study.global_fit.global_problem`): the curves checked and padded to one
length, the factor table, the weights of every sample (each curve's error model from its
first-stage fit), and start values from those fits.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax.numpy as jnp
import numpy as np

from fitting.data import Curve, as_curve
from fitting.fit import fit_many
from fitting.models import Model
from fitting.parameters import Layout, make_layout
from fitting.result import FitResult
from fitting.solve import padded_length
from fitting.study.global_fit.joint import joint_model, joint_parameters
from fitting.study.global_fit.law import factor_column
from fitting.study.global_fit.model import GlobalModel, curve_name

#: How the curves of a global fit are weighted against each other.
WEIGHTINGS = ("combined", "per-curve", "equal")


@dataclass(frozen=True, eq=False)
class GlobalProblem:
    """One study's joint least-squares problem, ready for the solver (see :func:`global_problem`).

    **Fields:**

    - `spec`: the :class:`GlobalModel`; `curves`: the curves, in order.
    - `factors`: the factor columns the laws read, one number per curve.
    - `model`: the joint model, a :class:`~fitting.models.Model` of the flattened, padded
      times of all curves (``n_curves × length`` samples, curve by curve).
    - `layout`: its :class:`~fitting.parameters.Layout` (every joint parameter is free).
    - `names`: the joint parameters: law coefficients, shared, then per curve as
      ``"tau[3]"`` (curve index 3).
    - `start`: start values of `names`.
    - `time`, `observed`, `weights`: flattened padded data (zero weights on padding).
    - `length`: samples per curve after padding.
    - `weighting`: ``"combined"``, ``"per-curve"``, ``"equal"`` or ``"given"``; `first`: the
      first-stage fits.
    """

    spec: GlobalModel
    curves: tuple[Curve, ...]
    factors: Mapping[str, np.ndarray]
    model: Model
    layout: Layout
    names: tuple[str, ...]
    start: np.ndarray
    time: np.ndarray
    observed: np.ndarray
    weights: np.ndarray
    length: int
    weighting: str = "per-curve"
    first: tuple[FitResult, ...] = field(default=(), repr=False)

    def predict(self, free_values):
        """The model curves of all curves, flattened like `time` (JAX; jit/grad/vmap-able).

        **Arguments:** `free_values`: values of :attr:`names`, shape ``(p,)``.

        **Returns:** the joint model at :attr:`time`, shape ``(n_curves × length,)``.
        """
        values = self.layout.all_values(free_values, jnp.asarray(self.start))
        return self.model(jnp.asarray(self.time), values)

    def residuals(self, free_values):
        """Weighted residuals ``sqrt(w) (model - data)``, zero on padding (JAX).

        **Arguments:** `free_values`: values of :attr:`names`.

        **Returns:** shape ``(n_curves × length,)``, in the data's unit (times ``sqrt(w)``).
        """
        weights = jnp.asarray(self.weights)
        difference = self.predict(free_values) - jnp.asarray(self.observed)
        return jnp.where(weights > 0, jnp.sqrt(weights) * difference, 0.0)

    def sse(self, free_values):
        """The joint objective ``Σ w r²`` over every sample of every curve (JAX).

        **Arguments:** `free_values`: values of :attr:`names`.

        **Returns:** a scalar, in the data's unit squared (times the weights).
        """
        residual = self.residuals(free_values)
        return residual @ residual


def _check_curves(curves: Sequence[Curve]) -> None:
    if len(curves) < 2:
        raise ValueError("a global fit needs at least two curves")
    units = {c.time_unit for c in curves}
    if len(units) > 1:
        raise ValueError(f"the curves have different time units ({', '.join(sorted(units))}); "
                         "give them in one unit")
    for index, curve in enumerate(curves):
        label = curve.name or f"curve {index}"
        if len(curve) < 2 or not np.all(np.diff(curve.time) > 0):
            raise ValueError(f"{label}: need at least two samples at increasing times")
        if not (np.all(np.isfinite(curve.time)) and np.all(np.isfinite(curve.value))):
            raise ValueError(f"{label}: times and values must be finite")


def _factor_table(spec: GlobalModel, factors: Mapping[str, Any] | None,
                  count: int) -> dict[str, np.ndarray]:
    factors = {} if factors is None else factors
    table = {}
    for name in spec.factors:
        column = factor_column(factors, name)
        if column.shape != (count,):
            raise ValueError(f"factor {name!r} has {column.size} values for {count} curves")
        table[name] = column
    for law in spec.laws:
        design = law.design(table)
        rank = np.linalg.matrix_rank(design)
        if rank < design.shape[1]:
            raise ValueError(f"the factor law of {law.parameter!r} cannot be estimated: its "
                             f"design ({', '.join(law.terms)} and an intercept over {count} "
                             f"curves) has rank {rank} < {design.shape[1]} (a term is constant "
                             "or a combination of the others)")
    return table


def _starts(spec: GlobalModel, first: Sequence[FitResult],
            factors: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Start values from the first-stage fits: per-curve values, medians of shared ones, the
    least-squares law through the transformed per-curve values."""
    start: dict[str, float] = {}
    curve_model = spec.curve_model
    for law in spec.laws:
        target = law.linear([r.values[law.parameter] for r in first])
        usable = np.isfinite(target)
        design = law.design(factors)
        if np.count_nonzero(usable) >= design.shape[1]:
            coefficients = np.linalg.lstsq(design[usable], target[usable], rcond=None)[0]
        else:  # too few usable first-stage values: a constant law at the model's default
            coefficients = np.zeros(design.shape[1])
            coefficients[0] = float(law.linear(curve_model.defaults[law.parameter].value))
        start.update(zip(law.coefficient_names, coefficients.tolist(), strict=True))
    for name in spec.shared:
        values = np.array([r.values[name] for r in first], dtype=float)
        values = values[np.isfinite(values)]
        start[name] = float(np.median(values)) if values.size else \
            curve_model.defaults[name].value
    for name in spec.per_curve:
        fallback = np.nanmedian([r.values[name] for r in first])
        for i, r in enumerate(first):
            value = float(r.values[name])
            start[curve_name(name, i)] = value if math.isfinite(value) else float(fallback)
    return start


def global_problem(
    spec: GlobalModel,
    curves: Sequence[Curve | tuple],
    factors: Mapping[str, Sequence[float]] | None,
    first: Sequence[FitResult] | None = None,
    weights: str | Sequence[float] = "combined",
) -> GlobalProblem:
    """The joint least-squares problem of a study (what :func:`global_fit` solves).

    **Arguments:**

    - `spec`: the :class:`GlobalModel`.
    - `curves`: :class:`~fitting.data.Curve` s or ``(time, values)`` pairs: raw signals
      (each has its own amplitude), each on its own time grid.
    - `factors`: factor columns by name, one number per curve, in the order of `curves`
      (every column a law reads).
    - `first`: first-stage fits of the curves (:func:`fitting.fit.fit_many` with
      ``spec.curve_model``; combined errors for ``weights="combined"``, else absolute), or
      ``None`` to run them here.
    - `weights`: ``"combined"`` (default: each sample weighted by ``1 / (a_i² + (b_i m)²)``,
      the additive plus proportional error model of curve ``i`` estimated by its own
      first-stage fit, ``m`` that fit's model curve: the error model ``axialmix fit`` uses),
      ``"per-curve"`` (weights ``1 / s_i²`` from the first-stage fits),
      ``"equal"`` (see the module docstring), or one known weight per curve (``1 / σ_i²``
      up to a common factor, e.g. from the detector's noise).

    **Returns:** a :class:`GlobalProblem`; a one-line ``ValueError`` for bad input.
    """
    if not isinstance(spec, GlobalModel):
        raise ValueError(f"spec must be a GlobalModel, got {type(spec).__name__}")
    curves = tuple(as_curve(c) for c in curves)
    _check_curves(curves)
    count = len(curves)
    given = None
    if isinstance(weights, str):
        if weights not in WEIGHTINGS:
            raise ValueError(f"weights must be one of {', '.join(WEIGHTINGS)} or one number "
                             f"per curve, got {weights!r}")
    else:
        given = np.asarray(weights, dtype=float)
        if given.shape != (count,) or not np.all(np.isfinite(given) & (given > 0)):
            raise ValueError(f"weights: give one positive number per curve ({count}), or "
                             f"{' or '.join(map(repr, WEIGHTINGS))}")
        weights = "given"
    table = _factor_table(spec, factors, count)
    if first is None:
        first = fit_many(spec.curve_model, curves,
                         errors="combined" if weights == "combined" else "absolute")
    first = tuple(first)
    if len(first) != count:
        raise ValueError(f"{len(first)} first-stage fits for {count} curves")
    missing = [n for n in spec.fitted if n not in first[0].values]
    if missing:
        raise ValueError(f"the first-stage fits have no {missing[0]!r}: fit the curves with "
                         "spec.curve_model")
    length = padded_length(max(len(c) for c in curves))
    times, observed, point_weights = [], [], []
    for index, (curve, result) in enumerate(zip(curves, first, strict=True)):
        extra = length - len(curve)
        step = curve.time[-1] - curve.time[-2]
        times.append(np.concatenate([curve.time, curve.time[-1] + step * np.arange(1, extra + 1)]))
        observed.append(np.concatenate([curve.value, np.zeros(extra)]))
        size = 1.0 if given is None else 1.0 / given[index]
        if weights == "combined":
            error = result.error_model
            if error is None or not (error.additive > 0 or error.proportional > 0):
                raise ValueError(f"curve {curve.name or index!r}: its own fit gives no error "
                                 "model (fitted without combined errors, or an exact curve?); "
                                 "use weights='equal'")
            sd = error.standard_deviation(np.asarray(result.predicted, dtype=float))
            point_weights.append(np.concatenate([1.0 / sd**2, np.zeros(extra)]))
            continue
        if weights == "per-curve":
            size = float(result.sigma) ** 2
            if not (math.isfinite(size) and size > 0):
                raise ValueError(f"curve {curve.name or index!r}: its own fit "
                                 "gives no noise level (an exact curve?); use weights='equal'")
        point_weights.append(np.concatenate([np.full(len(curve), 1.0 / size), np.zeros(extra)]))
    point_weights = np.concatenate(point_weights)
    point_weights = point_weights / point_weights.max()  # only relative weights matter
    designs = tuple(law.design(table).tobytes() for law in spec.laws)
    model = joint_model(spec, count, length, designs)
    start = _starts(spec, first, table)
    params = joint_parameters(spec, start, count)
    layout = make_layout(model.name, model.parameter_names, params)
    values = np.array([params[n].value for n in layout.names])
    return GlobalProblem(spec, curves, table, model, layout, layout.names, values,
                         np.concatenate(times), np.concatenate(observed), point_weights,
                         length, weights, first)
