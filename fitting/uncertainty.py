"""Uncertainty of fitted parameters from arrays: standard errors, intervals, degrees of freedom.

Least-squares theory (e.g. Bates & Watts, *Nonlinear Regression Analysis*, 1988, ch. 2):
with residuals ``r = y_model - y``, weights ``W = diag(w)`` and the Jacobian
``J = d y_model / d p`` of the free parameters at the optimum, the Gauss–Newton curvature is
``A = Jᵀ W J``, the residual variance ``s² = Σ w r² / (n - p)`` and the covariance
``C = s² A⁻¹`` (lmfit's default ``scale_covar=True``: the weights give relative, not absolute,
precision). Standard errors are ``sqrt(diag C)``; 95 % intervals ``p ± t(0.975, n - p) · se``
(Student t). Tied parameters get ``sqrt(g C gᵀ)`` with ``g`` the gradient of their expression.
For a model linear in its parameters this is the exact least-squares result.

These linearised errors assume Gaussian noise and a model close to linear over the interval;
:func:`fitting.diagnostics.profile_likelihood` checks that assumption by re-fitting. With the
``'mae'`` loss the numbers are the least-squares approximation at the MAE optimum.

Everything here takes and returns arrays and numbers; identifiability and profiles, which
need fit results and re-fits, are functions of :mod:`fitting.diagnostics`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from fitting.distributions import t_quantile as _t_quantile
from fitting.parameters import Parameter

__all__ = [
    "LOG_INTERVAL_LIMIT",
    "GaussNewtonUncertainty",
    "effective_degrees_of_freedom",
    "gauss_newton_uncertainty",
    "information_criteria",
    "interval",
    "t_quantile",
]

#: Curvature eigenvalues below this fraction of the largest are numerically zero: the
#: combination is not determined by the data at all (structural non-identifiability).
SINGULAR_RATIO = 1e-12


@dataclass(frozen=True)
class GaussNewtonUncertainty:
    """Linearised least-squares uncertainty of the free parameters (see module docstring).

    - `covariance`, `correlation`: ``(p, p)`` over the free parameters (NaN if singular).
    - `all_stderr`: standard error of every parameter (free, fixed = 0, tied propagated).
    - `sigma`: residual standard deviation ``s``; `dof`: ``n - p``.
    - `t_quantile`: Student-t 97.5 % quantile with `dof` degrees of freedom.
    - `singular`: the curvature matrix is (numerically) singular.
    """

    covariance: np.ndarray
    correlation: np.ndarray
    all_stderr: np.ndarray
    sigma: float
    dof: int
    t_quantile: float
    singular: bool


def _unit_columns(jacobian: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sqrt(W) J`` with unit-norm columns, and the column norms (0 for a zero column).

    The curvature of the scaled columns, ``D Jᵀ W J D`` with ``D = diag(1 / norms)``, has a
    unit diagonal whatever the units of the parameters (seconds or hours, a rate or a
    Peclet number), so a test of its eigenvalues for singularity does not depend on them;
    the columns are divided by their largest entry first, so squares neither overflow nor
    underflow.
    """
    root = np.sqrt(weights)[:, None] * jacobian
    peak = np.max(np.abs(root), axis=0) if root.size else np.zeros(jacobian.shape[1])
    peak = np.where(np.isfinite(peak) & (peak > 0), peak, 1.0)
    root = root / peak
    norm = np.sqrt(np.sum(root**2, axis=0))
    usable = norm > 0
    root = root / np.where(usable, norm, 1.0)
    return root, np.where(usable, norm * peak, 0.0)


def _singular(scaled_curvature: np.ndarray, norms: np.ndarray) -> bool:
    """Whether a unit-diagonal curvature (see :func:`_unit_columns`) is numerically singular."""
    if scaled_curvature.size == 0 or not np.all(np.isfinite(scaled_curvature)):
        return True
    return _singular_spectrum(np.linalg.eigvalsh(scaled_curvature), norms)


def _singular_spectrum(eigenvalues: np.ndarray, norms: np.ndarray) -> bool:
    """:func:`_singular` from the curvature's eigenvalues."""
    return bool(np.any(norms <= 0) or eigenvalues.max() <= 0
                or eigenvalues.min() <= SINGULAR_RATIO * eigenvalues.max())


def effective_degrees_of_freedom(jacobian: np.ndarray, weights: np.ndarray,
                                 variance_factors: np.ndarray) -> float:
    """Degrees of freedom of ``Σ w r²`` when the weights are not the inverse variances.

    With ``Var(y_i) = σ² v_i``, weights ``W`` and the weighted projection
    ``P = J (Jᵀ W J)⁻¹ Jᵀ W``, the residuals of the linearised fit are ``(I - P) ε`` and
    ``E[Σ w r²] = σ² tr(W (I - P) V (I - P)ᵀ)``: this trace is the number of degrees of
    freedom, ``n - p`` when ``W = V⁻¹``. Expanded, it is
    ``Σ_{w_i > 0} a_i - tr(A⁻¹ Jᵀ diag(w a) J)`` with ``A = Jᵀ W J`` and ``a = w v``, which
    costs ``O(n p²)`` time and ``O(n p)`` memory (never an ``n × n`` matrix).

    **Arguments:**

    - `jacobian`: ``d y_model / d p`` at the optimum, shape ``(n, p)``.
    - `weights`: ``w_i >= 0``, shape ``(n,)``.
    - `variance_factors`: ``a_i = w_i v_i``, shape ``(n,)`` (dimensionless; 1 where the
      weight is the inverse variance).

    **Returns:** the trace above (NaN when the curvature is singular).
    """
    jacobian = np.asarray(jacobian, dtype=float)
    weights = np.asarray(weights, dtype=float)
    factors = np.where(weights > 0, np.asarray(variance_factors, dtype=float), 0.0)
    columns, norms = _unit_columns(jacobian, weights)
    curvature = columns.T @ columns
    if _singular(curvature, norms):
        return math.nan
    # Jᵀ diag(w a) J in the same column scaling: (sqrt(W) J D)ᵀ diag(a) (sqrt(W) J D).
    spread = columns.T @ (factors[:, None] * columns)
    return float(np.sum(factors) - np.trace(np.linalg.solve(curvature, spread)))


