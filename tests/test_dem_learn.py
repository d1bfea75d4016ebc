"""Networks learned from cell sequences: counts, rates, bootstrap coverage, Markov test.

The known-rates checks run the identity particle engine of :mod:`axialmix.particles` on a
ring of cells with drift (a periodic section), track a tenth of the particles, and learn the
rates back from their cell sequences. The true continuous-time rates of the tracked
particles' chain are ``log P / dt`` with ``P`` the engine's one-step transition matrix.
"""

import numpy as np
import pytest
import scipy.linalg

from axialmix.dem._learn import (
    axial_cells,
    block_count_matrices,
    cell_length_limit,
    count_matrix,
    count_occupancy,
    learn_network,
    markov_test,
    observed_edges,
    rates_by_likelihood,
    rates_from_counts,
    sequences_from_particle_events,
)
from axialmix.network import CompartmentNetwork, backflow_chain_transport
from axialmix.particles import ParticleNetwork, simulate

N_CELLS, HOLDUP, FORWARD, BACKWARD, TRACKED, DT = 6, 200, 8, 4, 20, 0.01


def _ring():
    sources, targets, moves = [], [], []
    for i in range(N_CELLS):
        sources += [i, i]
        targets += [(i + 1) % N_CELLS, (i - 1) % N_CELLS]
        moves += [FORWARD, BACKWARD]
    network = ParticleNetwork(np.full(N_CELLS, HOLDUP), sources, targets, moves, step_seconds=DT)
    true = np.real(scipy.linalg.logm(network.step_matrix().T)) / DT
    return network, (np.array(sources), np.array(targets)), true


def _tracked_sequences(network, steps, seed, tracked=TRACKED):
    initial = np.column_stack([np.full(N_CELLS, HOLDUP - tracked), np.full(N_CELLS, tracked)])
    result = simulate(network, initial, steps, engine="identity", seed=seed, tracked_species=[1])
    return sequences_from_particle_events(result, 1)


def _coverage(repetitions, steps, block):
    network, connections, true = _ring()
    hits = []
    for rep in range(repetitions):
        sequences = _tracked_sequences(network, steps, seed=rep)
        learned = learn_network(sequences, N_CELLS, DT, 1, block, n_bootstrap=200, seed=rep)
        hits.append((learned.lower[connections] <= true[connections])
                    & (true[connections] <= learned.upper[connections]))
    return np.array(hits)


def test_sequences_follow_the_particle_events():
    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 300, seed=3)
    assert sequences.shape == (301, N_CELLS * TRACKED)
    # Each cell starts with its tracked particles, and the tracked total stays.
    assert np.bincount(sequences[0], minlength=N_CELLS).tolist() == [TRACKED] * N_CELLS
    assert np.all(np.bincount(sequences[-1], minlength=N_CELLS).sum() == N_CELLS * TRACKED)
    # A particle moves at most one cell (either way round the ring) per step.
    step = np.mod(np.diff(sequences, axis=0), N_CELLS)
    assert set(np.unique(step).tolist()) <= {0, 1, N_CELLS - 1}


def test_block_counts_sum_to_deeptime_counts():
    rng = np.random.default_rng(0)
    sequences = rng.integers(0, 5, size=(203, 17))
    blocks = block_count_matrices(sequences, 5, 3, 20)
    assert blocks.shape == (10, 5, 5)
    np.testing.assert_array_equal(blocks.sum(axis=0), count_matrix(sequences[:203], 5, 3))
    # Block 4 by hand.
    a, b = sequences[80:100], sequences[83:103]
    by_hand = np.zeros((5, 5))
    np.add.at(by_hand, (a.ravel(), b.ravel()), 1)
    np.testing.assert_array_equal(blocks[4], by_hand)


def test_rates_recover_an_exact_transition_matrix():
    # Counts proportional to exp(Q tau) give back Q.
    q = np.array([[-3.0, 2.0, 1.0], [0.5, -1.5, 1.0], [0.2, 0.8, -1.0]])
    counts = 1e6 * scipy.linalg.expm(q * 0.1)
    rates, clipped = rates_from_counts(counts, 0.1)
    np.testing.assert_allclose(rates, q, atol=1e-9)
    assert clipped == 0


def _random_ring(seed, n=6):
    rng = np.random.default_rng(seed)
    q = np.zeros((n, n))
    for i in range(n):
        q[i, (i + 1) % n], q[i, (i - 1) % n] = rng.uniform(2, 4), rng.uniform(0.5, 1.5)
    q -= np.diag(q.sum(axis=1))
    return q, np.argwhere(q > 0)


