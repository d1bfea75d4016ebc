"""Global fits: parameters shared across the curves of a study, or following a factor law.

A study's curves are fitted jointly: one least-squares problem over the residuals of every
curve, one parameter vector, one covariance. Each model parameter is

* **per curve** (the default): one value for each curve, like a fit of that curve alone;
* **shared** (:attr:`GlobalModel.shared`): one value for all curves; or
* **given by a factor law** (:class:`FactorLaw`): for curve ``i`` with factor values
  ``x_i1, x_i2, ...`` (columns of the study table), ``g(p_i) = c0 + c1 x_i1 + c2 x_i2 + ...``
  with ``g = ln`` (``transform="log"``, for positive parameters such as the Peclet number)
  or ``g`` the identity. The coefficients ``c`` are fitted parameters of the joint problem,
  so they come with standard errors and 95 % intervals from its one covariance.

Every curve keeps its own measurement model (:func:`fitting.measurement.measured`): its
amplitude ``A_i`` (tracer amount over the flow) is always a per-curve parameter (or
shared, if listed), and a freed dead time or baseline is per curve too. Curves keep their
own time grids: each is padded with zero-weight points to a common length, and the model of
all curves is one ``vmap`` over them (no loop over curves in the traced program).

How it is solved (:func:`global_fit`):

1. **First stage.** Each curve is fitted alone (:func:`fitting.fit.fit_many`, one compiled
   solver for all of them). These fits give the starts (per-curve values; the median of a
   shared parameter; the least-squares regression of ``g(p_i)`` on the factors for a
   law's coefficients) and each curve's error model: with ``weights="combined"`` (the
   default) its additive and proportional noise sizes ``a_i`` and ``b_i``, estimated as
   ``axialmix fit`` estimates them; with ``"per-curve"`` its noise level ``s_i``.
2. **Joint fit.** The stacked residuals ``sqrt(w_ij) (A_i (E_i ⊗ u)(t_ij) + b_i - c_ij)``, with
   ``w_ij = 1 / (a_i² + (b_i m_ij)²)`` (``"combined"``, ``m_ij`` the first-stage model curve:
   samples count by their precision within and across curves, as in two-stage generalised least
   squares), ``w_ij = 1 / s_i²`` (``"per-curve"``) or ``w_ij = 1`` (``"equal"``: one noise size for
   the whole study), are minimised by the project's compiled Levenberg–Marquardt solver
   (:func:`fitting.solve.compiled_solver`, the program fits treat as one curve), and the covariance
   is the Gauss–Newton one of :func:`fitting.uncertainty.gauss_newton_uncertainty` over all free
   parameters: ``C = s² (Jᵀ W J)⁻¹``, ``s² = Σ w r² / ν``, intervals ``± t(0.975, ν) · se`` with
   ``ν = N - p`` degrees of freedom (``N`` samples, ``p`` joint parameters), less the number of
   estimated noise sizes minus one (``2 n_curves - 1`` with combined weights, ``n_curves - 1`` with
   per-curve ones: estimated from the same data). Per-curve values that a law gives carry
   delta-method errors (``se(g(p_i)) = sqrt(x_i C_c x_iᵀ)``, intervals back-transformed, so positive
   under ``ln``).

:func:`two_stage_law` is the usual alternative: fit curves one by one, then regress their
fitted values on the factors; its intervals rest on the scatter of ``n_curves`` points
around the law (``n_curves - k - 1`` degrees of freedom) and are wider.

What the intervals assume (measured in ``tests/test_study_global.py``, opt-in study of 200
replicated 18-curve designs):

* **The law holds exactly for every run.** The global fit has no term for run-to-run
  scatter of the parameter around the law; where runs scatter (a process effect the law
  does not hold), its intervals are too short (ln Pe scattering by 0.05 between runs:
  coverage 0.68 to 0.75), while the two-stage regression, whose errors come from that scatter,
  stays right (coverage 0.925 to 0.97). Check the law first (an ANOVA of the one-by-one
  values, or the two-stage residuals) before trusting the global intervals.
* **The curves' weights.** With known weights (one number per curve, ``1 / σ_i²``) the
  intervals hold their 95 % (coverage 0.93 to 0.955; spread of the estimates over their
  standard errors 1.00 to 1.05); with weights estimated from each curve's own fit
  (``"per-curve"``, about 25 samples a curve) that ratio is 1.09 to 1.12 (coverage 0.915
  to 0.94): the estimated weights' own noise is not in the covariance.

The Jacobian of the joint problem is dense (``N`` samples by ``p = k + 1 + m n_curves``
parameters for one law and ``m`` per-curve parameters), so memory and time grow with the
square of the number of curves: a global fit is meant for studies of tens to a few hundred
curves; batch fits of thousands are :func:`fitting.fit.fit_many`'s business.
"""

from __future__ import annotations

