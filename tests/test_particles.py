"""The stochastic particle simulator checked against exact distributions and the network model.

Statistical tests use fixed seeds, so they are reproducible; each states its test and its
threshold. The simulator shares only the network description with :mod:`axialmix.network`;
the mean-field predictions below come from that independent implementation.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import axialmix.network as mean_field
import axialmix.particles as particles
from axialmix.particles._random import hypergeometric_many

ENGINES = ("count", "identity")


def _chi_square_p_value(observed: np.ndarray, expected: np.ndarray) -> float:
    """Pearson chi-square p-value after merging neighbouring cells until each expects >= 5."""
    merged_obs, merged_exp = [], []
    acc_o = acc_e = 0.0
    for o, e in zip(observed, expected, strict=True):
        acc_o += o
        acc_e += e
        if acc_e >= 5:
            merged_obs.append(acc_o)
            merged_exp.append(acc_e)
            acc_o = acc_e = 0.0
    merged_obs[-1] += acc_o
    merged_exp[-1] += acc_e
    merged_obs, merged_exp = np.array(merged_obs), np.array(merged_exp)
    statistic = np.sum((merged_obs - merged_exp) ** 2 / merged_exp)
    return float(stats.chi2.sf(statistic, merged_obs.size - 1))


@pytest.mark.parametrize(
    ("good", "bad", "sample"),
    [
        (5, 7, 4),  # direct selection (sample < 10)
        (6, 8, 11),  # direct selection of the complement (sample within 10 of the total)
        (40, 60, 30),  # ratio-of-uniforms, small population
        (1000, 199_000, 1000),  # V-blender scale
        (100_000_000, 100_000_000, 1000),  # 1e9-particle scale
        (3, 999_997, 500_000),  # rare species, sample of half the population
    ],
)
def test_hypergeometric_sampler_matches_exact_distribution(good, bad, sample):
    draws = hypergeometric_many(good, bad, sample, 20_000, 7)
    dist = stats.hypergeom(good + bad, good, sample)
    support = np.arange(max(0, sample - bad), min(good, sample) + 1)
    observed = np.bincount(draws - support[0], minlength=support.size)[: support.size]
    assert observed.sum() == draws.size  # nothing outside the support
    # Pearson chi-square at the 0.1 % level: a correct sampler fails 1 time in 1000.
    assert _chi_square_p_value(observed, draws.size * dist.pmf(support)) > 1e-3


def _v_blender_prediction(network: particles.ParticleNetwork, initial, steps) -> np.ndarray:
    reference = network.to_network()
    times = np.asarray(steps, dtype=float) * reference.time_step
    return np.asarray(mean_field.compartment_amounts(reference, initial.astype(float), times))


def test_v_blender_mean_counts_match_markov_prediction_over_20_seeds():
    network = particles.particle_v_blender()  # 1,000,000 particles, 1000/100/100/1000 per step
    initial = particles.v_blender_loading(network, "E")
    report = [1000, 3000, 10_000, 30_000]
    runs = np.array(
        [
            particles.simulate(network, initial, 30_000, seed=seed, report_steps=report).counts[
                1:, :, 0
            ]
            for seed in range(20)
        ]
    )
    predicted = _v_blender_prediction(network, initial, report)[:, :, 0]
    mean = runs.mean(axis=0)
    standard_error = runs.std(axis=0, ddof=1) / np.sqrt(runs.shape[0])
    z = (mean - predicted) / standard_error
    print(f"V-blender, 20 seeds: largest |mean - Markov| = {np.max(np.abs(z)):.2f} standard "
          f"errors over {z.size} (step, compartment) pairs")
    # Within 3 standard errors at every reported step and compartment.
    assert np.all(np.abs(mean - predicted) <= 3 * standard_error), (
        mean - predicted
    ) / standard_error
    # The check has teeth: the prediction moves by many standard errors between reports.
    assert np.all(
        np.abs(np.diff(predicted, axis=0))[:, [0, 1, 3, 4]] > 10 * standard_error[1:, [0, 1, 3, 4]]
    )


def _small_v_blender() -> tuple[particles.ParticleNetwork, np.ndarray]:
    # The V-blender scaled down 100 times: same fractions moved per step.
    network = particles.particle_v_blender(10_000, exchanges=(10, 1, 1, 10))
    return network, particles.v_blender_loading(network, "E")


def test_count_and_identity_engines_agree_on_v_blender_counts():
    network, initial = _small_v_blender()
    report = [300, 3000, 30_000]
    runs = {
        engine: np.array(
            [
                particles.simulate(
                    network, initial, 30_000, engine=engine, seed=s, report_steps=report
                ).counts[1:, :, 0]
                for s in range(30)
            ]
        )
        for engine in ENGINES
    }
    predicted = _v_blender_prediction(network, initial, report)[:, :, 0]
    count, identity = runs["count"], runs["identity"]
    for engine_runs in (count, identity):
        se = engine_runs.std(axis=0, ddof=1) / np.sqrt(engine_runs.shape[0])
        assert np.all(np.abs(engine_runs.mean(axis=0) - predicted) <= 3 * se)
    # Same mean (Welch t) and same spread (Levene) across seeds, 0.1 % level per comparison.
    for r in range(len(report)):
        for c in (0, 1, 3, 4):  # V3 starts and stays near 50 %: its test is the same as V1's
            assert stats.ttest_ind(count[:, r, c], identity[:, r, c], equal_var=False).pvalue > 1e-3
            assert stats.levene(count[:, r, c], identity[:, r, c]).pvalue > 1e-3


@pytest.mark.parametrize("engine", ENGINES)
def test_one_step_moves_distinct_particles_hypergeometric_not_binomial(engine):
    # Three compartments of 40, 10 particles each way per step: the finite-population
    # effect is large (a quarter of a compartment leaves each step), so drawing with
    # replacement (binomial) would be rejected.
    network = particles.ParticleNetwork([40, 40, 40], [0, 1, 1, 2], [1, 0, 2, 1], [10, 10, 10, 10])
    initial = np.array([[30, 10], [12, 28], [0, 40]])
    after = np.array(
        [
            particles.simulate(network, initial, 1, engine=engine, seed=s).final_counts[1, 0]
            for s in range(3000)
        ]
    )
    # Species-0 count of the middle compartment after one step: 12 - X + Y + Z with
    # X ~ H(40, 12, 20) leaving, Y ~ H(40, 30, 10) from the left, Z = 0 from the right.
    leaving = stats.hypergeom(40, 12, 20).pmf(np.arange(13))
    arriving = stats.hypergeom(40, 30, 10).pmf(np.arange(11))
    pmf = np.convolve(leaving[::-1], arriving)  # index k <-> count k - 12 + 12 = k
    observed = np.bincount(after, minlength=pmf.size)[: pmf.size]
    assert observed.sum() == after.size
    assert _chi_square_p_value(observed, after.size * pmf) > 1e-3
    binomial = np.convolve(
        stats.binom(20, 12 / 40).pmf(np.arange(21))[::-1],
        stats.binom(10, 30 / 40).pmf(np.arange(11)),
    )
    shift = 20 - 12  # binomial leaving can exceed 12: index k <-> count k - 8
    observed_b = np.bincount(after + shift, minlength=binomial.size)[: binomial.size]
    assert _chi_square_p_value(observed_b, after.size * binomial) < 1e-3


def _tracer_run(engine: str, seed: int = 3):
    # 100,000 particles and 30,000 tracers: enough to tell any of the four rates changed by
    # 20 % (with 3,000 tracers a 20 % change of k_f, k_r or k_s goes unnoticed: the RTD
    # barely depends on them, the source's identifiability problem).
    network = particles.particle_four_compartment(particles=100_000)
    steps = 9000  # 14 mean residence times (625 steps): 1e-6 of the tracer is left
    feed = particles.constant_feed(network, [1.0, 0.0], steps)
    initial = np.column_stack([network.holdups, np.zeros(4, np.int64)])
    pulse = particles.TracerPulse(step=5, particles=30_000, species=1)
    result = particles.simulate(
        network, initial, steps, engine=engine, seed=seed, feed=feed, tracer=pulse
    )
    return network, result


@pytest.fixture(scope="module")
def count_tracer_run():
    return _tracer_run("count")


def _rtd_p_value(exit_steps: np.ndarray, reference, pulse_step: int, steps: int) -> float:
    """Chi-square test of exit steps against a network's discrete RTD in 30 equiprobable bins."""
    residence = np.arange(1, steps - pulse_step + 1) * reference.time_step
    probability = np.asarray(mean_field.exit_age(reference, residence)) * reference.time_step
    cumulative = np.cumsum(probability)
    edges = np.searchsorted(cumulative, np.linspace(0, 1, 31)[1:-1])  # bin k ends at edges[k]
    expected = np.diff(np.concatenate([[0.0], cumulative[edges], [1.0]])) * exit_steps.size
    # residence step index of each exit (1 = left during the pulse step)
    index = exit_steps - pulse_step
    observed = np.bincount(np.searchsorted(edges, index, side="left"), minlength=30)
    return float(stats.chisquare(observed, expected).pvalue)


