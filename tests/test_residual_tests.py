"""Residual statistics for lack of fit: the exact runs distribution against enumeration,
and the null behaviour of both statistics on independent noise."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from fitting.residuals import (
    lag1_autocorrelation,
    lag1_autocorrelation_p,
    runs_distribution,
    runs_test,
)


@pytest.mark.parametrize(("n1", "n2"), [(1, 1), (3, 2), (4, 4), (5, 7)])
def test_exact_runs_distribution_matches_enumeration_of_all_orders(n1, n2):
    counts: dict[int, int] = {}
    n = n1 + n2
    for positions in itertools.combinations(range(n), n1):
        signs = -np.ones(n)
        signs[list(positions)] = 1
        runs = int(1 + np.sum(signs[1:] != signs[:-1]))
        counts[runs] = counts.get(runs, 0) + 1
    total = sum(counts.values())
    runs, probability = runs_distribution(n1, n2)
    for r, p in zip(runs, probability, strict=True):
        assert p == pytest.approx(counts.get(int(r), 0) / total, abs=1e-13)
    assert probability.sum() == pytest.approx(1.0, abs=1e-12)


def test_runs_test_p_is_uniform_for_independent_noise_and_small_for_a_smooth_misfit():
    rng = np.random.default_rng(3)
    p = np.array([runs_test(rng.normal(size=60)).p for _ in range(4000)])
    # A discrete statistic: P(p <= alpha) <= alpha, and close to it.
    for alpha in (0.01, 0.05, 0.2):
        assert 0.5 * alpha < np.mean(p <= alpha) <= alpha + 3 * np.sqrt(alpha / 4000)
    smooth = np.sin(np.linspace(0, 3 * np.pi, 60)) + 0.2 * rng.normal(size=60)
    assert runs_test(smooth).p < 1e-4


def test_lag1_autocorrelation_permutation_p_is_calibrated_for_independent_noise():
    rng = np.random.default_rng(4)
    n, trials = 40, 2000
    p = np.array([lag1_autocorrelation_p(rng.standard_t(3, size=n), permutations=199,
                                         seed=i) for i in range(trials)])
    for alpha in (0.01, 0.05, 0.2):  # binomial 3-sigma bands around alpha
        assert abs(np.mean(p <= alpha) - alpha) <= 3 * np.sqrt(alpha * (1 - alpha) / trials)
    drift = np.cumsum(rng.normal(size=n))
    assert lag1_autocorrelation(drift) > 0.6
    assert lag1_autocorrelation_p(drift) == pytest.approx(1 / 2000)


def test_signless_residuals_say_nothing():
    assert runs_test(np.zeros(10)).p == 1.0
    assert runs_test(np.ones(10)).p == 1.0


@pytest.mark.parametrize("null", ["signs", "order"])
def test_lag1_autocorrelation_p_in_blocks_of_draws_equals_all_draws_at_once(null, monkeypatch):
    # Long residual series are randomised a few draws at a time (bounded memory); the draws
    # are the same numbers in the same order, so the probability is exactly that of one batch.
    import fitting.residuals as residuals

    rng = np.random.default_rng(6)
    e = rng.normal(size=300) + 0.3 * np.sin(np.arange(300) / 7)
    at_once = lag1_autocorrelation_p(e, permutations=999, seed=2, null=null)
    monkeypatch.setattr(residuals, "DRAW_BLOCK_ELEMENTS", 7 * e.size)  # 7 draws per block
    assert lag1_autocorrelation_p(e, permutations=999, seed=2, null=null) == at_once
    assert 1 / 1000 < at_once < 1  # neither trivial bound


def _random_sign_p_by_definition(e, permutations, seed):
    """The random-sign probability written out: draws of rng.choice([-1, 1]), r1 of each."""
    e = np.asarray(e, float)
    observed = e[1:] @ e[:-1] / (e @ e)
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=(permutations, e.size))
    drawn = signs * e
    r1 = np.sum(drawn[:, 1:] * drawn[:, :-1], axis=1) / (e @ e)
    return (1 + np.sum(r1 >= observed - 1e-12 * abs(observed))) / (permutations + 1)


@pytest.mark.parametrize("size", [3, 17, 64, 140, 3000])
def test_random_sign_probability_equals_its_definition_draw_for_draw(size):
    # The kept draws (short curves), the blocked draws (long ones) and ties (a curve whose
    # residuals share one sign, where all-equal draws reproduce the observed r1 exactly).
    rng = np.random.default_rng(size)
    for e in (rng.standard_normal(size), np.abs(rng.standard_normal(size)),
              np.cumsum(rng.standard_normal(size)), np.round(rng.standard_normal(size), 1)):
        for seed in (0, 7):
            for permutations in (1999, 99):
                expected = _random_sign_p_by_definition(e, permutations, seed)
                assert lag1_autocorrelation_p(e, permutations, seed, null="signs") == expected
