"""Losses that score a model curve against a measured one.

Residuals are ``r_i = y_model(t_i) - y_exp(t_i)``. Weights ``w_i >= 0`` multiply the squared
residuals (``w_i = 1 / sigma_i²`` for points with known standard deviations ``sigma_i``); a
zero weight drops a point (used to pad curves of different lengths to one array).

* ``'sse'``: least squares ``Σ w_i r_i²``, the loss with a statistical meaning (Gaussian
  errors), used for standard errors and intervals.
* ``'mae'``: the source work's mean absolute error ``(1/n) Σ |r_i|`` (weighted:
  ``Σ w_i |r_i| / Σ w_i``), kept to compare with its grid search. It is not smooth at zero
  residuals, so gradient methods converge on it less cleanly than on ``'sse'``.

Error models say how large a measurement's error is, and so which weights least squares needs:

* absolute: errors of one size, ``Var(y_i) = a²`` (unweighted least squares);
* relative: errors proportional to the curve, ``Var(y_i) = (b m_i)²`` (``m_i`` the model value);
* combined (:class:`CombinedErrors`): both, ``Var(y_i) = a² + (b m_i)²``, as real detectors
  have (an additive noise floor and a proportional part). Both ``a`` and ``b`` are estimated
  from the data by iterated weights: after a fit, :func:`estimate_combined_errors` finds the
  ``(a, b)`` that maximise the Gaussian pseudo-likelihood of the residuals (Carroll and
  Ruppert 1988, *Transformation and Weighting in Regression*, ch. 3), each squared residual
  divided by ``1 - h_i`` (its leverage) so that it is unbiased for its variance; the curve is
  fitted again with weights ``1 / (a² + (b m_i)²)``, until the fitted values stop changing.
  A point where the model is zero keeps the weight ``1/a²``: no floor is needed.
* counting (:class:`CountingErrors`, ``errors="poisson"``): the values are particle counts
  divided by a known *exposure* ``x_i`` (a histogram's bin width, ``Curve.exposure``), so
  ``x_i y_i`` is a Poisson count of mean ``x_i m_i`` and ``Var(y_i) = m_i / x_i``, of known
  size. The curve is fitted again with weights ``x_i / m_i`` from its own model curve until
  the fitted values stop changing: the fixed point of these iterated weights solves the
  Poisson score equations ``Σ (y_i - m_i) / m_i ∂m_i/∂θ = 0``, so it is the maximum-likelihood
  fit (McCullagh and Nelder 1989, *Generalized Linear Models*, §2.5). With a free amplitude
  (the measurement model's) the Poisson likelihood factorises into the total count and the
  multinomial histogram of a fixed number of particles, so the shape parameters and their
  covariance are the multinomial ones too. The scale is known (1): standard errors are not
  rescaled by the residuals, intervals use the normal quantile, and lack of fit is tested
  on bins merged until each expects :data:`~fitting.residuals.COUNTS_PER_MERGED_BIN`
  particles (:func:`fitting.residuals.counting_lack_of_fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

import axialmix  # noqa: F401  (float64 before any JAX array is made)

__all__ = [
    "ERROR_KINDS",
    "LOSSES",
    "CombinedErrors",
    "CountingErrors",
    "ErrorEstimate",
    "check_passes",
    "counting_weights",
    "poisson_log_likelihood",
    "combined_weights",
    "estimate_combined_errors",
    "leverages",
    "mean_absolute_error",
    "proportional_shares",
    "residuals",
    "sum_of_squares",
]

#: The error models by name.
ERROR_KINDS = ("absolute", "relative", "combined", "poisson")


def residuals(predicted: ArrayLike, observed: ArrayLike) -> Array:
    """Model minus data at each sample time.

    **Arguments:**

    - `predicted`: model values ``y_model(t_i)``, shape ``(n,)``.
    - `observed`: measured values ``y_exp(t_i)``, shape ``(n,)``, same unit.

    **Returns:**

    ``y_model - y_exp``, shape ``(n,)``.
    """
    return jnp.asarray(predicted) - jnp.asarray(observed)


def sum_of_squares(
    residual: ArrayLike, weights: ArrayLike | None = None
) -> Array:
    """Weighted sum of squared residuals ``Σ w_i r_i²``.

    **Arguments:**

    - `residual`: residuals ``r_i``, shape ``(n,)``; unit U.
    - `weights`: ``w_i >= 0`` (default all one), shape ``(n,)``; unit 1/U² for ``1/sigma²``.

    **Returns:**

    The scalar loss; unit U² (dimensionless with ``1/sigma²`` weights).
    """
    residual = jnp.asarray(residual)
    squared = residual**2
    if weights is None:
        return jnp.sum(squared)
    return jnp.sum(jnp.asarray(weights) * squared)


def mean_absolute_error(
    residual: ArrayLike, weights: ArrayLike | None = None
) -> Array:
    """Mean absolute residual, the source's ``Error = (1/n) Σ |y_model - y_exp|``.

    **Arguments:**

    - `residual`: residuals ``r_i``, shape ``(n,)``; unit U.
    - `weights`: ``w_i >= 0`` (default all one); the weighted form is
      ``Σ w_i |r_i| / Σ w_i``.

    **Returns:**

    The scalar loss; unit U.
    """
    residual = jnp.abs(jnp.asarray(residual))
    if weights is None:
        return jnp.mean(residual)
    weights = jnp.asarray(weights)
    return jnp.sum(weights * residual) / jnp.sum(weights)


#: The losses :func:`fitting.fit.fit` accepts, by name.
LOSSES = {"sse": sum_of_squares, "mae": mean_absolute_error}


# --- the combined error model ------------------------------------------------------------------


class CombinedErrors(eqx.Module):
    """Settings of fits with additive plus proportional errors, ``Var = a² + (b m)²``, immutable.

    After a first (unweighted) fit, ``a`` and ``b`` are estimated from its residuals
    (:func:`estimate_combined_errors`) and the curve is fitted again with weights
    ``1 / (a² + (b m)²)`` from its own model curve ``m``, until the fitted values change by
    less than `change` (iterated weights).

    **Arguments:**

    - `max_passes`: most fits in all (at least 2).
    - `change`: relative change of every fitted value between passes below which the
      weights count as consistent with the fit.
    """

    max_passes: int = eqx.field(default=20, static=True)
    change: float = eqx.field(default=1e-8, static=True)

    def __check_init__(self):
        check_passes(self.max_passes, self.change)


def check_passes(max_passes: int, change: float, floor: float | None = None) -> None:
    """The checks every iterated-weights setting shares: at least 2 fits, a positive
    `change`, and a `floor` (when the setting has one) inside (0, 1); ``ValueError`` else."""
    if floor is not None and not 0 < floor < 1:
        raise ValueError(f"floor must lie in (0, 1), got {floor}")
    if not max_passes >= 2:
        raise ValueError(f"max_passes must be at least 2, got {max_passes}")
    if not change > 0:
        raise ValueError(f"change must be positive, got {change}")


class CountingErrors(eqx.Module):
    """Settings of fits to particle counts (Poisson errors of known size), immutable.

    After a first fit (weighted by the exposure alone) the curve is fitted again with
    weights ``x / max(m, floor · peak)`` (:func:`counting_weights`) from its own model curve
    ``m``, until the fitted values change by less than `change`: the maximum-likelihood fit
    of Poisson counts ``x y`` (see the module docstring).

    **Arguments:**

    - `floor`: floor of the weights' model value, as a fraction of the model's peak; only a
      guard against dividing by zero where the model vanishes (at 1e-9 of the peak a point
      expects 1e-9 of the peak bin's count: no count there is plausible but zero).
    - `max_passes`: most fits in all (at least 2).
    - `change`: relative change of every fitted value between passes below which the
      weights count as consistent with the fit.
    """

    floor: float = eqx.field(default=1e-9, static=True)
    max_passes: int = eqx.field(default=20, static=True)
    change: float = eqx.field(default=1e-8, static=True)

    def __check_init__(self):
        check_passes(self.max_passes, self.change, self.floor)


def counting_weights(model_values: np.ndarray, exposure: np.ndarray,
                     floor: float) -> np.ndarray:
    """Weights ``x / max(m, floor · peak)`` of counting errors (``Var(y) = m / x``).

    **Arguments:** `model_values`: ``m``, the model at each point (data unit);
    `exposure`: ``x``, the exposure of each point (counts = ``x y``; 1/data unit);
    `floor`: as in :class:`CountingErrors`.

    **Returns:** the weights, shape ``(n,)`` (1/data unit²).
    """
    m = np.asarray(model_values, float)
    size = np.maximum(m, floor * max(float(np.max(np.abs(m), initial=0.0)), 1e-300))
    return np.asarray(exposure, float) / size


def poisson_log_likelihood(observed: np.ndarray, model_values: np.ndarray,
                           exposure: np.ndarray) -> float:
    """Poisson log-likelihood ``Σ k ln μ - μ - ln k!`` of counts ``k = x y``, ``μ = x m``.

    **Arguments:** `observed`: ``y``; `model_values`: ``m`` (same unit); `exposure`: ``x``.
    Points of zero exposure are left out. **Returns:** the log-likelihood (``-inf`` where a
    count meets a model value of zero).
    """
    x = np.asarray(exposure, float)
    used = x > 0
    k = (x * np.asarray(observed, float))[used]
    mu = (x * np.asarray(model_values, float))[used]
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(k > 0, k * np.log(mu), 0.0) - mu
    return float(np.sum(terms) - sum(map(math.lgamma, np.rint(k) + 1.0)))


@dataclass(frozen=True)
class ErrorEstimate:
    """The error model a fit used and its estimated sizes, in the data's unit.

    - `kind`: ``"absolute"``, ``"relative"``, ``"combined"`` or ``"poisson"`` (counts:
      ``Var = m / exposure``, known; `proportional` then holds the Pearson dispersion
      ``X² / dof`` on the bins merged for the lack-of-fit test, 1 expected, as a check).
    - `additive`: ``a``, the standard deviation of the additive part (data unit; 0 when the
      model has none).
    - `proportional`: ``b``, the standard deviation of the proportional part as a fraction
      of the model value (0 when the model has none).
    - `passes`: fits made (1 for absolute errors).
    - `note`: why the fit's error model differs from the one asked for (empty otherwise).
    """

    kind: str
    additive: float
    proportional: float
    passes: int = 1
    note: str = ""

    def standard_deviation(self, model_values: np.ndarray) -> np.ndarray:
        """The measurement's standard deviation at model values ``m``: ``sqrt(a² + (b m)²)``."""
        model_values = np.asarray(model_values, float)
        return np.hypot(self.additive, self.proportional * model_values)

    def to_dict(self) -> dict:
        """A JSON-ready record."""

        def finite(x):
            return float(x) if math.isfinite(x) else None

        record = {"kind": self.kind, "additive_sd": finite(self.additive),
                  "proportional_sd": finite(self.proportional), "passes": int(self.passes)}
        if self.note:
            record["note"] = self.note
        return record

    def describe(self, unit: str = "") -> str:
        """The error model in words with its estimated sizes."""
        unit = f" {unit}" if unit else ""
        note = f" ({self.note})" if self.note else ""
        if self.kind == "absolute":
            return f"absolute errors, standard deviation {self.additive:.3g}{unit}{note}"
        if self.kind == "poisson":
            return (f"counting (Poisson) errors of known size, Var = model / exposure; "
                    f"Pearson dispersion {self.proportional:.3g} on merged bins (1 expected; "
                    f"{self.passes} fits)")
        if self.kind == "relative":
            return (f"relative errors, standard deviation {100 * self.proportional:.3g} % of "
                    f"the model ({self.passes} fits)")
        return (f"additive plus proportional errors, a = {self.additive:.3g}{unit} and "
                f"b = {100 * self.proportional:.3g} % of the model, both estimated from the "
                f"residuals ({self.passes} fits)")


def leverages(jacobian: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Leverages ``h_i`` of a weighted least-squares fit: the diagonal of the hat matrix.

    **Arguments:** `jacobian`: ``d y_model / d p``, shape ``(n, p)``; `weights`: ``w_i >= 0``.

    **Returns:** ``h_i = w_i J_i (Jᵀ W J)⁺ J_iᵀ`` in [0, 1], shape ``(n,)`` (pseudo-inverse:
    an undetermined direction adds nothing).
    """
    jacobian = np.asarray(jacobian, float)
    root = np.sqrt(np.asarray(weights, float))[:, None] * jacobian
    if root.size == 0:
        return np.zeros(jacobian.shape[0])
    basis, singular, _ = np.linalg.svd(root, full_matrices=False)
    keep = singular > 1e-12 * max(float(singular.max(initial=0.0)), 1e-300)
    return np.clip(np.sum(basis[:, keep] ** 2, axis=1), 0.0, 1.0)


#: Range of the proportional share ``f`` searched, in ``logit f``: up to ``1 - f = 4e-18``,
#: so an absent additive part is found as (numerically) zero, never exactly zero.
LOGIT_RANGE = 40.0


def proportional_shares(additive: float, proportional: float,
                        model_values: np.ndarray) -> np.ndarray | None:
    """Where the combined error estimate found no additive part: each point's share of the
    variance that is proportional, ``(b m)² / (a² + (b m)²)``; otherwise ``None``.

    The estimate searches the proportional share only up to ``logit f = LOGIT_RANGE``. Noise
    with no additive part (proportional down to the model's own accuracy) ends at that
    bound, with an ``a`` about ``2e-9 · b · max|m|`` that stands for zero: its weights
    ``1 / (a² + (b m)²)`` are capped far below the peak, where the residuals are smaller
    than ``a`` says. Those points hold less than a degree of freedom each; these shares
    count them (:func:`fitting.uncertainty.effective_degrees_of_freedom`), as the floor of
    relative errors is counted.

    **Arguments:** `additive` (``a``, data unit) and `proportional` (``b``, a fraction) of
    the estimate; `model_values` (data unit) at the fit's points.

    **Returns:** the shares (dimensionless, each in [0, 1]), or ``None`` where the estimate
    found an additive part.
    """
    size = np.abs(np.asarray(model_values, dtype=float))
    spread = proportional * float(size.max(initial=0.0))
    if not (spread > 0 and additive**2 <= math.exp(1.0 - LOGIT_RANGE) * spread**2):
        return None
    varying = (proportional * size) ** 2
    return varying / (additive**2 + varying)


#: Most numbers held at once by the grid search of the combined error sizes.
_GRID_BLOCK = 1 << 20


def estimate_combined_errors(residual: np.ndarray, model_values: np.ndarray,
                             leverage: np.ndarray | None = None) -> tuple[float, float]:
    """Estimate ``(a, b)`` of ``Var(y_i) = a² + (b m_i)²`` from a fit's residuals.

    Writes the variance as ``s² ((1 - f) + f (m_i / m_max)²)`` with ``f`` in (0, 1) the
    proportional share; for each ``f`` the scale ``s²`` has a closed form, and ``f`` maximises
    the Gaussian pseudo-likelihood ``-Σ [ln v_i + r̃_i² / v_i] / 2`` with
    ``r̃_i² = r_i² / (1 - h_i)`` (a grid in ``logit f``, then Brent's method). Points where
    both the model and the residual are exactly zero (a sample before the tracer arrives,
    fitted exactly) say nothing about either part and are left out.

    **Arguments:**

    - `residual`: model minus data, shape ``(n,)`` (data unit).
    - `model_values`: the fitted model curve at the same points.
    - `leverage`: the fit's leverages ``h_i`` (default 0).

    **Returns:** ``(a, b)``: the additive standard deviation (data unit) and the proportional
    one (a fraction of the model value).
    """
    residual = np.asarray(residual, float)
    model_values = np.asarray(model_values, float)
    leverage = np.zeros_like(residual) if leverage is None else np.asarray(leverage, float)
    informative = (residual != 0) | (model_values != 0)
    residual, model_values = residual[informative], model_values[informative]
    leverage = leverage[informative]
    scale = float(np.max(np.abs(model_values), initial=0.0))
    squared = residual**2 / np.clip(1.0 - leverage, 1e-3, None)
    if squared.size == 0 or not np.any(squared > 0):
        return 0.0, 0.0
    if scale == 0.0:
        return math.sqrt(float(np.mean(squared))), 0.0
    relative = (model_values / scale) ** 2

    def shares(logit: float) -> tuple[float, float]:
        """``(1 - f, f)``, each without cancellation."""
        return 1.0 / (1.0 + math.exp(logit)), 1.0 / (1.0 + math.exp(-logit))

    def negative_log_likelihood(logit: float) -> float:
        additive, proportional = shares(logit)
        g = additive + proportional * relative
        return float(np.sum(np.log(g)) + squared.size * math.log(np.mean(squared / g)))

    grid = np.linspace(-LOGIT_RANGE, LOGIT_RANGE, 161)
    # The same likelihood on many grid points at once (array operations, not 161 calls), in
    # blocks of at most _GRID_BLOCK numbers so that a curve of a million samples stays small.
    values = np.empty(grid.size)
    rows = max(1, _GRID_BLOCK // max(relative.size, 1))
    for start in range(0, grid.size, rows):
        logits = grid[start:start + rows]
        additive_share = 1.0 / (1.0 + np.exp(logits))[:, None]
        proportional_share = 1.0 / (1.0 + np.exp(-logits))[:, None]
        g = additive_share + proportional_share * relative[None, :]
        values[start:start + rows] = (np.sum(np.log(g), axis=1)
                                      + squared.size * np.log(np.mean(squared / g, axis=1)))
    best = int(np.argmin(values))
    low, high = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    logit = grid[best]
    found, value = _golden_section_minimum(negative_log_likelihood, low, high, 1e-6)
    if value <= values[best]:
        logit = found
    additive, proportional = shares(logit)
    variance = float(np.mean(squared / (additive + proportional * relative)))
    return math.sqrt(variance * additive), math.sqrt(variance * proportional) / scale


def _golden_section_minimum(function, low: float, high: float,
                            tolerance: float) -> tuple[float, float]:
    """The minimum of a unimodal `function` on ``[low, high]`` by golden-section search.

    Kept here instead of ``scipy.optimize.minimize_scalar`` (which costs 0.3-0.9 s to import at
    every start of the command line) for a one-dimensional bracket of width ``2 * 80 / 160``.

    **Returns:** ``(x, function(x))`` with ``x`` within `tolerance` of the minimiser.
    """
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    left, right = high - ratio * (high - low), low + ratio * (high - low)
    f_left, f_right = function(left), function(right)
    while high - low > tolerance:
        if f_left <= f_right:
            high, right, f_right = right, left, f_left
            left = high - ratio * (high - low)
            f_left = function(left)
        else:
            low, left, f_left = left, right, f_right
            right = low + ratio * (high - low)
            f_right = function(right)
    middle = 0.5 * (low + high)
    return middle, function(middle)


def combined_weights(model_values: np.ndarray, additive: float,
                     proportional: float) -> np.ndarray:
    """Least-squares weights ``1 / (a² + (b m_i)²)`` of the combined error model.

    **Arguments:** `model_values`: the model curve ``m_i``; `additive`: ``a`` (data unit);
    `proportional`: ``b`` (fraction).

    **Returns:** the weights (1/data unit²), shape of `model_values`.
    """
    variance = additive**2 + (proportional * np.asarray(model_values, float)) ** 2
    return 1.0 / np.maximum(variance, np.finfo(float).tiny)
