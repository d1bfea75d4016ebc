"""Sampling a simulated blender and the source's homogeneity statistics (MODELS.md §1, §4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import axialmix.particles as particles


def test_samples_from_one_location_are_disjoint_draws_without_replacement():
    counts = np.array([[30, 70], [5, 5]])
    # Ten samples of 10 exhaust compartment 0: together they are exactly its content.
    samples = particles.sample_compartments(counts, [0], 10, 10, seed=1)
    assert samples.shape == (10, 2) and np.all(samples.sum(axis=1) == 10)
    assert np.array_equal(samples.sum(axis=0), counts[0])
    with pytest.raises(ValueError, match="need more than"):
        particles.sample_compartments(counts, [1], 2, 6)


def test_sample_counts_follow_the_hypergeometric_distribution():
    counts = np.array([[300, 700]])
    draws = np.concatenate(
        [particles.sample_compartments(counts, [0], 1, 50, seed=k)[:, 0] for k in range(4000)]
    )
    dist = stats.hypergeom(1000, 300, 50)
    assert draws.mean() == pytest.approx(dist.mean(), abs=3 * dist.std() / np.sqrt(4000))
    # variance within 3 standard errors (normal approximation of the sample variance)
    assert draws.var(ddof=1) == pytest.approx(dist.var(), abs=3 * dist.var() * np.sqrt(2 / 3999))


def test_outflow_samples_come_from_the_steps_just_before_each_sample_step():
    outflow = np.zeros((20, 2), np.int64)
    outflow[:, 0] = 4
    outflow[9, :] = [0, 4]  # step 9 releases only species 1
    samples = particles.sample_outflow(outflow, [9, 19], 4, seed=0)
    assert samples.tolist() == [[0, 4], [4, 0]]
    eight = particles.sample_outflow(outflow, [9], 8, seed=0)  # window: steps 8 and 9
    assert eight.tolist() == [[4, 4]]
    with pytest.raises(ValueError, match="overlap"):
        particles.sample_outflow(outflow, [9, 10], 8)


def test_rsd_variance_vrr_and_chi_square_follow_the_source_definitions():
    x = np.array([0.1, 0.3, 0.2, 0.4])
    mean = x.mean()
    assert particles.relative_standard_deviation(x) == pytest.approx(
        np.sqrt(np.sum((x - mean) ** 2) / 3) / mean
    )
    assert particles.sample_variance(x) == pytest.approx(np.sum((x - mean) ** 2) / 4)
    y = x / 4 + 0.1
    assert particles.variance_reduction_ratio(x, y) == pytest.approx(16.0)
    counts = np.array([[10, 90], [30, 70], [20, 180]])  # 60 of species 0 among 400
    expected = np.array([100, 100, 200]) * 60 / 400
    assert particles.chi_square(counts, 0) == pytest.approx(
        np.sum((counts[:, 0] - expected) ** 2 / expected)
    )
    assert particles.species_fraction(counts, 1).tolist() == [0.9, 0.7, 0.9]


def test_chi_square_of_a_mixed_v_blender_follows_its_distribution_and_not_before():
    # Perfectly mixed, the arrangement of the particles is uniformly random, so chi-square
    # has the distribution of chi-square over random arrangements (drawn here by shuffling).
    # Before mixing completes its distribution is different (the source's observation).
    network = particles.particle_v_blender(5000, exchanges=(200, 100, 100, 200))
    initial = particles.v_blender_loading(network, "E")
    runs = [
        particles.simulate(network, initial, 1500, seed=s, report_steps=[60]) for s in range(300)
    ]
    early = [particles.chi_square(r.counts[1]) for r in runs]
    mixed = [particles.chi_square(r.final_counts) for r in runs]
    rng = np.random.default_rng(0)
    pool = np.repeat([0, 1], 2500)
    exact = []
    for _ in range(3000):
        rng.shuffle(pool)
        ones = (pool.reshape(5, 1000) == 0).sum(axis=1)
        exact.append(particles.chi_square(np.column_stack([ones, 1000 - ones])))
    assert stats.ks_2samp(mixed, exact).pvalue > 1e-3
    assert stats.ks_2samp(early, exact).pvalue < 1e-3
