"""The three distribution functions the fit reports need, in plain Python and NumPy.

* :func:`log_factorials`: ``ln k!`` for k = 0..n (the exact runs distribution of residual
  signs);
* :func:`chi_square_survival`: ``P(X > x)`` for a chi-square variable (the scaled residual
  sum of squares against its expected value);
* :func:`t_quantile`: quantiles of Student's t (confidence intervals).

``scipy.special`` has all three, but importing it costs about a fifth of a second, as much
as a first fit's whole computation; every ``axialmix fit`` would pay for it. These are the
classical algorithms (series and continued fractions, Numerical Recipes §6.2 and §6.4, with
Newton's method for the quantile) and are checked against scipy to 1e-11 relative in
``tests/test_distributions.py``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["chi_square_survival", "log_factorials", "t_quantile"]

_EPS = 1e-16
_TINY = 1e-300
#: Degrees of freedom from which t quantiles come from their expansion in 1/dof.
_EXPANSION_FROM = 1e5


def log_factorials(n: int) -> np.ndarray:
    """``ln k!`` for k = 0, 1, ..., n.

    **Arguments:** `n`: the largest k (a non-negative integer).

    **Returns:** a float array of length ``n + 1`` (each value exact to rounding:
    ``math.lgamma`` per entry).
    """
    if n < 0:
        raise ValueError(f"n must be non-negative, got {n}")
    return np.fromiter(map(math.lgamma, range(1, n + 2)), float, count=n + 1)


def _lentz_step(numerator: float, denominator: float, c: float, d: float):
    """One step of the modified Lentz method for ``b_0 + a_1/(b_1 + a_2/(b_2 + ...))``:
    the new ``c`` and ``d`` and the factor ``c d`` that multiplies the fraction so far."""
    d = numerator * d + denominator
    d = 1.0 / (_TINY if abs(d) < _TINY else d)
    c = denominator + numerator / c
    c = _TINY if abs(c) < _TINY else c
    return c, d, c * d


def _iterations(a: float) -> int:
    # Series and fractions converge after a few times sqrt(a) terms near x = a.
    return int(200 + 50 * math.sqrt(a))


# Above this argument the log-gamma differences below use Stirling's series, whose next term
# is below 1e-21 there; plain lgamma differences of numbers near 1e7 would lose 8 digits.
_STIRLING_FROM = 30.0


def _stirling_correction(a: float) -> float:
    """``ln Γ(a) - [(a - 1/2) ln a - a + ln(2 pi)/2]`` for large a (Stirling's series)."""
    inverse = 1.0 / a
    square = inverse * inverse
    return inverse * (1.0 / 12.0 - square * (1.0 / 360.0 - square * (1.0 / 1260.0
                                                                     - square / 1680.0)))


def _log_gamma_ratio(a: float, b: float) -> float:
    """``ln Γ(a + b) - ln Γ(a)`` without the cancellation of two large log-gammas."""
    if a < _STIRLING_FROM:
        return math.lgamma(a + b) - math.lgamma(a)
    return ((a - 0.5) * math.log1p(b / a) + b * math.log(a + b) - b
            + _stirling_correction(a + b) - _stirling_correction(a))


def _log_gamma_prefactor(a: float, x: float) -> float:
    """``ln(x^a e^{-x} / Γ(a))``."""
    if a < _STIRLING_FROM:
        return -x + a * math.log(x) - math.lgamma(a)
    relative = (x - a) / a
    return (a * (math.log1p(relative) - relative) + 0.5 * math.log(a)
            - 0.5 * math.log(2.0 * math.pi) - _stirling_correction(a))


def _upper_gamma(a: float, x: float) -> float:
    """Regularised upper incomplete gamma ``Q(a, x)`` for ``a > 0``, ``x >= 0``."""
    if x <= 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    prefactor = _log_gamma_prefactor(a, x)
    if x < a + 1.0:  # the series of P(a, x)
        term = total = 1.0 / a
        shifted = a
        for _ in range(_iterations(a)):
            shifted += 1.0
            term *= x / shifted
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return max(0.0, 1.0 - total * math.exp(prefactor))
    # The continued fraction of Q(a, x), modified Lentz.
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _iterations(a)):
        b += 2.0
        c, d, delta = _lentz_step(-i * (i - a), b, c, d)
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return math.exp(prefactor) * h


def chi_square_survival(x: float, dof: float) -> float:
    """Probability that a chi-square variable with `dof` degrees of freedom exceeds `x`.

    **Arguments:**

    - `x`: the observed value (dimensionless, at least 0).
    - `dof`: degrees of freedom (positive, need not be an integer).

    **Returns:** ``Q(dof/2, x/2)``, between 0 and 1.
    """
    if not dof > 0:
        raise ValueError(f"dof must be positive, got {dof}")
    if math.isnan(x):
        return math.nan
    return _upper_gamma(0.5 * dof, 0.5 * max(x, 0.0))


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of the incomplete beta function (modified Lentz)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = 1.0
    d = 1.0 - qab * x / qap
    d = _TINY if abs(d) < _TINY else d
    d = 1.0 / d
    h = d
    for m in range(1, _iterations(max(a, b))):
        m2 = 2 * m
        c, d, even = _lentz_step(m * (b - m) * x / ((qam + m2) * (a + m2)), 1.0, c, d)
        c, d, delta = _lentz_step(-(a + m) * (qab + m) * x / ((a + m2) * (qap + m2)), 1.0, c, d)
        h *= even * delta
        if abs(delta - 1.0) < _EPS:
            break
    return h