@pytest.fixture(scope="module")
def identity_tracer_run():
    return _tracer_run("identity")


@pytest.mark.parametrize("engine", ENGINES)
def test_continuous_tracer_rtd_matches_network_exit_age(engine, request):
    network, result = request.getfixturevalue(f"{engine}_tracer_run")
    steps = result.steps_completed
    outflow = result.outflow[:, 1]
    exit_steps = np.repeat(np.arange(steps), outflow)
    assert outflow.sum() == 30_000  # every tracer left within the run
    # Pearson chi-square over 30 bins of equal predicted probability, 0.1 % level.
    p_value = _rtd_p_value(exit_steps, network.to_network(), 5, steps)
    print(f"{engine} engine tracer RTD vs network RTD: chi-square p = {p_value:.3g}")
    assert p_value > 1e-3
    if engine == "identity":
        exits = result.exit_steps()
        assert np.array_equal(np.sort(exits[:, 1]), exit_steps)


_RATE_GROUPS = {
    "forward": {("C1", "C2"), ("C3", "C4")},
    "backward": {("C2", "C1"), ("C4", "C3")},
    "side": {("C1", "C3"), ("C3", "C1"), ("C2", "C4"), ("C4", "C2")},
}


@pytest.mark.parametrize("rate", ["forward", "backward", "side", "outflow"])
def test_continuous_tracer_rtd_rejects_network_with_rate_changed_by_20_percent(
    rate, count_tracer_run
):
    network, result = count_tracer_run
    steps = result.steps_completed
    exit_steps = np.repeat(np.arange(steps), result.outflow[:, 1])
    reference = network.to_network()
    assert _rtd_p_value(exit_steps, reference, 5, steps) > 1e-3
    if rate == "outflow":
        changed = reference.with_rates(outflow_rates=reference.outflow_rates * 1.2)
    else:
        rates = [
            c.rate * (1.2 if (c.source, c.target) in _RATE_GROUPS[rate] else 1.0)
            for c in reference.connections
        ]
        changed = reference.with_rates(rates=rates)
    p_value = _rtd_p_value(exit_steps, changed, 5, steps)
    print(f"tracer RTD vs network with {rate} rate x 1.2: chi-square p = {p_value:.3g}")
    assert p_value < 1e-3


