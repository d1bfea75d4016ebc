"""Uncertainty of fitted parameters: standard errors, intervals, identifiability, profiles.

Least-squares theory (e.g. Bates & Watts, *Nonlinear Regression Analysis*, 1988, ch. 2):
with residuals ``r = y_model - y``, weights ``W = diag(w)`` and the Jacobian
``J = d y_model / d p`` of the free parameters at the optimum, the Gauss–Newton curvature is
``A = Jᵀ W J``, the residual variance ``s² = Σ w r² / (n - p)`` and the covariance
``C = s² A⁻¹`` (lmfit's default ``scale_covar=True``: the weights give relative, not absolute,
precision). Standard errors are ``sqrt(diag C)``; 95 % intervals ``p ± t(0.975, n - p) · se``
(Student t). Tied parameters get ``sqrt(g C gᵀ)`` with ``g`` the gradient of their expression.
For a model linear in its parameters this is the exact least-squares result.

These linearised errors assume Gaussian noise and a model close to linear over the interval;
:func:`profile_likelihood` checks that assumption by re-fitting. With the ``'mae'`` loss
the numbers are the least-squares approximation at the MAE optimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np
from scipy import stats

if TYPE_CHECKING:
    from fitting.optimize import FitResult

__all__ = [
    "GaussNewtonUncertainty",
    "Identifiability",
    "Profile",
    "equivalent_dispersion",
    "gauss_newton_uncertainty",
    "identifiability",
    "information_criteria",
    "profile_likelihood",
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
    curvature = jacobian.T @ (weights[:, None] * jacobian)
    eigenvalues, eigenvectors = np.linalg.eigh(curvature)
    largest = eigenvalues.max() if eigenvalues.size else 0.0
    singular = bool(largest <= 0 or eigenvalues.min() <= SINGULAR_RATIO * largest)
    if singular:
        covariance = np.full((n_free, n_free), np.nan)
    else:
        covariance = variance * (eigenvectors / eigenvalues) @ eigenvectors.T
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
    t_quantile = float(stats.t.ppf(0.975, dof)) if dof > 0 else math.nan
    return GaussNewtonUncertainty(covariance, correlation, all_stderr, math.sqrt(variance)
                                  if dof > 0 else math.nan, dof, t_quantile, singular)


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