@pytest.mark.parametrize("lag", [0.1, 0.5, 1.0])
def test_likelihood_rates_recover_an_exact_transition_matrix(lag):
    # Counts proportional to exp(Q tau) of a drifting ring (up to three cells of drift a
    # lag): the rates of largest likelihood on the ring's connections are Q.
    for seed in range(3):
        q, edges = _random_ring(seed)
        counts = 1e6 * scipy.linalg.expm(q * lag)
        np.testing.assert_allclose(rates_by_likelihood(counts, lag, edges), q, rtol=0,
                                   atol=1e-9 * np.abs(q).max())


def _log_likelihood(counts, rates, lag):
    return float(np.sum(counts * np.log(np.clip(scipy.linalg.expm(rates * lag), 1e-300, None))))


def test_likelihood_network_is_valid_and_at_least_as_likely_as_the_clipped_logarithm():
    # Sampled counts of a few hundred transitions a row: the matrix logarithm needs negative
    # rates and is clipped; the likelihood estimate (started from it) keeps the ring's
    # connections only, with positive rates, and explains the counts at least as well.
    rng = np.random.default_rng(4)
    q, edges = _random_ring(1)
    lag = 0.5
    exact = scipy.linalg.expm(q * lag)
    counts = np.stack([rng.multinomial(300, row / row.sum()) for row in exact]).astype(float)
    clipped_rates, clipped = rates_from_counts(counts, lag)
    assert clipped > 0
    rates = rates_by_likelihood(counts, lag, edges)
    off = ~np.eye(6, dtype=bool)
    assert np.all(rates[off & (q > 0)] > 0) and np.all(rates[off & (q == 0)] == 0)
    np.testing.assert_allclose(rates.sum(axis=1), 0.0, atol=1e-12)
    assert _log_likelihood(counts, rates, lag) >= _log_likelihood(counts, clipped_rates, lag)


def _steady(rates):
    values, vectors = np.linalg.eig(rates.T)
    pi = np.real(vectors[:, np.argmin(np.abs(values))])
    return pi / pi.sum()


@pytest.mark.parametrize("lag", [0.1, 1.0])
def test_stationary_rates_recover_an_exact_transition_matrix(lag):
    # Counts of a steady chain, pi_i exp(Q tau)_ij: their occupancy is the chain's steady
    # state, so holding it costs nothing and the constrained rates are Q.
    for seed in range(3):
        q, edges = _random_ring(seed)
        counts = 1e6 * _steady(q)[:, None] * scipy.linalg.expm(q * lag)
        np.testing.assert_allclose(count_occupancy(counts), _steady(q), rtol=1e-12)
        np.testing.assert_allclose(rates_by_likelihood(counts, lag, edges, stationary=True),
                                   q, rtol=0, atol=1e-7 * np.abs(q).max())


def _sampled_counts(seed, per_row=400):
    # The same number of transitions counted from every cell (not the chain's steady share):
    # the counts' occupancy is not the steady state of the rates of largest likelihood.
    rng = np.random.default_rng(seed)
    q, edges = _random_ring(seed)
    lag = 0.5
    exact = scipy.linalg.expm(q * lag)
    counts = np.stack([rng.multinomial(per_row, row / row.sum()) for row in exact])
    return counts.astype(float), edges, lag


