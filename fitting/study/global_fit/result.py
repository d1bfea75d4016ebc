"""The record of a global fit (:class:`~fitting.study.global_fit.GlobalFitResult`): the joint
values, errors and intervals, the laws' coefficients, every curve's parameters, and the fit as
a table of curves and as a report in words.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from fitting.result import FitResult
from fitting.solve import Status
from fitting.study.global_fit.estimate import LawEstimate
from fitting.study.global_fit.model import GlobalModel

#: How the report describes the curves' weights.
_WEIGHTING_WORDS = {"combined": "by each sample's noise, a_i² + (b_i m)², both estimated "
                                "from the curve's own fit",
                    "per-curve": "by their own noise level (estimated)", "equal": "equally",
                    "given": "by the given weights"}


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
