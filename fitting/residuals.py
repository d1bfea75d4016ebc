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
  puts 1.5 % in its nominal 1 % tail at n = 40), or when the signs of the residuals are
  random (``null="signs"``: independent noise symmetric about zero, of any size at each
  point; this one also sees residuals that all share one sign).

Residuals exactly zero carry no sign and are left out of the runs test.

:func:`lack_of_fit_test` turns these into the verdict every fit carries (:class:`LackOfFit`):
the residuals are standardised by the fit's error model first (``sqrt(w) r``), and the fit is
called systematic when either test, or, where the noise level is known, the scaled residual
sum of squares, is significant at :data:`LACK_OF_FIT_LEVEL`. Fit residuals are not
independent noise even when the model is right: ``p`` fitted parameters remove ``p`` smooth
components, which makes neighbouring residuals slightly anti-correlated and both tests
conservative. Measured false-alarm rates (``tests/test_lack_of_fit_study.py``: fits of noisy
exact closed–closed ADM curves, tau 40 s, Pe log-uniform in 2–50, 200 curves per setting, at
15, 30, 60 and 200 points): E with 2 % additive noise, unweighted, 1.5, 0.0, 1.0 and 1.5 %;
E with 3 % proportional noise, relative-error weights, 0.5, 0.5, 1.0 and 1.0 % (1,000 curves
each at 60 and 200 points: 0.7 and 1.0 %); raw concentrations with 1 % additive and 2 %
proportional noise, measurement model and combined error model, 0.0, 0.5, 1.0 and 2.0 %.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from fitting.distributions import chi_square_survival, log_factorials

