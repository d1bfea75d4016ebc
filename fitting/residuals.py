"""Tests of fit residuals for systematic structure (lack of fit): arrays in, numbers out.

A model that describes a curve leaves residuals that look like measurement noise: their
signs change often and neighbouring residuals are nearly uncorrelated. A model that misses
the curve's shape (a tail it cannot make, a background it does not have) leaves long runs of
one sign and a strong positive correlation between neighbours. Two classical statistics
measure this; both use the residuals in time order:

* the Wald–Wolfowitz runs test on residual signs (Wald and Wolfowitz 1940): the number of
  runs R of equal signs is compared with its exact distribution given the numbers of positive
  and negative residuals, and :func:`runs_test` returns the one-sided probability of so few
  runs, P(R <= r);
* the lag-1 autocorrelation r1 = sum e_i e_(i+1) / sum e_i^2 (:func:`lag1_autocorrelation`),
  with the one-sided probability of a value at least this large when the order of the
  residuals is random (:func:`lag1_autocorrelation_p`, a permutation test: like the runs
  test, it assumes exchangeable noise only, not normality; a normal approximation of r1
  puts 1.5 % in its nominal 1 % tail at n = 40).

Residuals exactly zero carry no sign and are left out of the runs test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

__all__ = [
    "RunsTest",
    "lag1_autocorrelation",
    "lag1_autocorrelation_p",
    "runs_distribution",
    "runs_test",
]


@dataclass(frozen=True)
class RunsTest:
    """The runs test of a sequence of residual signs.

    **Fields:** `runs` (observed number of runs), `n_positive`, `n_negative`, `expected`
    (mean number of runs for random order), `p` (one-sided probability of at most `runs`
    runs for random order; 1 when one sign is absent, where the test says nothing).
    """

    runs: int
    n_positive: int
    n_negative: int
    expected: float
    p: float


def _log_binomial(n: np.ndarray, k: np.ndarray) -> np.ndarray:
    n = np.asarray(n, float)
    k = np.asarray(k, float)
    valid = (k >= 0) & (k <= n)
    value = special.gammaln(n + 1) - special.gammaln(k + 1) - special.gammaln(n - k + 1)
    return np.where(valid, value, -np.inf)


def runs_distribution(n_positive: int, n_negative: int) -> tuple[np.ndarray, np.ndarray]:
    """The exact distribution of the number of runs for a random order of two kinds.

    **Arguments:** `n_positive`, `n_negative`: how many of each kind (both at least 1).

    **Returns:** ``(runs, probability)``, arrays over runs = 2 ... n_positive + n_negative.
    """
    n1, n2 = int(n_positive), int(n_negative)
    if n1 < 1 or n2 < 1:
        raise ValueError(f"need both kinds present, got {n1} and {n2}")
    total = _log_binomial(n1 + n2, n1)
    runs = np.arange(2, n1 + n2 + 1)
    k = runs // 2
    even = math.log(2.0) + _log_binomial(n1 - 1, k - 1) + _log_binomial(n2 - 1, k - 1)
    odd = np.logaddexp(_log_binomial(n1 - 1, k) + _log_binomial(n2 - 1, k - 1),
                       _log_binomial(n1 - 1, k - 1) + _log_binomial(n2 - 1, k))
    log_p = np.where(runs % 2 == 0, even, odd) - total
    return runs, np.exp(log_p)


def runs_test(residuals: np.ndarray) -> RunsTest:
    """The Wald–Wolfowitz runs test on the signs of residuals in time order.

    **Arguments:** `residuals`: data minus model, shape ``(n,)``, any unit.

    **Returns:** a :class:`RunsTest`; its `p` is small when there are too few sign changes.
    """
    signs = np.sign(np.asarray(residuals, float))
    signs = signs[signs != 0]
    n1 = int(np.sum(signs > 0))
    n2 = int(np.sum(signs < 0))
    runs = int(1 + np.sum(signs[1:] != signs[:-1])) if signs.size else 0
    if n1 == 0 or n2 == 0:
        return RunsTest(runs, n1, n2, float(runs), 1.0)
    expected = 2.0 * n1 * n2 / (n1 + n2) + 1.0
    values, probability = runs_distribution(n1, n2)
    p = float(min(1.0, probability[values <= runs].sum()))
    return RunsTest(runs, n1, n2, expected, p)


def lag1_autocorrelation(residuals: np.ndarray) -> float:
    """The lag-1 autocorrelation of residuals in time order, sum e_i e_(i+1) / sum e_i^2.

    **Arguments:** `residuals`: shape ``(n,)`` with ``n >= 3``.

    **Returns:** a number in [-1, 1]; near -1/n for independent noise, near 1 for a smooth
    systematic misfit. ``nan`` when every residual is zero.
    """
    e = np.asarray(residuals, float)
    if e.size < 3:
        raise ValueError(f"need at least 3 residuals, got {e.size}")
    denominator = float(e @ e)
    if denominator == 0.0:
        return float("nan")
    return float(e[1:] @ e[:-1] / denominator)


def lag1_autocorrelation_p(residuals: np.ndarray, permutations: int = 1999,
                           seed: int = 0) -> float:
    """One-sided permutation probability of a lag-1 autocorrelation at least the observed.

    **Arguments:**

    - `residuals`: shape ``(n,)``, ``n >= 3``, in time order.
    - `permutations`: random orders drawn (the p-value's resolution is 1/(permutations+1)).
    - `seed`: seed of the orders, so a report is reproducible.

    **Returns:** ``(1 + #{orders with r1 >= observed}) / (permutations + 1)``; 1 when every
    residual is zero.
    """
    e = np.asarray(residuals, float)
    observed = lag1_autocorrelation(e)
    if not math.isfinite(observed):
        return 1.0
    rng = np.random.default_rng(seed)
    shuffled = rng.permuted(np.broadcast_to(e, (permutations, e.size)), axis=1)
    r1 = np.sum(shuffled[:, 1:] * shuffled[:, :-1], axis=1) / float(e @ e)
    return float((1 + np.sum(r1 >= observed - 1e-12 * abs(observed))) / (permutations + 1))
