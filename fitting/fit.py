"""Fitting residence-time models to curves: :func:`fit`, :func:`fit_many`, relative errors.

A fit merges the model's defaults with the user's parameter settings
(:mod:`fitting.parameters`), checks the data (:mod:`fitting.data`), draws the starts and runs
one compiled multi-start solver (:mod:`fitting.solve`), then computes the uncertainty
(:mod:`fitting.uncertainty`) into an immutable :class:`~fitting.result.FitResult`.

Settings are small immutable modules: :class:`~fitting.solve.Optimiser`,
:class:`~fitting.solve.MultiStart` and :class:`~fitting.result.RelativeErrors`, gathered
into one :class:`~fitting.result.FitSettings` by :func:`settings_from_keywords`.

* Starts: by default a fit runs from the start values and, when those differ from the
  model's method-of-moments estimate, from that estimate too (a start whose model curve
  misses the data sits on a flat loss no local method can leave; the moment estimate always
  overlaps the data). ``n_starts=1`` runs the start values alone. (The command line uses
  ``Model.default_starts`` where a model gives one.)
* Relative errors: after a first fit, the curve is fitted again from its result with
  weights ``1 / max(|model|, floor)²`` until the fitted values stop changing (iteratively
  reweighted least squares); degrees of freedom then count floored points right
  (:func:`fitting.uncertainty.effective_degrees_of_freedom`).
* Additive plus proportional errors (``errors="combined"``,
  :class:`~fitting.losses.CombinedErrors`): after a first, unweighted fit, ``a`` and ``b``
  of ``Var = a² + (b m)²`` are estimated from its residuals (pseudo-likelihood,
  :func:`fitting.losses.estimate_combined_errors`), the curve is fitted again with weights
  ``1 / (a² + (b m)²)``, and both steps repeat until the fitted values stop changing
  (iterated weights). No floor: where the model is zero the
  additive part sets the weight. Standard errors and intervals use these weights.
* ``n_evaluations`` counts objective evaluations, each one value and gradient (one model
  evaluation plus its reverse pass), summed over all starts.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from axialmix._heap import long_lived_frozen
from axialmix.analytic.panels import LONG_CURVE
from fitting.data import Curve, as_curve
from fitting.engine import ErrorPlan, launch_chunk_arrays
from fitting.losses import (
    ERROR_KINDS,
    CombinedErrors,
    CountingErrors,
    ErrorEstimate,
    combined_weights,
    counting_weights,
    estimate_combined_errors,
    leverages,
    poisson_log_likelihood,
    proportional_shares,
)
from fitting.models import Model, get_model
from fitting.optima import with_other_optima
from fitting.parameters import Layout, Parameter, Parameters, clip_into_bounds, make_layout
from fitting.result import FitResult, FitSettings, RelativeErrors, residual_verdict
from fitting.solve import (
    CONVERGED,
    METHOD_NAMES,
    SECOND_ORDER_DISTANCE,
    STATUS_MESSAGES,
    MultiStart,
    Optimiser,
    SolverPlan,
    Status,
    compiled_solver,
    make_plan,
    pad_curve,
    padded_length,
    run_solver,
    second_order_distance,
    start_points,
)
from fitting.uncertainty import (
    effective_degrees_of_freedom,
    gauss_newton_uncertainty,
    information_criteria,
    interval,
    t_quantile,
)

__all__ = ["fit", "fit_many", "launch_many", "prepare", "settings_from_keywords"]


def settings_from_keywords(loss: str = "sse", optimiser: Optimiser | None = None,
                           multistart: MultiStart | None = None,
                           relative_errors: RelativeErrors | bool | None = None) -> FitSettings:
    """The one mapping from the keyword arguments of :func:`fit` onto :class:`FitSettings`.

    **Arguments:**

    - `loss`, `optimiser`, `multistart`, `relative_errors`: the settings (``True`` for
      :class:`RelativeErrors` with its defaults, ``False``/``None`` for none).

    **Returns:** the :class:`FitSettings`.
    """
    optimiser = optimiser if optimiser is not None else Optimiser()
    multistart = multistart if multistart is not None else MultiStart()
    if relative_errors is True:
        relative_errors = RelativeErrors()
    elif relative_errors is False:
        relative_errors = None
    return FitSettings(loss=loss, optimiser=optimiser, multistart=multistart,
                       relative_errors=relative_errors)


def with_error_model(settings: FitSettings,
                     errors: str | RelativeErrors | CombinedErrors | CountingErrors | None,
                     ) -> FitSettings:
    """`settings` with the error model `errors`: ``None`` keeps them as they are;
    ``"absolute"``, ``"relative"``, ``"combined"`` or ``"poisson"`` (or the settings of the
    last three)."""
    if errors is None:
        return settings
    if isinstance(errors, str):
        if errors not in ERROR_KINDS:
            raise ValueError(f"errors must be one of {', '.join(ERROR_KINDS)}, got {errors!r}")
        errors = {"absolute": None, "relative": RelativeErrors(),
                  "combined": CombinedErrors(), "poisson": CountingErrors()}[errors]
    if errors is not None and not isinstance(errors,
                                             RelativeErrors | CombinedErrors | CountingErrors):
        raise ValueError(f"errors must be a name, RelativeErrors, CombinedErrors or "
                         f"CountingErrors, got {type(errors).__name__}")
    if settings.relative_errors is not None and not isinstance(errors, RelativeErrors):
        raise ValueError("give the error model once: errors or relative_errors")
    return dataclasses.replace(
        settings,
        relative_errors=errors if isinstance(errors, RelativeErrors) else None,
        combined_errors=errors if isinstance(errors, CombinedErrors) else None,
        counting_errors=errors if isinstance(errors, CountingErrors) else None)


def merge_parameters(model: Model, params, curve: Curve | None,
                     defaults: Parameters | None = None) -> Parameters:
    """Model defaults (moment estimates as start values when a curve is given), then the user's.

    A number replaces only the start value; a :class:`Parameter` replaces the whole setting.
    `defaults`: ``model.parameters(curve)`` when the caller already has it (it is not changed).
    """
    merged = model.parameters(curve) if defaults is None else defaults.copy()
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


def check_data(curve: Curve, weights: np.ndarray) -> None:
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


@dataclass(frozen=True, eq=False)
class Prepared:
    """One curve made ready for the solver: merged settings, layout, weights, starts."""

    model: Model
    curve: Curve
    params: Parameters
    layout: Layout
    weights: np.ndarray
    base: np.ndarray
    starts: np.ndarray
    warm: np.ndarray


def _without_idle_warmup(options: SolverPlan, prepared: Sequence[Prepared]) -> SolverPlan:
    """Drop the Adam warm-up from the compiled solver when no start is random."""
    if options.warmup_steps > 0 and not any(p.warm.any() for p in prepared):
        return dataclasses.replace(options, warmup_steps=0)
    return options


def prepare(model, curve: Curve, params, weights, n_starts: int | None,
             seed: int) -> Prepared:
    """One curve made ready for the solver (see :class:`Prepared`).

    **Arguments:** the model (or its name), the curve, parameter settings, weights (or
    ``None``), the number of starts (``None``: the model's default) and the seed.

    **Returns:** a :class:`Prepared`; a one-line ``ValueError`` for bad data or settings.
    """
    model = get_model(model)
    # The model's defaults with the moment estimates, worked out once for both uses below.
    guess = model.parameters(curve) if model.initial_guess is not None else None
    merged = merge_parameters(model, params, curve, guess)
    layout = make_layout(model.name, model.parameter_names, merged)
    weights = np.ones(len(curve)) if weights is None else np.asarray(weights, dtype=float)
    check_data(curve, weights)
    n_used = int(np.count_nonzero(weights))
    if n_used <= len(layout.free):
        raise ValueError(
            f"{n_used} weighted data points cannot determine {len(layout.free)} free parameters"
        )
    base = np.array([merged[n].value for n in layout.names])
    start = base[list(layout.free_index)]
    anchor = None
    if guess is not None and (n_starts is None or n_starts > 1):
        anchor = np.array([clip_into_bounds(guess[n].value, merged[n]) if n in guess
                           else merged[n].value for n in layout.free])
    if n_starts is None:
        # The start values, and the moment estimate when it differs from them.
        # np.allclose(anchor, start, rtol=1e-9, atol=0.0) on a few numbers, in Python (an
        # infinite or NaN value is close only to an equal one, as there).
        same = anchor is None or all(
            a == b or (math.isfinite(a) and math.isfinite(b) and abs(a - b) <= 1e-9 * abs(b))
            for a, b in zip(anchor.tolist(), start.tolist(), strict=True))
        n_starts = 1 if same else 2
    starts, warm = start_points(layout, start, anchor, n_starts, seed)
    return Prepared(model, curve, merged, layout, weights, base, starts, warm)


def _distinct_starts(prepared: Prepared) -> int:
    """The curve's distinct starts (fit_many pads a batch to a common number of starts)."""
    return len({tuple(row) for row in prepared.starts.tolist()})


def _result(prepared: Prepared, layout: Layout, options: SolverPlan, out: dict,
            wall_time: float, compile_time: float, settings: FitSettings, *,
            method_note: str | None = None,
            error_model: ErrorEstimate | None = None,
            absolute_errors: bool = False) -> FitResult:
    """The fit result of one curve from a solver's outputs (`out`, the curve's own samples);
    `method_note` is appended to the method's description and `error_model` is the error
    model behind the weights (as given, without a result built twice); `absolute_errors`:
    an unweighted least-squares fit's model, errors of one size estimated by ``s``."""
    curve, merged, weights = prepared.curve, prepared.params, prepared.weights
    n_starts = _distinct_starts(prepared)
    out = {k: np.asarray(v) for k, v in out.items()}
    residual = out["predicted"] - curve.value
    n_points = int(np.count_nonzero(weights))
    sse = float(np.sum(weights * residual**2))
    # The loss of fitting.losses in NumPy (one curve's numbers: no JAX dispatch).
    if options.loss == "sse":
        loss = sse
    else:
        loss = float(np.sum(weights * np.abs(residual)) / np.sum(weights))
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
        ci95[name] = interval(values[name], uncertainty.t_quantile * error, setting)
    status = Status(int(out["status"]))
    message = STATUS_MESSAGES[status]
    if status == Status.FLAT and options.loss == "sse" and uncertainty.dof > 0 and sse > 0:
        distance, on_bound = second_order_distance(
            prepared.model, layout, out["free_values"], prepared.base, curve.time, curve.value,
            weights, sse, uncertainty.dof)
        if distance <= SECOND_ORDER_DISTANCE:
            status = Status.ON_BOUND if on_bound else Status.SECOND_ORDER
            message = STATUS_MESSAGES[status].replace("{names}", ", ".join(on_bound))
            message = f"{message} (distance {distance:.1g} standard errors)"
    converged = status in CONVERGED
    aic, bic = information_criteria(sse, n_points, len(layout.free))
    fitted = Parameters({n: merged[n].replace(value=values[n]) for n in layout.names})
    method = METHOD_NAMES[options.method]
    if options.method != "adam" and options.warmup_steps > 0:
        method = f"{method} ({options.warmup_steps} adam steps first from random starts)"
    if method_note is not None:
        method = f"{method}; {method_note}"
    if absolute_errors and options.loss == "sse":
        error_model = ErrorEstimate("absolute", uncertainty.sigma, 0.0)
    extra = {} if error_model is None else {"error_model": error_model}
    return FitResult(
        model=prepared.model, params=fitted, init_params=merged, free_names=layout.free,
        values=values, stderr=stderr, ci95=ci95, covariance=uncertainty.covariance,
        correlation=uncertainty.correlation, loss=loss, loss_name=options.loss, sse=sse,
        n_points=n_points, dof=uncertainty.dof, sigma=uncertainty.sigma, aic=aic, bic=bic,
        n_evaluations=int(out["evaluations"]), n_steps=int(out["steps"]), n_starts=n_starts,
        start_losses=out["start_losses"], start_values=out.get("start_values"),
        grad_norm=float(out["grad_norm"]),
        newton_step=float(out["newton_step"]), wall_time=wall_time, compile_time=compile_time,
        success=converged and bool(np.isfinite(loss)), converged=converged, status=status,
        message=message, method=method, curve=curve, weights=weights,
        predicted=out["predicted"], residuals=residual, jacobian=out["jacobian"],
        settings=settings, **extra,
    )


def fit(
    model: Model | str,
    data: Curve | tuple,
    params: Mapping[str, Parameter | float] | None = None,
    *,
    loss: str = "sse",
    weights: Sequence[float] | np.ndarray | None = None,
    optimiser: Optimiser | None = None,
    multistart: MultiStart | None = None,
    relative_errors: RelativeErrors | bool | None = None,
    errors: str | RelativeErrors | CombinedErrors | None = None,
) -> FitResult:
    """Fit a residence-time model to one curve by gradient descent; see the module docstring.

    **Arguments:**

    - `model`: a :class:`~fitting.models.Model` or a built-in name (``'adm'``, ``'adm-fv'``,
      ``'adm-open'``, ``'tanks'``, ``'four-compartment'``).
    - `data`: a :class:`~fitting.data.Curve` or a ``(time, values)`` pair (time strictly
      increasing, unit T; values E in 1/T).
    - `params`: start values and settings overriding the model's defaults: name ->
      :class:`~fitting.parameters.Parameter` (whole setting) or number (start value only).
      Unset start values come from the model's method-of-moments guess when it has one.
    - `loss`: ``'sse'`` (least squares, default) or ``'mae'`` (the source's mean absolute
      error); see :mod:`fitting.losses`.
    - `weights`: ``w_i >= 0`` multiplying the squared (or absolute) residuals, e.g.
      ``1/sigma_i²``; zero drops a point.
    - `optimiser`: :class:`~fitting.solve.Optimiser` (method, tolerances, step limit).
    - `multistart`: :class:`~fitting.solve.MultiStart` (number of starts, seed, warm-up).
    - `relative_errors`: :class:`~fitting.result.RelativeErrors` (or ``True``) to treat the
      data's errors as proportional to the curve (multiplicative noise): fit, then refit with
      weights ``1 / max(|model|, floor)²`` until consistent. Not combined with `weights`.
    - `errors`: the error model by name: ``"absolute"`` (errors of one size; the default
      when neither this nor `relative_errors` is given), ``"relative"`` (as
      `relative_errors`) or ``"combined"`` (additive plus proportional, both estimated;
      :class:`~fitting.losses.CombinedErrors`); or the settings of the last two. Not
      combined with `weights`.

    **Returns:**

    A :class:`~fitting.result.FitResult`; its `error_model` holds the error sizes.
    """
    settings = settings_from_keywords(loss, optimiser, multistart, relative_errors)
    settings = with_error_model(settings, errors)
    return _fit_one(model, data, params, weights, settings)


def _fit_one(model, data, params, weights, settings: FitSettings) -> FitResult:
    # One curve is a chunk of one: fit and fit_many share the engine and its programs.
    return _fit_final(model, [data], params, None if weights is None else [weights],
                      settings)[0]


def _fit_final(model, curves, params, weights, settings: FitSettings) -> list[FitResult]:
    """The fits of :func:`_fit_batch` with their intervals widened to hold the other optima
    the multi-start found (:func:`fitting.optima.with_other_optima`) and, for long curves,
    the model's evaluation checked on every point (:func:`_with_evaluation_check`)."""
    return _launch_final(model, curves, params, weights, settings)()


def _launch_final(model, curves, params, weights, settings: FitSettings
                  ) -> Callable[[], list[FitResult]]:
    """:func:`_fit_final` started (see :func:`launch_many`)."""
    finish = _launch_batch(model, curves, params, weights, settings)
    return lambda: [_with_evaluation_check(with_other_optima(r)) for r in finish()]


#: Largest deviation of an interpolated model from the exact one, as a share of the peak,
#: at which a fit's numbers still count as the exact model's (the interpolation itself is
#: about 1e-13; each evaluation already falls back to the exact one past 1e-11 between nodes).
EVALUATION_TOLERANCE = 1e-10


def _with_evaluation_check(result: FitResult) -> FitResult:
    """A long curve's fit with the model's interpolated evaluation measured against the exact
    one on every point at the fitted values (the model's ``long_curve_check``); a deviation
    past :data:`EVALUATION_TOLERANCE` of the peak makes the fit unsuccessful, saying why."""
    base = getattr(result.model, "base", result.model)
    inlet = getattr(result.model, "inlet", None)
    check = getattr(base, "long_curve_check", None)
    if (check is None or (inlet is not None and inlet.kind != "pulse")
            or padded_length(len(result.curve)) < LONG_CURVE):
        return result
    shift = result.values.get("dead_time", 0.0)
    largest, peak = check(result.curve.time - shift,
                          {n: result.values[n] for n in base.parameter_names})
    amplitude = abs(result.values.get("amplitude", 1.0))
    found = (largest * amplitude, peak * amplitude)
    if largest <= EVALUATION_TOLERANCE * peak:
        return dataclasses.replace(result, evaluation_check=found)
    return dataclasses.replace(
        result, evaluation_check=found, success=False,
        message=(f"{result.message}; but the model's interpolated evaluation deviates from the "
                 f"exact one by {largest / peak:.2g} of the peak at the fitted values (more "
                 f"than {EVALUATION_TOLERANCE:g}): these numbers are not the exact model's"))


def fit_many(
    model: Model | str,
    curves: Sequence[Curve | tuple],
    params: Mapping[str, Parameter | float] | Sequence[Mapping | None] | None = None,
    *,
    loss: str = "sse",
    weights: Sequence[Sequence[float] | None] | None = None,
    optimiser: Optimiser | None = None,
    multistart: MultiStart | None = None,
    relative_errors: RelativeErrors | bool | None = None,
    errors: str | RelativeErrors | CombinedErrors | None = None,
) -> list[FitResult]:
    """Fit one model to many curves in a single vmapped, jitted call.

    Curves of different lengths are padded to the longest with zero-weight points (times
    continuing the last spacing), so they need not share a grid. Start values come from each
    curve's moments (or `params`); the free/fixed/tied layout and the bounds are shared.

    **Arguments:**

    - `model`, `loss`, `optimiser`, `multistart`, `relative_errors`, `errors`: as
      in :func:`fit` (curve i uses seed ``seed + i``); relative-error passes are one vmapped
      call each.
    - `params`: as in :func:`fit`, for all curves, or a list with one setting per curve.
    - `curves`: :class:`~fitting.data.Curve` objects or ``(time, values)`` pairs.
    - `weights`: one weight array (or ``None``) per curve, or ``None``.

    **Returns:**

    One :class:`~fitting.result.FitResult` per curve, in order; `wall_time` is each curve's
    share of its program's run (see :class:`~fitting.result.FitResult`).
    """
    with long_lived_frozen():  # a long batch: see axialmix._heap
        return launch_many(model, curves, params, loss=loss, weights=weights,
                           optimiser=optimiser, multistart=multistart,
                           relative_errors=relative_errors, errors=errors)()


def launch_many(
    model: Model | str,
    curves: Sequence[Curve | tuple],
    params: Mapping[str, Parameter | float] | Sequence[Mapping | None] | None = None,
    *,
    loss: str = "sse",
    weights: Sequence[Sequence[float] | None] | None = None,
    optimiser: Optimiser | None = None,
    multistart: MultiStart | None = None,
    relative_errors: RelativeErrors | bool | None = None,
    errors: str | RelativeErrors | CombinedErrors | None = None,
) -> Callable[[], list[FitResult]]:
    """:func:`fit_many`, started: the compiled fits run while the caller goes on.

    The arguments are :func:`fit_many`'s; bad data or settings raise here. The returned
    function waits for the fits and gives what :func:`fit_many` returns, the same numbers.
    A study starts its next chunk this way before it writes the records of the last, so
    its Python work and its compiled fits overlap.
    """
    settings = settings_from_keywords(loss, optimiser, multistart, relative_errors)
    settings = with_error_model(settings, errors)
    return _launch_final(model, curves, params, weights, settings)



def _error_plan(settings: FitSettings) -> ErrorPlan:
    """The engine's static error model of `settings`."""
    if settings.combined_errors is not None:
        combined = settings.combined_errors
        return ErrorPlan("combined", combined.max_passes, float(combined.change))
    if settings.relative_errors is not None:
        relative = settings.relative_errors
        return ErrorPlan("relative", relative.max_passes, float(relative.change),
                         float(relative.floor))
    if settings.counting_errors is not None:
        counting = settings.counting_errors
        return ErrorPlan("poisson", counting.max_passes, float(counting.change),
                         float(counting.floor))
    return ErrorPlan()


def _exposures(curves: Sequence[Curve]) -> list[np.ndarray]:
    """Each curve's exposure (counts per unit value; ones where a curve gives none), after
    checking that value × exposure is a count at every point (a whole number, at least 0)."""
    exposures = []
    for curve in curves:
        x = curve.exposure if curve.exposure is not None else np.ones(len(curve))
        counts = x * curve.value
        off = np.abs(counts - np.rint(counts)) > 1e-6 * np.maximum(1.0, np.abs(counts))
        bad = np.flatnonzero(off | (counts < 0))
        if bad.size:
            i = int(bad[0])
            label = f"curve {curve.name!r}" if curve.name else "the curve"
            raise ValueError(
                f"counting errors need counts: {label} has {counts[i]:.6g} particles at t = "
                f"{curve.time[i]:g} {curve.time_unit} (value x exposure, not a whole number at "
                "least 0); read the histogram with its 'count' column, give the curve its "
                "exposure (bin widths), or choose another error model")
        exposures.append(x)
    return exposures


def _reweighting(settings: FitSettings) -> str | None:
    """The settings' error model that sets the weights itself, by its keyword (or None)."""
    for name in ("combined_errors", "relative_errors", "counting_errors"):
        if getattr(settings, name) is not None:
            return name
    return None


def _prepare_batch(model, curves, params, weights, settings: FitSettings) -> list[Prepared]:
    """Every curve made ready, with one number of starts for all (the largest default)."""
    multistart = settings.multistart
    per_curve_weights = weights if weights is not None else [None] * len(curves)
    if len(per_curve_weights) != len(curves):
        raise ValueError(f"{len(per_curve_weights)} weight arrays for {len(curves)} curves")
    per_curve_params = (params if isinstance(params, Sequence) and not isinstance(params, str)
                        else [params] * len(curves))
    if len(per_curve_params) != len(curves):
        raise ValueError(f"{len(per_curve_params)} parameter settings for {len(curves)} curves")

    def prepare_all(count):
        return [prepare(model, c, p, w, count, multistart.seed + i)
                for i, (c, p, w) in enumerate(zip(curves, per_curve_params, per_curve_weights,
                                                  strict=True))]

    prepared = prepare_all(multistart.n_starts)
    counts = {p.starts.shape[0] for p in prepared}
    if len(counts) > 1:
        # Default starts differ in number between curves: one chunk needs one number.
        prepared = prepare_all(max(counts))
    layout = prepared[0].layout
    for other in prepared[1:]:
        if dataclasses.replace(other.layout, scale=layout.scale) != layout:
            raise ValueError("fit_many: every curve must have the same free, fixed and tied "
                             "parameters and bounds")
    return prepared


def _fit_batch(model, curves, params, weights, settings: FitSettings) -> list[FitResult]:
    """Fit curves with the batched engine (:mod:`fitting.engine`): the curves of each padded
    length in one compiled call; curves the engine flags for polishing by the multi-start
    solver's path."""
    return _launch_batch(model, curves, params, weights, settings)()


def _launch_batch(model, curves, params, weights, settings: FitSettings
                  ) -> Callable[[], list[FitResult]]:
    """:func:`_fit_batch` started: the engine's programs run, the returned function waits
    for them and builds the results (the multi-start solver's path runs in it)."""
    if _reweighting(settings) is not None and weights is not None:
        raise ValueError(f"{_reweighting(settings)} sets the weights itself; pass weights=None")
    curves = [as_curve(c) for c in curves]
    if not curves:
        raise ValueError("fit_many needs at least one curve")
    options = make_plan(settings.loss, settings.optimiser, settings.multistart)
    if options.method != "lm":
        # L-BFGS and Adam (the mean absolute error): each start on its own.
        return lambda: _fit_polished(model, curves, params, weights, settings)
    counting = settings.counting_errors is not None
    # Counts: the first fit is weighted by the exposure, which the passes' weights keep.
    prepared = _prepare_batch(model, curves, params,
                              _exposures(curves) if counting else weights, settings)
    if any(p.warm.any() for p in prepared):
        # Random starts, each first moved by Adam steps (the compartment networks' default
        # of 8 starts): inside the chunk program the warm-up ran 30-45 times slower than in
        # the single-start programs (measured: 24 s against 0.5 s for the four-compartment
        # model's 8 starts), so these fits keep the multi-start solver's path. The choice
        # follows the settings and the model only, never the chunk.
        return lambda: _fit_polished(model, curves, params, weights, settings)
    options = _without_idle_warmup(options, prepared)
    errors = _error_plan(settings)
    layout = prepared[0].layout
    # What every curve's results share: the settings of the unweighted first fit and the
    # plan of the passes (made once, not per curve).
    shared = _EngineShared(
        settings, dataclasses.replace(settings, relative_errors=None, combined_errors=None,
                                      counting_errors=None),
        options, dataclasses.replace(options, warmup_steps=0), errors,
        weights is not None or counting)
    groups: dict[int, list[int]] = {}
    for i, p in enumerate(prepared):
        groups.setdefault(padded_length(len(p.curve)), []).append(i)
    launched = []
    for length, members in groups.items():
        padded = [pad_curve(prepared[i].curve.time, prepared[i].curve.value,
                             prepared[i].weights, length) for i in members]
        launched.append((members, launch_chunk_arrays(
            prepared[0].model, layout, options, errors,
            np.stack([prepared[i].starts for i in members]),
            np.stack([prepared[i].warm for i in members]),
            np.stack([prepared[i].base for i in members]),
            np.stack([prepared[i].layout.scale for i in members]),
            *(np.stack([row[k] for row in padded]) for k in range(3)))))

    def finish() -> list[FitResult]:
        results: list[FitResult | None] = [None] * len(curves)
        polish: list[int] = []
        for members, chunk in launched:
            compile_share = chunk.compile_seconds / len(members)
            begin = 0
            # Program by program: the results of one are made while the next runs.
            for out, used, wall in chunk.parts():
                part = members[begin:begin + used]
                begin += used
                for row, i in enumerate(part):
                    lane = _lane_of(out, row)
                    result = _engine_result(prepared[i], lane, shared, wall / len(part),
                                            compile_share)
                    if result is None:
                        polish.append(i)
                    else:
                        results[i] = result
        # Curves the multi-start solver polishes, each alone (so that its path and numbers
        # are the same in every chunk).
        for i in sorted(polish):
            results[i] = _fit_polished(
                model, [curves[i]], [prepared[i].params],
                None if weights is None else [weights[i]], settings)[0]
        return results

    return finish


def _lane_of(outputs: dict, row: int) -> dict:
    """One curve's outputs from a part's (nested dicts of NumPy arrays with a leading curve
    axis): ``jax.tree.map(lambda a: a[row], outputs)`` without its per-call overhead."""
    return {key: _lane_of(value, row) if isinstance(value, dict) else value[row]
            for key, value in outputs.items()}


def _lane_output(lane: dict, n: int) -> dict:
    """One fit's outputs from the engine, trimmed to the curve's own samples."""
    out = {k: np.asarray(v) for k, v in lane.items()}
    out["predicted"] = out["predicted"][:n]
    out["jacobian"] = out["jacobian"][:n]
    return out


@dataclass(frozen=True)
class _EngineShared:
    """What the results of one batch of engine fits share: the settings (and those of the
    unweighted first fit), the solver plan (and that of the passes, without the warm-up),
    the error model and whether the curves came with weights."""

    settings: FitSettings
    plain: FitSettings
    options: SolverPlan
    single: SolverPlan
    errors: ErrorPlan
    weighted: bool


def _engine_result(prepared: Prepared, lane: dict, shared: _EngineShared, wall: float,
                   compile_time: float) -> FitResult | None:
    """The fit result of one curve from the engine's arrays, or ``None`` where the curve
    needs the multi-start solver's polishing."""
    if bool(lane["polish_first"]):
        return None
    settings, options, errors = shared.settings, shared.options, shared.errors
    n = len(prepared.curve)
    layout = prepared.layout
    first_out = _lane_output(lane["first"], n)

    def first_result(absolute_errors: bool = False) -> FitResult:
        return _result(prepared, layout, options, first_out, wall, compile_time,
                       shared.plain if errors.kind != "absolute" else settings,
                       absolute_errors=absolute_errors)

    if errors.kind == "absolute":
        return first_result(absolute_errors=not shared.weighted)
    doubtful = False
    if errors.kind == "combined":
        # Where the unweighted fit's residuals look systematic, they may be misfit (then it
        # is kept: see _fit_polished) or noise that grows with the model; the weighted fit's
        # own verdict tells them apart. The unweighted result is built only where it is
        # kept (its verdict here is that of the result that would be built: same
        # residuals, weights and degrees of freedom).
        doubtful = residual_verdict(
            first_out["predicted"] - prepared.curve.value, prepared.weights,
            prepared.curve.value, int(np.count_nonzero(prepared.weights)) - len(layout.free),
            options.loss, np.ones(n, dtype=bool)).systematic
    if bool(lane["polish_passes"]):
        return None
    passes = int(lane["passes"])

    def settled(result: FitResult, kind: str) -> FitResult:
        return _with_settling(result, kind, passes, float(lane["change"]), errors.max_passes,
                              errors.change)

    final_out = _lane_output(lane["final"], n)
    # What the first fit's result says of its starts (the passes share its starts and
    # settings: the same number of distinct starts and initial parameters).
    final_out["start_losses"] = first_out["start_losses"]
    final_out["evaluations"] = lane["evaluations"]
    reweighted = dataclasses.replace(prepared, weights=np.asarray(lane["weights"])[:n])
    if errors.kind == "poisson":
        final = _result(reweighted, layout, shared.single, final_out, wall, compile_time,
                        settings)
        return settled(_with_counting_errors(final, passes), "counting")
    if errors.kind == "relative":
        note = f"relative errors: reweighted by 1/model^2 until consistent ({passes} passes)"
        final = _with_effective_dof(_result(reweighted, layout, shared.single, final_out,
                                            wall, compile_time, settings, method_note=note))
        return settled(dataclasses.replace(
            final, error_model=ErrorEstimate("relative", 0.0, final.sigma, passes)), "relative")
    note = ("additive plus proportional errors: reweighted by 1/(a^2 + (b model)^2), a "
            "and b estimated from the residuals, until consistent "
            f"({passes} passes)")
    a, b = (float(x) for x in lane["sizes"])
    combined = settled(_with_estimated_weight_shape(_result(
        reweighted, layout, shared.single, final_out, wall, compile_time, settings,
        method_note=note, error_model=ErrorEstimate("combined", a, b, passes))), "combined")
    if doubtful and combined.lack_of_fit.systematic:
        return _kept_unweighted(first_result(), settings)
    return combined


def _fit_polished(model, curves, params, weights, settings: FitSettings) -> list[FitResult]:
    """The multi-start solver's path (:class:`fitting.solve.MultiStartSolver`): each start
    of each curve one compiled call, then its Python polishing (Newton's method, L-BFGS)
    where Levenberg–Marquardt stopped short; used for the curves the batched engine flags."""
    if settings.combined_errors is not None:
        if weights is not None:
            raise ValueError("the combined error model sets the weights itself; pass "
                             "weights=None")
        curves = [as_curve(c) for c in curves]
        plain = dataclasses.replace(settings, combined_errors=None)
        first = _fit_polished(model, curves, params, None, plain)
        # The error model is estimated from residuals, which measure the noise only where
        # the model describes the curve: a systematic misfit would be read as noise growing
        # with the model, and the weights it gives pull the fit away from the peak, further
        # each pass (a collapse, e.g. a Gaussian pulse fitted by the ADM: amplitude 28 where
        # the curve's area is 250). Such curves keep their unweighted fit, saying why. But
        # the signs of an unweighted fit's residuals also run in long stretches where the
        # noise grows with the model: where it is small (the tails), the residuals are
        # those of the fitted values' own error. So a curve whose unweighted residuals look
        # systematic is refitted too, by itself (the passes of the others stay theirs), and
        # keeps its unweighted fit only where the weighted fit's residuals look systematic
        # as well.
        results = list(first)
        doubtful = [i for i, r in enumerate(first) if r.lack_of_fit.systematic]
        described = sorted(set(range(len(first))) - set(doubtful))
        for group in ([described] if described else []) + [[i] for i in doubtful]:
            refitted = _refit_with_combined_errors(
                model, [curves[i] for i in group], [first[i] for i in group], settings)
            for i, r in zip(group, refitted, strict=True):
                kept = first[i].lack_of_fit.systematic and r.lack_of_fit.systematic
                results[i] = _kept_unweighted(first[i], settings) if kept else r
        return results
    if settings.relative_errors is not None:
        if weights is not None:
            raise ValueError("relative_errors sets the weights itself; pass weights=None")
        curves = [as_curve(c) for c in curves]
        plain = dataclasses.replace(settings, relative_errors=None)
        first = _fit_polished(model, curves, params, None, plain)
        return _refit_with_relative_errors(model, curves, first, settings)
    if settings.counting_errors is not None:
        if weights is not None:
            raise ValueError("counting_errors sets the weights itself; pass weights=None")
        curves = [as_curve(c) for c in curves]
        plain = dataclasses.replace(settings, counting_errors=None)
        first = _fit_polished(model, curves, params, _exposures(curves), plain)
        return _refit_with_counting_errors(model, curves, first, settings)
    curves = [as_curve(c) for c in curves]
    if not curves:
        raise ValueError("fit_many needs at least one curve")
    multistart = settings.multistart
    n_starts, seed = multistart.n_starts, multistart.seed
    options = make_plan(settings.loss, settings.optimiser, multistart)
    per_curve_weights = weights if weights is not None else [None] * len(curves)
    if len(per_curve_weights) != len(curves):
        raise ValueError(f"{len(per_curve_weights)} weight arrays for {len(curves)} curves")
    per_curve_params = (params if isinstance(params, Sequence) and not isinstance(params, str)
                        else [params] * len(curves))
    if len(per_curve_params) != len(curves):
        raise ValueError(f"{len(per_curve_params)} parameter settings for {len(curves)} curves")

    def prepare_all(count):
        return [prepare(model, c, p, w, count, seed + i)
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
    solver = compiled_solver(prepared[0].model, layout, options, "curves")
    out, wall_time, compile_time = run_solver(
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
                               compile_time / len(curves), settings,
                               absolute_errors=weights is None))
    return results


def _relative_weights(result: FitResult, loss: str, floor: float) -> np.ndarray:
    """The next pass's weights ``1 / max(|m|, floor · peak)²`` from a pass's model curve;
    a one-line ``ValueError`` where they cannot be formed (a model curve of zero: the
    passes collapsed, as they do where the noise does not scale with the model)."""
    size = np.abs(np.asarray(result.predicted, dtype=float))
    peak = float(size.max(initial=0.0))
    size = np.maximum(size, floor * max(peak, 1e-300))
    with np.errstate(divide="ignore", over="ignore"):
        weights = 1.0 / (size**2 if loss == "sse" else size)
    if not np.all(np.isfinite(weights)):
        label = f"curve {result.name!r}" if result.name else "the curve"
        raise ValueError(
            f"relative errors collapsed on {label}: a reweighted fit's model curve peaks at "
            f"{peak:.3g} (the fitted values drifted pass after pass), so the weights "
            "1/model^2 cannot be formed; the noise of this curve does not scale with the "
            "model: fit it with combined errors (the default) or absolute errors")
    return weights


@dataclasses.dataclass
class _Passes:
    """The outcome of :func:`_reweighted_passes`: the last pass's fits, how many fits each
    curve took, and the evaluations and times summed over the passes."""

    results: list[FitResult]
    count: int
    evaluations: np.ndarray
    wall: np.ndarray
    compile_time: np.ndarray
    #: Per curve, the relative change of its fitted values at the last pass (inf: none).
    changes: np.ndarray

    def finished(self, first: Sequence[FitResult], settings: FitSettings,
                 method: str) -> list[FitResult]:
        """The last pass's fits with the totals, the first pass's starts and `settings`."""
        return [dataclasses.replace(
            r, n_evaluations=int(e), wall_time=float(w), compile_time=float(c),
            method=f"{r.method}; {method}", n_starts=f.n_starts, init_params=f.init_params,
            start_losses=f.start_losses, start_values=f.start_values, settings=settings)
            for r, f, e, w, c in zip(self.results, first, self.evaluations, self.wall,
                                     self.compile_time, strict=True)]


#: A reweighted fit stopped by its limit of passes counts as settled when its last pass moved
#: every fitted value by less than this share of the smallest relative standard error (the
#: weights' last change then moves nothing its intervals can show).
SETTLED_SHARE = 0.1


#: Why reweighted fits may not settle, and what to do, by error model.
_UNSETTLED_ADVICE = {
    "relative": ("the noise of this curve does not grow with the model: try combined errors "
                 "(the default: they estimate how the noise grows with the model)"),
    "combined": ("the error sizes estimated from each fit's residuals keep moving the fit: try "
                 "absolute errors (one unweighted fit)"),
    "counting": ("counts have Poisson noise, so the fits moved between distinct optima of "
                 "parameters this curve determines poorly (see what it determines): fix or tie "
                 "one of them"),
}


def _with_settling(result: FitResult, kind: str, passes: int, change: float,
                   max_passes: int, change_limit: float) -> FitResult:
    """`result`, told plainly where its reweighted passes did not settle.

    The passes stop when the fitted values change by at most `change_limit` (relative), or
    after `max_passes` fits. Stopped by the limit with a last change above
    :data:`SETTLED_SHARE` of the smallest relative standard error, the error model's weights
    still moved the fit when the passes stopped: it is not a fit under that error model (for
    relative errors on noise that does not scale with the model the passes wander without
    end), so the result is marked not converged, saying why.
    """
    if passes < max_passes or not change > change_limit:
        return result
    relative = [abs(result.stderr[n] / result.values[n]) for n in result.free_names
                if result.stderr.get(n) is not None and result.values[n]
                and math.isfinite(result.stderr[n])]
    scale = min(relative, default=math.nan)
    if math.isfinite(change) and math.isfinite(scale) and change < SETTLED_SHARE * scale:
        return result
    message = (f"not converged: the {kind} error model's reweighted fits did not settle in "
               f"{passes} passes (the last moved the fitted values by {change:.2g}, relative"
               + (f"; their smallest relative standard error is {scale:.2g}" if
                  math.isfinite(scale) else "")
               + "), so its values and intervals are not those of a fit under this error "
               "model; " + _UNSETTLED_ADVICE[kind])
    # The method's own words ("until consistent", "the maximum-likelihood fit") no longer hold.
    method = re.sub(r"until consistent(, the maximum-likelihood fit)? \(\d+ passes\)",
                    f"not consistent after {passes} passes", result.method)
    return dataclasses.replace(result, converged=False, success=False, message=message,
                               method=method)


def _reweighted_passes(model, curves: Sequence[Curve], first: Sequence[FitResult],
                       settings: FitSettings, max_passes: int, change_limit: float,
                       next_weights: Callable[[list[FitResult]], list[np.ndarray] | None],
                       ) -> _Passes:
    """Fit again with the weights `next_weights` makes from the last pass's fits (one start,
    from the last fit), until the fitted values change by at most `change_limit` (relative)
    or `max_passes` fits were made; `next_weights` returns ``None`` to stop early."""
    results, count = list(first), 1
    changes = np.full(len(first), np.inf)
    evaluations = np.array([r.n_evaluations for r in first])
    wall = np.array([r.wall_time for r in first])
    compile_time = np.array([r.compile_time for r in first])
    single = dataclasses.replace(
        settings, relative_errors=None, combined_errors=None,
        counting_errors=None,
        multistart=MultiStart(n_starts=1, seed=settings.multistart.seed,
                              warmup_steps=settings.multistart.warmup_steps))
    for _ in range(max_passes - 1):
        weights = next_weights(results)
        if weights is None:
            break
        starts = [r.restart_parameters() for r in results]
        new = _fit_polished(model, curves, starts, weights, single)
        count += 1
        evaluations += [r.n_evaluations for r in new]
        wall += [r.wall_time for r in new]
        compile_time += [r.compile_time for r in new]
        changes = np.array([max(abs(b.values[n] / a.values[n] - 1) if a.values[n]
                                else abs(b.values[n]) for n in a.free_names)
                            for a, b in zip(results, new, strict=True)])
        results = new
        if changes.max(initial=0.0) <= change_limit:
            break
    return _Passes(results, count, evaluations, wall, compile_time, changes)


def _refit_with_relative_errors(model, curves: Sequence[Curve], first: Sequence[FitResult],
                                settings: FitSettings) -> list[FitResult]:
    """Iteratively reweighted fits: weights from the previous pass's model curves, until the
    fitted values stop changing (the weights are then those of the fit's own curve)."""
    relative = settings.relative_errors
    passes = _reweighted_passes(
        model, curves, first, settings, relative.max_passes, relative.change,
        lambda results: [_relative_weights(r, settings.loss, relative.floor) for r in results])
    method = f"relative errors: reweighted by 1/model^2 until consistent ({passes.count} passes)"
    finished = [_with_effective_dof(r) for r in passes.finished(first, settings, method)]
    return [_with_settling(dataclasses.replace(
                r, error_model=ErrorEstimate("relative", 0.0, r.sigma, passes.count)),
                "relative", passes.count, change, relative.max_passes, relative.change)
            for r, change in zip(finished, passes.changes, strict=True)]


def _refit_with_counting_errors(model, curves: Sequence[Curve], first: Sequence[FitResult],
                                settings: FitSettings) -> list[FitResult]:
    """Iterated weights ``x / m`` for counts (Poisson errors), from each pass's model curve,
    until the fitted values stop changing: the Poisson maximum-likelihood fit."""
    counting = settings.counting_errors
    exposures = _exposures(curves)
    passes = _reweighted_passes(
        model, curves, first, settings, counting.max_passes, counting.change,
        lambda results: [counting_weights(r.predicted, x, counting.floor)
                         for r, x in zip(results, exposures, strict=True)])
    method = f"{_COUNTING_METHOD} ({passes.count} passes)"
    return [_with_settling(_with_counting_errors(r, passes.count), "counting", passes.count,
                           change, counting.max_passes, counting.change)
            for r, change in zip(passes.finished(first, settings, method), passes.changes,
                                 strict=True)]


_COUNTING_METHOD = ("counting (Poisson) errors: reweighted by exposure/model until consistent, "
                    "the maximum-likelihood fit")


def _with_counting_errors(result: FitResult, passes: int) -> FitResult:
    """A fit to counts with the known Poisson scale: standard errors and covariance from
    ``(Jᵀ W J)⁻¹`` with ``W = x / m`` (not rescaled by the residuals), 95 % intervals from
    the normal quantile, AIC and BIC from the Poisson likelihood; the Pearson dispersion
    ``X² / dof`` of the merged bins (1 expected) is kept in the error model as a check."""
    sigma = result.sigma
    method = result.method if _COUNTING_METHOD in result.method else (
        f"{result.method}; {_COUNTING_METHOD} ({passes} passes)")
    # Pearson's X² / dof on the merged bins (that of bins expecting a fraction of a particle
    # scatters far more than a chi-square's: Var((k - μ)²/μ) = 2 + 1/μ).
    merged = result.lack_of_fit  # its settings hold the counting errors: on merged bins
    dispersion = merged.scaled_sse if merged.scaled_sse is not None else math.nan
    if not (sigma is not None and math.isfinite(sigma) and sigma > 0):
        return dataclasses.replace(result, method=method,
                                   error_model=ErrorEstimate("poisson", 0.0, dispersion, passes))
    factor = 1.0 / sigma
    stderr, ci95 = _rescaled_errors(result, factor, t_quantile(math.inf))
    exposure = result.exposure
    log_likelihood = poisson_log_likelihood(result.observed, result.predicted, exposure)
    n_free = len(result.free_names)
    n_points = int(np.count_nonzero(exposure))
    aic = -2.0 * log_likelihood + 2 * n_free
    bic = -2.0 * log_likelihood + n_free * math.log(max(n_points, 1))
    return dataclasses.replace(
        result, stderr=stderr, ci95=ci95, covariance=result.covariance * factor**2,
        aic=aic, bic=bic, method=method,
        error_model=ErrorEstimate("poisson", 0.0, dispersion, passes))


def _combined_estimate(result: FitResult) -> tuple[float, float]:
    """``(a, b)`` of the combined error model from a fit's residuals and leverages."""
    used = result.weights > 0
    leverage = leverages(result.jacobian[used], result.weights[used])
    return estimate_combined_errors(result.residuals[used], result.predicted[used], leverage)


def _refit_with_combined_errors(model, curves: Sequence[Curve], first: Sequence[FitResult],
                                settings: FitSettings) -> list[FitResult]:
    """Iterated weights for additive plus proportional errors: estimate ``(a, b)`` from the
    last fit, refit with weights ``1 / (a² + (b m)²)`` from its model curve, until the fitted
    values stop changing (the weights are then those of the fit's own curve and residuals)."""
    combined = settings.combined_errors
    used = [_combined_estimate(r) for r in first]  # the sizes behind the last pass's weights

    def next_weights(results):
        estimates = [_combined_estimate(r) for r in results]
        if all(a == 0.0 and b == 0.0 for a, b in estimates):
            return None  # an exact fit: no noise to weight by
        used[:] = estimates
        weights = []
        for r, (a, b) in zip(results, estimates, strict=True):
            w = combined_weights(r.predicted, a, b)
            weights.append(w / w.max())  # only relative weights matter; keep them of order 1
        return weights

    passes = _reweighted_passes(model, curves, first, settings, combined.max_passes,
                                combined.change, next_weights)
    method = (f"additive plus proportional errors: reweighted by 1/(a^2 + (b model)^2), a and "
              f"b estimated from the residuals, until consistent ({passes.count} passes)")
    return [_with_settling(_with_estimated_weight_shape(dataclasses.replace(
                r, error_model=ErrorEstimate("combined", a, b, passes.count))),
                "combined", passes.count, change, combined.max_passes, combined.change)
            for r, (a, b), change in zip(passes.finished(first, settings, method), used,
                                         passes.changes, strict=True)]


def _kept_unweighted(result: FitResult, settings: FitSettings) -> FitResult:
    """The unweighted fit of a curve its model does not describe, under combined errors."""
    note = ("the combined error model was not estimated: the unweighted fit's residuals are "
            "systematic, so they measure the misfit, not the noise")
    sigma = result.sigma if result.sigma is not None else math.nan
    return dataclasses.replace(result, settings=settings,
                               error_model=ErrorEstimate("absolute", float(sigma), 0.0, 1, note))


def _with_estimated_weight_shape(result: FitResult) -> FitResult:
    """Count the share ``a² : (b m)²`` of the combined error model as a fitted parameter.

    The weights' shape is estimated from the same residuals that then give ``s²``, so it
    takes one degree of freedom: ``s² = Σ w r² / (n - p - 1)``, and the intervals use the
    Student t of ``n - p - 1`` degrees of freedom (as for a variance-function parameter in
    generalised least squares with estimated weights).

    Where the estimate found no additive part (:func:`fitting.losses.proportional_shares`),
    the points far below the peak, whose weights the stand-in ``a`` caps, count as the
    shares of a degree of freedom their residuals hold (with ``n - p`` they would understate
    ``s``: 80 % coverage of the 95 % intervals on dense curves with 2 % proportional noise).
    """
    if result.loss_name != "sse" or result.dof <= 1:
        return result
    dof = result.dof
    error = result.error_model
    shares = (None if error is None or error.kind != "combined" else
              proportional_shares(error.additive, error.proportional, result.predicted))
    if shares is not None:
        effective = effective_degrees_of_freedom(result.jacobian, result.weights, shares)
        if math.isfinite(effective) and effective > 1:
            dof = effective
    return _with_degrees_of_freedom(result, dof - 1)


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
    model_size = np.abs(np.asarray(result.predicted, dtype=float))
    dof = effective_degrees_of_freedom(result.jacobian, result.weights,
                                       result.weights * model_size**2)
    if not (math.isfinite(dof) and dof > 0):
        return result
    return _with_degrees_of_freedom(result, dof)


def _rescaled_errors(result: FitResult, factor: float, quantile: float):
    """Standard errors times `factor` and the 95 % intervals they give with `quantile`
    (``None`` kept for parameters without an error)."""
    stderr, ci95 = {}, {}
    for name, error in result.stderr.items():
        if error is None:
            stderr[name], ci95[name] = None, None
            continue
        stderr[name] = error * factor
        ci95[name] = interval(result.values[name], quantile * stderr[name],
                              result.init_params[name])
    return stderr, ci95


def _with_degrees_of_freedom(result: FitResult, dof: float) -> FitResult:
    """`result` with ``s² = Σ w r² / dof``: standard errors, covariance and ``s`` rescaled by
    ``sqrt(result.dof / dof)``, intervals from the Student t of `dof` degrees of freedom."""
    factor = math.sqrt(result.dof / dof)
    stderr, ci95 = _rescaled_errors(result, factor, t_quantile(dof))
    return dataclasses.replace(result, stderr=stderr, ci95=ci95,
                               covariance=result.covariance * factor**2,
                               sigma=result.sigma * factor, dof=dof)