def gauss_newton_uncertainty(
    jacobian: np.ndarray,
    residual: np.ndarray,
    weights: np.ndarray,
    all_from_free: np.ndarray | None = None,
) -> GaussNewtonUncertainty:
    """Covariance, correlation and standard errors from the Gauss–Newton curvature.

    **Arguments:**

    - `jacobian`: ``d y_model / d p`` at the optimum, shape ``(n, p)`` (free parameters).
    - `residual`: ``y_model - y``, shape ``(n,)``.
    - `weights`: ``w_i >= 0``, shape ``(n,)``; points with zero weight do not count in ``n``.
    - `all_from_free`: ``d p_all / d p_free``, shape ``(m, p)``, to propagate errors to tied
      (and fixed, giving 0) parameters; default the identity.

    **Returns:**

    A :class:`GaussNewtonUncertainty`.
    """
    jacobian = np.asarray(jacobian, dtype=float)
    residual = np.asarray(residual, dtype=float)
    weights = np.asarray(weights, dtype=float)
    n_free = jacobian.shape[1]
    n_points = int(np.count_nonzero(weights))
    dof = n_points - n_free
    sse = float(np.sum(weights * residual**2))
    variance = sse / dof if dof > 0 else math.nan
    # C = s² A⁻¹ = (s D) (D A D)⁻¹ (s D), in unit-free column scaling (see _unit_columns).
    columns, norms = _unit_columns(jacobian, weights)
    scaled = columns.T @ columns
    # One eigen-decomposition decides singularity (as :func:`_singular`) and inverts.
    singular = scaled.size == 0 or not np.all(np.isfinite(scaled))
    if not singular:
        eigenvalues, eigenvectors = np.linalg.eigh(scaled)
        singular = _singular_spectrum(eigenvalues, norms)
    if singular:
        covariance = np.full((n_free, n_free), np.nan)
    else:
        spread = math.sqrt(variance) / norms if dof > 0 else np.full(n_free, np.nan)
        covariance = (spread[:, None] * ((eigenvectors / eigenvalues) @ eigenvectors.T)
                      * spread[None, :])
    stderr = np.sqrt(np.clip(np.diag(covariance), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(stderr, stderr)
    if all_from_free is None:
        all_from_free = np.eye(n_free)
    all_from_free = np.asarray(all_from_free, dtype=float)
    all_stderr = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", all_from_free, covariance,
                                           all_from_free), 0, None))
    if singular:
        all_stderr = np.where(np.any(all_from_free != 0, axis=1), np.nan, 0.0)
    return GaussNewtonUncertainty(covariance, correlation, all_stderr, math.sqrt(variance)
                                  if dof > 0 else math.nan, dof, t_quantile(dof), singular)


def information_criteria(sse: float, n_points: int, n_free: int) -> tuple[float, float]:
    """Akaike and Bayesian information criteria for a least-squares fit (Gaussian likelihood).

    **Arguments:**

    - `sse`: sum of squared residuals ``Σ w r²``.
    - `n_points`: number of data points ``n``.
    - `n_free`: number of fitted parameters ``k``.

    **Returns:**

    ``(AIC, BIC)`` with ``AIC = n ln(SSE/n) + 2k`` and ``BIC = n ln(SSE/n) + k ln n``
    (constants common to all models on the same data dropped; lower is better).
    """
    log_likelihood_term = n_points * math.log(max(sse, 1e-300) / n_points)
    return log_likelihood_term + 2 * n_free, log_likelihood_term + n_free * math.log(n_points)


@functools.lru_cache(maxsize=4096)
def t_quantile(dof: float) -> float:
    """Student-t 97.5 % quantile with `dof` degrees of freedom (NaN for ``dof <= 0``)."""
    return _t_quantile(dof, 0.975)


#: Half-width in ln p beyond which a positive parameter's interval is reported as (0, inf):
#: a factor of 1e20 either way bounds nothing.
LOG_INTERVAL_LIMIT = math.log(1e20)


def interval(value: float, half_width: float, setting: Parameter) -> tuple[float, float]:
    """95 % interval ``value ± half_width``; for a positive parameter with a lower bound of
    zero or more, symmetric in ``ln p`` instead (the coordinate the fit uses), so that it
    stays positive: ``value · exp(±half_width / value)``. The two agree when the relative
    error is small.

    **Arguments:** `value`, `half_width` (same unit); `setting`: the parameter's bounds.

    **Returns:** ``(low, high)``; ``(0, inf)`` when the log-scale half-width exceeds
    :data:`LOG_INTERVAL_LIMIT`.
    """
    if setting.min is not None and setting.min >= 0 and value > 0:
        if not half_width / value <= LOG_INTERVAL_LIMIT:
            return (0.0, math.inf)  # not bounded at all (or an undefined error)
        factor = math.exp(half_width / value)
        return (value / factor, value * factor)
    return (value - half_width, value + half_width)


#: Half-width in ln p beyond which a positive parameter's interval is reported as (0, inf):
#: a factor of 1e20 either way bounds nothing.
LOG_INTERVAL_LIMIT = math.log(1e20)
