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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from fitting.optimize import LOG_INTERVAL_LIMIT

if TYPE_CHECKING:
    from fitting.optimize import FitResult

__all__ = [
    "GaussNewtonUncertainty",
    "Identifiability",
    "Profile",
    "effective_degrees_of_freedom",
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


def effective_degrees_of_freedom(jacobian: np.ndarray, weights: np.ndarray,
                                 variance_factors: np.ndarray) -> float:
    """Degrees of freedom of ``Σ w r²`` when the weights are not the inverse variances.

    With ``Var(y_i) = σ² v_i``, weights ``W`` and the weighted projection
    ``P = J (Jᵀ W J)⁻¹ Jᵀ W``, the residuals of the linearised fit are ``(I - P) ε`` and
    ``E[Σ w r²] = σ² tr(W (I - P) V (I - P)ᵀ)``: this trace is the number of degrees of
    freedom, ``n - p`` when ``W = V⁻¹``.

    **Arguments:**

    - `jacobian`: ``d y_model / d p`` at the optimum, shape ``(n, p)``.
    - `weights`: ``w_i >= 0``, shape ``(n,)``.
    - `variance_factors`: ``a_i = w_i v_i``, shape ``(n,)`` (dimensionless; 1 where the
      weight is the inverse variance).

    **Returns:** the trace above (NaN when the curvature is singular).
    """
    jacobian = np.asarray(jacobian, dtype=float)
    weights = np.asarray(weights, dtype=float)
    factors = np.asarray(variance_factors, dtype=float)
    curvature = jacobian.T @ (weights[:, None] * jacobian)
    eigenvalues = np.linalg.eigvalsh(curvature)
    if eigenvalues.size == 0 or eigenvalues.min() <= SINGULAR_RATIO * max(eigenvalues.max(), 0):
        return math.nan
    projection = jacobian @ np.linalg.solve(curvature, jacobian.T * weights[None, :])
    residual_map = np.eye(len(weights)) - projection
    variance = np.divide(factors, weights, out=np.zeros_like(factors), where=weights > 0)
    return float(np.einsum("i,ij,j->", weights, residual_map**2, variance))


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


# --- identifiability ---------------------------------------------------------------------------

#: A parameter combination whose 95 % half-width exceeds this (in natural-log units, i.e. the
#: combination is not known within a factor of two) counts as poorly determined.
MAX_LOG_HALF_WIDTH = math.log(2.0)


def _combination_words(direction: np.ndarray, names: Sequence[str], log_scale: np.ndarray) -> str:
    """A parameter combination in words, e.g. ``'ln k_f - 0.98 ln k_r (the ratio k_f/k_r)'``."""
    order = np.argsort(-np.abs(direction))
    direction = direction / direction[order[0]]
    terms = []
    for i in order:
        if abs(direction[i]) < 0.15:
            continue
        symbol = f"ln {names[i]}" if log_scale[i] else f"{names[i]}/|{names[i]}|"
        coefficient = direction[i]
        text = symbol if abs(abs(coefficient) - 1) < 0.005 else f"{abs(coefficient):.2f} {symbol}"
        sign = "-" if coefficient < 0 else "+"
        terms.append(text if not terms else f"{sign} {text}")
    words = " ".join(terms)
    big = [i for i in order if abs(direction[i]) >= 0.15]
    if len(big) == 1:
        return f"{names[big[0]]} alone"
    if len(big) == 2 and all(log_scale[i] for i in big):
        a, b = names[big[0]], names[big[1]]
        if direction[big[1]] < 0:
            return f"{words} (the ratio {a}/{b})"
        return f"{words} (the product {a}·{b})"
    return words


@dataclass(frozen=True)
class Identifiability:
    """Which parameter combinations an RTD determines: eigen-analysis of the curvature.

    The Gauss–Newton curvature ``Jᵀ W J / s²`` is expressed in relative changes of the free
    parameters (``d ln p``; for parameters that may be zero or negative, changes relative to
    ``|p|``), so eigenvalues of different parameters are comparable.

    - `names`: free parameter names.
    - `eigenvalues`: descending; `directions`: the matching unit eigenvectors (columns).
    - `ratios`: eigenvalue / largest eigenvalue.
    - `half_widths`: 95 % half-width of each combination (Student t, log units; ``inf`` for
      a zero eigenvalue).
    - `poorly_determined`: indices of combinations with a half-width above ln 2 or a ratio
      below :data:`SINGULAR_RATIO` (numerically not determined at all).
    - `summary`: the diagnosis in plain words with numbers.
    """

    names: tuple[str, ...]
    eigenvalues: np.ndarray
    directions: np.ndarray
    ratios: np.ndarray
    half_widths: np.ndarray
    poorly_determined: tuple[int, ...]
    summary: str

    def __str__(self) -> str:
        return self.summary


def identifiability(result: FitResult) -> Identifiability:
    """Diagnose poorly determined parameter combinations of a fit from its curvature.

    **Arguments:**

    - `result`: a :class:`~fitting.optimize.FitResult` (least squares).

    **Returns:**

    An :class:`Identifiability`; ``str()`` of it reads like "the data fix ln k_f + ln k_r
    (±3 %) but not ln k_f - ln k_r (the ratio k_f/k_r): eigenvalue ratio 2e-07, direction
    (k_f 0.71, k_r -0.70, k_s 0.05), 95 % half-width ±4.1 (factor 60)".
    """
    names = result.free_names
    values = np.array([result.values[n] for n in names])
    log_scale = np.array([result.init_params[n].min is not None and result.init_params[n].min
                          >= 0 and v > 0 for n, v in zip(names, values, strict=True)])
    scale = np.where(values != 0, np.abs(values), 1.0)
    jacobian = result.jacobian * scale[None, :]
    weights = result.weights
    variance = result.sigma**2 if np.isfinite(result.sigma) and result.sigma > 0 else math.nan
    curvature = jacobian.T @ (weights[:, None] * jacobian)
    eigenvalues, directions = np.linalg.eigh(curvature)
    eigenvalues, directions = eigenvalues[::-1], directions[:, ::-1]
    largest = max(eigenvalues[0], 1e-300)
    ratios = eigenvalues / largest
    t_quantile = float(stats.t.ppf(0.975, result.dof)) if result.dof > 0 else math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        half_widths = np.where(eigenvalues > 0,
                               t_quantile * np.sqrt(variance / np.maximum(eigenvalues, 1e-300)),
                               np.inf)
    poorly = tuple(int(i) for i in range(len(names))
                   if ratios[i] < SINGULAR_RATIO or half_widths[i] > MAX_LOG_HALF_WIDTH)

    def describe(i: int) -> str:
        components = ", ".join(f"{n} {c:+.2f}" for n, c in zip(names, directions[:, i],
                                                                   strict=True))
        width = half_widths[i]
        if not np.isfinite(width):
            width_text = "no bound at all"
        elif width > LOG_INTERVAL_LIMIT:
            width_text = f"95 % half-width ±{width:.3g} in the logarithm (no bound in practice)"
        else:
            width_text = f"95 % half-width ±{width:.3g} (factor {math.exp(width):.3g})"
        return (f"{_combination_words(directions[:, i], names, log_scale)}: eigenvalue ratio "
                f"{ratios[i]:.2g}, direction ({components}), {width_text}")

    if len(names) == 1:
        summary = f"one free parameter: {describe(0)}"
    elif not poorly:
        summary = (f"all {len(names)} parameter combinations are determined; the weakest is "
                   f"{describe(len(names) - 1)}")
    else:
        good = [i for i in range(len(names)) if i not in poorly]
        fixed = "; ".join(
            f"{_combination_words(directions[:, i], names, log_scale)} (±{half_widths[i]:.2g})"
            for i in good
        ) or "no combination well"
        lacking = "; ".join(describe(i) for i in poorly)
        summary = f"the data fix {fixed} but not {lacking}"
    return Identifiability(tuple(names), eigenvalues, directions, ratios, half_widths, poorly,
                           summary)


# --- profile likelihood ------------------------------------------------------------------------


@dataclass(frozen=True)
class Profile:
    """Profile of the least-squares loss along one parameter, the others re-fitted.

    - `name`: the profiled parameter; `values`: the grid of fixed values.
    - `sse`: minimum ``Σ w r²`` over the other parameters at each value.
    - `converged`: whether each re-fit converged.
    - `threshold`: ``SSE_min (1 + t² / (n - p))``, the F-test level matching the Wald 95 %
      interval (the two agree exactly for a model linear in its parameters).
    - `ci95`: ``(low, high)`` where the profile first crosses the threshold on either side of
      the fitted value (linear interpolation); ``None`` on a side where it does not cross
      inside the grid (the interval is open there: the data do not bound the parameter).
    - `regions`: every stretch of the grid where the profile lies below the threshold, as
      ``(low, high)`` pairs in the same form; more than one means the data allow separate
      ranges (a second minimum, such as the four-compartment model's mirror solution), and
      the 95 % confidence set is their union, not `ci95` alone.
    """

    name: str
    values: np.ndarray
    sse: np.ndarray
    converged: np.ndarray
    threshold: float
    ci95: tuple[float | None, float | None]
    regions: tuple[tuple[float | None, float | None], ...] = ()

    def __str__(self) -> str:
        low, high = self.ci95
        text = [f"profile of {self.name}: 95 % interval "
                f"[{'open' if low is None else f'{low:.6g}'}, "
                f"{'open' if high is None else f'{high:.6g}'}]"]
        if len(self.regions) > 1:
            parts = ", ".join(f"[{'open' if a is None else f'{a:.6g}'}, "
                              f"{'open' if b is None else f'{b:.6g}'}]" for a, b in self.regions)
            text[0] += f"; below the threshold in {len(self.regions)} separate ranges: {parts}"
        for value, sse, ok in zip(self.values, self.sse, self.converged, strict=True):
            mark = "" if ok else "  (re-fit not converged)"
            text.append(f"    {value:<14.6g} SSE {sse:.6g}{mark}")
        return "\n".join(text)


def profile_likelihood(
    result: FitResult,
    name: str,
    values: Sequence[float] | np.ndarray | None = None,
    *,
    n_points: int = 21,
    span: float = 4.0,
) -> Profile:
    """Profile the loss along one parameter: fix it on a grid and re-fit the others (vmapped).

    **Arguments:**

    - `result`: a least-squares :class:`~fitting.optimize.FitResult`.
    - `name`: a free parameter of the fit.
    - `values`: the grid of fixed values; by default `n_points` values spanning ``± span``
      standard errors around the fitted value (geometric, within a factor ``e^{±span·rse}``,
      for positive parameters; a factor 4 each way when the standard error is undefined),
      kept inside the parameter's bounds.
    - `n_points`, `span`: the default grid.

    **Returns:**

    A :class:`Profile`.
    """
    from fitting.optimize import _compiled_solver, _options, _prepare, _run_solver

    if name not in result.free_names:
        raise ValueError(f"{name!r} is not a free parameter of this fit "
                         f"(free: {', '.join(result.free_names)})")
    setting = result.init_params[name]
    best = result.values[name]
    if values is None:
        error = result.stderr[name]
        positive = setting.min is not None and setting.min >= 0 and best > 0
        if positive:
            relative = error / best if error is not None and np.isfinite(error) else math.log(4)
            values = best * np.exp(np.linspace(-span, span, n_points) * min(relative, 1.0))
        else:
            width = error if error is not None and np.isfinite(error) else max(abs(best), 1.0)
            values = best + np.linspace(-span, span, n_points) * width
        low = setting.min if setting.min is not None else -np.inf
        high = setting.max if setting.max is not None else np.inf
        values = values[(values > low) & (values < high)]
    values = np.asarray(values, dtype=float)
    params = result.params.copy()
    params[name] = params[name].replace(vary=False)
    options = _options(result.loss_name, "lbfgs", None, 1e-10, 1e-10, 1e-6, 0, 0.05, 1)
    curve = _profile_curve(result)
    prepared = _prepare(result.model, curve, params, result.weights, 1, 0)
    layout = prepared.layout
    index = layout.names.index(name)
    bases = np.tile(prepared.base, (len(values), 1))
    bases[:, index] = values
    starts = np.tile(prepared.starts, (len(values), 1, 1))
    solver = _compiled_solver(prepared.model, layout, options, "bases")
    out, _, _ = _run_solver(solver, starts, prepared.warm, bases, curve.time, curve.value,
                            result.weights)
    predicted = np.asarray(out["predicted"])
    sse = np.sum(result.weights * (predicted - curve.value) ** 2, axis=1)
    converged = np.isin(np.asarray(out["status"]), (0, 1, 5))
    dof = result.dof
    t_quantile = float(stats.t.ppf(0.975, dof)) if dof > 0 else math.nan
    minimum = min(result.sse, float(np.min(sse)))
    threshold = minimum * (1 + t_quantile**2 / dof) if dof > 0 else math.nan
    return Profile(name, values, sse, converged, threshold,
                   _crossings(values, sse, threshold, best), _regions(values, sse, threshold))


def _profile_curve(result: FitResult):
    from fitting.io import Curve

    return Curve(name=result.name, time=result.time, value=result.observed)


def _crossings(values: np.ndarray, sse: np.ndarray, threshold: float,
               best: float) -> tuple[float | None, float | None]:
    """Where a profile crosses `threshold` below and above `best` (linear interpolation)."""
    below = values < best
    above = values > best

    def crossing(xs: np.ndarray, ys: np.ndarray) -> float | None:
        # xs ordered from the optimum outwards
        for k in range(len(xs)):
            if ys[k] >= threshold:
                if k == 0:
                    return float(xs[0])
                x0, x1, y0, y1 = xs[k - 1], xs[k], ys[k - 1], ys[k]
                return float(x0 + (threshold - y0) * (x1 - x0) / (y1 - y0))
        return None

    low = crossing(values[below][::-1], sse[below][::-1])
    high = crossing(values[above], sse[above])
    return low, high


def _regions(values: np.ndarray, sse: np.ndarray,
             threshold: float) -> tuple[tuple[float | None, float | None], ...]:
    """Maximal stretches of a profile below `threshold`, ends linearly interpolated (``None``
    where a stretch runs off the grid)."""
    order = np.argsort(values)
    xs, ys = values[order], sse[order]
    inside = ys < threshold

    def cross(k: int) -> float:
        x0, x1, y0, y1 = xs[k], xs[k + 1], ys[k], ys[k + 1]
        return float(x0 + (threshold - y0) * (x1 - x0) / (y1 - y0))

    regions = []
    k = 0
    while k < len(xs):
        if not inside[k]:
            k += 1
            continue
        start = k
        while k + 1 < len(xs) and inside[k + 1]:
            k += 1
        low = None if start == 0 else cross(start - 1)
        high = None if k == len(xs) - 1 else cross(k)
        regions.append((low, high))
        k += 1
    return tuple(regions)


# --- information criteria and the equivalent ADM of network fits --------------------------------


def equivalent_dispersion(result: FitResult, length: float = 1.0) -> dict[str, dict[str, float]]:
    """The axial dispersion model equivalent to a fitted four-compartment network.

    Two readings (see :mod:`axialmix.network`): moment matching (the closed–closed ADM with the
    network's mean and variance) and the axial chain of the fluxes (``v = (k_f - k_r) L/2``,
    ``D_z = (k_f + k_r) L² / 8``).

    **Arguments:**

    - `result`: a fit of the ``'four-compartment'`` model.
    - `length`: blender length ``L`` (m).

    **Returns:**

    ``{"moments": {tau, variance, peclet, velocity, axial_dispersion},
    "chain": {velocity, axial_dispersion, peclet}}`` (s, s², -, m/s, m²/s for times in s).
    """
    from axialmix.network import equivalent_adm, four_compartment, four_compartment_chain_transport

    if set(result.model.parameter_names) != {"k_f", "k_r", "k_s", "k_out"}:
        raise ValueError("equivalent_dispersion needs a four-compartment fit")
    v = result.values
    moments = equivalent_adm(four_compartment(v["k_f"], v["k_r"], v["k_s"], v["k_out"]), length)
    velocity, dispersion, peclet = four_compartment_chain_transport(v["k_f"], v["k_r"], length)
    return {
        "moments": {
            "tau": moments.mean_residence_time,
            "variance": moments.variance,
            "peclet": moments.peclet,
            "velocity": moments.velocity,
            "axial_dispersion": moments.axial_dispersion,
        },
        "chain": {"velocity": velocity, "axial_dispersion": dispersion, "peclet": peclet},
    }