import functools
import math
import time as _time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.data import Curve, as_curve
from fitting.fit import fit_many
from fitting.measurement import FREEABLE, Inlet, measured
from fitting.models import MODELS, Model, get_model
from fitting.parameters import Layout, Parameter, Parameters, make_layout
from fitting.physical import PhysicalQuantity, hook_numbers, propagated_quantities
from fitting.result import FitResult
from fitting.solve import (
    CONVERGED,
    STATUS_MESSAGES,
    MultiStart,
    Optimiser,
    Status,
    compiled_solver,
    make_plan,
    padded_length,
    run_solver,
)
from fitting.uncertainty import gauss_newton_uncertainty, interval, t_quantile

__all__ = [
    "LAW_TRANSFORMS",
    "curve_physical_quantities",
    "WEIGHTINGS",
    "FactorLaw",
    "GlobalFitResult",
    "GlobalModel",
    "GlobalProblem",
    "LawEstimate",
    "global_fit",
    "global_problem",
    "two_stage_law",
]

#: The transforms a factor law may apply to its parameter.
LAW_TRANSFORMS = ("log", "identity")
#: How the curves of a global fit are weighted against each other.
WEIGHTINGS = ("combined", "per-curve", "equal")
#: Inlet signals a global fit supports (every curve gets the same kind).
_INLETS = ("pulse", "step")
#: How the report describes the curves' weights.
_WEIGHTING_WORDS = {"combined": "by each sample's noise, a_i² + (b_i m)², both estimated "
                                "from the curve's own fit",
                    "per-curve": "by their own noise level (estimated)", "equal": "equally",
                    "given": "by the given weights"}
#: Joint models kept per process (same structure: the same compiled solver).
_CACHE_SIZE = 16