__all__ = [
    "LACK_OF_FIT_LEVEL",
    "COUNTS_PER_MERGED_BIN",
    "LackOfFit",
    "RunsTest",
    "lag1_autocorrelation",
    "lag1_autocorrelation_p",
    "lag1_signs_normal_p",
    "counting_lack_of_fit",
    "lack_of_fit_test",
    "merged_counts",
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


def _log_binomial(table: np.ndarray, n, k) -> np.ndarray:
    """``ln C(n, k)`` from a table of ``ln m!`` (``-inf`` where k is outside 0..n)."""
    n = np.asarray(n)
    k = np.asarray(k)
    valid = (k >= 0) & (k <= n)
    safe_k = np.where(valid, k, 0)
    safe_rest = np.where(valid, n - k, 0)
    value = table[np.where(valid, n, 0)] - table[safe_k] - table[safe_rest]
    return np.where(valid, value, -np.inf)


@functools.lru_cache(maxsize=4096)
def runs_distribution(n_positive: int, n_negative: int) -> tuple[np.ndarray, np.ndarray]:
    """The exact distribution of the number of runs for a random order of two kinds.

    **Arguments:** `n_positive`, `n_negative`: how many of each kind (both at least 1).

    **Returns:** ``(runs, probability)``, arrays over runs = 2 ... n_positive + n_negative.
    """
    n1, n2 = int(n_positive), int(n_negative)
    if n1 < 1 or n2 < 1:
        raise ValueError(f"need both kinds present, got {n1} and {n2}")
    table = log_factorials(n1 + n2)
    total = _log_binomial(table, n1 + n2, n1)
    runs = np.arange(2, n1 + n2 + 1)
    k = runs // 2
    even = (math.log(2.0) + _log_binomial(table, n1 - 1, k - 1)
            + _log_binomial(table, n2 - 1, k - 1))
    odd = np.logaddexp(_log_binomial(table, n1 - 1, k) + _log_binomial(table, n2 - 1, k - 1),
                       _log_binomial(table, n1 - 1, k - 1) + _log_binomial(table, n2 - 1, k))
    log_p = np.where(runs % 2 == 0, even, odd) - total
    probability = np.exp(log_p)
    # Cached (a study meets the same counts again and again): read-only.
    runs.flags.writeable = False
    probability.flags.writeable = False
    return runs, probability


def runs_test(residuals: np.ndarray) -> RunsTest:
    """The Wald–Wolfowitz runs test on the signs of residuals in time order.

    **Arguments:** `residuals`: data minus model, shape ``(n,)``, any unit.

    **Returns:** a :class:`RunsTest`; its `p` is small when there are too few sign changes.
    """
    signs = np.sign(np.asarray(residuals, float))
    signs = signs[signs != 0]
    n1 = int(np.count_nonzero(signs > 0))
    n2 = int(np.count_nonzero(signs < 0))
    runs = int(1 + np.count_nonzero(signs[1:] != signs[:-1])) if signs.size else 0
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


#: Most draws x residuals the randomisation test holds at once (32 MB of float64).
DRAW_BLOCK_ELEMENTS = 1 << 22
#: Most draws x residuals of a random-sign test whose draws are kept for the next curve of
#: the same length (1 MB each, 64 lengths kept: 1,999 draws of up to 65 residuals).
KEPT_DRAW_ELEMENTS = 1 << 17


def lag1_autocorrelation_p(residuals: np.ndarray, permutations: int = 1999,
                           seed: int = 0, null: str = "order") -> float:
    """One-sided randomisation probability of a lag-1 autocorrelation at least the observed.

    **Arguments:**

    - `residuals`: shape ``(n,)``, ``n >= 3``, in time order.
    - `permutations`: random draws (the p-value's resolution is 1/(permutations+1)).
    - `seed`: seed of the draws, so a report is reproducible.
    - `null`: ``"order"``: random orders of the residuals (exchangeable noise);
      ``"signs"``: random signs of each residual (independent noise symmetric about zero,
      of any size at each point). Only ``"signs"`` sees residuals that share one sign (an
      offset the model lacks), since reordering or r1's own normalisation hide it.

    **Returns:** ``(1 + #{draws with r1 >= observed}) / (permutations + 1)``; 1 when every
    residual is zero. With ``null="signs"`` and at least :data:`NORMAL_FROM` residuals, the
    probability from the null distribution's exact cumulants instead
    (:func:`lag1_signs_normal_p`, no draws), unless the residuals are concentrated on a few
    points.
    """
    if null not in ("order", "signs"):
        raise ValueError(f"null must be 'order' or 'signs', got {null!r}")
    e = np.asarray(residuals, float)
    observed = lag1_autocorrelation(e)
    if not math.isfinite(observed):
        return 1.0
    threshold = observed - 1e-12 * abs(observed)
    scale = float(e @ e)
    if null == "signs" and e.size >= NORMAL_FROM:
        p = lag1_signs_normal_p(e)
        if p is not None:
            return p
    if null == "signs" and e.size * permutations <= KEPT_DRAW_ELEMENTS:
        # The draws depend on the seed, their number and the length only: kept.
        neighbours = e[1:] * e[:-1]
        r1 = (neighbours.sum() - 2.0 * (_sign_flips(seed, permutations, e.size) @ neighbours)
              ) / scale
        return float((1 + int(np.sum(r1 >= threshold))) / (permutations + 1))
    rng = np.random.default_rng(seed)
    # Draws in blocks of rows, the same numbers in the same order as all at once: 1999 draws
    # of a million residuals at once took 16 GB.
    rows = max(1, DRAW_BLOCK_ELEMENTS // e.size)
    at_least = 0
    neighbours = e[1:] * e[:-1]
    for start in range(0, permutations, rows):
        count = min(rows, permutations - start)
        if null == "signs":
            r1 = (neighbours.sum() - 2.0 * (_flips(rng, count, e.size) @ neighbours)) / scale
        else:
            shuffled = rng.permuted(np.broadcast_to(e, (count, e.size)), axis=1)
            r1 = np.sum(shuffled[:, 1:] * shuffled[:, :-1], axis=1) / scale
        at_least += int(np.sum(r1 >= threshold))
    return float((1 + at_least) / (permutations + 1))


def _flips(rng: np.random.Generator, count: int, size: int) -> np.ndarray:
    """`count` draws of random signs of `size` residuals, as whether neighbours differ.

    The draws of ``rng.choice([-1, 1], (count, size))`` (the same stream: it draws these
    integers), five times faster. With signs ``s_i = 2 b_i - 1``, ``s_i s_(i+1)`` is
    ``1 - 2 (b_i xor b_(i+1))``, so a draw's ``sum s_i e_i s_(i+1) e_(i+1)`` is
    ``sum e_i e_(i+1) - 2 flips · (e_i e_(i+1))``. Returns ``(count, size - 1)`` zeros and ones.
    """
    bits = rng.integers(0, 2, size=(count, size))
    return (bits[:, 1:] ^ bits[:, :-1]).astype(float)


@functools.lru_cache(maxsize=64)
def _sign_flips(seed: int, permutations: int, size: int) -> np.ndarray:
    """All draws of a random-sign test of `size` residuals (:func:`_flips`), read-only:
    a study tests thousands of curves of a few lengths with the same seed."""
    flips = _flips(np.random.default_rng(seed), permutations, size)
    flips.flags.writeable = False
    return flips


#: Residuals from which the random-sign test of the lag-1 autocorrelation is computed from
#: its null distribution's exact cumulants (:func:`lag1_signs_normal_p`) instead of 1,999
#: random draws (O(n) instead of O(1999 n): 8 s for a million residuals). Below it the test
#: draws, and its results are unchanged.
NORMAL_FROM = 20_000
#: Largest ``Σ a⁴ / (Σ a²)²`` (``a_i = e_i e_(i+1)``) at which that approximation is used:
#: the reciprocal of an effective number of terms of at least 100 (for normal noise it is
#: about 9/n; at 0.01 to 0.05 the approximation was still within 0.003 of 100,000 random
#: draws). Residuals dominated by a few points keep the random draws.
NORMAL_CONCENTRATION = 0.01


def lag1_signs_normal_p(residuals: np.ndarray) -> float | None:
    """The random-sign probability of a lag-1 autocorrelation at least the observed, from the
    exact cumulants of its null distribution (for long curves).

    Under random signs ``s_i`` of the residuals, ``r1 = Σ s_i s_(i+1) a_i / Σ e_i²`` with
    ``a_i = e_i e_(i+1)``, and the products ``s_i s_(i+1)`` are independent random signs:
    r1 is a weighted sum of independent signs, symmetric about 0, with exact variance
    ``Σ a_i² / (Σ e_i²)²`` and fourth cumulant ``-2 Σ a_i⁴ / (Σ e_i²)⁴``. Its upper tail is
    the normal one corrected by that fourth cumulant (the Edgeworth expansion of a symmetric
    sum, whose error is of order ``(Σ a⁴ / (Σ a²)²)^(3/2)``; the uncorrected normal tail is off
    by about ``Σ a⁴ / (Σ a²)²``, 1e-5 for 100,000 normal residuals). The randomisation test
    it replaces (:func:`lag1_autocorrelation_p`, 1,999 draws) has a Monte Carlo standard error
    of 0.002 at p = 0.01 and 0.011 at p = 0.5, and reports at least 1/2000.

    **Arguments:** `residuals`: shape ``(n,)``, ``n >= 3``, in time order (any unit).

    **Returns:** the one-sided probability (no floor at 1/2000); 1 when every residual is
    zero; ``None`` when the residuals are too concentrated on a few points for the
    approximation (``Σ a⁴ / (Σ a²)²`` above :data:`NORMAL_CONCENTRATION`), or all their
    neighbour products are zero.
    """
    e = np.asarray(residuals, float)
    observed = lag1_autocorrelation(e)
    if not math.isfinite(observed):
        return 1.0
    products = e[1:] * e[:-1]
    # Scaled by the largest product, so that squares and fourth powers neither overflow
    # nor underflow.
    largest = float(np.max(np.abs(products)))
    if largest == 0.0:
        return None
    weights = products / largest
    second = float(weights @ weights)
    fourth = float(np.sum(weights**4))
    concentration = fourth / second**2
    if concentration > NORMAL_CONCENTRATION:
        return None
    threshold = observed - 1e-12 * abs(observed)
    # r1 / sd with sd = sqrt(Σ a²) / Σ e²: the observed statistic in standard units.
    x = threshold * float(e @ e) / (largest * math.sqrt(second))
    excess_kurtosis = -2.0 * concentration
    density = math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)
    tail = 0.5 * math.erfc(x / math.sqrt(2.0)) + excess_kurtosis / 24.0 * (x**3 - 3.0 * x
                                                                           ) * density
    return float(min(1.0, max(0.0, tail)))


# --- the verdict -------------------------------------------------------------------------------

#: Significance level of each residual test (runs, lag-1 autocorrelation, and the scaled sum of
#: squares where the noise level is known): below it in any one, the misfit is systematic.
LACK_OF_FIT_LEVEL = 0.01
#: A root-mean-square residual below this fraction of the data's peak counts as an exact fit:
#: no detector resolves a millionth of its range, and the residuals of a fit to noise-free
#: numbers are round-off, whose order carries no meaning.
NEGLIGIBLE_MISFIT = 1e-6
#: Fewest points (with non-zero weight) on which the residual tests are run.
MIN_TEST_POINTS = 8


@dataclass(frozen=True)
class LackOfFit:
    """Whether a fit's residuals show systematic structure, with the evidence in numbers.

    **Fields:**

    - `systematic`: the model does not describe the curve (some test below `level`).
    - `tested`: whether the tests were run (``False`` for fewer than
      :data:`MIN_TEST_POINTS` points, or residuals at round-off level).
    - `runs_test_p`, `runs`, `expected_runs`: the runs test on the signs of the
      standardised residuals (:func:`runs_test`).
    - `lag1_autocorrelation`, `lag1_p`: lag-1 autocorrelation of the standardised
      residuals and its random-sign probability (:func:`lag1_autocorrelation_p` with
      ``null="signs"``, which also sees an offset: residuals that all share one sign).
    - `scaled_sse`, `scaled_sse_p`: with a known noise level, ``Σ w r² / (noise² dof)``
      (1 expected) and ``P(χ²_dof >= Σ w r² / noise²)``; ``None`` when the noise level is
      estimated from the same residuals (then the ratio is 1 by construction).
    - `n_points`: points tested (non-zero weight).
    - `level`: the significance level of each test.
    - `statement`: the verdict in plain words with its numbers.
    """

    systematic: bool
    tested: bool
    runs_test_p: float
    runs: int
    expected_runs: float
    lag1_autocorrelation: float
    lag1_p: float
    scaled_sse: float | None
    scaled_sse_p: float | None
    n_points: int
    level: float
    statement: str

    def __str__(self) -> str:
        return self.statement

    def to_dict(self) -> dict:
        """A JSON-ready record (plain numbers; ``None`` for undefined ones)."""

        def number(x):
            return float(x) if x is not None and math.isfinite(x) else None

        return {
            "systematic": bool(self.systematic),
            "tested": bool(self.tested),
            "runs_test_p": number(self.runs_test_p),
            "runs": int(self.runs),
            "expected_runs": number(self.expected_runs),
            "lag1_autocorrelation": number(self.lag1_autocorrelation),
            "lag1_p": number(self.lag1_p),
            "scaled_sse": number(self.scaled_sse),
            "scaled_sse_p": number(self.scaled_sse_p),
            "n_points": int(self.n_points),
            "level": float(self.level),
            "statement": self.statement,
        }


def _probability_text(p: float, floor: float = 0.0) -> str:
    return f"p <= {floor:.1g}" if p <= floor else f"p = {p:.2g}"


def lack_of_fit_test(
    residuals: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    dof: float | None = None,
    noise: float | None = None,
    peak: float | None = None,
    described: np.ndarray | None = None,
    level: float = LACK_OF_FIT_LEVEL,
    permutations: int = 1999,
    seed: int = 0,
) -> LackOfFit:
    """The lack-of-fit verdict on a fit's residuals: runs, lag-1 autocorrelation, scaled SSE.

    **Arguments:**

    - `residuals`: model minus data in time order, shape ``(n,)``, unit U.
    - `weights`: the fit's weights ``w_i >= 0`` multiplying squared residuals (its error
      model: ``1/σ_i²`` up to a common factor); residuals are standardised as ``sqrt(w) r``
      and zero-weight points are left out. ``None``: all one.
    - `dof`: degrees of freedom of ``Σ w r²`` (``n - p``), for the scaled sum of squares.
    - `noise`: the known standard deviation of ``sqrt(w) r`` (1 when the weights are
      ``1/σ_i²`` with known ``σ_i``; the relative noise level for weights ``1/model²``), or
      ``None`` when it is estimated from these residuals (no scaled-SSE test then).
    - `peak`: the data's largest magnitude (unit U); a root-mean-square residual below
      :data:`NEGLIGIBLE_MISFIT` of it counts as an exact fit. ``None``: no such check.
    - `described`: boolean mask of the points whose noise the weights describe (default:
      all). The others are left out of the tests: where an error model caps a weight
      (relative errors below their floor), the noise of those points is far below what the
      weight implies, and their signs follow the model's smooth deviation, not the noise.
    - `level`: significance level of each test.
    - `permutations`, `seed`: of the lag-1 autocorrelation's random-sign test.

    **Returns:** a :class:`LackOfFit`.
    """
    r = np.asarray(residuals, float)
    w = np.ones_like(r) if weights is None else np.asarray(weights, float)
    if w.shape != r.shape:
        raise ValueError(f"weights have shape {w.shape}, residuals {r.shape}")
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    if noise is not None and not (math.isfinite(noise) and noise > 0):
        raise ValueError(f"noise must be a positive number, got {noise}")
    used = w > 0
    if described is not None:
        used &= np.asarray(described, bool)
    raw = r[used]
    z = np.sqrt(w[used]) * raw
    n = int(z.size)
    nan = math.nan

    def untested(reason: str) -> LackOfFit:
        return LackOfFit(False, False, nan, 0, nan, nan, nan, None, None, n, level, reason)

    if n < MIN_TEST_POINTS:
        return untested(f"Not tested for lack of fit: {n} points, fewer than the "
                        f"{MIN_TEST_POINTS} the residual tests need.")
    rms = float(np.sqrt(np.mean(raw**2)))
    if peak is not None and peak > 0 and rms <= NEGLIGIBLE_MISFIT * peak:
        return untested(f"The model reproduces the curve exactly (root-mean-square residual "
                        f"{rms / peak:.1g} of the peak, below {NEGLIGIBLE_MISFIT:g}): no "
                        "measurement is this precise, so the residual tests do not apply.")
    runs = runs_test(z)
    r1 = lag1_autocorrelation(z)
    r1_p = lag1_autocorrelation_p(z, permutations, seed, null="signs")
    scaled = scaled_p = None
    if noise is not None and dof is not None and dof > 0:
        chi_square = float(z @ z) / noise**2
        scaled = chi_square / dof
        scaled_p = chi_square_survival(chi_square, dof)
    failed = [runs.p < level, r1_p < level, scaled_p is not None and scaled_p < level]
    systematic = any(failed)
    floor = 1.0 / (permutations + 1)
    if runs.n_positive and runs.n_negative:
        signs = (f"{runs.runs} runs of residual signs where {runs.expected:.1f} are expected "
                 f"at random ({_probability_text(runs.p)})")
    else:
        signs = f"all {runs.n_positive + runs.n_negative} non-zero residuals of one sign"
    evidence = f"{signs}, lag-1 autocorrelation {r1:+.2f} ({_probability_text(r1_p, floor)})"
    if scaled is not None:
        evidence += (f", residual sum of squares {scaled:.3g} times its expected value "
                     f"({_probability_text(scaled_p)})")
    if systematic:
        statement = (f"The model does not describe this curve: its residuals are systematic "
                     f"({evidence}; level {level:g}). Its standard errors and intervals "
                     "assume a model that fits, so they understate the uncertainty; try "
                     "another model, a baseline or a dead time, or check the data (noise "
                     "correlated between neighbouring samples gives the same signs).")
    else:
        statement = (f"No lack of fit: the residuals look like noise ({evidence}; "
                     f"level {level:g}).")
    return LackOfFit(systematic, True, runs.p, runs.runs, runs.expected, r1, r1_p, scaled,
                     scaled_p, n, level, statement)


# --- counts ------------------------------------------------------------------------------------

#: Expected particles per merged bin in the lack-of-fit test of counts: the residual tests
#: assume noise that is nearly normal and symmetric; a Poisson count of mean 10 has skewness
#: 0.32 (a histogram bin expecting 0.01 particles holds 0 or 1, whose sign and size say
#: nothing by themselves).
COUNTS_PER_MERGED_BIN = 10.0


def merged_counts(observed_counts: np.ndarray, expected_counts: np.ndarray,
                  per_bin: float = COUNTS_PER_MERGED_BIN) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
    """Neighbouring bins merged, in time order, until each expects `per_bin` counts.

    **Arguments:** `observed_counts`, `expected_counts`: counts per bin and their model
    means (particles), shape ``(n,)``; `per_bin`: expected counts per merged bin. A last
    group expecting fewer joins the one before it.

    **Returns:** ``(observed, expected, first)``: the merged counts and means, and the index
    of each merged bin's first bin.
    """
    k = np.asarray(observed_counts, float)
    mu = np.asarray(expected_counts, float)
    if k.shape != mu.shape or k.ndim != 1:
        raise ValueError(f"counts and means must be 1-D of one shape, got {k.shape}, {mu.shape}")
    if not per_bin > 0:
        raise ValueError(f"per_bin must be positive, got {per_bin}")
    # Greedy, in time order: a merged bin closes as soon as it expects per_bin counts.
    group = np.empty(mu.size, dtype=np.int64)
    current, total = 0, 0.0
    for index, mean in enumerate(mu.tolist()):
        group[index] = current
        total += mean
        if total >= per_bin:
            current, total = current + 1, 0.0
    n_groups = current + (1 if total > 0 or current == 0 else 0)
    if mu.size == 0:
        n_groups = 0
    elif n_groups > 1 and total < per_bin and group[-1] == n_groups - 1:
        # The last group expects too few: it joins the one before.
        group[group == n_groups - 1] = n_groups - 2
        n_groups -= 1
    observed = np.bincount(group, weights=k, minlength=n_groups)
    expected = np.bincount(group, weights=mu, minlength=n_groups)
    first = np.searchsorted(group, np.arange(n_groups))
    return observed, expected, first


def counting_lack_of_fit(observed: np.ndarray, predicted: np.ndarray, exposure: np.ndarray,
                         n_free: int, *, level: float = LACK_OF_FIT_LEVEL,
                         per_bin: float = COUNTS_PER_MERGED_BIN) -> LackOfFit:
    """The lack-of-fit verdict of a fit to counts, on bins merged to `per_bin` expected counts.

    Counts ``x y`` of Poisson noise with means ``x m`` are merged in time order
    (:func:`merged_counts`); on the merged bins the runs test, the lag-1 autocorrelation and
    Pearson's ``X² = Σ (K - M)² / M`` against ``χ²`` of ``groups - n_free`` degrees of freedom
    (the noise level is known: 1 for standardised counts) are run as in
    :func:`lack_of_fit_test`. Single histogram bins of a fraction of a particle are not
    tested one by one: their noise is neither normal nor symmetric.

    **Arguments:** `observed`, `predicted`: the data and the model (data unit), shape
    ``(n,)``; `exposure`: ``x`` (counts per data unit); `n_free`: fitted parameters;
    `level`, `per_bin`: of the tests and the merging.

    **Returns:** a :class:`LackOfFit` (``n_points`` the number of merged bins).
    """
    x = np.asarray(exposure, float)
    used = x > 0
    k = (x * np.asarray(observed, float))[used]
    mu = np.clip((x * np.asarray(predicted, float))[used], 0.0, None)
    merged, expected, _ = merged_counts(k, mu, per_bin)
    positive = expected > 0
    merged, expected = merged[positive], expected[positive]
    dof = merged.size - n_free
    result = lack_of_fit_test(expected - merged, 1.0 / expected, dof=dof if dof > 0 else None,
                              noise=1.0, level=level)
    where = (f" (on {merged.size} bins merged to at least {per_bin:g} expected particles "
             "each)")
    statement = result.statement.replace("; level", f"{where}; level", 1)
    return dataclasses.replace(result, statement=statement)
