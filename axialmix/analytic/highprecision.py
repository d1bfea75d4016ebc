"""Extended-precision reference for the closed–closed axial dispersion model.

This module is the independent reference used by the tests and benchmarks of
:mod:`axialmix.analytic`; it is slow (pure mpmath) and not meant for fitting. It sums the
eigenfunction series of MODELS.md section 2,

    E(theta) = 8 e^{Pe/2} Σ_n (-1)^{n+1} λ_n² / (4 λ_n² + Pe² + 4 Pe)
               · exp(-(4 λ_n² + Pe²) theta / (4 Pe)),

with the roots ``λ_n`` of ``(4 λ² - Pe²) sin λ = 4 λ Pe cos λ`` in ``((n-1) π, n π)``.
The terms reach ``e^{Pe/2}`` while the sum is of order one, so the working precision is
raised to ``Pe / (2 ln 10) + 30`` digits; at each time the sum runs until the terms, which
alternate and (past ``λ² theta > Pe``) decrease, are below ``1e-30``.
mpmath is imported lazily, so importing :mod:`axialmix.analytic` does not need it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["eigenvalues_closed", "exit_age_closed_series", "step_response_closed_series"]


def _working_digits(peclet: float, extra_digits: int) -> int:
    return int(math.ceil(peclet / (2.0 * math.log(10.0)))) + extra_digits


def eigenvalues_closed(peclet: float, count: int, digits: int | None = None) -> list:
    """Return the first ``count`` eigenvalues of the closed–closed dispersion problem.

    **Arguments:**

    - `peclet`: Peclet number ``Pe = v L / D_z`` (dimensionless, positive).
    - `count`: how many roots ``λ_1 < λ_2 < ...`` to return.
    - `digits`: mpmath working precision in decimal digits (default: ``Pe/(2 ln 10) + 30``).

    **Returns:**

    A list of mpmath numbers, ``λ_n`` in ``((n-1) π, n π)``, roots of
    ``(4 λ² - Pe²) sin λ = 4 λ Pe cos λ``.
    """
    import mpmath

    if digits is None:
        digits = _working_digits(peclet, 30)
    with mpmath.workdps(digits):
        pe = mpmath.mpf(peclet)

        def phase_condition(lam, shift):
            # (4λ² - Pe²) sin λ - 4 λ Pe cos λ = (4λ² + Pe²) sin(λ - 2 atan(Pe / (2λ))), so
            # the n-th root solves λ - 2 atan(Pe / (2λ)) = (n-1) π: a monotone, well-scaled
            # equation with exactly one root in ((n-1) π, n π).
            return lam - 2 * mpmath.atan(pe / (2 * lam)) - shift

        roots = []
        for n in range(1, count + 1):
            low = (n - 1) * mpmath.pi if n > 1 else mpmath.mpf(10) ** (-digits)
            high = n * mpmath.pi
            shift = (n - 1) * mpmath.pi
            root = mpmath.findroot(
                lambda lam, shift=shift: phase_condition(lam, shift),
                (low, high),
                solver="anderson",
            )
            if not low < root < high:
                raise RuntimeError(f"eigenvalue {n} for Pe={peclet} left its bracket")
            roots.append(root)
    return roots


def exit_age_closed_series(
    theta: Sequence[float] | np.ndarray, peclet: float, extra_digits: int = 30
) -> np.ndarray:
    """Return the closed–closed exit-age density E(theta) from the eigenfunction series.

    **Arguments:**

    - `theta`: dimensionless times ``t / tau`` (any order); values ``<= 0`` give 0.
    - `peclet`: Peclet number (dimensionless, positive).
    - `extra_digits`: digits of precision beyond those lost to the ``e^{Pe/2}`` cancellation;
      the result is accurate to about ``10^-extra_digits`` in absolute terms.

    **Returns:**

    A float64 numpy array of ``E(theta)`` in units of ``1/tau``.
    """
    return _closed_series(theta, peclet, extra_digits, cumulative=False)


def step_response_closed_series(
    theta: Sequence[float] | np.ndarray, peclet: float, extra_digits: int = 30
) -> np.ndarray:
    """Return the closed–closed cumulative distribution F(theta) from the eigenfunction series.

    ``F = 1 - ∫_theta^∞ E``, integrated term by term: each term of E gains the factor
    ``4 Pe / (4 λ_n² + Pe²)``.

    **Arguments:**

    - `theta`: dimensionless times ``t / tau`` (any order); values ``<= 0`` give 0.
    - `peclet`: Peclet number (dimensionless, positive).
    - `extra_digits`: digits of precision beyond those lost to the ``e^{Pe/2}`` cancellation.

    **Returns:**

    A float64 numpy array of ``F(theta)`` (dimensionless).
    """
    return _closed_series(theta, peclet, extra_digits, cumulative=True)


def _closed_series(theta, peclet: float, extra_digits: int, cumulative: bool) -> np.ndarray:
    import mpmath

    digits = _working_digits(peclet, extra_digits)
    theta = np.asarray(theta, dtype=float)
    out = np.zeros(theta.shape)
    positive = theta[theta > 0]
    if positive.size == 0:
        return out
    with mpmath.workdps(digits):
        pe = mpmath.mpf(peclet)
        tolerance = mpmath.mpf(10) ** (-extra_digits)
        # Terms are bounded by 2 exp(Pe/2 - λ² θ / Pe): enough roots so that, at the
        # smallest positive theta, the first omitted term is below the tolerance.
        log_tolerance = float(mpmath.log(tolerance))
        theta_min = float(positive.min())
        lam_needed = math.sqrt(peclet * (peclet / 2.0 + 5.0 - log_tolerance) / theta_min)
        roots = eigenvalues_closed(peclet, int(lam_needed / math.pi) + 2, digits)
        prefactor = 8 * mpmath.exp(pe / 2)
        weights = []
        for n, lam in enumerate(roots):
            weight = (1 if n % 2 == 0 else -1) * lam**2 / (4 * lam**2 + pe**2 + 4 * pe)
            if cumulative:
                weight *= -4 * pe / (4 * lam**2 + pe**2)
            weights.append(prefactor * weight)
        decay = [(4 * lam**2 + pe**2) / (4 * pe) for lam in roots]
        for index in np.flatnonzero(theta > 0):
            th = mpmath.mpf(float(theta.flat[index]))
            total = mpmath.mpf(1) if cumulative else mpmath.mpf(0)
            for lam, weight, rate in zip(roots, weights, decay, strict=True):
                term = weight * mpmath.exp(-rate * th)
                total += term
                # Past λ² θ / Pe = 1 the magnitudes decrease, so the alternating tail is
                # bounded by the last term.
                if abs(term) < tolerance and lam**2 * th > pe:
                    break
            else:
                raise RuntimeError("series did not converge; increase the number of roots")
            out.flat[index] = float(total)
    return out