def _names(value, what: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = (value,)
    names = tuple(value)
    for name in names:
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"{what} must be non-empty names, got {name!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"{what} lists a name twice: {', '.join(names)}")
    return names


class FactorLaw(eqx.Module):
    """A model parameter given by the process factors, ``g(p_i) = c0 + Σ_j c_j x_ij``.

    **Arguments:**

    - `parameter`: the model parameter the law gives (``"peclet"``, ``"tau"``, ...).
    - `terms`: factor columns of the study table, numeric, each entering linearly; a term
      ``"a:b"`` is the product of columns ``a`` and ``b`` (an interaction).
    - `transform`: ``"log"`` (default: ``ln p_i`` is linear in the factors, so ``p_i`` stays
      positive and a coefficient is a relative change per unit of its factor) or
      ``"identity"`` (``p_i`` itself is linear).

    The law's coefficients are named ``"<parameter>:intercept"`` and
    ``"<parameter>:<term>"`` (:attr:`coefficient_names`).
    """

    parameter: str = eqx.field(static=True)
    terms: tuple[str, ...] = eqx.field(static=True, converter=lambda t: _names(t, "terms"))
    transform: str = eqx.field(default="log", static=True)

    def __check_init__(self):
        if not isinstance(self.parameter, str) or not self.parameter.strip():
            raise ValueError(f"a factor law needs a parameter name, got {self.parameter!r}")
        if not self.terms:
            raise ValueError(f"the factor law of {self.parameter!r} has no terms: give at least "
                             "one factor column (a parameter equal for all curves is shared)")
        if self.transform not in LAW_TRANSFORMS:
            raise ValueError(f"transform must be one of {', '.join(LAW_TRANSFORMS)}, got "
                             f"{self.transform!r}")
        for term in self.terms:
            if any(not part.strip() for part in term.split(":")):
                raise ValueError(f"term {term!r}: an interaction names factors as a:b")

    @property
    def coefficient_names(self) -> tuple[str, ...]:
        """The names of the law's coefficients: the intercept, then one per term."""
        return (f"{self.parameter}:intercept",
                *(f"{self.parameter}:{term}" for term in self.terms))

    @property
    def factors(self) -> tuple[str, ...]:
        """The factor columns the law reads, in order of first use."""
        return tuple(dict.fromkeys(part for term in self.terms for part in term.split(":")))

    def describe(self) -> str:
        """The law as a formula, e.g. ``ln peclet = c0 + c1 speed + c2 flow``."""
        left = f"ln {self.parameter}" if self.transform == "log" else self.parameter
        right = " + ".join(["c0", *(f"c{j} {t}" for j, t in enumerate(self.terms, start=1))])
        return f"{left} = {right}"

    def design(self, factors: Mapping[str, np.ndarray]) -> np.ndarray:
        """The design matrix ``[1, x_i1, x_i2, ...]`` of the law over the curves.

        **Arguments:** `factors`: factor columns by name, one number per curve.

        **Returns:** an ``(n_curves, 1 + len(terms))`` array; a one-line ``ValueError`` for a
        missing or non-numeric column.
        """
        columns = []
        for term in self.terms:
            column = None
            for part in term.split(":"):
                values = _factor_column(factors, part)
                column = values if column is None else column * values
            columns.append(column)
        count = len(columns[0])
        return np.column_stack([np.ones(count), *columns])

    def apply(self, linear):
        """The parameter from the law's linear predictor (``exp`` for ``"log"``; JAX or NumPy)."""
        return jnp.exp(linear) if self.transform == "log" else linear

    def linear(self, value: np.ndarray) -> np.ndarray:
        """The law's linear predictor from parameter values (``ln`` for ``"log"``; NumPy)."""
        value = np.asarray(value, dtype=float)
        if self.transform == "log":
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(value > 0, np.log(np.where(value > 0, value, 1.0)), np.nan)
        return value


def _factor_column(factors: Mapping[str, Any], name: str) -> np.ndarray:
    if name not in factors:
        known = ", ".join(map(repr, factors)) or "none"
        raise ValueError(f"factor {name!r} is not among the study's factor columns ({known})")
    try:
        values = np.asarray(factors[name], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"factor {name!r} is not numeric; a factor law needs numbers") from None
    if values.ndim != 1 or not np.all(np.isfinite(values)):
        raise ValueError(f"factor {name!r} needs one finite number per curve")
    return values


class GlobalModel(eqx.Module):
    """Which parameters of a study's curves are shared, given by factor laws, or per curve.

    **Arguments:**

    - `model`: a built-in model name (:data:`fitting.models.MODELS`, e.g. ``"adm"``); each
      curve is fitted as that model in the measurement model
      ``A_i (E ⊗ u)(t - t_d) + b`` (:func:`fitting.measurement.measured`).
    - `laws`: :class:`FactorLaw` s, at most one per parameter of the model.
    - `shared`: parameters with one value for all curves: of the model, or measurement
      parameters (``"amplitude"``, and a freed ``"dead_time"`` or ``"baseline"``).
    - `free`: measurement parameters fitted besides the amplitude (``"dead_time"``,
      ``"baseline"``; fixed at 0 otherwise), per curve unless shared.
    - `inlet`: ``"pulse"`` (default: the curves are pulse responses) or ``"step"``
      (F-curves).

    Every other parameter (and the amplitude) is fitted per curve.
    """

    model: str = eqx.field(static=True)
    laws: tuple[FactorLaw, ...] = eqx.field(default=(), static=True, converter=tuple)
    shared: tuple[str, ...] = eqx.field(default=(), static=True,
                                        converter=lambda s: _names(s, "shared"))
    free: tuple[str, ...] = eqx.field(default=(), static=True,
                                      converter=lambda s: _names(s, "free"))
    inlet: str = eqx.field(default="pulse", static=True)

    def __check_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; choose from "
                             f"{', '.join(sorted(MODELS))}")
        base = MODELS[self.model].parameter_names
        for law in self.laws:
            if not isinstance(law, FactorLaw):
                raise ValueError(f"laws must be FactorLaw objects, got {type(law).__name__}")
            if law.parameter not in base:
                raise ValueError(f"a factor law gives {law.parameter!r}, which is not a "
                                 f"parameter of model {self.model!r} ({', '.join(base)})")
        given = [law.parameter for law in self.laws]
        if len(set(given)) != len(given):
            raise ValueError("two factor laws give the same parameter")
        unknown = [name for name in self.free if name not in FREEABLE]
        if unknown:
            raise ValueError(f"free: {unknown[0]!r} is not a measurement parameter that can be "
                             f"freed ({', '.join(FREEABLE)})")
        allowed = (*base, "amplitude", *self.free)
        for name in self.shared:
            if name not in allowed:
                raise ValueError(f"shared parameter {name!r} is not a parameter of model "
                                 f"{self.model!r} or a fitted measurement parameter "
                                 f"({', '.join(allowed)})")
            if name in given:
                raise ValueError(f"{name!r} is both shared and given by a factor law")
        if not (self.laws or self.shared):
            raise ValueError("a global fit needs a factor law or a shared parameter; without "
                             "one the curves are independent (fit them with fit_many)")
        if self.inlet not in _INLETS:
            raise ValueError(f"inlet must be one of {', '.join(_INLETS)}, got {self.inlet!r}")

    @property
    def curve_model(self) -> Model:
        """The model one curve is fitted with (the measurement model around :attr:`model`)."""
        inlet = Inlet.pulse() if self.inlet == "pulse" else Inlet.step()
        return measured(self.model, inlet, self.free)

    @property
    def fitted(self) -> tuple[str, ...]:
        """The parameters fitted for a curve: the model's, the amplitude, freed ones."""
        return (*get_model(self.model).parameter_names, "amplitude", *self.free)

    @property
    def per_curve(self) -> tuple[str, ...]:
        """The parameters fitted once per curve."""
        given = {law.parameter for law in self.laws}
        return tuple(n for n in self.fitted if n not in given and n not in self.shared)

    @property
    def factors(self) -> tuple[str, ...]:
        """Every factor column the laws read."""
        return tuple(dict.fromkeys(f for law in self.laws for f in law.factors))

    def law_of(self, name: str) -> FactorLaw | None:
        """The law that gives parameter `name`, or ``None``."""
        return next((law for law in self.laws if law.parameter == name), None)