def test_equilibrium_sample_variance_matches_hypergeometric_prediction():
    # A small, fast-mixing batch chain (5 x 1000 particles) run far past mixing: the
    # stationary state is a uniformly random arrangement, so an m-particle sample from a
    # compartment is an m-subset of all 5000 particles: hypergeometric(5000, 2500, m).
    network = particles.particle_v_blender(5000, exchanges=(200, 100, 100, 200))
    initial = np.array([[1000, 0], [1000, 0], [500, 500], [0, 1000], [0, 1000]])
    finals = [particles.simulate(network, initial, 1500, seed=s).final_counts for s in range(600)]
    for m in (2, 20, 200):
        samples = [
            particles.sample_compartments(c, [0], 1, m, seed=k) for k, c in enumerate(finals)
        ]
        fractions = particles.species_fraction(np.concatenate(samples), 0)
        dist = stats.hypergeom(5000, 2500, m)
        support = np.arange(m + 1)
        pmf = dist.pmf(support)
        x = support / m
        mu = np.sum(pmf * x)
        sigma2 = np.sum(pmf * (x - mu) ** 2)
        mu4 = np.sum(pmf * (x - mu) ** 4)
        r = fractions.size
        # Standard error of the sample variance (ddof=1) from the exact fourth moment.
        se = np.sqrt(mu4 / r - sigma2**2 * (r - 3) / (r * (r - 1)))
        estimate = np.var(fractions, ddof=1)
        print(f"m = {m}: sample variance {estimate:.5g}, hypergeometric {sigma2:.5g}, "
              f"z = {(estimate - sigma2) / se:+.2f}")
        assert abs(estimate - sigma2) <= 3 * se, (m, estimate, sigma2, se)
        assert sigma2 == pytest.approx(0.25 / m * (5000 - m) / 4999)