def test_stationary_network_holds_the_occupancy_and_is_the_constrained_optimum():
    """Against a second formulation: scipy's trust-constr maximising the same likelihood over
    the rates themselves, with ``occupancy @ Q = 0`` as explicit linear constraints, from the
    unconstrained optimum (no reparametrisation, no row scaling)."""
    from scipy.optimize import LinearConstraint, minimize

    for seed in range(2):
        counts, edges, lag = _sampled_counts(seed)
        occupancy = count_occupancy(counts)
        free = rates_by_likelihood(counts, lag, edges)
        held = rates_by_likelihood(counts, lag, edges, stationary=True)
        assert np.abs(_steady(free) - occupancy).max() > 1e-3  # the constraint binds
        scale = occupancy @ np.abs(np.diag(held))
        assert np.abs(occupancy @ held).max() / scale < 1e-10
        np.testing.assert_allclose(held.sum(axis=1), 0.0, atol=1e-12)
        assert _log_likelihood(counts, held, lag) <= _log_likelihood(counts, free, lag)

        # (occupancy @ Q)_b = sum over edges (a, b) of occ_a q_ab - sum over (b, c) occ_b q_bc
        balance = np.zeros((len(occupancy), len(edges)))
        for e, (a, b) in enumerate(edges):
            balance[b, e] += occupancy[a]
            balance[a, e] -= occupancy[a]

        def rates_of(x, edges=edges):
            q = np.zeros((6, 6))
            q[edges[:, 0], edges[:, 1]] = x
            return q - np.diag(q.sum(axis=1))

        def loss(x, counts=counts, lag=lag, rates_of=rates_of):
            return -_log_likelihood(counts, rates_of(x), lag) / counts.sum()

        best = minimize(loss, free[edges[:, 0], edges[:, 1]], method="trust-constr",
                        bounds=[(1e-6, None)] * len(edges),
                        # the balances sum to zero: one of them is left out.
                        constraints=[LinearConstraint(balance[:-1], 0.0, 0.0)],
                        options={"xtol": 1e-12, "gtol": 1e-12, "maxiter": 5000})
        assert np.abs(balance @ best.x).max() < 1e-8
        # held is at least as likely as the constrained optimum found the other way, and the
        # same network (trust-constr stops at a tolerance of its own: rates to 1e-4 of the
        # largest).
        assert _log_likelihood(counts, held, lag) >= _log_likelihood(
            counts, rates_of(best.x), lag) - 1e-9 * abs(_log_likelihood(counts, held, lag))
        np.testing.assert_allclose(rates_of(best.x), held, rtol=0,
                                   atol=1e-4 * np.abs(held).max())


def test_stationary_estimator_refuses_an_empty_cell_and_gives_intervals():
    counts, edges, lag = _sampled_counts(0)
    empty = counts.copy()
    empty[2] = empty[:, 2] = 0.0  # a cell no particle visits cannot be held
    both = rates_by_likelihood(np.stack([counts, empty]), lag, edges, stationary=True)
    np.testing.assert_array_equal(both[0], rates_by_likelihood(counts, lag, edges,
                                                               stationary=True))
    assert np.isnan(both[1]).all()
    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 2000, seed=3)
    learned = learn_network(sequences, N_CELLS, DT, 1, 100, n_bootstrap=20,
                            estimator="stationary")
    np.testing.assert_allclose(_steady(learned.rates), count_occupancy(learned.counts),
                               rtol=1e-9)
    assert np.isfinite(learned.lower).all() and learned.failed == 0
    with pytest.raises(ValueError, match="estimator must be one of"):
        learn_network(sequences, N_CELLS, DT, 1, 100, estimator="mle")
    # A cell no particle enters: said, not a network that cannot hold it.
    with pytest.raises(ValueError, match=f"cell.s. {N_CELLS} hold no particle"):
        learn_network(sequences, N_CELLS + 1, DT, 1, 100, n_bootstrap=0,
                      estimator="stationary")


def test_observed_edges_are_the_moves_from_frame_to_frame():
    sequences = np.array([[0, 1], [1, 1], [1, 2], [2, 0]])
    assert observed_edges(sequences, 3).tolist() == [[0, 1], [1, 2], [2, 0]]


def test_all_particles_tracked_give_the_exact_moves():
    # Tracking every particle, the counts are the engine's fixed moves: T = P exactly.
    network, connections, true = _ring()
    sequences = _tracked_sequences(network, 400, seed=1, tracked=HOLDUP)
    counts = count_matrix(sequences, N_CELLS, 1)
    np.testing.assert_allclose(counts / counts.sum(axis=1, keepdims=True),
                               network.step_matrix().T, atol=1e-12)


@pytest.mark.slow
def test_bootstrap_intervals_cover_known_rates_quick():
    # 20 repetitions x 12 rates; the full 100-repetition study is the opt-in test below. The
    # bounds are wide because the 240 intervals are correlated within a repetition; a wrong
    # truth (the first-order rates p / dt, 5 % off) or intervals without block structure
    # fall far outside them.
    hits = _coverage(20, 3000, 75)
    assert 0.85 <= hits.mean() <= 0.995


@pytest.mark.study
def test_bootstrap_intervals_cover_known_rates_study():
    hits = _coverage(100, 4000, 100)
    print(f"coverage of the 95 % intervals: {hits.mean():.4f} over {hits.size} intervals; "
          f"per rate {hits.mean(axis=0).min():.2f}-{hits.mean(axis=0).max():.2f}")
    assert 0.90 <= hits.mean() <= 0.99