def _curve_name(name: str, index: int) -> str:
    return f"{name}[{index}]"


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
        column = _factor_column(factors, name)
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


@functools.lru_cache(maxsize=_CACHE_SIZE)
def _joint_model(spec: GlobalModel, count: int, length: int, designs: tuple[bytes, ...]) -> Model:
    """The joint model of a study structure; the same structure gives the same object, so
    its compiled solver is reused (the designs are constants of the program)."""
    curve_model = spec.curve_model
    matrices = {law.parameter: jnp.asarray(np.frombuffer(blob).reshape(count, -1))
                for law, blob in zip(spec.laws, designs, strict=True)}
    names = _joint_names(spec, count)
    per_curve = spec.per_curve
    fixed = {n: curve_model.defaults[n].value for n in curve_model.parameter_names
             if n not in spec.fitted}

    def function(t, p):
        size = count * length
        columns = {}
        for name in spec.fitted:
            law = spec.law_of(name)
            if law is not None:
                coefficients = jnp.stack([p[c] for c in law.coefficient_names])
                columns[name] = law.apply(matrices[name] @ coefficients)
            elif name in spec.shared:
                columns[name] = jnp.broadcast_to(p[name], (count,))
            else:
                # Gathers the per-curve entries of the parameter vector (bookkeeping; the
                # model itself runs once, vmapped over the curves).
                columns[name] = jnp.stack([p[_curve_name(name, i)] for i in range(count)])
        for name, value in fixed.items():
            columns[name] = jnp.full((count,), value)
        times = t[:size].reshape(count, length)
        curves = jax.vmap(curve_model)(times, columns)
        return jnp.concatenate([curves.reshape(size), jnp.zeros(t.shape[0] - size)])

    defaults = {n: Parameter(0.0) for n in names}
    label = ", ".join([law.describe() for law in spec.laws]
                      + [f"shared {', '.join(spec.shared)}"] * bool(spec.shared))
    return Model(name=f"global-{spec.model}", parameter_names=names, function=function,
                 defaults=defaults,
                 description=f"{count} curves of {curve_model.description}; {label}; "
                 f"{', '.join(per_curve)} per curve")


def _joint_names(spec: GlobalModel, count: int) -> tuple[str, ...]:
    names = [c for law in spec.laws for c in law.coefficient_names]
    names += [n for n in spec.fitted if n in spec.shared]
    names += [_curve_name(n, i) for n in spec.per_curve for i in range(count)]
    return tuple(names)


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
            start[_curve_name(name, i)] = value if math.isfinite(value) else float(fallback)
    return start


def _joint_parameters(spec: GlobalModel, start: Mapping[str, float], count: int) -> Parameters:
    defaults = spec.curve_model.defaults
    params = Parameters()
    for law in spec.laws:
        for name in law.coefficient_names:
            params[name] = Parameter(start[name])
    for name in spec.fitted:
        setting = defaults[name].replace(vary=True)
        keys = [name] if name in spec.shared else \
            [_curve_name(name, i) for i in range(count)] if name in spec.per_curve else []
        for key in keys:
            value = start[key]
            low = setting.min if setting.min is not None else -math.inf
            high = setting.max if setting.max is not None else math.inf
            if not low < value < high:  # a first-stage value on its bound: start inside
                value = min(max(value, low + 1e-9 * max(abs(low), 1.0)),
                            high - 1e-9 * max(abs(high), 1.0))
            params[key] = setting.replace(value=value)
    return params


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
    model = _joint_model(spec, count, length, designs)
    start = _starts(spec, first, table)
    params = _joint_parameters(spec, start, count)
    layout = make_layout(model.name, model.parameter_names, params)
    values = np.array([params[n].value for n in layout.names])
    return GlobalProblem(spec, curves, table, model, layout, layout.names, values,
                         np.concatenate(times), np.concatenate(observed), point_weights,
                         length, weights, first)


