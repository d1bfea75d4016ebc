"""Transport, tracer spreading, partitions and composition errors of recorded runs.

Recorded runs are built by hand here (a :class:`DEMRun` is plain arrays), so the expected
answers are known; the hybrid's conservation is checked on a small real DEM run.
"""

import numpy as np
import pytest

from axialmix.dem import (
    BladedMixer,
    DEMRun,
    PaddleSection,
    RunSettings,
    composition_errors,
    dem_available,
    dem_transport,
    flux_partition,
    independent_mean_error,
    learn_network,
    region_counts,
    repeat_floor,
    tracer_fractions,
    tracer_spreading,
    velocity_partition,
)
from axialmix.dem._learn import sequences_from_particle_events
from axialmix.particles import ParticleNetwork, simulate


def _run(geometry, positions, velocities=None, species=None, dt=0.01):
    frames, n, _ = positions.shape
    return DEMRun(
        geometry, RunSettings(), 1e-4, np.arange(frames) * dt, positions.astype(np.float32),
        np.zeros_like(positions, np.float32) if velocities is None
        else velocities.astype(np.float32),
        np.zeros(n, np.int64) if species is None else species, 0.0, frames,
    )


def test_dem_transport_recovers_drift_and_dispersion_of_brownian_tracks():
    rng = np.random.default_rng(4)
    v, d, dt, frames, n = -0.03, 1e-4, 0.01, 2000, 200
    steps = v * dt + np.sqrt(2 * d * dt) * rng.standard_normal((frames - 1, n))
    z = np.vstack([rng.uniform(0, 0.12, n), steps]).cumsum(axis=0)
    positions = np.stack([np.zeros_like(z), -0.05 * np.ones_like(z), z], axis=2)
    transport = dem_transport(_run(PaddleSection(), positions), lags=(0.05, 0.5),
                              blender_length=0.74)
    assert transport.velocity == pytest.approx(v, rel=0.05)
    assert transport.dispersion == pytest.approx(d, rel=0.1)
    np.testing.assert_allclose(transport.lag_dispersion, d, rtol=0.1)  # no memory: flat
    assert transport.peclet == pytest.approx(abs(transport.velocity) * 0.74
                                             / transport.dispersion)


def test_region_counts_and_partitions_find_the_active_regions():
    rng = np.random.default_rng(0)
    mixer = BladedMixer(particles=(50, 50))
    frames, n = 60, 100
    z = np.empty((frames, n))
    z[:, :50] = rng.uniform(0.0, 0.1, (frames, 50))  # species 0 jumps between regions 1-2
    z[:, 50:] = np.linspace(0.31, 0.49, 50)[None, :]  # species 1 at rest in regions 7-10
    positions = np.stack([np.zeros_like(z), -0.08 * np.ones_like(z), z], axis=2)
    velocities = np.zeros_like(positions)
    velocities[:, :50, 0] = rng.normal(0, 0.3, (frames, 50))
    run = _run(mixer, positions, velocities, np.repeat([0, 1], 50), dt=0.05)
    counts = region_counts(run, 10)
    assert counts.shape == (frames, 10, 2)
    assert np.all(counts.sum(axis=1) == [50, 50])
    assert np.all(counts[:, 2:, 0] == 0) and np.all(counts[:, :6, 1] == 0)
    flux = flux_partition(run, 10, interval=0.05)
    assert flux.dem_regions == (0, 1)
    assert np.all(flux.measure[6:] == 0)  # regions at rest have no flux
    velocity = velocity_partition(run, 10)
    assert velocity.dem_regions == (0, 1)
    assert velocity.score[0] == pytest.approx(0.09, rel=0.15)
    assert flux_partition(run, 10, interval=0.05, n_dem=1).dem_regions in ((0,), (1,))
    assert "DEM" in flux.table()