def test_learned_network_file_round_trip_and_transport():
    network, _, true = _ring()
    sequences = _tracked_sequences(network, 2000, seed=5)
    dx = 0.02
    centres = (np.arange(N_CELLS) + 0.5) * dx
    learned = learn_network(sequences, N_CELLS, DT, 1, 100, centres=centres,
                            period=N_CELLS * dx)
    text = learned.network().to_json()
    again = CompartmentNetwork.from_json(text)
    assert again.compartments == learned.names and not again.is_discrete
    for c in again.connections:
        assert c.rate == pytest.approx(learned.rates[again.index(c.source), again.index(c.target)])
    # The particle engine runs the learned network as it is (hold-ups rounded to particles).
    particles = ParticleNetwork.from_network(again, total_particles=1200, time_step=DT,
                                             round_moves=True)
    assert abs(particles.n_particles - 1200) <= N_CELLS  # hold-ups rounded one by one
    # Equivalent ADM of the ring: near the exact chain (a - b) dx, (a + b) dx² / 2 (the
    # log rates include small two-cell jumps, so the comparison is with the true log rates).
    v, d = learned.transport()
    a, b = true[0, 1], true[0, N_CELLS - 1]
    v0, d0 = backflow_chain_transport(a, b, dx)
    (vlo, vhi), (dlo, dhi) = learned.transport_interval()
    assert vlo <= v <= vhi and dlo <= d <= dhi
    assert v == pytest.approx(v0, rel=0.15) and d == pytest.approx(d0, rel=0.15)


def test_markov_test_of_a_markov_chain_is_flat():
    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 3000, seed=2)
    test = markov_test(sequences, N_CELLS, DT, (1, 2, 4, 8), ck_steps=(2, 4))
    # Implied time scales of a Markov chain do not depend on the lag.
    np.testing.assert_allclose(test.timescales, np.broadcast_to(test.timescales[0],
                               test.timescales.shape), rtol=0.1)
    assert np.all(test.ck_error < 4 * test.ck_sampling + 1e-3)
    assert "Chapman-Kolmogorov" in test.report()
    # The spheres given as two runs of the same frames: the same counts, the same test.
    split = markov_test([sequences[:, :50], sequences[:, 50:]], N_CELLS, DT, (1, 2, 4, 8),
                        ck_steps=(2, 4))
    np.testing.assert_allclose(split.timescales, test.timescales, rtol=1e-10)
    np.testing.assert_allclose(split.ck_error, test.ck_error, rtol=1e-10, atol=1e-15)


def test_axial_cells_and_cell_length_rule():
    z = np.array([-0.01, 0.0, 0.049, 0.05, 0.499, 0.62])
    assert axial_cells(z, 0.5, 10).tolist() == [0, 0, 0, 1, 9, 9]
    assert axial_cells(z, 0.5, 10, periodic=True).tolist() == [9, 0, 0, 1, 9, 2]
    r = np.array([0.0, 0.07, 0.0, 0.08, 0.0, 0.1])
    cells = axial_cells(z, 0.5, 10, radius=r, vessel_radius=0.1, n_radial=2)
    assert cells.tolist() == [0, 0, 0, 3, 18, 19]  # (0.07/0.1)² < 0.5 < (0.08/0.1)²
    # 2 D_z / |v|: the trial's section, D_z 100 mm²/s, v -34 mm/s: about 6 mm cells.
    assert cell_length_limit(-0.034, 100e-6) == pytest.approx(2 * 100e-6 / 0.034)
    assert cell_length_limit(0.0, 1e-4) == float("inf")


def test_simulate_runs_a_learned_network_file_as_it_is(tmp_path, capsys):
    import json

    from fitting.cli import main

    network, _, _ = _ring()
    learned = learn_network(_tracked_sequences(network, 2000, seed=5), N_CELLS, DT, 1, 100)
    path = tmp_path / "network.json"
    learned.network().to_json(path)
    out = tmp_path / "run.json"
    assert main(["simulate", "network", str(path), "--particles", "6000", "--step", str(DT),
                 "--tracer", "C1", "--steps", "40", "--report-every", "20", "--seed", "3",
                 "--json", str(out), "--quiet"]) == 0
    assert "tracer in C1" in capsys.readouterr().out
    data = json.loads(out.read_text())
    # The mean field of the network the particles ran (hold-ups and moves rounded to whole
    # particles): n(t) = expm(K t) n(0), K from its per-step rates. Each count is a sum of
    # nearly independent moves, so it lies within a few binomial standard deviations.
    ran = ParticleNetwork.from_network(CompartmentNetwork.from_json(path), total_particles=6000,
                                       time_step=DT, round_moves=True).to_network()
    names = list(ran.compartments)
    generator = np.zeros((len(names), len(names)))
    for c in ran.connections:
        i, j = names.index(c.source), names.index(c.target)
        generator[j, i] += c.rate / DT
        generator[i, i] -= c.rate / DT
    start = np.asarray(data["reports"][0]["tracer_counts"], float)
    assert start[0] == data["tracer"]["particles"] and start[1:].sum() == 0
    last = data["reports"][-1]
    expected = scipy.linalg.expm(generator * last["time_s"]) @ start
    holdups = np.asarray(data["holdups"], float)
    spread = np.sqrt(expected * (1 - expected / holdups)) + 1.0
    assert np.all(np.abs(np.asarray(last["tracer_counts"]) - expected) <= 5 * spread)
    assert sum(last["tracer_counts"]) == data["tracer"]["particles"]  # conserved
    assert last["chi_square"] < data["reports"][0]["chi_square"]