@pytest.mark.parametrize("engine", ENGINES)
def test_batch_run_conserves_particles_at_every_step(engine):
    network, initial = _small_v_blender()
    result = particles.simulate(network, initial, 400, engine=engine, seed=4, report_every=1)
    assert result.counts.shape == (401, 5, 2)
    assert np.all(result.counts.sum(axis=2) == network.holdups)
    assert np.all(result.counts.sum(axis=1) == initial.sum(axis=0))
    assert np.all(result.counts >= 0)


@pytest.mark.parametrize("engine", ENGINES)
def test_continuous_run_balances_feed_outflow_and_holdup_at_every_step(engine):
    network = particles.particle_axial_radial_grid(6, 3)
    steps = 600
    feed = particles.feeder_feed(network, [12.16, 6.55], [2.46, 1.16], steps, seed=1)
    initial = np.column_stack([network.holdups, np.zeros(network.n_compartments, np.int64)])
    result = particles.simulate(
        network, initial, steps, engine=engine, seed=5, feed=feed, report_every=1
    )
    held = result.counts.sum(axis=1)  # (steps + 1, species)
    fed = np.concatenate([[0], np.cumsum(result.fed.sum(axis=1)[:, 1])])
    left = np.concatenate([[0], np.cumsum(result.outflow[:, 1])])
    assert np.array_equal(fed, left + held[:, 1] - held[0, 1])  # species 2: in = out + held
    assert np.all(result.counts.sum(axis=2) == network.holdups)
    assert left[-1] > 0


@pytest.mark.parametrize("engine", ENGINES)
def test_same_seed_reproduces_a_run_and_another_seed_does_not(engine):
    network, initial = _small_v_blender()
    first, again, other = (
        particles.simulate(network, initial, 500, engine=engine, seed=s, report_every=100)
        for s in (11, 11, 12)
    )
    assert np.array_equal(first.counts, again.counts)
    assert not np.array_equal(first.counts, other.counts)


@pytest.mark.parametrize("engine", ENGINES)
def test_interrupted_run_keeps_results_so_far(engine):
    network, initial = _small_v_blender()
    calls = []

    def stop_at_second_report(step, total, elapsed):
        calls.append(step)
        if len(calls) == 2:
            raise KeyboardInterrupt

    stopped = particles.simulate(
        network,
        initial,
        1000,
        engine=engine,
        seed=8,
        report_every=100,
        progress=stop_at_second_report,
    )
    full = particles.simulate(network, initial, 1000, engine=engine, seed=8, report_every=100)
    assert stopped.interrupted and not full.interrupted
    assert stopped.steps_completed == 200
    assert np.array_equal(stopped.report_steps, [0, 100, 200])
    assert np.array_equal(stopped.counts, full.counts[:3])


def test_identity_history_adds_up_to_each_tracer_residence_time(identity_tracer_run):
    network, result = identity_tracer_run
    exits = result.exit_steps()
    assert exits.shape == (30_000, 2) and np.all(exits[:, 1] >= 5)
    for particle, exit_step in exits[:20]:
        places, spent = result.history(int(particle))
        assert places[0] == 0  # tagged in the inlet compartment C1
        assert np.all(spent >= 1)
        assert spent.sum() == exit_step - 5 + 1  # pulse at the start of step 5
        assert places[-1] == 3  # left over the weir from C4


def test_particle_network_step_matrix_matches_network_model():
    network = particles.particle_four_compartment()
    expected = np.asarray(mean_field.step_matrix(network.to_network()))
    np.testing.assert_allclose(network.step_matrix(), expected, rtol=0, atol=1e-15)
    assert np.all(network.moves == np.rint(network.moves))


