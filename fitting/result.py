"""The result of a fit: the curve with its units, values, uncertainty, statistics, settings.

A :class:`FitResult` is immutable (a frozen dataclass with read-only arrays), like
``scipy.optimize``'s results with lmfit's readable report.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from typing import Any

import equinox as eqx
import numpy as np

from fitting.data import Curve
from fitting.losses import (
    CombinedErrors,
    CountingErrors,
    ErrorEstimate,
    check_passes,
    proportional_shares,
)
from fitting.models import Model
from fitting.parameters import Parameters
from fitting.residuals import LackOfFit, counting_lack_of_fit, lack_of_fit_test
from fitting.solve import MultiStart, Optimiser

__all__ = ["FitResult", "FitSettings", "FitStats", "RelativeErrors"]


class RelativeErrors(eqx.Module):
    """Settings of relative-error fits (errors proportional to the curve), immutable.

    After a first fit the curve is fitted again from its result with weights
    ``1 / max(|model|, floor · peak)²`` (``1 / max(|model|, floor · peak)`` for the mean
    absolute error), and again, until the fitted values change by less than `change`
    (iteratively reweighted least squares).

    **Arguments:**

    - `floor`: floor of the weights' model value, as a fraction of the model's peak (a
      measurement's error never vanishes; an unbounded weight would let one point near zero
      decide the fit).
    - `max_passes`: most fits in all.
    - `change`: relative change of every fitted value between passes below which the
      weights count as consistent with the fit.
    """

    floor: float = eqx.field(default=1e-3, static=True)
    max_passes: int = eqx.field(default=10, static=True)
    change: float = eqx.field(default=1e-8, static=True)

    def __check_init__(self):
        check_passes(self.max_passes, self.change, self.floor)


class FitSettings(eqx.Module):
    """Every setting a fit ran with, immutable: loss, optimiser, starts, error model.

    **Arguments:**

    - `loss`: ``'sse'`` or ``'mae'``.
    - `optimiser`: :class:`~fitting.solve.Optimiser`.
    - `multistart`: :class:`~fitting.solve.MultiStart`.
    - `relative_errors`: :class:`RelativeErrors`, or ``None`` for errors of equal size.
    - `combined_errors`: :class:`~fitting.losses.CombinedErrors` for additive plus
      proportional errors, both estimated, or ``None``.
    - `counting_errors`: :class:`~fitting.losses.CountingErrors` for particle counts
      (Poisson errors of known size), or ``None``.
    """

    loss: str = eqx.field(default="sse", static=True)
    optimiser: Optimiser = Optimiser()
    multistart: MultiStart = MultiStart()
    relative_errors: RelativeErrors | None = None
    combined_errors: CombinedErrors | None = None
    counting_errors: CountingErrors | None = None

    def __check_init__(self):
        if self.loss not in ("sse", "mae"):
            raise ValueError(f"loss must be one of ['mae', 'sse'], got {self.loss!r}")
        chosen = [name for name in ("relative_errors", "combined_errors", "counting_errors")
                  if getattr(self, name) is not None]
        if len(chosen) > 1:
            raise ValueError(f"choose one error model, not {' and '.join(chosen)}")
        if self.counting_errors is not None and self.loss != "sse":
            raise ValueError("counting errors need the least-squares loss 'sse'")


@dataclass(frozen=True)
class FitStats:
    """Statistics of a fit: loss, ``Σ w r²``, degrees of freedom, ``s``, AIC, BIC, counts, times.

    Units: those of the data (``sse`` in its unit squared, ``sigma`` in its unit), seconds
    for the times.
    """

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
    wall_time: float
    compile_time: float


def residual_verdict(residuals: np.ndarray, weights: np.ndarray, observed: np.ndarray,
                     dof: float, loss_name: str, described: np.ndarray) -> LackOfFit:
    """The lack-of-fit verdict of a (not counting) fit from its arrays: what
    :attr:`FitResult.lack_of_fit` gives, for a fit whose result is not built (yet).

    **Arguments:** `residuals` (model - data) and `weights` per point, `observed` (the data),
    `dof`, `loss_name` (``"sse"`` or ``"mae"``, whose weights multiply ``|r|``) and
    `described` (:meth:`FitResult.described_points`).
    """
    weights = np.asarray(weights, dtype=float)
    if loss_name == "mae":
        weights = weights**2
    used = weights > 0
    peak = float(np.max(np.abs(observed[used]), initial=0.0))
    return lack_of_fit_test(residuals, weights, dof=dof, peak=peak, described=described)


@dataclass(frozen=True, eq=False)
class FitResult:
    """The outcome of a fit: values, uncertainty, convergence and the fitted curve.

    Attributes (units are those of the model's parameters and of the data):

    - `values`: fitted value of every parameter (free, fixed and tied), by name.
    - `stderr`: standard error by name (``None`` for fixed parameters; tied ones by
      propagation through their expression); from the Gauss–Newton curvature, see
      :mod:`fitting.uncertainty`.
    - `ci95`: ``(low, high)`` 95 % interval by name (Student t with ``n - p`` degrees of
      freedom), ``None`` for fixed parameters; widened to hold other optima of the fit
      (`joined`, :mod:`fitting.optima`) or replaced by a profile (`profiled`); see
      :meth:`interval_kind`.
    - `correlation`, `covariance`: matrices over `free_names`.
    - `loss`: the minimised loss, unscaled (``Σ w r²`` or the mean absolute error).
    - `sse`: ``Σ w r²`` at the optimum whatever the loss (for AIC/BIC and errors).
    - `dof`: degrees of freedom of ``sse``, ``n - p`` (not a whole number for relative-error
      fits, where weights capped at the floor count less); `sigma`: ``sqrt(sse / dof)``.
    - `n_evaluations`: objective evaluations (value and gradient), all starts together.
    - `wall_time`: seconds the compiled solver ran (for :func:`fit_many`, its share of the
      time from the start of its program, or the collection of the program before, to the
      collection of its outputs: where results are built while later programs run, that
      time includes some of the Python work); `compile_time`: seconds spent compiling it
      first (0 when reused).
    - `success`: converged with a finite loss; `converged`: a convergence test was met;
      `status` and `message`: which stopping rule ended the fit.
    - `model`, `params` (:class:`Parameters` with fitted values), `curve` (the data, with
      its time unit; `time`, `observed`, `name` and `time_unit` read from it), `weights`,
      `predicted`, `residuals` (model - data), `jacobian` (d predicted / d free), all
      read-only arrays.
    - `settings`: the :class:`FitSettings` the fit ran with.
    - `error_model`: the :class:`~fitting.losses.ErrorEstimate` behind the weights (kind and
      estimated sizes), or ``None`` for weights given by the caller.
    - `lack_of_fit`: the :class:`~fitting.residuals.LackOfFit` verdict on the residuals
      (computed on first use).
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
    curve: Curve = field(repr=False)
    weights: np.ndarray = field(repr=False)
    predicted: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)
    jacobian: np.ndarray = field(repr=False)
    compile_time: float = 0.0
    settings: FitSettings | None = field(default=None, repr=False)
    error_model: ErrorEstimate | None = field(default=None, repr=False)
    start_values: np.ndarray | None = field(default=None, repr=False)
    #: Free parameters whose `ci95` is a profile-likelihood interval
    #: (:func:`fitting.diagnostics.with_profile_intervals`); the others' are linearised.
    profiled: tuple[str, ...] = field(default=(), repr=False)
    #: Free parameters whose `ci95` was widened to hold another optimum of the fit
    #: (:func:`fitting.optima.with_other_optima`).
    joined: tuple[str, ...] = field(default=(), repr=False)
    #: The linearised intervals of the best optimum alone, where `joined` is not empty
    #: (``None``: `ci95` is that interval).
    linearised_ci95: dict[str, tuple[float, float] | None] | None = field(default=None,
                                                                          repr=False)
    #: For a curve long enough that the model is evaluated on interpolation panels (a model
    #: with a ``long_curve_check`` hook): ``(largest deviation from the exact model over
    #: every point at the fitted values, peak)`` in the curve's unit (``None``: exact
    #: everywhere, no check needed).
    evaluation_check: tuple[float, float] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name in ("weights", "predicted", "residuals", "jacobian", "start_losses",
                     "covariance", "correlation"):
            array = np.array(getattr(self, name), dtype=float)
            array.flags.writeable = False
            object.__setattr__(self, name, array)
        if self.start_values is not None:
            ends = np.array(self.start_values, dtype=float)
            ends.flags.writeable = False
            object.__setattr__(self, "start_values", ends)

    @property
    def linearised_intervals(self) -> dict[str, tuple[float, float] | None]:
        """The linearised 95 % intervals of the best optimum's neighbourhood, by name (the
        same as `ci95` unless another optimum widened it, or a profile replaced it)."""
        return self.ci95 if self.linearised_ci95 is None else self.linearised_ci95

    def interval_kind(self, name: str) -> str | None:
        """How the 95 % interval of `name` was found: ``'profile'``, ``'linearised'`` or
        ``'linearised and other optima'`` (widened to hold them); ``None`` for none."""
        if self.ci95.get(name) is None:
            return None
        if name in self.profiled:
            return "profile"
        return "linearised and other optima" if name in self.joined else "linearised"

    @property
    def time(self) -> np.ndarray:
        """Sample times of the fitted curve, in :attr:`time_unit`."""
        return self.curve.time

    @property
    def observed(self) -> np.ndarray:
        """The fitted data values (E in 1/:attr:`time_unit` for a normalised curve)."""
        return self.curve.value

    @property
    def name(self) -> str:
        """The curve's label."""
        return self.curve.name

    @property
    def time_unit(self) -> str:
        """Unit of the curve's times, and of the time-like parameters (``"s"``, ``"min"``, ...)."""
        return self.curve.time_unit

    @property
    def stats(self) -> FitStats:
        """The fit statistics as one block (loss, SSE, dof, s, AIC, BIC, counts, times)."""
        return FitStats(self.loss, self.loss_name, self.sse, self.n_points, self.dof,
                        self.sigma, self.aic, self.bic, self.n_evaluations, self.n_steps,
                        self.n_starts, self.wall_time, self.compile_time)

    @functools.cached_property
    def lack_of_fit(self) -> LackOfFit:
        """The lack-of-fit verdict on this fit's residuals, standardised by its error model.

        Runs test, lag-1 autocorrelation (:func:`fitting.residuals.lack_of_fit_test`) on
        ``sqrt(w) r`` (``w r`` for the mean absolute error, whose weights multiply ``|r|``),
        leaving out zero-weight points and, for relative-error fits, the points whose weight
        the floor caps (:meth:`described_points`). The noise level is taken as estimated from
        the same residuals, so there is no scaled-SSE test here; give a known one to
        :func:`fitting.diagnostics.lack_of_fit`. A fit to counts (counting errors) is tested
        on bins merged to a few expected particles each, with the known Poisson noise
        (:func:`fitting.residuals.counting_lack_of_fit`).
        """
        if self.counting:
            return counting_lack_of_fit(self.observed, self.predicted, self.exposure,
                                        len(self.free_names))
        return residual_verdict(self.residuals, self.weights, self.observed, self.dof,
                                self.loss_name, self.described_points())

    @property
    def counting(self) -> bool:
        """Whether the fit treated its values as counts (counting errors of known size)."""
        return getattr(self.settings, "counting_errors", None) is not None

    @property
    def exposure(self) -> np.ndarray:
        """Counts per unit value at each point (``Curve.exposure``; ones when the curve
        gives none: the values are then the counts themselves)."""
        if self.curve.exposure is not None:
            return self.curve.exposure
        return np.ones(len(self.curve))

    def described_points(self) -> np.ndarray:
        """Which points' noise the fit's weights describe (boolean, one per point).

        All of them, except in a relative-error fit the points whose model value lies below
        the floor (``|model| < floor · peak``): their weight is capped there, so it no longer
        says how large their noise is. Likewise in a combined-error fit whose estimate found
        no additive part (:func:`fitting.losses.proportional_shares`): the points where the
        stand-in additive part holds most of the variance (far below the peak, where the
        residuals may be the model's own rounding, not noise).
        """
        relative = getattr(self.settings, "relative_errors", None)
        size = np.abs(np.asarray(self.predicted, dtype=float))
        error = self.error_model
        if error is not None and error.kind == "combined" and size.size:
            shares = proportional_shares(error.additive, error.proportional, size)
            if shares is not None:
                return shares >= 0.5
        if relative is None or size.size == 0:
            return np.ones(size.shape, dtype=bool)
        return size >= relative.floor * size.max()

    def equivalent_adm(self, length: float | None = None) -> dict[str, Any] | None:
        """The closed–closed ADM equivalent to this fit, from the model's hook, with units.

        **Arguments:**

        - `length`: blender length ``L`` (m) for ``v`` and ``D_z``; ``None`` gives ``tau``
          and ``Pe`` only (there is no default length).

        **Returns:** ``{"tau_<unit>", "peclet", "length_m", "velocity_m_per_s",
        "dispersion_m2_per_s", ...}`` (``None`` where undefined), or ``None`` when the model
        has no equivalent ADM.
        """
        if self.model.equivalent_adm is None:
            return None
        return self.model.equivalent_adm(self.values, length, self.curve.time_unit)

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
            f"    residual scale s   = {self.sigma:.6g} ({self._scale_meaning()})",
            f"    AIC                = {self.aic:.4f}",
            f"    BIC                = {self.bic:.4f}",
            "[[Lack of fit]]",
            f"    {self.lack_of_fit.statement}",
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

    def _scale_meaning(self) -> str:
        """What ``s = sqrt(Σ w r² / dof)`` measures under this fit's error model, in words."""
        kind = self.error_model.kind if self.error_model is not None else "absolute"
        unit = self.curve.value_unit or ("1/" + self.time_unit if self.curve.normalised
                                         else "in the data's unit")
        if kind == "relative":
            return "the noise as a fraction of the model"
        if kind == "combined":
            return "the weighted residuals' scale, weights from the estimated noise sizes"
        if kind == "poisson":
            return "Pearson's, 1 expected for counts"
        if np.all(self.weights[self.weights > 0] == 1.0):
            return f"the noise's standard deviation, {unit}"
        return "the weighted residuals' scale"

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (plain floats, ``None`` for undefined numbers)."""

        def number(x):
            if x is None:
                return None
            x = float(x)
            return x if math.isfinite(x) else None

        parameters = {}
        for name, value in self.values.items():
            setting = self.init_params[name]
            interval = self.ci95[name]
            parameters[name] = {
                "value": number(value),
                "stderr": number(self.stderr[name]),
                "ci95": [number(interval[0]), number(interval[1])] if interval else None,
                "interval": self.interval_kind(name),
                "vary": bool(setting.vary and setting.expr is None),
                "expr": setting.expr,
                "min": setting.min,
                "max": setting.max,
                "init": setting.value,
            }
        return {
            "model": self.model.name,
            "data": self.name,
            "time_unit": self.time_unit,
            "parameters": parameters,
            "correlation": {
                "names": list(self.free_names),
                "matrix": [[number(x) for x in row] for row in self.correlation.tolist()],
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
            "lack_of_fit": self.lack_of_fit.to_dict(),
            "error_model": None if self.error_model is None else self.error_model.to_dict(),
        } | ({} if self.evaluation_check is None else {"evaluation_check": {
            "largest_deviation": number(self.evaluation_check[0]),
            "peak": number(self.evaluation_check[1]), "points": len(self.curve)}})

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

    def to_json(self, **kwargs: Any) -> str:
        """:meth:`to_dict` as a JSON string."""
        return json.dumps(self.to_dict(), **kwargs)