def test_simulate_network_refuses_an_open_network_and_an_unknown_tracer(tmp_path, capsys):
    from fitting.cli import main

    open_network = tmp_path / "open.json"
    open_network.write_text(json_text({
        "compartments": [{"name": "a", "holdup": 10}, {"name": "b", "holdup": 10}],
        "connections": [{"source": "a", "target": "b", "rate": 1.0}],
        "inlets": [{"compartment": "a", "fraction": 1.0}],
        "outlets": [{"compartment": "b", "rate": 1.0}]}))
    assert main(["simulate", "network", str(open_network), "--quiet"]) == 2
    assert "runs closed networks" in capsys.readouterr().err
    network, _, _ = _ring()
    learned = learn_network(_tracked_sequences(network, 500, seed=1), N_CELLS, DT, 1, 50)
    closed = tmp_path / "closed.json"
    learned.network().to_json(closed)
    assert main(["simulate", "network", str(closed), "--tracer", "nowhere", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tracer: no compartment nowhere" in err[0]


def json_text(data):
    import json

    return json.dumps(data)


# Count matrices whose transition matrix has no accurate real logarithm (scipy's logm of
# each, exponentiated, misses the matrix by more than a tenth of its 1-norm).
NO_LOGARITHM = (
    [[2, 2, 0, 0], [1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]],
    [[1, 0, 0, 0], [2, 1, 0, 0], [0, 0, 0, 1], [0, 2, 0, 0]],
    [[0, 0, 1, 0], [2, 0, 2, 0], [0, 0, 1, 0], [0, 1, 0, 2]],
)


@pytest.mark.parametrize("counts", NO_LOGARITHM)
def test_a_matrix_without_an_accurate_logarithm_gives_no_rates(counts):
    counts = np.array(counts, float)
    transition = counts / counts.sum(axis=1, keepdims=True)
    log = np.real(scipy.linalg.logm(transition))
    error = np.linalg.norm(scipy.linalg.expm(log) - transition, 1)
    assert not error < 1e-1  # the premise: scipy's logarithm is far off (or not a number)
    rates, clipped = rates_from_counts(counts, 1.0)
    assert np.isnan(rates).all() and clipped == 0.0
    good = np.array([[9.0, 1, 0, 0], [1, 8, 1, 0], [0, 1, 8, 1], [0, 0, 1, 9]])
    batch, _ = rates_from_counts(np.stack([counts, good]), 1.0)
    assert np.isnan(batch[0]).all() and np.isfinite(batch[1]).all()
    np.testing.assert_allclose(batch[1], rates_from_counts(good, 1.0)[0], rtol=0, atol=1e-14)


def test_learning_refuses_a_run_without_a_rate_matrix_and_counts_failed_replicates():
    # Three frames of six particles whose moves give the first matrix's transition matrix.
    tracks = [(0, 0, 1), (1, 0, 0), (2, 1, 1), (3, 3, 3), (0, 1, 0), (2, 1, 1)]
    sequences = np.array(tracks).T
    counts, wanted = count_matrix(sequences, 4, 1), np.array(NO_LOGARITHM[0], float)
    np.testing.assert_array_equal(counts / counts.sum(axis=1, keepdims=True),
                                  wanted / wanted.sum(axis=1, keepdims=True))
    with pytest.raises(ValueError, match="no accurate real matrix logarithm"):
        learn_network(sequences, 4, 1.0, 1, 1, n_bootstrap=10)
    network, _, _ = _ring()
    learned = learn_network(_tracked_sequences(network, 600, seed=2), N_CELLS, DT, 1, 50,
                            n_bootstrap=50)
    assert learned.failed == 0 and learned.replicates.shape[0] == 50
    assert np.isfinite(learned.lower).all()


def test_too_few_replicates_give_the_rates_without_intervals():
    """Below MIN_REPLICATES the percentile limits would be the extreme replicates' own
    values: the rates (those of every bootstrap size) come without intervals."""
    from axialmix.dem import MIN_REPLICATES

    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 600, seed=2)
    enough = learn_network(sequences, N_CELLS, DT, 1, 50, n_bootstrap=MIN_REPLICATES)
    assert np.isfinite(enough.lower).all() and np.isfinite(enough.upper).all()
    for replicates in (0, 2, MIN_REPLICATES - 1):
        few = learn_network(sequences, N_CELLS, DT, 1, 50, n_bootstrap=replicates)
        np.testing.assert_array_equal(few.rates, enough.rates)
        assert few.replicates.shape[0] == replicates and few.failed == 0
        assert np.isnan(few.lower).all() and np.isnan(few.upper).all()
        assert all(np.isnan(interval).all() for interval in few.transport_interval())


@pytest.mark.parametrize("failing", [5, 20])
def test_replicates_without_rates_are_left_out_and_too_many_give_no_interval(monkeypatch,
                                                                            failing):
    # The first `failing` of 200 replicates are made to have no matrix logarithm.
    import axialmix.dem._learn as learn

    original = learn.rates_from_counts

    def some_fail(counts, lag_seconds):
        rates, clipped = original(counts, lag_seconds)
        if np.ndim(counts) == 3:
            rates = rates.copy()
            rates[:failing] = np.nan
        return rates, clipped

    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 600, seed=2)
    whole = learn_network(sequences, N_CELLS, DT, 1, 50, n_bootstrap=200)
    monkeypatch.setattr(learn, "rates_from_counts", some_fail)
    learned = learn_network(sequences, N_CELLS, DT, 1, 50, n_bootstrap=200)
    assert learned.failed == failing and learned.replicates.shape[0] == 200 - failing
    np.testing.assert_array_equal(learned.rates, whole.rates)
    np.testing.assert_array_equal(learned.replicates, whole.replicates[failing:])
    if failing <= learn.FAILED_SHARE * 200:
        np.testing.assert_array_equal(learned.lower,
                                      np.percentile(whole.replicates[failing:], 2.5, axis=0))
        assert np.isfinite(learned.upper).all()
    else:
        assert np.isnan(learned.lower).all() and np.isnan(learned.upper).all()
        assert all(np.isnan(interval).all() for interval in learned.transport_interval())


