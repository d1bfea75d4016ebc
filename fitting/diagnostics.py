"""Diagnostics of fits: lack of fit, identifiable combinations, profiles, model comparison.

:func:`lack_of_fit` tests a fit's residuals for systematic structure (the verdict every
:class:`~fitting.result.FitResult` carries, with an optional known noise level);
:func:`identifiability` analyses the curvature of a fit; :func:`profile_likelihood` re-fits
with one parameter held on a grid (one vmapped, compiled call through :mod:`fitting.solve`),
checking the linearised intervals of :mod:`fitting.uncertainty`; :func:`compare_models`
ranks fits of several models to one curve by AICc and BIC together with their lack-of-fit
verdicts, and says when the data cannot tell them apart.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fitting.fit import fit_many, prepare
from fitting.optima import other_optima
from fitting.residuals import LACK_OF_FIT_LEVEL, LackOfFit, lack_of_fit_test
from fitting.result import FitResult
from fitting.solve import (
    FIRST_ORDER_CONVERGED,
    MultiStart,
    Optimiser,
    compiled_solver,
    make_plan,
    run_solver,
)
from fitting.uncertainty import LOG_INTERVAL_LIMIT, SINGULAR_RATIO, t_quantile

__all__ = [
    "INDISTINGUISHABLE_AICC",
    "MAX_LOG_HALF_WIDTH",
    "STRONG_AICC",
    "Identifiability",
    "ModelComparison",
    "Profile",
    "compare_models",
    "has_poorly_determined_combinations",
    "identifiability",
    "lack_of_fit",
    "other_optima",
    "points_on_curve",
    "profile_intervals",
    "profile_likelihood",
    "with_profile_intervals",
]

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


#: A point lies on the fitted curve where the model rises above this share of its range over
#: the fit's points (from its lowest value there: a baseline is not the curve).
ON_CURVE_SHARE = 0.05


def points_on_curve(result: FitResult) -> int:
    """How many of a fit's points lie on its curve rather than on the baseline around it.

    The Gauss–Newton intervals are those of the model linearised at the fit: they hold when
    the points trace the curve's shape. Where no more points than free parameters rise above
    :data:`ON_CURVE_SHARE` of the fitted model's range over the points (a peak narrower than
    the sampling interval, caught by one sample), the shape is not sampled: the curve is
    then free in ways the linearisation does not see (a sharp Pe = 1000 pulse caught at one
    point fitted as Pe 185 ± 27; its profile: Pe from 151 to 58,688), and those intervals
    do not hold.

    **Arguments:** `result`: a :class:`~fitting.result.FitResult`.

    **Returns:** the number of used points (weight above zero) on the curve.
    """
    model = np.asarray(result.predicted, dtype=float)
    used = np.asarray(result.weights, dtype=float) > 0
    if not used.any():
        return 0
    low, high = float(model[used].min()), float(model[used].max())
    if not high > low:
        return 0
    return int(np.count_nonzero(used & (model - low >= ON_CURVE_SHARE * (high - low))))


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


def _curvature_spectrum(result: FitResult) -> tuple[np.ndarray, ...]:
    """The numbers of :func:`identifiability`: which free parameters are on a log scale, the
    curvature's eigenvalues (descending) and directions, their ratios to the largest, the
    95 % half-widths, and the indices of the poorly determined combinations."""
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
    quantile = t_quantile(result.dof)
    # A curvature eigenvalue near zero gives an infinite half-width: no bound, as intended.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        half_widths = np.where(eigenvalues > 0,
                               quantile * np.sqrt(variance / np.maximum(eigenvalues, 1e-300)),
                               np.inf)
    poorly = tuple(int(i) for i in range(len(names))
                   if ratios[i] < SINGULAR_RATIO or half_widths[i] > MAX_LOG_HALF_WIDTH)
    return log_scale, eigenvalues, directions, ratios, half_widths, poorly


def has_poorly_determined_combinations(result: FitResult) -> bool:
    """Whether :func:`identifiability` finds a poorly determined parameter combination (its
    numbers alone, without the sentences: what a fit's record asks of every curve)."""
    return bool(_curvature_spectrum(result)[-1])


def identifiability(result: FitResult) -> Identifiability:
    """Diagnose poorly determined parameter combinations of a fit from its curvature.

    **Arguments:**

    - `result`: a :class:`~fitting.result.FitResult` (least squares).

    **Returns:**

    An :class:`Identifiability`; ``str()`` of it reads like "the data fix ln k_f + ln k_r
    (±3 %) but not ln k_f - ln k_r (the ratio k_f/k_r): eigenvalue ratio 2e-07, direction
    (k_f 0.71, k_r -0.70, k_s 0.05), 95 % half-width ±4.1 (factor 60)".
    """
    names = result.free_names
    log_scale, eigenvalues, directions, ratios, half_widths, poorly = _curvature_spectrum(result)

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

    - `result`: a least-squares :class:`~fitting.result.FitResult`.
    - `name`: a free parameter of the fit.
    - `values`: the grid of fixed values; by default `n_points` values spanning ``± span``
      standard errors around the fitted value (geometric, within a factor ``e^{±span·rse}``,
      for positive parameters; a factor 4 each way when the standard error is undefined),
      kept inside the parameter's bounds.
    - `n_points`, `span`: the default grid.

    **Returns:**

    A :class:`Profile`.
    """
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
    plan = make_plan(result.loss_name, Optimiser(), MultiStart(n_starts=1))
    curve = result.curve
    prepared = prepare(result.model, curve, params, result.weights, 1, 0)
    layout = prepared.layout
    index = layout.names.index(name)
    bases = np.tile(prepared.base, (len(values), 1))
    bases[:, index] = values
    starts = np.tile(prepared.starts, (len(values), 1, 1))
    solver = compiled_solver(prepared.model, layout, plan, "bases")
    out, _, _ = run_solver(solver, starts, prepared.warm, bases, curve.time, curve.value,
                            result.weights)
    predicted = np.asarray(out["predicted"])
    sse = np.sum(result.weights * (predicted - curve.value) ** 2, axis=1)
    converged = np.isin(np.asarray(out["status"]), [int(s) for s in FIRST_ORDER_CONVERGED])
    dof = result.dof
    quantile = t_quantile(dof)
    minimum = min(result.sse, float(np.min(sse)))
    threshold = minimum * (1 + quantile**2 / dof) if dof > 0 else math.nan
    return Profile(name, values, sse, converged, threshold,
                   crossings(values, sse, threshold, best), regions(values, sse, threshold))


#: Default reach of :func:`profile_intervals`: each parameter is held from its fitted value
#: divided by this factor to the value times it (positive parameters).
PROFILE_FACTOR = 1e3
#: Default number of held values of :func:`profile_intervals` on each side of the fit.
PROFILE_POINTS_PER_SIDE = 12


def profile_intervals(
    result: FitResult,
    names: Sequence[str] | None = None,
    *,
    factor: float = PROFILE_FACTOR,
    points_per_side: int = PROFILE_POINTS_PER_SIDE,
    progress=None,
) -> dict[str, Profile]:
    """95 % profile-likelihood intervals: each parameter held on a wide grid, the others
    re-fitted from the optimum (every held value its own fit of the batched engine).

    Where one curve does not determine a parameter, the linearised interval describes only
    the neighbourhood of the optimum found (the four-compartment rates of one RTD: a second
    optimum, a valley in which the truth can lie far outside it). The profile follows the
    loss along the parameter instead; its 95 % set is where it stays below the F-test level
    of :func:`profile_likelihood` (the same threshold, at the fit's weights), which for a
    linear model is the linearised interval.

    **Arguments:**

    - `result`: a least-squares :class:`~fitting.result.FitResult`.
    - `names`: the free parameters to profile (default: every free one).
    - `factor`: a positive parameter is held at ``value · factor^(k/n)`` for
      ``k = -n..n`` (``n`` = `points_per_side`), kept inside its bounds; any other at
      ``value + k/n · 4·max(stderr, |value|)``.
    - `progress`: called with each parameter's name before it is profiled, or ``None``.

    **Returns:** ``{name: Profile}``; a side whose profile stays below the threshold to the
    end of the grid is open (``None`` in the profile's ``ci95`` and regions).
    """
    if result.loss_name != "sse":
        raise ValueError("profile intervals need a least-squares fit")
    names = list(result.free_names if names is None else names)
    unknown = [name for name in names if name not in result.free_names]
    if unknown:
        raise ValueError(f"{unknown[0]!r} is not a free parameter of this fit "
                         f"(free: {', '.join(result.free_names)})")
    if not (factor > 1 and points_per_side >= 1):
        raise ValueError("the profile needs a factor above 1 and at least one point a side")
    steps = np.arange(-points_per_side, points_per_side + 1) / points_per_side
    base = result.restart_parameters()
    profiles: dict[str, Profile] = {}
    for name in names:
        if progress is not None:
            progress(name)
        setting, best = result.init_params[name], result.values[name]
        low = setting.min if setting.min is not None else -np.inf
        high = setting.max if setting.max is not None else np.inf
        # The wide grid, and values at the linearised interval's scale, so that a parameter
        # the curve does determine gets its ends resolved too (the wide grid's steps are a
        # factor factor^(1/n) apart). Both are laid out on the log scale for a positive
        # parameter, on its own scale otherwise.
        positive = low >= 0 and best > 0
        scale, unscale = (np.log, np.exp) if positive else (np.asarray, np.asarray)
        if positive:
            reach_wide = math.log(factor)
        else:
            error = result.stderr.get(name)
            reach_wide = 4.0 * max(error if error is not None and np.isfinite(error) else 0.0,
                                   abs(best), 1e-12)
        centre = float(scale(best))
        grid = centre + reach_wide * steps
        linear = result.linearised_intervals.get(name)
        if linear is not None and all(x is not None and np.isfinite(x) and (x > 0 or not positive)
                                      for x in linear):
            reach = max(float(scale(linear[1])) - centre, centre - float(scale(linear[0])))
            if 0 < reach < reach_wide / points_per_side:
                near = np.array([0.5, 1.0, 1.5, 2.0])
                grid = np.concatenate([grid, centre + np.concatenate([-near, near]) * reach])
        values = unscale(grid)
        values = np.unique(values[(values >= low) & (values <= high)])
        if len(result.free_names) == 1:  # nothing else to refit: the loss itself
            time, observed = result.curve.time, result.curve.value
            sse = np.array([np.sum(result.weights * (result.model.evaluate(
                time, result.values | {name: float(v)}) - observed) ** 2) for v in values])
            converged = np.ones(values.size, dtype=bool)
        else:
            settings = []
            for value in values:
                held = base.copy()
                held[name] = held[name].replace(value=float(value), vary=False)
                settings.append(held)
            fits = fit_many(result.model, [result.curve] * len(values), settings,
                            weights=[result.weights] * len(values),
                            multistart=MultiStart(n_starts=1))
            sse = np.array([f.sse for f in fits], dtype=float)
            converged = np.array([bool(f.converged) for f in fits])
        dof = result.dof
        minimum = min(result.sse, float(np.nanmin(sse)))
        threshold = minimum * (1 + t_quantile(dof) ** 2 / dof) if dof > 0 else math.nan
        # Crossings interpolated on the root of the loss above its minimum, which is linear
        # in a parameter the model is linear in (the profile's ends then equal the
        # linearised interval's exactly) and close to linear near any optimum.
        root = np.sqrt(np.maximum(np.where(np.isfinite(sse), sse, np.inf) - minimum, 0.0))
        level = math.sqrt(threshold - minimum)
        profiles[name] = Profile(name, values, sse, converged, threshold,
                                 crossings(values, root, level, best),
                                 regions(values, root, level))
    return profiles


def with_profile_intervals(result: FitResult, profiles: dict[str, Profile]) -> FitResult:
    """`result` with the 95 % intervals of the profiled parameters taken from their profiles.

    Each interval is the smallest one holding every stretch where the profile lies below its
    threshold (separate stretches are joined: a conservative hull of the 95 % set); an open
    side becomes the parameter's bound, or ``inf``/``-inf``, as a parameter the curve does not
    bound there. The names are recorded in :attr:`~fitting.result.FitResult.profiled`.

    **Arguments:** `result`; `profiles` from :func:`profile_intervals`.

    **Returns:** a new :class:`~fitting.result.FitResult`.
    """
    intervals = dict(result.ci95)
    # Starts of the fit that ended at another optimum within the same level are points of
    # the 95 % set that a profile run from the best optimum may not reach.
    optima = other_optima(result)
    for name, profile in profiles.items():
        setting = result.init_params[name]
        lows = [a for a, _ in profile.regions]
        highs = [b for _, b in profile.regions]
        if not profile.regions:  # the grid never fell below the threshold: only the optimum
            intervals[name] = (result.values[name], result.values[name])
            continue
        low = (setting.min if setting.min is not None else -math.inf) if None in lows \
            else min(lows)
        high = (setting.max if setting.max is not None else math.inf) if None in highs \
            else max(highs)
        known = [result.values[name], *(o.values[name] for o in optima if name in o.values)]
        intervals[name] = (min(low, *known), max(high, *known))
    return dataclasses.replace(result, ci95=intervals,
                               linearised_ci95=dict(result.linearised_intervals),
                               profiled=tuple(dict.fromkeys((*result.profiled, *profiles))))


def crossings(values: np.ndarray, sse: np.ndarray, threshold: float,
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


def regions(values: np.ndarray, sse: np.ndarray,
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


# --- lack of fit ---------------------------------------------------------------------------------


def lack_of_fit(result: FitResult, noise: float | None = None,
                level: float = LACK_OF_FIT_LEVEL) -> LackOfFit:
    """Test a fit's residuals for systematic structure: the model does not describe the curve.

    The runs test on the signs and the lag-1 autocorrelation of the residuals standardised
    by the fit's error model (``sqrt(w) r``), and, when the noise level is known, the scaled
    residual sum of squares against its expected value (``χ²`` with the fit's degrees of
    freedom); see :func:`fitting.residuals.lack_of_fit_test`. Without `noise` and at the
    default level this is ``result.lack_of_fit``.

    **Arguments:**

    - `result`: a :class:`~fitting.result.FitResult`.
    - `noise`: the known standard deviation of ``sqrt(w) r``: 1 when the fit's weights are
      ``1/σ_i²`` with known ``σ_i`` (the data's unit), or the relative noise level (e.g.
      0.02) for a relative-error fit (weights ``1/model²``). ``None``: estimated from the
      residuals, no scaled-SSE test.
    - `level`: significance level of each test.

    **Returns:** a :class:`~fitting.residuals.LackOfFit`.
    """
    if noise is None and level == LACK_OF_FIT_LEVEL:
        return result.lack_of_fit
    weights = np.asarray(result.weights, dtype=float)
    if result.loss_name == "mae":
        weights = weights**2
    peak = float(np.max(np.abs(result.observed[weights > 0]), initial=0.0))
    return lack_of_fit_test(result.residuals, weights, dof=result.dof, noise=noise, peak=peak,
                            described=result.described_points(), level=level)


# --- model comparison ----------------------------------------------------------------------------

#: Models whose AICc differ by less than this are not told apart by the data (Burnham and
#: Anderson 2002, section 2.6: both have substantial support).
INDISTINGUISHABLE_AICC = 2.0
#: A difference of AICc above this leaves the other model essentially no support (ibid.).
STRONG_AICC = 10.0


def _criteria(result: FitResult) -> tuple[float, int, float, float]:
    """``(log-likelihood, K, AICc, BIC)`` of a least-squares fit, Gaussian errors.

    The weights are taken as inverse variances up to one common factor, estimated by maximum
    likelihood: ``-2 ln L = n ln(2π Σwr²/n) + n - Σ ln w_i`` over the points with ``w > 0``.
    The ``Σ ln w`` term matters when the weights depend on the model (relative or combined
    errors); for weights shared by all models it is a common constant. ``K`` counts the free
    parameters and the error model's: one (the variance factor), two for additive plus
    proportional errors (``a`` and ``b``, estimated with each fit);
    ``AICc = -2 ln L + 2K + 2K(K+1)/(n-K-1)`` (``nan`` for ``n <= K+1``),
    ``BIC = -2 ln L + K ln n``.
    """
    weights = np.asarray(result.weights, dtype=float)
    used = weights > 0
    n = int(np.count_nonzero(used))
    sse = float(np.sum(weights[used] * np.asarray(result.residuals)[used] ** 2))
    error_model = getattr(result, "error_model", None)
    k = len(result.free_names) + (2 if getattr(error_model, "kind", None) == "combined" else 1)
    if n == 0 or not (math.isfinite(sse) and sse > 0):
        return math.nan, k, math.nan, math.nan
    minus_two_log_l = (n * math.log(2 * math.pi * sse / n) + n
                       - float(np.sum(np.log(weights[used]))))
    aicc = (minus_two_log_l + 2 * k + 2 * k * (k + 1) / (n - k - 1)) if n > k + 1 else math.nan
    bic = minus_two_log_l + k * math.log(n)
    return -0.5 * minus_two_log_l, k, aicc, bic


@dataclass(frozen=True)
class ModelComparison:
    """Fits of several models to one curve, ranked by AICc, with their lack-of-fit verdicts.

    - `results`: the fits, in the order given; `names`: their model names.
    - `n_parameters`: ``K`` of each (free parameters plus the error model's: one, the
      variance factor; two for additive plus proportional errors).
    - `log_likelihood`, `aicc`, `bic`: Gaussian criteria (see :func:`compare_models`);
      lower AICc and BIC are better, only differences between models mean anything.
    - `delta_aicc`: AICc minus the lowest AICc of the compared fits (``nan`` for fits not
      compared); `akaike_weights`: ``exp(-Δ/2)`` normalised over the compared fits.
    - `compared`: whether each fit has finite criteria (the others are not ranked). A fit
      that did not converge is ranked all the same: its AICc is an upper bound (often it
      drifts along a ridge where extra parameters are not determined, such as an exchange
      zone on a curve without one), and the recommendation says so.
    - `systematic`: each fit's lack-of-fit verdict.
    - `best`: the recommended model (``None`` when no fit could be compared).
    - `indistinguishable`: the other models the data cannot tell from `best`
      (ΔAICc below :data:`INDISTINGUISHABLE_AICC`, same lack-of-fit verdict).
    - `recommendation`: the conclusion in plain words with numbers.
    """

    results: tuple[FitResult, ...]
    names: tuple[str, ...]
    n_parameters: tuple[int, ...]
    log_likelihood: tuple[float, ...]
    aicc: tuple[float, ...]
    bic: tuple[float, ...]
    delta_aicc: tuple[float, ...]
    akaike_weights: tuple[float, ...]
    compared: tuple[bool, ...]
    systematic: tuple[bool, ...]
    best: str | None
    indistinguishable: tuple[str, ...]
    recommendation: str

    def __str__(self) -> str:
        return self.recommendation

    def to_dict(self) -> dict:
        """A JSON-ready record: one entry per model (criteria, verdict, parameters) and the
        recommendation."""

        def number(x):
            return float(x) if x is not None and math.isfinite(x) else None

        models = []
        for i, result in enumerate(self.results):
            models.append({
                "model": self.names[i],
                "parameters": {n: {"value": number(result.values[n]),
                                   "stderr": number(result.stderr[n])
                                   if result.stderr[n] is not None else None}
                               for n in result.values},
                "n_parameters": self.n_parameters[i],
                "sse": number(result.sse),
                "log_likelihood": number(self.log_likelihood[i]),
                "aicc": number(self.aicc[i]),
                "delta_aicc": number(self.delta_aicc[i]),
                "akaike_weight": number(self.akaike_weights[i]),
                "bic": number(self.bic[i]),
                "converged": bool(result.converged),
                "compared": bool(self.compared[i]),
                "lack_of_fit": result.lack_of_fit.to_dict(),
            })
        return {"data": self.results[0].name, "models": models, "best": self.best,
                "indistinguishable": list(self.indistinguishable),
                "recommendation": self.recommendation}


def _join(names: Sequence[str]) -> str:
    names = list(names)
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _recommend(names, k, aicc, compared, systematic,
               converged) -> tuple[str | None, tuple, str]:
    """The best model, the ones not told apart from it, and the recommendation in words."""
    order = [int(i) for i in np.argsort(np.nan_to_num(aicc, nan=np.inf), kind="stable")
             if compared[i]]
    skipped = [names[i] for i in range(len(names)) if i not in order]
    loose = [names[i] for i in order if not converged[i]]
    note = ""
    if loose:
        verb = "did" if len(loose) == 1 else "do"
        note += (f" ({_join(loose)} {verb} not converge: AICc is an upper bound there, and "
                 "parameters without a bound are not determined by this curve.)")
    if skipped:
        note += f" ({_join(skipped)}: no finite loss, not compared.)"
    if not order:
        return None, (), "No fit has a finite loss; no model can be recommended." + note
    described = [i for i in order if not systematic[i]]
    flagged = [i for i in order if systematic[i]]
    pool = described or order
    best = pool[0]
    gap = {i: aicc[i] - aicc[best] for i in pool}
    close = [i for i in pool[1:] if gap[i] < INDISTINGUISHABLE_AICC]
    if not described:
        text = (f"No model describes this curve: every one leaves systematic residuals "
                f"(lack of fit), so none of their intervals can be trusted. {names[best]} has "
                "the lowest AICc")
        if close:
            text += (f", but the data cannot tell it from {_join(names[i] for i in close)} "
                     f"(ΔAICc < {INDISTINGUISHABLE_AICC:g})")
        text += "; try another model, a baseline or a dead time."
        return names[best], tuple(names[i] for i in close), text + note
    if close:
        group = [best, *close]
        simplest = min(group, key=lambda i: (k[i], aicc[i]))
        gaps = ", ".join(f"{names[i]} {gap[i]:.2g}" for i in close)
        text = (f"The data cannot tell {_join(names[i] for i in group)} apart: each describes "
                f"the curve (no lack of fit) and their AICc differ by less than "
                f"{INDISTINGUISHABLE_AICC:g} (ΔAICc: {gaps}). {names[best]} has the lowest "
                f"AICc; the simplest, {names[simplest]} ({k[simplest] - 1} parameters), is "
                "the safer choice unless other knowledge favours another.")
    else:
        text = f"{names[best]} is recommended: it describes the curve (no lack of fit)"
        if len(pool) > 1:
            second = pool[1]
            strength = "clearly" if gap[second] >= STRONG_AICC else "but not decisively"
            text += (f" and has the lowest AICc, {strength} (next {names[second]}, "
                     f"ΔAICc = {gap[second]:.3g}, evidence ratio "
                     f"{math.exp(min(0.5 * gap[second], 700.0)):.3g})")
        elif len(order) > 1:
            second = next(i for i in order if i != best)
            difference = aicc[second] - aicc[best]
            text += (f", the only one that does (next by AICc: {names[second]}, "
                     f"ΔAICc = {difference:+.3g})")
        text += "."
    if flagged:
        verb = "does" if len(flagged) == 1 else "do"
        text += (f" {_join(names[i] for i in flagged)} {verb} not describe the curve "
                 "(systematic residuals).")
        lower = [names[i] for i in flagged if aicc[i] < aicc[best]]
        if lower:
            text += (f" {_join(lower)} {'has' if len(lower) == 1 else 'have'} a lower AICc, "
                     "but a model with systematic residuals is not an explanation of the "
                     "curve.")
    return names[best], tuple(names[i] for i in close), text + note


def compare_models(results: Sequence[FitResult]) -> ModelComparison:
    """Rank fits of several models to the same curve by AICc, with their lack-of-fit verdicts.

    The criteria are Gaussian likelihoods of the least-squares fits, with the fits' weights
    as inverse variances up to a common factor estimated by maximum likelihood (so
    relative-error fits, whose weights follow each model's own curve, are compared on one
    footing): ``-2 ln L = n ln(2π Σwr²/n) + n - Σ ln w``, ``K`` = free parameters + 1 (+ 2
    for additive plus proportional errors),
    ``AICc = -2 ln L + 2K + 2K(K+1)/(n-K-1)``, ``BIC = -2 ln L + K ln n``. (Fits on the
    mean absolute error are scored by their ``Σ w r²`` all the same.)

    The recommendation puts the lack-of-fit verdict first: among the models that describe
    the curve (no systematic residuals) the lowest AICc wins; the data cannot tell models
    apart when their AICc differ by less than :data:`INDISTINGUISHABLE_AICC` and they share
    a verdict; when every model shows lack of fit, none is recommended as a description.

    **Arguments:**

    - `results`: at least two :class:`~fitting.result.FitResult` of one curve (same times and
      values).

    **Returns:** a :class:`ModelComparison`.
    """
    results = tuple(results)
    if len(results) < 2:
        raise ValueError(f"compare_models needs at least two fits, got {len(results)}")
    first = results[0]
    for other in results[1:]:
        if not (np.array_equal(other.time, first.time)
                and np.array_equal(other.observed, first.observed)):
            raise ValueError("compare_models: every fit must be of the same curve (same times "
                             f"and values); {other.model.name!r} differs from "
                             f"{first.model.name!r}")
    names = []
    for result in results:
        name, suffix = result.model.name, 2
        while name in names:
            name, suffix = f"{result.model.name} ({suffix})", suffix + 1
        names.append(name)
    criteria = [_criteria(r) for r in results]
    log_l, k, aicc, bic = (tuple(column) for column in zip(*criteria, strict=True))
    compared = tuple(bool(math.isfinite(a)) for a in aicc)
    converged = tuple(bool(r.converged) for r in results)
    systematic = tuple(bool(r.lack_of_fit.systematic) for r in results)
    reference = min((a for a, c in zip(aicc, compared, strict=True) if c), default=math.nan)
    delta = tuple(a - reference if c else math.nan for a, c in zip(aicc, compared, strict=True))
    raw = [math.exp(-0.5 * d) if c else 0.0 for d, c in zip(delta, compared, strict=True)]
    total = sum(raw)
    weights = tuple(x / total if total > 0 else math.nan for x in raw)
    best, close, text = _recommend(names, k, aicc, compared, systematic, converged)
    return ModelComparison(results, tuple(names), k, log_l, aicc, bic, delta, weights,
                           compared, systematic, best, close, text)