@dataclass(frozen=True)
class LawEstimate:
    """The fitted coefficients of one factor law, with their uncertainty.

    **Fields:**

    - `law`: the :class:`FactorLaw`; `method`: how they were estimated (``"global fit"`` or
      ``"two-stage regression"``).
    - `names`: :attr:`FactorLaw.coefficient_names`; `values`, `stderr`: per coefficient (unit:
      that of ``g(p)``, per unit of the term's factor for a slope).
    - `ci95`: 95 % intervals ``value ± t(0.975, dof) · se``.
    - `dof`: degrees of freedom of the residual variance behind the errors.
    - `covariance`: of the coefficients, ``(k + 1, k + 1)``.
    """

    law: FactorLaw
    method: str
    names: tuple[str, ...]
    values: tuple[float, ...]
    stderr: tuple[float, ...]
    ci95: tuple[tuple[float, float], ...]
    dof: float
    covariance: np.ndarray = field(repr=False)

    def covers(self, truth: Mapping[str, float] | Sequence[float]) -> tuple[bool, ...]:
        """Whether each 95 % interval holds the true coefficient.

        **Arguments:** `truth`: by coefficient name, or in the order of :attr:`names`.

        **Returns:** one flag per coefficient.
        """
        if isinstance(truth, Mapping):
            truth = [truth[n] for n in self.names]
        return tuple(bool(low <= float(t) <= high)
                     for t, (low, high) in zip(truth, self.ci95, strict=True))

    def report(self, units: Mapping[str, str] | None = None) -> str:
        """The coefficients as a small text table.

        **Arguments:** `units`: each coefficient's unit by name (e.g.
        :attr:`GlobalFitResult.units`), printed in a last column.

        **Returns:** the table as text.
        """
        units = units or {}
        lines = [f"{self.law.describe()} ({self.method}, {self.dof:g} degrees of freedom)",
                 f"  {'coefficient':<24} {'value':>12} {'std err':>11} {'95 % interval':>27}"
                 + ("  unit" if units else "")]
        for name, value, error, (low, high) in zip(self.names, self.values, self.stderr,
                                                   self.ci95, strict=True):
            lines.append(f"  {name:<24} {value:>12.6g} {error:>11.3g} "
                         f"[{low:>11.6g}, {high:>11.6g}]"
                         + (f"  {units.get(name, '')}" if units else ""))
        return "\n".join(lines)


def _law_estimate(law: FactorLaw, method: str, names: Sequence[str], values: np.ndarray,
                  covariance: np.ndarray, dof: float, quantile: float) -> LawEstimate:
    errors = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    intervals = tuple(interval(float(v), quantile * float(e), Parameter(float(v)))
                      for v, e in zip(values, errors, strict=True))
    return LawEstimate(law, method, tuple(names), tuple(map(float, values)),
                       tuple(map(float, errors)), intervals, float(dof), covariance)


def two_stage_law(law: FactorLaw, fits: Sequence[FitResult],
                  factors: Mapping[str, Sequence[float]]) -> LawEstimate:
    """A factor law regressed on curves fitted one by one (the usual two-stage analysis).

    Ordinary least squares of ``g(p_i)`` (the law's transform of each curve's fitted value)
    on the law's design; errors from the residual scatter, ``n_curves - k - 1`` degrees of
    freedom. Each curve's own standard error is not used (as in a regression of a table of
    fitted parameters).

    **Arguments:**

    - `law`: the :class:`FactorLaw`.
    - `fits`: one fit per curve (e.g. from :func:`fitting.fit.fit_many`), each with the
      law's parameter.
    - `factors`: factor columns by name, one number per fit.

    **Returns:** a :class:`LawEstimate`; a one-line ``ValueError`` when the fits cannot
    determine the law (too few curves, a fitted value the transform cannot take).
    """
    if not fits:
        raise ValueError("two_stage_law needs fitted curves")
    if any(law.parameter not in f.values for f in fits):
        raise ValueError(f"a fit has no parameter {law.parameter!r}")
    design = law.design({name: _factor_column(factors, name) for name in law.factors})
    if design.shape[0] != len(fits):
        raise ValueError(f"{design.shape[0]} factor rows for {len(fits)} fits")
    target = law.linear([f.values[law.parameter] for f in fits])
    if not np.all(np.isfinite(target)):
        raise ValueError(f"a fitted {law.parameter} is not positive; the log law cannot take it")
    if len(fits) <= design.shape[1]:
        raise ValueError(f"{len(fits)} curves leave no degrees of freedom for a law of "
                         f"{design.shape[1]} coefficients")
    coefficients = np.linalg.lstsq(design, target, rcond=None)[0]
    residual = design @ coefficients - target
    uncertainty = gauss_newton_uncertainty(design, residual, np.ones(len(fits)))
    return _law_estimate(law, "two-stage regression", law.coefficient_names, coefficients,
                         uncertainty.covariance, uncertainty.dof, uncertainty.t_quantile)