def test_markov_test_leaves_out_cells_no_particle_visits():
    """An extra cell that no sequence enters (a ring inside the shaft) leaves the implied
    time scales of the visited cells as they are, instead of a disconnected matrix."""
    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 3000, seed=2)
    alone = markov_test(sequences, N_CELLS, DT, (1, 2), ck_steps=(2,))
    padded = markov_test(sequences, N_CELLS + 1, DT, (1, 2), ck_steps=(2,))
    np.testing.assert_allclose(padded.timescales, alone.timescales, rtol=1e-12)
    np.testing.assert_allclose(padded.ck_error, alone.ck_error, rtol=1e-12)


def test_a_network_without_bootstrap_has_the_same_rates_and_no_interval():
    network, _, _ = _ring()
    sequences = _tracked_sequences(network, 2000, seed=3)
    for estimator in ("logm", "likelihood", "stationary"):
        full = learn_network(sequences, N_CELLS, DT, 1, 100, n_bootstrap=20,
                             estimator=estimator)
        bare = learn_network(sequences, N_CELLS, DT, 1, 100, n_bootstrap=0,
                             estimator=estimator)
        np.testing.assert_array_equal(bare.rates, full.rates)
        assert bare.replicates.shape == (0, N_CELLS, N_CELLS) and bare.failed == 0
        assert np.isnan(bare.lower).all() and np.isnan(bare.upper).all()
        assert np.isnan(np.concatenate(bare.transport_interval())).all()
        assert np.isfinite(full.lower).all()
    with pytest.raises(ValueError, match="n_bootstrap"):
        learn_network(sequences, N_CELLS, DT, 1, 100, n_bootstrap=-1)


