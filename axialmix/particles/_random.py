"""Random draws for the particle engines, compiled with numba.

Why numba: the particle process is a loop over time steps, compartments and connections whose
body is a handful of integer random draws; it has no gradient to take and no array expression
to vectorise, so JAX (traced, float-first, no cheap scalar integer RNG in a loop) would be
slower by orders of magnitude, and pure Python would take hours (the source's FORTRAN code
needed 8,000 CPU seconds for one 1,000,000-particle batch run). numba compiles the loop to
machine code, and its ``np.random`` (a Mersenne Twister, seeded with ``np.random.seed`` inside
compiled code) makes runs reproducible.

numba's own ``np.random.hypergeometric`` is numpy's legacy ``HYP`` algorithm, whose cost
grows with the sample size (one uniform per particle drawn). The count engine needs a cost
independent of the numbers involved, so :func:`hypergeometric` ports numpy's ``Generator``
algorithm instead: Stadlober's ratio-of-uniforms method ``HRUA`` for samples of 10 or more
(constant expected cost), direct sequential selection for smaller samples.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_LOG_FACTORIAL_TABLE = np.array([math.lgamma(k + 1.0) for k in range(126)])
_HALF_LOG_TWO_PI = 0.9189385332046728
_D1 = 1.7155277699214135  # 2 sqrt(2/e)
_D2 = 0.8989161620588988  # 3 - 2 sqrt(3/e)


@numba.njit(cache=True)
def seed_generator(seed: int) -> None:
    """Seed numba's random generator (the one compiled code draws from)."""
    np.random.seed(seed)


@numba.njit(cache=True)
def _log_factorial(k: int) -> float:
    if k < 126:
        return _LOG_FACTORIAL_TABLE[k]
    # Stirling series to the 1/k**3 term: within a few ulp for k >= 126 (as in numpy).
    kf = float(k)
    return (
        (kf + 0.5) * math.log(kf)
        - kf
        + (_HALF_LOG_TWO_PI + (1.0 / kf) * (1.0 / 12.0 - 1.0 / (360.0 * kf * kf)))
    )


@numba.njit(cache=True)
def _hypergeometric_small(good: int, bad: int, sample: int) -> int:
    # Selects the sample one particle at a time; used for samples below 10 (or within 10 of
    # the whole population), where it is cheaper than the rejection method.
    total = good + bad
    computed = total - sample if sample > total // 2 else sample
    remaining_total = total
    remaining_good = good
    while computed > 0 and remaining_good > 0 and remaining_total > remaining_good:
        if np.random.randint(0, remaining_total) < remaining_good:
            remaining_good -= 1
        remaining_total -= 1
        computed -= 1
    if remaining_total == remaining_good:
        remaining_good -= computed
    if sample > total // 2:
        return remaining_good
    return good - remaining_good


@numba.njit(cache=True)
def _hypergeometric_hrua(good: int, bad: int, sample: int) -> int:
    # Stadlober (1989, 1990) ratio-of-uniforms, transcribed from numpy's
    # random_hypergeometric.c (the Generator algorithm).
    popsize = good + bad
    computed = min(sample, popsize - sample)
    min_gb = min(good, bad)
    max_gb = max(good, bad)
    p = min_gb / popsize
    q = max_gb / popsize
    mu = computed * p
    a = mu + 0.5
    var = (popsize - computed) * computed * p * q / (popsize - 1)
    c = math.sqrt(var + 0.5)
    h = _D1 * c + _D2
    m = int(math.floor((computed + 1.0) * (min_gb + 1.0) / (popsize + 2.0)))
    g = (
        _log_factorial(m)
        + _log_factorial(min_gb - m)
        + _log_factorial(computed - m)
        + _log_factorial(max_gb - computed + m)
    )
    b = min(min(computed, min_gb) + 1.0, math.floor(a + 16.0 * c))
    k = 0
    while True:
        u = np.random.random()
        v = np.random.random()
        x = a + h * (v - 0.5) / u
        if x < 0.0 or x >= b:
            continue
        k = int(math.floor(x))
        gp = (
            _log_factorial(k)
            + _log_factorial(min_gb - k)
            + _log_factorial(computed - k)
            + _log_factorial(max_gb - computed + k)
        )
        t = g - gp
        if u * (4.0 - u) - 3.0 <= t:
            break
        if u * (u - t) >= 1.0:
            continue
        if 2.0 * math.log(u) <= t:
            break
    if good > bad:
        k = computed - k
    if computed < sample:
        k = good - k
    return k


@numba.njit(cache=True)
def hypergeometric(good: int, bad: int, sample: int) -> int:
    """Number of "good" particles among ``sample`` drawn without replacement from good + bad."""
    if sample <= 0 or good <= 0:
        return 0
    if bad <= 0:
        return sample
    if sample >= 10 and sample <= good + bad - 10:
        return _hypergeometric_hrua(good, bad, sample)
    return _hypergeometric_small(good, bad, sample)


@numba.njit(cache=True)
def multivariate_hypergeometric(
    pool: np.ndarray, pool_total: int, sample: int, out: np.ndarray
) -> None:
    """Species counts of ``sample`` particles drawn without replacement from ``pool``.

    Sequential conditional draws: species s gets a hypergeometric share of what is left to
    draw, against the particles of the species after it; the last species takes the rest.
    ``pool_total`` must equal ``pool.sum()``; the result is written into ``out``.
    """
    remaining_total = pool_total
    remaining_sample = sample
    n_species = pool.shape[0]
    for s in range(n_species - 1):
        if remaining_sample == 0:
            out[s] = 0
            continue
        here = pool[s]
        drawn = hypergeometric(here, remaining_total - here, remaining_sample)
        out[s] = drawn
        remaining_total -= here
        remaining_sample -= drawn
    out[n_species - 1] = remaining_sample


@numba.njit(cache=True)
def hypergeometric_many(good: int, bad: int, sample: int, n: int, seed: int) -> np.ndarray:
    """``n`` seeded hypergeometric draws (used to check the sampler against its distribution)."""
    np.random.seed(seed)
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        out[i] = hypergeometric(good, bad, sample)
    return out


# xoshiro256** (Blackman and Vigna, 2018): the identity engine draws one uniform per particle
# moved, and this generator makes that draw about 9 times cheaper than numba's Mersenne
# Twister (1 ns against 9 ns), which halves the identity engine's time per move.
_MASK64 = (1 << 64) - 1


def xoshiro_state(seed: int) -> np.ndarray:
    """Initial xoshiro256** state for a seed (expanded by splitmix64, as its authors advise)."""
    x = int(seed) & _MASK64
    words = []
    for _ in range(4):
        x = (x + 0x9E3779B97F4A7C15) & _MASK64
        z = x
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
        words.append(z ^ (z >> 31))
    return np.array(words, dtype=np.uint64)


@numba.njit(inline="always")
def _rotate_left(x, k):
    return (x << numba.uint64(k)) | (x >> numba.uint64(64 - k))


@numba.njit(inline="always")
def next_uniform(state) -> float:
    """A uniform double in [0, 1) with 53 random bits from a xoshiro256** state (advanced)."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    result = _rotate_left(s1 * numba.uint64(5), 7) * numba.uint64(9)
    t = s1 << numba.uint64(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotate_left(s3, 45)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3
    return (result >> numba.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True)
def uniform_many(state, n: int) -> np.ndarray:
    """``n`` uniforms from a xoshiro256** state (used to check the generator)."""
    out = np.empty(n)
    for i in range(n):
        out[i] = next_uniform(state)
    return out