@dataclass(frozen=True)
class GlobalFitResult:
    """A global fit of a study, immutable.

    **Fields:**

    - `spec`: the :class:`GlobalModel`; `curve_names`: the curves' names, in order.
    - `factors`: the factor columns the laws read (one number per curve).
    - `names`: the joint parameters (see :class:`GlobalProblem`); `values`, `stderr`,
      `ci95`: by joint name (units in `units`).
    - `covariance`, `correlation`: over `names`, the one covariance of the joint fit.
    - `laws`: a :class:`LawEstimate` per factor law.
    - `per_curve`: each fitted model or measurement parameter's value for every curve
      (from its law, shared or per-curve value), with `per_curve_stderr` and
      `per_curve_ci95` (delta method for law values).
    - `units`: unit of each joint name and each parameter.
    - `sse` (``Σ w r²``), `n_points`, `dof` (``N - p``, less ``n_curves - 1`` for
      per-curve weights estimated from the data), `sigma` (``s``), `weighting`,
      `curve_weights` (the weight of each curve, relative).
    - `status`, `converged`, `message`, `n_steps`, `n_evaluations` as in a
      :class:`~fitting.result.FitResult`; `wall_time`, `compile_time`, seconds.
    - `predicted`, `residuals`: per curve, on its own samples; `jacobian`: per curve, the
      derivative of its model curve in every joint parameter (``(n_i, p)``).
    - `first`: the first-stage fits the joint fit started from.
    """

    spec: GlobalModel
    curve_names: tuple[str, ...]
    factors: Mapping[str, np.ndarray]
    names: tuple[str, ...]
    values: Mapping[str, float]
    stderr: Mapping[str, float]
    ci95: Mapping[str, tuple[float, float]]
    covariance: np.ndarray = field(repr=False)
    correlation: np.ndarray = field(repr=False)
    laws: tuple[LawEstimate, ...] = ()
    per_curve: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    per_curve_stderr: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    per_curve_ci95: Mapping[str, np.ndarray] = field(default_factory=dict, repr=False)
    units: Mapping[str, str] = field(default_factory=dict, repr=False)
    sse: float = math.nan
    n_points: int = 0
    dof: int = 0
    sigma: float = math.nan
    weighting: str = "per-curve"
    curve_weights: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    status: Status = Status.MAX_STEPS
    converged: bool = False
    message: str = ""
    n_steps: int = 0
    n_evaluations: int = 0
    wall_time: float = 0.0
    compile_time: float = 0.0
    predicted: tuple[np.ndarray, ...] = field(default=(), repr=False)
    residuals: tuple[np.ndarray, ...] = field(default=(), repr=False)
    jacobian: tuple[np.ndarray, ...] = field(default=(), repr=False)
    first: tuple[FitResult, ...] = field(default=(), repr=False)

    def law(self, parameter: str) -> LawEstimate:
        """The :class:`LawEstimate` of the law that gives `parameter`."""
        for estimate in self.laws:
            if estimate.law.parameter == parameter:
                return estimate
        raise KeyError(f"no factor law gives {parameter!r}")

    def table(self) -> dict[str, list]:
        """One row per curve: its name, factors and every parameter with its standard error
        and interval, as columns (``"<name>"``, ``"<name>_stderr"``, ``"<name>_low"``,
        ``"<name>_high"``)."""
        columns: dict[str, list] = {"curve": list(self.curve_names)}
        for name, values in self.factors.items():
            columns[name] = [float(v) for v in values]
        for name, values in self.per_curve.items():
            columns[name] = [float(v) for v in values]
            columns[f"{name}_stderr"] = [float(v) for v in self.per_curve_stderr[name]]
            columns[f"{name}_low"] = [float(v) for v in self.per_curve_ci95[name][:, 0]]
            columns[f"{name}_high"] = [float(v) for v in self.per_curve_ci95[name][:, 1]]
        return columns

    def report(self) -> str:
        """The fit in words: settings, convergence, the laws' and shared parameters' values."""
        spec = self.spec
        lines = [f"global fit of {len(self.curve_names)} curves, model {spec.model} "
                 f"({spec.inlet} inlet), {self.n_points} samples, {len(self.names)} "
                 f"parameters, {self.dof} degrees of freedom",
                 f"per curve: {', '.join(spec.per_curve)}; curves weighted "
                 f"{_WEIGHTING_WORDS[self.weighting]}",
                 f"{self.message} ({self.n_steps} steps)"]
        for estimate in self.laws:
            lines.append(estimate.report(self.units))
        for name in spec.fitted:
            if name in spec.shared:
                low, high = self.ci95[name]
                lines.append(f"shared {name} = {self.values[name]:.6g} {self.units[name]} "
                             f"± {self.stderr[name]:.3g} (95 %: {low:.6g} to {high:.6g})")
        return "\n".join(lines)