def _lanes_network(n, dx, lanes, exchange):
    """A periodic two-lane chain: lane l moves forward at a_l and back at b_l between axial
    neighbours, and changes lane at `exchange` each way (cell index ``axial * 2 + lane``)."""
    from axialmix.dem import LearnedNetwork

    size = 2 * n
    rates = np.zeros((size, size))
    for i in range(n):
        for lane, (a, b) in enumerate(lanes):
            here = 2 * i + lane
            rates[here, 2 * ((i + 1) % n) + lane] += a
            rates[here, 2 * ((i - 1) % n) + lane] += b
            rates[here, 2 * i + 1 - lane] += exchange
    np.fill_diagonal(rates, -rates.sum(axis=1))
    centres = np.repeat((np.arange(n) + 0.5) * dx, 2)
    nan = np.full(rates.shape, np.nan)
    return LearnedNetwork(
        names=tuple(f"C{i}" for i in range(size)), rates=rates, lower=nan, upper=nan,
        replicates=np.zeros((0, size, size)), counts=np.zeros((size, size)), lag_seconds=1.0,
        lag_frames=1, holdups=np.ones(size), centres=centres,
        period=n * dx, clipped=0.0, blocks=1, block_seconds=1.0, failed=0)


def test_equivalent_adm_of_two_lanes_is_their_taylor_dispersion():
    """Two lanes of drift v_1, v_2 and dispersion D_1, D_2 exchanging at rate k each way: the
    long-time ADM is the mean drift and (D_1 + D_2)/2 + (v_1 - v_2)² / (8 k), exactly."""
    n, dx, k = 10, 0.01, 0.7
    lanes = [(9.0, 1.0), (2.0, 3.0)]
    learned = _lanes_network(n, dx, lanes, k)
    v, d = learned.transport()
    speeds = [(a - b) * dx for a, b in lanes]
    dispersions = [(a + b) * dx**2 / 2 for a, b in lanes]
    assert v == pytest.approx(np.mean(speeds), rel=1e-12)
    assert d == pytest.approx(np.mean(dispersions) + (speeds[0] - speeds[1]) ** 2 / (8 * k),
                              rel=1e-10)
    # Equal lanes: no Taylor term, the chain's own (a + b) dx² / 2.
    same = _lanes_network(n, dx, [(9.0, 1.0), (9.0, 1.0)], k)
    v_same, d_same = same.transport()
    assert v_same == pytest.approx(8.0 * dx, rel=1e-12)
    assert d_same == pytest.approx(5.0 * dx**2, rel=1e-10)


def test_equivalent_adm_matches_the_spread_of_the_unwrapped_network():
    """An independent check of the long-time formula: the variance growth of a particle on
    the network unwrapped over many periods (expm of the lifted chain), late in time."""
    import scipy.linalg

    n, dx, k = 6, 0.01, 0.5
    lanes = [(6.0, 1.0), (1.5, 2.0)]
    learned = _lanes_network(n, dx, lanes, k)
    v, d = learned.transport()
    copies = 40
    cells = 2 * n * copies
    lifted = np.zeros((cells, cells))
    for i in range(n * copies - 1):
        for lane, (a, b) in enumerate(lanes):
            lifted[2 * i + lane, 2 * (i + 1) + lane] = a
            lifted[2 * (i + 1) + lane, 2 * i + lane] = b
    for i in range(n * copies):
        lifted[2 * i, 2 * i + 1] = lifted[2 * i + 1, 2 * i] = k
    np.fill_diagonal(lifted, -lifted.sum(axis=1))
    z = np.repeat(np.arange(n * copies) * dx, 2)
    start = np.zeros(cells)
    middle = n * copies // 2
    start[2 * middle:2 * middle + 2] = 0.5  # both lanes (their stationary shares)
    moments = []
    for t in (6.0, 8.0):
        p = start @ scipy.linalg.expm(lifted * t)
        mean = p @ z
        moments.append((mean, p @ (z - mean) ** 2))
    (m1, s1), (m2, s2) = moments
    assert (m2 - m1) / 2.0 == pytest.approx(v, rel=1e-6)
    assert (s2 - s1) / (2 * 2.0) == pytest.approx(d, rel=1e-3)