def test_particle_network_rejects_inconsistent_descriptions():
    with pytest.raises(ValueError, match="receives"):
        particles.ParticleNetwork([10, 10], [0, 1], [1, 0], [3, 2])
    with pytest.raises(ValueError, match="hands out"):
        particles.ParticleNetwork([10, 10], [0, 1], [1, 0], [11, 11])
    with pytest.raises(ValueError, match="whole"):
        particles.ParticleNetwork([10.5, 10], [0, 1], [1, 0], [1, 1])
    with pytest.raises(ValueError, match="whole number"):
        particles.ParticleNetwork.from_network(
            mean_field.four_compartment(1, 1, 1, 1, total_holdup=1000), time_step=0.013
        )
    network, initial = _small_v_blender()
    with pytest.raises(ValueError, match="hold-up"):
        particles.simulate(network, initial + 1, 10)
    with pytest.raises(ValueError, match="engine"):
        particles.simulate(network, initial, 10, engine="fast")


def test_identity_engine_generator_matches_reference_xoshiro256starstar():
    from axialmix.particles._random import uniform_many, xoshiro_state

    mask = (1 << 64) - 1
    state = [int(w) for w in xoshiro_state(2024)]

    def rotl(x, k):
        return ((x << k) | (x >> (64 - k))) & mask

    expected = []
    for _ in range(1000):  # reference algorithm from Blackman and Vigna (2018), in Python
        result = rotl((state[1] * 5) & mask, 7) * 9 & mask
        t = (state[1] << 17) & mask
        state[2] ^= state[0]
        state[3] ^= state[1]
        state[1] ^= state[2]
        state[0] ^= state[3]
        state[2] ^= t
        state[3] = rotl(state[3], 45)
        expected.append((result >> 11) * 2.0**-53)
    got = uniform_many(xoshiro_state(2024), 1000)
    assert np.array_equal(got, np.array(expected))
    assert stats.kstest(uniform_many(xoshiro_state(5), 100_000), "uniform").pvalue > 1e-3


def test_constant_feed_is_exact_and_feeder_feed_follows_feeder_rates():
    network = particles.particle_axial_radial_grid(4, 3)  # 3 inlets, 1 particle each per step
    feed = particles.constant_feed(network, [0.7, 0.3], 1000)
    assert feed.shape == (1000, 3, 2) and np.all(feed.sum(axis=2) == 1)
    assert np.all(np.abs(feed.sum(axis=0)[:, 1] - 300) <= 1)  # running share within 1 particle
    fluctuating = particles.feeder_feed(network, [12.16, 6.55], [2.46, 1.16], 20_000, seed=3)
    assert np.all(fluctuating.sum(axis=2) == 1)
    share = fluctuating[:, :, 1].mean()
    # E[6.55 / (12.16 + 6.55)] for independent normal rates, by simulation of the rates only
    rng = np.random.default_rng(0)
    rates = np.maximum(rng.normal([12.16, 6.55], [2.46, 1.16], (200_000, 2)), 0)
    # The per-step fraction has a standard deviation of about 0.06: 3 standard errors of
    # the two means (20,000 and 200,000 draws) come to about 0.0014.
    assert share == pytest.approx(np.mean(rates[:, 1] / rates.sum(axis=1)), abs=0.0015)
    with pytest.raises(ValueError, match="sum to 1"):
        particles.constant_feed(network, [0.7, 0.4], 10)


def test_identity_history_first_stay_in_inlet_is_geometric(identity_tracer_run):
    # A particle leaves compartment C1 during a step with probability L_1 / N_1 (particles
    # handed out over those held), whatever happened before: its first stay, counted from
    # the tagging at the start of the pulse step, is geometric.
    network, result = identity_tracer_run
    leave = network.handed_out[0] / network.holdups[0]
    events = result.events  # sorted by particle, then step, the tagging first
    _, first = np.unique(events[:, 0], return_index=True)
    assert np.all(events[first, 2] == -2) and np.all(events[first + 1, 2] == 0)
    stays = events[first + 1, 1] - events[first, 1] + 1
    for p in events[first[:5], 0]:  # the same as the per-particle history
        assert result.history(int(p))[1][0] == stays[np.searchsorted(events[first, 0], p)]
    top = 40
    observed = np.bincount(np.minimum(stays, top), minlength=top + 1)[1:]
    k = np.arange(1, top)
    expected = np.append(leave * (1 - leave) ** (k - 1), (1 - leave) ** (top - 1)) * stays.size
    assert _chi_square_p_value(observed, expected) > 1e-3
