"""A factor law's fitted coefficients with their uncertainty
(:class:`~fitting.study.global_fit.LawEstimate`), and the usual two-stage analysis that
estimates them from curves fitted one by one (:func:`~fitting.study.global_fit.two_stage_law`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from fitting.parameters import Parameter
from fitting.result import FitResult
from fitting.study.global_fit.law import FactorLaw, factor_column
from fitting.uncertainty import gauss_newton_uncertainty, interval


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


def law_estimate(law: FactorLaw, method: str, names: Sequence[str], values: np.ndarray,
                 covariance: np.ndarray, dof: float, quantile: float) -> LawEstimate:
    """A :class:`LawEstimate` from coefficient values and their covariance."""
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
    design = law.design({name: factor_column(factors, name) for name in law.factors})
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
    return law_estimate(law, "two-stage regression", law.coefficient_names, coefficients,
                        uncertainty.covariance, uncertainty.dof, uncertainty.t_quantile)