def test_angular_sectors_and_equal_occupancy_edges():
    from axialmix.dem import equal_occupancy_sectors

    z = np.array([0.01, 0.01, 0.07, 0.07])
    angle = np.array([-3.0, 0.5, -1.0, 3.1])
    edges = np.array([-np.pi, -np.pi / 2, np.pi / 2, np.pi])
    assert axial_cells(z, 0.1, 2, angle=angle, sector_edges=edges).tolist() == [0, 1, 4, 5]
    r = np.array([0.09, 0.01, 0.09, 0.01])
    both = axial_cells(z, 0.1, 2, radius=r, vessel_radius=0.1, n_radial=2, angle=angle,
                       sector_edges=edges)
    assert both.tolist() == [(0 * 2 + 1) * 3 + 0, (0 * 2 + 0) * 3 + 1,
                             (1 * 2 + 1) * 3 + 1, (1 * 2 + 0) * 3 + 2]
    # A bed in the lower left quarter: equal shares, outer edges -pi and pi.
    rng = np.random.default_rng(1)
    bed = rng.uniform(-np.pi, -np.pi / 2, 40_000)
    quarters = equal_occupancy_sectors(bed, 4)
    assert quarters[0] == -np.pi and quarters[-1] == np.pi
    shares = np.bincount(axial_cells(np.zeros_like(bed), 1.0, 1, angle=bed,
                                     sector_edges=quarters), minlength=4) / bed.size
    np.testing.assert_allclose(shares, 0.25, atol=0.01)
    with pytest.raises(ValueError, match="rise strictly"):
        axial_cells(z, 0.1, 2, angle=angle, sector_edges=[-np.pi, 1.0, 0.5, np.pi])
    with pytest.raises(ValueError, match="need the angle"):
        axial_cells(z, 0.1, 2, sector_edges=edges)
    with pytest.raises(ValueError, match="distinct sectors"):
        equal_occupancy_sectors(np.zeros(10), 3)


def test_several_runs_learn_the_network_of_their_summed_counts():
    """Runs of the same cells given as a list: one network of their counts together.

    Invariant: the particles of one run split into two "runs" of the same frames count
    exactly the transitions of the whole run, so every estimator must give the whole run's
    network; two independent runs give the network of their summed counts (checked against
    the estimators called on those counts directly), and their bootstrap draws from the
    blocks of both.
    """
    network, _, _ = _ring()
    one = _tracked_sequences(network, 2000, seed=3, tracked=40)
    other = _tracked_sequences(network, 1500, seed=4, tracked=30)
    for estimator in ("logm", "likelihood", "stationary"):
        whole = learn_network(one, N_CELLS, DT, 2, 100, n_bootstrap=0, estimator=estimator)
        split = learn_network([one[:, :25], one[:, 25:]], N_CELLS, DT, 2, 100, n_bootstrap=0,
                              estimator=estimator)
        np.testing.assert_allclose(split.rates, whole.rates, rtol=1e-10, atol=1e-12)
        # Holdups are per run (the mean over every run's frames): two runs that share the
        # frames and split the spheres hold, on average, half of what the one run holds.
        np.testing.assert_allclose(split.holdups, whole.holdups / 2, rtol=1e-12)
        assert split.blocks == 2 * whole.blocks
    counts = count_matrix(one, N_CELLS, 2) + count_matrix(other, N_CELLS, 2)
    np.testing.assert_array_equal(count_matrix([one, other], N_CELLS, 2), counts)
    edges = observed_edges([one, other], N_CELLS)
    union = {tuple(e) for e in observed_edges(one, N_CELLS)} | {
        tuple(e) for e in observed_edges(other, N_CELLS)}
    assert {tuple(e) for e in edges} == union and len(edges) == len(union)
    # The network sees the transitions its bootstrap blocks cover: whole blocks of each run
    # (blocks never straddle two runs), 19 of run one's 1999 starts and 14 of the other's.
    blocks = block_count_matrices([one, other], N_CELLS, 2, 100)
    assert blocks.shape[0] == 19 + 14
    np.testing.assert_array_equal(blocks[:19], block_count_matrices(one, N_CELLS, 2, 100))
    np.testing.assert_array_equal(blocks[19:], block_count_matrices(other, N_CELLS, 2, 100))
    covered = blocks.sum(axis=0)
    both = learn_network([one, other], N_CELLS, DT, 2, 100, n_bootstrap=40,
                         estimator="likelihood")
    np.testing.assert_array_equal(both.counts, covered)
    np.testing.assert_allclose(both.rates, rates_by_likelihood(covered, 2 * DT, edges),
                               rtol=1e-10, atol=1e-12)
    assert both.blocks == 33 and np.isfinite(both.lower).all()
    logm = learn_network((one, other), N_CELLS, DT, 2, 100, n_bootstrap=0)
    np.testing.assert_allclose(logm.rates, rates_from_counts(covered, 2 * DT)[0], rtol=1e-12)
    with pytest.raises(ValueError, match=r"\(run 2 of 2\)"):
        learn_network([one, other[:, 0]], N_CELLS, DT, 2, 100)
    with pytest.raises(ValueError, match="no cell sequences"):
        learn_network([], N_CELLS, DT, 2, 100)