def _incomplete_beta(a: float, b: float, x: float, y: float) -> float:
    """Regularised incomplete beta ``I_x(a, b)`` for ``a, b > 0``, ``0 <= x <= 1``, given
    ``y = 1 - x`` too (computed without rounding by the caller)."""
    if x <= 0.0:
        return 0.0
    if y <= 0.0:
        return 1.0
    log_front = (_log_gamma_ratio(a, b) - math.lgamma(b) if a >= b
                 else _log_gamma_ratio(b, a) - math.lgamma(a))
    log_front += a * math.log(x) + b * math.log(y)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_fraction(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_fraction(b, a, y) / b


def _t_tail(t: float, dof: float) -> float:
    """``P(T > t)`` for t >= 0."""
    square = t * t
    return 0.5 * _incomplete_beta(0.5 * dof, 0.5, dof / (dof + square), square / (dof + square))


def _t_density(t: float, dof: float) -> float:
    log_density = (_log_gamma_ratio(0.5 * dof, 0.5) - 0.5 * math.log(dof * math.pi)
                   - 0.5 * (dof + 1.0) * math.log1p(t * t / dof))
    return math.exp(log_density)


def _normal_quantile(p: float) -> float:
    """Standard normal quantile for ``0.5 <= p < 1`` (Newton on ``erfc``)."""
    # Start above the quantile; the tail is convex, so the first step lands below it and the
    # rest climb to it.
    z = math.sqrt(-2.0 * math.log(1.0 - p))
    for _ in range(100):
        tail = 0.5 * math.erfc(z / math.sqrt(2.0))
        step = (tail - (1.0 - p)) / (math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi))
        z += step
        if abs(step) <= 1e-15 * z:
            break
    return z


#: Degrees of freedom below which the t quantile comes from its tail's leading term (Newton's
#: method from the normal quantile stalls there: at 0.001 the quantile is about e^3000).
_FAR_BELOW = 0.01


def t_quantile(dof: float, probability: float = 0.975) -> float:
    """Quantile of Student's t distribution with `dof` degrees of freedom.

    **Arguments:**

    - `dof`: degrees of freedom (need not be an integer); ``dof <= 0`` or NaN gives NaN.
    - `probability`: the lower-tail probability, in ``[0.5, 1)`` (0.975 by default, the
      two-sided 95 % point).

    **Returns:** ``t`` with ``P(T <= t) = probability`` (dimensionless).
    """
    if not 0.5 <= probability < 1.0:
        raise ValueError(f"probability must be in [0.5, 1), got {probability}")
    if not dof > 0:
        return math.nan
    if probability == 0.5:
        return 0.0
    target = 1.0 - probability
    z = _normal_quantile(probability)
    if dof >= _EXPANSION_FROM:
        # The Cornish-Fisher expansion in 1/dof (Abramowitz & Stegun 26.7.5); its first
        # omitted term is below 1e-20 of t here, where the incomplete beta function of
        # arguments near 1e5 and above would lose digits.
        z2 = z * z
        terms = (
            (z2 + 1.0) / 4.0,
            ((5.0 * z2 + 16.0) * z2 + 3.0) / 96.0,
            (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) / 384.0,
            ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) / 92160.0,
        )
        inverse = 1.0 / dof
        return z * (1.0 + inverse * (terms[0] + inverse * (terms[1] + inverse * (
            terms[2] + inverse * terms[3]))))
    # P(T > t) is convex and decreasing for t > 0, and the normal quantile is below every t
    # quantile: Newton's method climbs to the root without overshooting (with heavy tails,
    # small dof, each step multiplies t by about 1 + 1/dof until it is near).
    if dof < _FAR_BELOW:
        return _t_quantile_far(dof, target)
    t = z
    for _ in range(1000):
        density = _t_density(t, dof)
        if not (density > 0 and math.isfinite(t)):
            return _t_quantile_far(dof, target)
        step = (_t_tail(t, dof) - target) / density
        t += step
        if abs(step) <= 1e-15 * t:
            break
    return t


def _t_quantile_far(dof: float, tail: float) -> float:
    """The t quantile of upper tail `tail` far out, where the density underflows (a tiny
    `dof`): from ``P(T > t) ~ C t^-dof``, ``C = Γ((dof+1)/2) dof^((dof-1)/2) / (√π Γ(dof/2))``
    (the leading term of the tail, whose relative error is of order ``dof / t²``); infinite
    when it exceeds the largest float."""
    log_c = (math.lgamma((dof + 1.0) / 2.0) + (0.5 * dof - 1.0) * math.log(dof)
             - 0.5 * math.log(math.pi) - math.lgamma(dof / 2.0))
    log_t = (log_c - math.log(tail)) / dof
    return math.exp(log_t) if log_t < 709.0 else math.inf
