"""Other optima of a multi-start fit, and 95 % intervals that hold them.

A curve that does not determine every parameter can be fitted equally well at distant
points (the four-compartment rates of one RTD: twin optima, k_f and k_s nearly exchanged).
The multi-start solver finds them: starts whose first-fit loss lies within the 95 % level
of the best, ``loss_min (1 + t² / (n - p))`` (the level of the profile likelihood), at
which some free parameter lies outside the best optimum's linearised interval. Such a
point is inside the likelihood's 95 % region, which the linearised interval of one optimum
does not describe; a fit's reported interval is therefore the smallest one holding the
linearised interval and every such optimum (:func:`with_other_optima`, applied by
:func:`fitting.fit.fit` and :func:`fitting.fit.fit_many`). The linearised interval of the
best optimum alone stays in :attr:`~fitting.result.FitResult.linearised_ci95`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from fitting.result import FitResult
from fitting.uncertainty import t_quantile

__all__ = ["OtherOptimum", "other_optima", "with_other_optima"]


@dataclass(frozen=True)
class OtherOptimum:
    """A start of a multi-start fit that ended elsewhere with a loss as low as the best's.

    **Fields:** `start` (0-based), `values` (its free parameters), `loss` (its first-fit
    loss, in the loss's unit), `outside` (the free parameters whose value there lies outside
    the best optimum's linearised 95 % interval).
    """

    start: int
    values: dict[str, float]
    loss: float
    outside: tuple[str, ...]


def other_optima(result: FitResult) -> list[OtherOptimum]:
    """The starts that ended at another optimum fitting the curve as well as the best one.

    A start counts when its first-fit loss lies within the 95 % threshold of the best one's,
    ``loss_min (1 + t² / (n - p))`` (the level of :func:`fitting.diagnostics.profile_likelihood`),
    and at least one free parameter there lies outside the best optimum's linearised 95 %
    interval (:attr:`~fitting.result.FitResult.linearised_ci95`): the curve does not choose
    between the two. Only fits whose starts' ends are known (the multi-start solver's path:
    fits with random starts) can be checked; others give ``[]``.

    **Arguments:** `result`: a :class:`~fitting.result.FitResult`.

    **Returns:** the other optima, the lowest loss first (at most one per distinct end).
    """
    ends, losses = result.start_values, np.asarray(result.start_losses, dtype=float)
    if ends is None or ends.ndim != 2 or ends.shape[0] < 2 or losses.shape[0] != ends.shape[0]:
        return []
    dof = result.n_points - len(result.free_names)
    finite = np.isfinite(losses)
    if dof <= 0 or not finite.any():
        return []
    best = float(np.min(losses[finite]))
    quantile = t_quantile(dof)
    threshold = best * (1 + quantile**2 / dof)
    local = result.linearised_intervals
    found: list[OtherOptimum] = []
    seen: list[tuple[tuple[str, ...], np.ndarray]] = []
    for index in np.argsort(np.where(finite, losses, np.inf)):
        if not (finite[index] and losses[index] <= threshold):
            break
        end = ends[index]
        values = dict(zip(result.free_names, (float(v) for v in end), strict=True))
        outside = []
        for name, value in values.items():
            interval = local.get(name)
            if interval is None:
                continue
            low, high = interval
            if (low is not None and value < low) or (high is not None and value > high):
                outside.append(name)
        if not outside:
            continue
        # The same optimum as one found already: the same parameters outside the interval
        # and the others within 1 % (a parameter that runs off along a flat direction ends
        # anywhere far out).
        inside = np.array([name not in outside for name in result.free_names])
        key = (tuple(outside), end[inside])
        if any(key[0] == other[0] and np.allclose(key[1], other[1], rtol=1e-2)
               for other in seen):
            continue
        seen.append(key)
        found.append(OtherOptimum(int(index), values, float(losses[index]), tuple(outside)))
    return found


def with_other_optima(result: FitResult) -> FitResult:
    """`result` with each 95 % interval widened to hold the other optima's values.

    Every free parameter that lies outside its linearised interval at an optimum of
    :func:`other_optima` gets the smallest interval holding the linearised one and those
    values (a conservative hull of two neighbourhoods of the 95 % region, which the
    linearised interval of one optimum does not cover); its name is recorded in
    :attr:`~fitting.result.FitResult.joined` and the linearised intervals are kept in
    :attr:`~fitting.result.FitResult.linearised_ci95`. A fit without other optima is returned
    as it is.

    **Arguments:** `result`: a :class:`~fitting.result.FitResult`.

    **Returns:** a new :class:`~fitting.result.FitResult` (or `result` itself).
    """
    optima = other_optima(result)
    if not optima:
        return result
    local = result.linearised_intervals
    intervals = dict(result.ci95)
    joined = list(result.joined)
    for optimum in optima:
        for name in optimum.outside:
            low, high = intervals[name]
            value = optimum.values[name]
            intervals[name] = (None if low is None else min(low, value),
                               None if high is None else max(high, value))
            if name not in joined:
                joined.append(name)
    return dataclasses.replace(result, ci95=intervals, linearised_ci95=dict(local),
                               joined=tuple(joined))