def test_composition_errors_by_hand():
    e = np.array([[10, 0], [20, 5], [30, 40]])
    h = np.array([[12, 0], [15, 5], [30, 44]])
    errors = composition_errors(e, h)
    expected = np.array([[20.0, np.nan], [25.0, 0.0], [0.0, 10.0]])
    np.testing.assert_allclose(errors.relative, expected)
    assert errors.average == pytest.approx(np.nanmean(expected))
    np.testing.assert_allclose(errors.variance, [(4 + 25) / 3, 16 / 3])


def test_noise_floor_of_a_run_without_sampling_noise_is_zero():
    from axialmix.dem import dem_noise_floor

    # Every sphere of a species in the same region at all frames: both halves agree exactly.
    mixer = BladedMixer(particles=(40, 40))
    z = np.concatenate([np.full(40, 0.02), np.full(40, 0.47)])
    positions = np.stack([np.zeros(80), np.full(80, -0.08), z], axis=1)[None].repeat(3, 0)
    run = _run(mixer, positions, species=np.repeat([0, 1], 40))
    floor = dem_noise_floor(run, 10)
    assert floor.average == 0 and np.all(floor.variance == 0)
    assert np.isnan(floor.relative[1:9]).all()  # regions without spheres


def test_tracer_spreading_of_a_markov_ring_is_at_the_noise_floor():
    # A ring with drift run by the identity engine; the network learned on the first half
    # predicts the second half's tracer about as well as an exact network would (ratio near
    # 1; the learned rates add their own estimation error).
    n, holdup = 8, 300
    sources, targets, moves = [], [], []
    for i in range(n):
        sources += [i, i]
        targets += [(i + 1) % n, (i - 1) % n]
        moves += [12, 6]
    ring = ParticleNetwork(np.full(n, holdup), sources, targets, moves, step_seconds=0.01)
    initial = np.column_stack([np.full(n, 200), np.full(n, 100)])
    ratios = []
    for seed in range(5):
        result = simulate(ring, initial, 2000, engine="identity", seed=seed,
                          tracked_species=[1])
        cells = sequences_from_particle_events(result, 1)
        learned = learn_network(cells[:1000], n, 0.01, 1, 100)
        spreading = tracer_spreading(cells, learned, 0.01, 1000, (10, 30, 60))
        assert spreading.dem.shape == spreading.predicted.shape == (3, n)
        np.testing.assert_allclose(spreading.dem.sum(axis=1), 1)
        np.testing.assert_allclose(spreading.predicted.sum(axis=1), 1)
        np.testing.assert_allclose(spreading.halves.sum(axis=2), 1)
        ratios.append(spreading.ratio)
    # The floor is calibrated: for a Markov process the error is the floor on average
    # (single runs spread by about 0.15 around it).
    assert 0.75 < np.mean(ratios) < 1.25 and max(ratios) < 1.5


@pytest.mark.skipif(not dem_available(), reason="the dem extra is not installed")
def test_hybrid_conserves_particles_and_species():
    from axialmix.dem import run_dem, run_hybrid
    from axialmix.dem._learn import axial_cells

    mixer = BladedMixer(particles=(150, 150), diameter=0.0082)
    settings = RunSettings(duration=0.6, record_interval=0.05, settle_time=0.2, seed=5)
    reference = run_dem(mixer, settings, progress=False)
    cells = axial_cells(reference.positions[:, :, 2], mixer.length, 10)
    learned = learn_network(cells, 10, reference.frame_interval, 1, 4)
    start = region_counts(reference, 10)[0]
    # Interface rates made large enough that identities are swapped in every interval.
    learned = type(learned)(**{**learned.__dict__,
                               "rates": learned.rates + 2 * (np.eye(10, k=1) + np.eye(10, k=-1))})
    hybrid = run_hybrid(mixer, learned, start, 4, settings, exchange_interval=0.1,
                        progress=False)
    assert hybrid.exchanged.sum() > 0
    # Exactly the same particles of each species, everywhere, at every record.
    np.testing.assert_array_equal(hybrid.counts.sum(axis=1),
                                  np.broadcast_to(start.sum(axis=0), hybrid.counts.shape[::2]))
    # The compartments keep their hold-ups; the DEM part keeps its spheres.
    np.testing.assert_array_equal(hybrid.counts[:, 4:].sum(axis=2),
                                  np.broadcast_to(start[4:].sum(axis=1), (hybrid.times.size, 6)))
    assert hybrid.compartment_cpu_seconds >= 0 and hybrid.dem_cpu_seconds > 0