def curve_physical_quantities(result: GlobalFitResult, length_m: float | None
                              ) -> list[dict[str, PhysicalQuantity]]:
    """Each curve's physical quantities (the model's equivalent ADM: ``tau``, ``peclet``,
    and with a length the velocity and axial dispersion in SI units) from the global fit,
    with standard errors and 95 % intervals by the delta method over the one joint
    covariance (a law's parameters carry the laws' uncertainty, shared ones theirs).

    **Arguments:** `result`, a :class:`GlobalFitResult`; `length_m`, the blender length (m)
    or ``None`` (then no velocity and dispersion; there is no default length).

    **Returns:** per curve, in order, ``{key: PhysicalQuantity}`` (keys as in
    :func:`fitting.physical.physical_quantities`); empty dicts for a model without an
    equivalent ADM.
    """
    spec = result.spec
    model = spec.curve_model
    count = len(result.curve_names)
    if model.equivalent_adm is None:
        return [{} for _ in range(count)]
    time_unit = result.first[0].time_unit if result.first else "s"
    defaults = model.defaults
    designs = {law.parameter: law.design(result.factors) for law in spec.laws}
    settings = {}
    for name in result.names:
        stem = name.split("[", 1)[0] if "[" in name else name
        base = defaults[stem] if stem in defaults else None
        settings[name] = Parameter(result.values[name],
                                   min=None if base is None else base.min)
    covariance = np.asarray(result.covariance, float)

    def curve_values(joint: dict, i: int) -> dict[str, float]:
        values = {}
        for name in model.parameter_names:
            law = spec.law_of(name)
            if law is not None:
                coefficients = np.array([joint[c] for c in law.coefficient_names])
                values[name] = float(law.apply(designs[name][i] @ coefficients))
            elif name in spec.shared:
                values[name] = joint[name]
            elif name in spec.per_curve:
                values[name] = joint[_curve_name(name, i)]
            else:
                values[name] = defaults[name].value
        return values

    quantities = []
    for i in range(count):
        def evaluate(changes, i=i):
            joint = {**result.values, **changes}
            return hook_numbers(model.equivalent_adm(curve_values(joint, i), length_m,
                                                     time_unit))

        quantities.append(propagated_quantities(evaluate, dict(result.values), settings,
                                                covariance, result.dof, time_unit))
    return quantities


def _units(spec: GlobalModel, curves: Sequence[Curve], names: Sequence[str],
           count: int) -> dict[str, str]:
    curve_model = spec.curve_model
    time_unit, value_unit = curves[0].time_unit, curves[0].value_unit
    units = {n: curve_model.unit(n, time_unit, value_unit) for n in spec.fitted}
    for law in spec.laws:
        unit = units.get(law.parameter) or "1"
        left = ("1" if unit == "1" else f"ln({unit})") if law.transform == "log" else unit
        units[law.coefficient_names[0]] = left
        for name, term in zip(law.coefficient_names[1:], law.terms, strict=True):
            units[name] = f"{left} per unit of {term}"
    for name in spec.per_curve:
        for i in range(count):
            units[_curve_name(name, i)] = units[name]
    return {n: units[n] for n in (*names, *spec.fitted)}


def global_fit(
    spec: GlobalModel,
    curves: Sequence[Curve | tuple],
    factors: Mapping[str, Sequence[float]] | None = None,
    *,
    first: Sequence[FitResult] | None = None,
    weights: str | Sequence[float] = "combined",
    optimiser: Optimiser | None = None,
) -> GlobalFitResult:
    """Fit the curves of a study jointly: shared parameters and factor laws with one covariance.

    See the module docstring for the model, the two stages and the uncertainty.

    **Arguments:**

    - `spec`: the :class:`GlobalModel` (which parameters are shared, given by laws, per
      curve).
    - `curves`: raw tracer curves (:class:`~fitting.data.Curve` s or ``(time, values)``
      pairs, time in seconds for pairs), each on its own time grid, all in one time unit.
    - `factors`: factor columns by name, one number per curve (every column a law reads).
    - `first`: first-stage fits (:func:`fitting.fit.fit_many` with ``spec.curve_model``),
      or ``None`` to fit them here.
    - `weights`: ``"combined"`` (default), ``"per-curve"``, ``"equal"``, or one known weight
      per curve (see :func:`global_problem`).
    - `optimiser`: settings of the solver (:class:`~fitting.solve.Optimiser`; default
      Levenberg–Marquardt).

    **Returns:** a :class:`GlobalFitResult`.
    """
    began = _time.perf_counter()
    problem = global_problem(spec, curves, factors, first, weights)
    optimiser = optimiser if optimiser is not None else Optimiser()
    plan = make_plan("sse", optimiser, MultiStart(n_starts=1))
    layout = problem.layout
    solver = compiled_solver(problem.model, layout, plan, "curves")
    start_u = layout.unconstrained_from_physical(problem.start)
    out, _, compile_time = run_solver(
        solver, start_u[None, None, :], np.zeros(1, dtype=bool), problem.start[None, :],
        problem.time[None, :], problem.observed[None, :], problem.weights[None, :])
    out = {k: np.asarray(v[0]) for k, v in out.items()}
    status = Status(int(out["status"]))
    return _result(problem, out, status, compile_time, _time.perf_counter() - began)