def test_tracer_ratio_cannot_be_given_without_a_noise_floor():
    import warnings

    from axialmix.dem import TracerSpreading

    still = np.zeros((2, 3))
    spread = TracerSpreading(times=np.array([0.1, 0.2]), dem=still, predicted=still + 0.1,
                             halves=np.stack([still, still]), error=np.full(2, 0.1),
                             floor=np.zeros(2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(spread.ratio)
    moving = TracerSpreading(times=spread.times, dem=still, predicted=still,
                             halves=spread.halves, error=np.array([0.2, 0.4]),
                             floor=np.array([0.1, 0.1]))
    assert moving.ratio == pytest.approx(3.0, rel=1e-15)


def _ring_cells(seed: int, n: int = 8):
    sources, targets, moves = [], [], []
    for i in range(n):
        sources += [i, i]
        targets += [(i + 1) % n, (i - 1) % n]
        moves += [12, 6]
    ring = ParticleNetwork(np.full(n, 300), sources, targets, moves, step_seconds=0.01)
    initial = np.column_stack([np.full(n, 200), np.full(n, 100)])
    result = simulate(ring, initial, 2000, engine="identity", seed=seed, tracked_species=[1])
    return sequences_from_particle_events(result, 1)


def test_floor_of_two_independent_runs_is_the_sampling_floor_without_shared_motion():
    """Particles that move independently share nothing: the floor of two independent runs
    (repeat_floor) is then the floor of two halves of one run's tracer, on average."""
    n = 8
    ratios = []
    for seed in range(0, 8, 2):
        first, second = _ring_cells(seed), _ring_cells(seed + 1)
        learned = learn_network(first[:1000], n, 0.01, 1, 100, n_bootstrap=0)
        a = tracer_spreading(first, learned, 0.01, 1000, (10, 30, 60))
        b = tracer_spreading(second, learned, 0.01, 1000, (10, 30, 60))
        floor = repeat_floor(a, b)
        assert floor.shape == (3,) and np.all(floor > 0)
        ratios.append(floor.mean() / a.floor.mean())
    assert 0.7 < np.mean(ratios) < 1.4, ratios


@pytest.mark.skipif(not dem_available(), reason="the dem extra is not installed")
def test_repeat_floor_by_hand_and_its_refusals():
    from axialmix.dem import TracerSpreading

    times = np.array([0.1, 0.2])
    base = np.array([[0.5, 0.3, 0.2], [0.4, 0.4, 0.2]])

    def spreading(dem, t=times):
        return TracerSpreading(times=t, dem=dem, predicted=dem, halves=np.stack([dem, dem]),
                               error=np.zeros(len(t)), floor=np.ones(len(t)))

    shifted = base + np.array([[0.03, -0.03, 0.0], [0.06, 0.0, -0.06]])
    np.testing.assert_allclose(repeat_floor(spreading(base), spreading(shifted)),
                               [0.02 / np.sqrt(2), 0.04 / np.sqrt(2)], rtol=1e-12)
    np.testing.assert_array_equal(repeat_floor(spreading(base), spreading(base)), [0.0, 0.0])
    # Several measurements: the mean over their pairs.
    third = base - np.array([[0.03, -0.03, 0.0], [0.0, 0.0, 0.0]])
    pairs = [[0.02, 0.04], [0.02, 0.0], [0.04, 0.04]]
    np.testing.assert_allclose(
        repeat_floor(spreading(base), spreading(shifted), spreading(third)),
        np.mean(pairs, axis=0) / np.sqrt(2), rtol=1e-12)
    with pytest.raises(ValueError, match="two"):
        repeat_floor(spreading(base))
    with pytest.raises(ValueError, match="share"):
        repeat_floor(spreading(base), spreading(base[:, :2]))
    with pytest.raises(ValueError, match="share"):
        repeat_floor(spreading(base), spreading(base, times * 2))


def test_sub_cells_that_are_markov_predict_the_layers_the_lumped_layers_do_not():
    # Two lanes per axial layer, one fast and one slow, exchanging slowly: the lanes'
    # network (two cells per layer) is Markov and predicts the tracer's spread over the layers
    # at the noise floor; the same spheres counted by layer alone have memory (a sphere in the
    # fast lane stays fast for a while), and the layers' network misses by far more.
    layers, holdup = 8, 300
    sources, targets, moves = [], [], []
    for a in range(layers):
        for lane, (forward, backward) in enumerate(((24, 2), (2, 2))):
            i = 2 * a + lane
            sources += [i, i]
            targets += [2 * ((a + 1) % layers) + lane, 2 * ((a - 1) % layers) + lane]
            moves += [forward, backward]
        sources += [2 * a, 2 * a + 1]
        targets += [2 * a + 1, 2 * a]
        moves += [3, 3]
    lanes = ParticleNetwork(np.full(2 * layers, holdup), sources, targets, moves,
                            step_seconds=0.01)
    initial = np.column_stack([np.full(2 * layers, 200), np.full(2 * layers, 100)])
    starts, delays = np.arange(1000, 1900, 10), (10, 30, 60)
    by_lane, by_layer = [], []
    for seed in range(4):
        result = simulate(lanes, initial, 2000, engine="identity", seed=seed,
                          tracked_species=[1])
        cells = sequences_from_particle_events(result, 1)
        learned = learn_network(cells[:1000], 2 * layers, 0.01, 1, 100, n_bootstrap=0,
                                estimator="likelihood")
        spreading = tracer_spreading(cells, learned, 0.01, starts, delays, cells_per_layer=2)
        assert spreading.predicted.shape == (3, layers)
        np.testing.assert_allclose(spreading.predicted.sum(axis=1), 1)
        by_lane.append(spreading.ratio)
        lumped = learn_network(cells[:1000] // 2, layers, 0.01, 1, 100, n_bootstrap=0,
                               estimator="likelihood")
        by_layer.append(tracer_spreading(cells // 2, lumped, 0.01, starts, delays).ratio)
    assert 0.6 < np.mean(by_lane) < 1.5
    assert min(by_layer) > 5 * max(by_lane)
    with pytest.raises(ValueError, match="layers of 3"):
        tracer_spreading(cells, learned, 0.01, starts, delays, cells_per_layer=3)


def test_cells_of_run_numbers_layers_rings_and_sectors():
    from axialmix.dem import cells_of_run

    # Four spheres at fixed places in a periodic section: angles -3pi/4, -pi/4 (the bed),
    # pi/2 (above the shaft) and -0.4 pi near the axis; two frames.
    section = PaddleSection()
    angles = np.array([-0.75 * np.pi, -0.25 * np.pi, 0.5 * np.pi, -0.4 * np.pi])
    radii = np.array([0.9, 0.9, 0.9, 0.1]) * section.radius
    z = np.array([0.1, 0.6, 1.1, 1.6]) * section.length / 2  # layers 0, 0, 1, 1 of 2
    positions = np.stack([radii * np.cos(angles), radii * np.sin(angles), z], axis=1)
    run = _run(section, positions[None].repeat(2, axis=0))
    edges = np.array([-np.pi, -0.5 * np.pi, 0.0, np.pi])
    layout = cells_of_run(run, 2, n_radial=2, sector_edges=edges)
    assert layout.n_sectors == 3 and layout.per_layer == 6 and layout.n_cells == 12
    # (axial * rings + ring) * sectors + sector
    assert layout.cells[0].tolist() == [(0 * 2 + 1) * 3 + 0, (0 * 2 + 1) * 3 + 1,
                                        (1 * 2 + 1) * 3 + 2, (1 * 2 + 0) * 3 + 1]
    assert layout.names[:4] == ("z1r1s1", "z1r1s2", "z1r1s3", "z1r2s1")
    np.testing.assert_allclose(layout.centres, np.repeat([0.25, 0.75], 6) * section.length)
    # Equal-occupancy sectors from the run's own angles: each of the two holds two spheres.
    own = cells_of_run(run, 1, n_sectors=2)
    assert np.bincount(own.cells[0], minlength=2).tolist() == [2, 2]
    for bad in ({"n_sectors": 0}, {"n_radial": 0}):
        with pytest.raises(ValueError, match="positive whole number"):
            cells_of_run(run, 2, **bad)


def test_tracer_fractions_by_hand():
    # Frames x spheres of axial cells; the tracer: spheres in cell 0 at the start.
    axial = np.array([[0, 0, 1, 2],
                      [1, 0, 1, 2],
                      [2, 1, 0, 0],
                      [0, 0, 0, 0]])
    np.testing.assert_array_equal(tracer_fractions(axial, 3, 0, (1, 2)),
                                  [[0.5, 0.5, 0.0], [0.0, 0.5, 0.5]])
    # Two starts: frame 0 (spheres 0, 1) and frame 2 (spheres 2, 3), one frame later.
    np.testing.assert_array_equal(tracer_fractions(axial, 3, [0, 2], (1,)),
                                  [[(0.5 + 1.0) / 2, 0.5 / 2, 0.0]])
    np.testing.assert_array_equal(tracer_fractions(axial, 3, 0, (1,), mask=np.array(
        [False, True, True, True])), [[1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="runs past"):
        tracer_fractions(axial, 3, 2, (2,))
    with pytest.raises(ValueError, match="no tracer sphere"):
        tracer_fractions(axial, 3, 1, (1,), mask=np.array([True, False, True, True]))


def test_independent_mean_error_by_hand_and_its_expected_size():
    from axialmix.dem import TracerSpreading

    times = np.array([0.1, 0.2])

    def spreading(dem, t=times):
        return TracerSpreading(times=t, dem=dem, predicted=dem, halves=np.stack([dem, dem]),
                               error=np.zeros(len(t)), floor=np.ones(len(t)))

    base = np.array([[0.5, 0.3, 0.2], [0.4, 0.4, 0.2]])
    up = base + np.array([[0.06, -0.06, 0.0], [0.0, 0.03, -0.03]])
    down = base - np.array([[0.0, 0.0, 0.0], [0.0, 0.03, -0.03]])
    # The others' mean is base + [[0.03, -0.03, 0], [0, 0, 0]].
    np.testing.assert_allclose(independent_mean_error(spreading(base), spreading(up),
                                                      spreading(down)),
                               [0.02, 0.0], atol=1e-15)
    with pytest.raises(ValueError, match="at least one"):
        independent_mean_error(spreading(base))
    with pytest.raises(ValueError, match="share"):
        independent_mean_error(spreading(base), spreading(base, times * 2))
    # Independent Markov runs share nothing beyond their sampling noise: the others' mean
    # misses each run by sqrt(1 + 1/m) times the floor of independent runs, on average.
    n = 8
    runs = [_ring_cells(seed) for seed in range(20, 28)]
    learned = learn_network(runs[0][:1000], n, 0.01, 1, 100, n_bootstrap=0)
    tracers = [tracer_spreading(cells, learned, 0.01, np.arange(1000, 1900, 50),
                                (10, 30, 60)) for cells in runs]
    floor = repeat_floor(*tracers).mean()
    ratios = [independent_mean_error(t, *(tracers[:k] + tracers[k + 1:])).mean() / floor
              for k, t in enumerate(tracers)]
    expected = np.sqrt(1 + 1 / 7)
    assert abs(np.mean(ratios) / expected - 1) < 0.15, (np.mean(ratios), ratios)