def _result(problem: GlobalProblem, out: dict, status: Status, compile_time: float,
            wall_time: float) -> GlobalFitResult:
    spec, count, length = problem.spec, len(problem.curves), problem.length
    names = problem.names
    residual = out["predicted"] - problem.observed
    weights = problem.weights
    uncertainty = gauss_newton_uncertainty(out["jacobian"], residual, weights)
    covariance, dof = uncertainty.covariance, uncertainty.dof
    all_stderr, sigma = uncertainty.all_stderr, uncertainty.sigma
    # Weights estimated from residuals of the same data take one degree of freedom each,
    # less one for their common scale (as for the estimated weight shape of the combined
    # error model, fitting.fit): the n_curves - 1 ratios of per-curve weights; the additive
    # and proportional sizes of each curve under combined weights.
    estimated = 0
    if problem.weighting == "per-curve":
        estimated = count - 1
    elif problem.weighting == "combined":
        estimated = sum(2 if r.error_model.kind == "combined" else 1
                        for r in problem.first) - 1
    if estimated and dof > estimated + 1:
        factor = dof / (dof - estimated)
        dof -= estimated
        covariance, all_stderr, sigma = (covariance * factor, all_stderr * math.sqrt(factor),
                                         sigma * math.sqrt(factor))
    quantile = t_quantile(dof)
    free = np.asarray(out["free_values"], dtype=float)
    values = dict(zip(names, free.tolist(), strict=True))
    index = {n: j for j, n in enumerate(names)}
    settings = problem.model.defaults
    joint_settings = {n: settings[n] for n in names}
    curve_defaults = spec.curve_model.defaults
    for name in spec.fitted:  # bounds of the curve parameters, for their intervals
        keys = [name] if name in spec.shared else [_curve_name(name, i) for i in range(count)] \
            if name in spec.per_curve else []
        for key in keys:
            joint_settings[key] = curve_defaults[name].replace(vary=True)
    stderr = dict(zip(names, all_stderr.tolist(), strict=True))
    ci95 = {n: interval(values[n], quantile * stderr[n], joint_settings[n]) for n in names}
    laws = []
    per_curve, per_curve_stderr, per_curve_ci95 = {}, {}, {}
    for law in spec.laws:
        picked = [index[c] for c in law.coefficient_names]
        block = covariance[np.ix_(picked, picked)]
        coefficients = free[picked]
        laws.append(_law_estimate(law, "global fit", law.coefficient_names, coefficients,
                                  block, dof, quantile))
        design = law.design(problem.factors)
        linear = design @ coefficients
        linear_error = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", design, block, design), 0,
                                       None))
        value = np.asarray(law.apply(linear))
        low = np.asarray(law.apply(linear - quantile * linear_error))
        high = np.asarray(law.apply(linear + quantile * linear_error))
        scale = value if law.transform == "log" else 1.0
        per_curve[law.parameter] = value
        per_curve_stderr[law.parameter] = scale * linear_error
        per_curve_ci95[law.parameter] = np.column_stack([low, high])
    for name in spec.fitted:
        if name in per_curve:
            continue
        keys = [name] * count if name in spec.shared else \
            [_curve_name(name, i) for i in range(count)]
        per_curve[name] = np.array([values[k] for k in keys])
        per_curve_stderr[name] = np.array([stderr[k] for k in keys])
        per_curve_ci95[name] = np.array([ci95[k] for k in keys], dtype=float)
    predicted = out["predicted"].reshape(count, length)
    residuals = residual.reshape(count, length)
    jacobian = out["jacobian"].reshape(count, length, len(names))
    sizes = [len(c) for c in problem.curves]
    curve_weights = weights.reshape(count, length)[:, 0]
    converged = status in CONVERGED
    n_points = int(np.count_nonzero(weights))
    correlation = uncertainty.correlation
    return GlobalFitResult(
        spec=spec, curve_names=tuple(c.name or f"curve {i}" for i, c in
                                     enumerate(problem.curves)),
        factors=dict(problem.factors), names=names, values=values, stderr=stderr, ci95=ci95,
        covariance=covariance, correlation=correlation, laws=tuple(laws),
        per_curve=per_curve, per_curve_stderr=per_curve_stderr,
        per_curve_ci95=per_curve_ci95,
        units=_units(spec, problem.curves, names, count),
        sse=float(np.sum(weights * residual**2)), n_points=n_points, dof=dof, sigma=sigma,
        weighting=problem.weighting,
        curve_weights=curve_weights, status=status, converged=converged,
        message=STATUS_MESSAGES[status], n_steps=int(out["steps"]),
        n_evaluations=int(out["evaluations"]), wall_time=wall_time, compile_time=compile_time,
        predicted=tuple(p[:n] for p, n in zip(predicted, sizes, strict=True)),
        residuals=tuple(r[:n] for r, n in zip(residuals, sizes, strict=True)),
        jacobian=tuple(j[:n] for j, n in zip(jacobian, sizes, strict=True)),
        first=problem.first,
    )
