"""Tests of PEPT trajectory analysis (MODELS.md section 5) against known synthetic truth."""

import math

import numpy as np
import pytest

from axialmix.trajectories import (
    Trajectory,
    analyse_trajectories,
    axial_dispersion,
    expected_noisy_path_length,
    helix_polyline_length,
    mean_square_displacement,
    path_length,
    pooled_mean_square_displacement,
    read_trajectories,
    synthetic_trajectories,
    zone_residence_times,
)

BLENDER_LENGTH = 0.31  # m, blender 2 of the source work
PEPT_TIME_STEP = 0.0169  # s
SOURCE_TIME_STEPS = (0.0169, 0.0336, 0.0472)  # s, compared by the source work
MEASUREMENT_NOISE = 0.0005  # m, PEPT location error per coordinate
TRACKED_TIME = 2800.0  # s of trajectory per case: ~166,000 samples

# (D_z in mm²/s, mean residence time L/v in s): the blender-2 range, D_z 10-200 mm²/s,
# residence 7-140 s, Pe = L²/(D_z tau) from 8 to 137.
BLENDER_2_CASES = [
    (10.0, 140.0),  # 16 RPM: Pe 69
    (10.0, BLENDER_LENGTH**2 / (137 * 10e-6)),  # Pe 137
    (50.0, 40.0),  # Pe 48
    (100.0, 15.0),  # Pe 64
    (170.0, 7.0),  # 300 RPM: Pe 81
    (200.0, BLENDER_LENGTH**2 / (8 * 200e-6)),  # Pe 8
]


def _case_id(case):
    return f"D{case[0]:.0f}mm2s-tau{case[1]:.0f}s"


@pytest.mark.parametrize("case", BLENDER_2_CASES, ids=_case_id)
def test_axial_dispersion_recovers_known_coefficient_across_blender_2_range(case):
    dispersion = case[0] * 1e-6
    mean_residence_time = case[1]
    n_trajectories = math.ceil(TRACKED_TIME / mean_residence_time)
    trajectories = synthetic_trajectories(
        n_trajectories,
        axial_velocity=BLENDER_LENGTH / mean_residence_time,
        dispersion_coefficient=dispersion,
        blender_length=BLENDER_LENGTH,
        boundary="entry_exit",
        position_noise=MEASUREMENT_NOISE,
        seed=11,
    )
    summary = analyse_trajectories(trajectories, BLENDER_LENGTH)
    mean_error = summary.mean_dispersion_coefficient / dispersion - 1
    pooled_error = summary.pooled_dispersion.dispersion_coefficient / dispersion - 1
    standard_error = summary.dispersion_standard_error / dispersion
    print(
        f"D_z {case[0]:.0f} mm²/s, tau {mean_residence_time:.1f} s, {n_trajectories} "
        f"trajectories: mean error {mean_error:+.4f} (standard error {standard_error:.4f}), "
        f"pooled error {pooled_error:+.4f}, window {summary.pooled_dispersion.window_start:.4f}"
        f"-{summary.pooled_dispersion.window_end:.4f} s, Pe {summary.peclet:.1f}"
    )
    # The statistical error must be well below the 5 % claim for the test to mean anything.
    assert standard_error < 0.015
    assert summary.pooled_dispersion.window_is_flat
    assert abs(mean_error) < 0.05
    assert abs(pooled_error) < 0.05


@pytest.mark.parametrize("case", [BLENDER_2_CASES[0], BLENDER_2_CASES[4]], ids=_case_id)
def test_window_selection_skips_short_time_ballistic_regime(case):
    dispersion = case[0] * 1e-6
    mean_residence_time = case[1]
    ballistic_fraction, ballistic_time = 0.3, 0.05
    trajectories = synthetic_trajectories(
        math.ceil(3 * TRACKED_TIME / mean_residence_time),
        axial_velocity=BLENDER_LENGTH / mean_residence_time,
        dispersion_coefficient=dispersion,
        boundary="free",
        duration=mean_residence_time,
        ballistic_fraction=ballistic_fraction,
        ballistic_time=ballistic_time,
        position_noise=MEASUREMENT_NOISE,
        seed=5,
    )
    summary = analyse_trajectories(trajectories, BLENDER_LENGTH)
    window = summary.pooled_dispersion
    first_lags = (PEPT_TIME_STEP, 4 * PEPT_TIME_STEP)
    naive = np.mean(
        [axial_dispersion(tr, window=first_lags).dispersion_coefficient for tr in trajectories]
    )
    # Independent prediction of the naive estimate: least-squares slope of the exact MSD
    # 2 D t - 2 f D tau_b (1 - exp(-t/tau_b)) over the same first four lags.
    lags = PEPT_TIME_STEP * np.arange(1, 5)
    exact_msd = _ballistic_msd(lags, dispersion, ballistic_fraction, ballistic_time)
    predicted_naive = np.polyfit(lags, exact_msd, 1)[0] / 2
    error = summary.mean_dispersion_coefficient / dispersion - 1
    print(
        f"D_z {case[0]:.0f} mm²/s with ballistic part: automatic window "
        f"{window.window_start:.4f}-{window.window_end:.4f} s error {error:+.4f} "
        f"(standard error {summary.dispersion_standard_error / dispersion:.4f}); "
        f"first-lags window error {naive / dispersion - 1:+.4f} "
        f"(predicted {predicted_naive / dispersion - 1:+.4f})"
    )
    assert summary.dispersion_standard_error / dispersion < 0.015
    assert window.window_start > ballistic_time
    assert abs(error) < 0.05
    assert naive / dispersion - 1 < -0.10
    assert naive == pytest.approx(predicted_naive, rel=0.03)


def _ballistic_msd(lags, dispersion, ballistic_fraction, ballistic_time):
    """Exact MSD of Brownian motion plus an integrated Ornstein-Uhlenbeck velocity."""
    return 2 * dispersion * lags - 2 * ballistic_fraction * dispersion * ballistic_time * (
        1 - np.exp(-lags / ballistic_time)
    )


def test_synthetic_ballistic_motion_has_exact_mean_square_displacement():
    dispersion, ballistic_fraction, ballistic_time = 5e-5, 0.3, 0.05
    trajectories = synthetic_trajectories(
        100, axial_velocity=0.01, dispersion_coefficient=dispersion, boundary="free",
        duration=80.0, ballistic_fraction=ballistic_fraction, ballistic_time=ballistic_time,
        seed=12,
    )
    msd = pooled_mean_square_displacement(trajectories)
    exact = _ballistic_msd(msd.lag_time, dispersion, ballistic_fraction, ballistic_time)
    # About 470,000 samples: the relative statistical error is about sqrt(4k / 3N) at lag k,
    # 0.2 % at the first lag and 0.7 % at lag 16.
    np.testing.assert_allclose(msd.msd[:16], exact[:16], rtol=0.02)
    assert msd.msd[0] / exact[0] == pytest.approx(1.0, abs=0.01)


def test_single_long_trajectory_window_skips_ballistic_regime():
    dispersion, ballistic_time = 5e-5, 0.05
    (trajectory,) = synthetic_trajectories(
        1, axial_velocity=0.01, dispersion_coefficient=dispersion, boundary="free",
        duration=TRACKED_TIME, ballistic_fraction=0.3, ballistic_time=ballistic_time,
        position_noise=MEASUREMENT_NOISE, seed=13,
    )
    fit = axial_dispersion(trajectory)
    print(
        f"single {TRACKED_TIME:.0f} s trajectory: D_z error "
        f"{fit.dispersion_coefficient / dispersion - 1:+.4f}, window "
        f"{fit.window_start:.4f}-{fit.window_end:.4f} s"
    )
    assert fit.window_is_flat
    assert fit.window_start > ballistic_time
    assert fit.dispersion_coefficient == pytest.approx(dispersion, rel=0.05)


def test_mean_square_displacement_matches_direct_sum_with_bridge_correction():
    (trajectory,) = synthetic_trajectories(
        1, axial_velocity=0.005, dispersion_coefficient=5e-5, boundary="free", duration=20.0,
        position_noise=MEASUREMENT_NOISE, seed=2,
    )
    msd = mean_square_displacement(trajectory)
    z, t = trajectory.z, trajectory.time
    total = t[-1] - t[0]
    drift = (z[-1] - z[0]) / total
    direct = []
    for k in range(1, msd.lag_time.size + 1):
        displacement = z[k:] - z[:-k] - drift * (t[k:] - t[:-k])
        direct.append(np.mean(displacement**2) / (1 - k * PEPT_TIME_STEP / total))
    np.testing.assert_allclose(msd.msd, direct, rtol=1e-9)
    assert msd.lag_time[-1] <= total / 10 + 1e-12

    # Slightly irregular sampling takes the pair-by-pair path; it must agree.
    jittered = Trajectory(
        time=t + np.random.default_rng(0).uniform(-1e-7, 1e-7, t.size),
        x=trajectory.x, y=trajectory.y, z=z,
    )
    np.testing.assert_allclose(mean_square_displacement(jittered).msd, msd.msd, rtol=1e-4)


def test_bridge_correction_removes_drift_estimation_bias_at_long_lags():
    dispersion = 1e-4
    trajectories = synthetic_trajectories(
        2000, axial_velocity=0.02, dispersion_coefficient=dispersion, boundary="free",
        duration=200 * PEPT_TIME_STEP, seed=3,
    )
    msd = pooled_mean_square_displacement(trajectories)
    ratio = msd.msd[-1] / (2 * dispersion * msd.lag_time[-1])
    # At the largest lag (T/10) the uncorrected MSD would be 0.9 of 2 D dt; the statistical
    # error of the ratio is about 0.01 here.
    assert msd.lag_time[-1] == pytest.approx(20 * PEPT_TIME_STEP)
    assert ratio == pytest.approx(1.0, abs=0.03)


def test_zone_residence_times_match_hand_computed_piecewise_path():
    trajectory = Trajectory(
        time=np.array([0.0, 1.0, 2.0, 3.0]),
        x=np.zeros(4), y=np.zeros(4),
        z=np.array([0.0, 0.1, 0.05, 0.31]),
    )
    zone = BLENDER_LENGTH / 5
    expected = np.zeros(5)
    expected[0] += zone / 0.1 + (zone - 0.05) / 0.05 + (zone - 0.05) / 0.26
    expected[1] += (0.1 - zone) / 0.1 + (0.1 - zone) / 0.05 + zone / 0.26
    expected[2:] += zone / 0.26
    np.testing.assert_allclose(zone_residence_times(trajectory, BLENDER_LENGTH), expected,
                               rtol=1e-12)


def test_zone_residence_times_sum_to_residence_time():
    trajectories = synthetic_trajectories(
        30, axial_velocity=BLENDER_LENGTH / 20.0, dispersion_coefficient=6e-4,
        position_noise=MEASUREMENT_NOISE, seed=4,
    )
    summary = analyse_trajectories(trajectories, BLENDER_LENGTH, n_zones=5)
    for analysis in summary.analyses:
        assert analysis.zone_residence_times.shape == (5,)
        assert np.all(analysis.zone_residence_times >= 0)
        assert analysis.zone_residence_times.sum() == pytest.approx(
            analysis.residence_time, rel=1e-12
        )
    assert summary.mean_zone_residence_times.sum() == pytest.approx(summary.mean_residence_time)
    assert summary.peclet == pytest.approx(
        summary.mean_axial_velocity * BLENDER_LENGTH
        / summary.pooled_dispersion.dispersion_coefficient
    )
    assert "Peclet" in summary.report()


def test_trajectory_too_short_for_pooled_window_is_left_out_of_mean_dispersion():
    long_trajectories = synthetic_trajectories(
        20, axial_velocity=0.01, dispersion_coefficient=5e-5, boundary="free", duration=30.0,
        ballistic_fraction=0.3, ballistic_time=0.05, seed=14,
    )
    short = Trajectory(
        time=PEPT_TIME_STEP * np.arange(30), x=np.zeros(30), y=np.zeros(30),
        z=0.001 * np.arange(30), trajectory_id="short",
    )
    summary = analyse_trajectories([*long_trajectories, short], BLENDER_LENGTH)
    # The short trajectory's largest lag, T/10 = 0.049 s, lies below the window start.
    assert summary.pooled_dispersion.window_start > short.duration / 10
    assert math.isnan(summary.analyses[-1].dispersion.dispersion_coefficient)
    assert math.isnan(summary.analyses[-1].peclet)
    assert summary.n_dispersion_fits == 20
    fitted = [a.dispersion.dispersion_coefficient for a in summary.analyses[:-1]]
    assert summary.mean_dispersion_coefficient == pytest.approx(np.mean(fitted))
    assert summary.analyses[-1].residence_time == pytest.approx(29 * PEPT_TIME_STEP)


def test_reflecting_motion_spends_zone_times_of_exponential_stationary_profile():
    peclet, dispersion = 2.0, 2e-3
    trajectories = synthetic_trajectories(
        40, axial_velocity=peclet * dispersion / BLENDER_LENGTH,
        dispersion_coefficient=dispersion, boundary="reflecting", duration=550.0, seed=15,
    )
    # Drop the first 50 s (about ten relaxation times L²/(π² D)) of the uniform start.
    k = int(50.0 / PEPT_TIME_STEP)
    settled = [
        Trajectory(time=tr.time[k:], x=tr.x[k:], y=tr.y[k:], z=tr.z[k:]) for tr in trajectories
    ]
    assert all(np.all((tr.z >= 0) & (tr.z <= BLENDER_LENGTH)) for tr in trajectories)
    fractions = np.array(
        [zone_residence_times(tr, BLENDER_LENGTH) / tr.duration for tr in settled]
    )
    # Stationary density of drift-diffusion between reflecting walls: ∝ exp(Pe z / L).
    edges = np.linspace(0.0, 1.0, 6)
    expected = np.diff(np.exp(peclet * edges)) / (math.exp(peclet) - 1)
    standard_error = fractions.std(axis=0, ddof=1) / math.sqrt(len(settled))
    assert np.all(np.abs(fractions.mean(axis=0) - expected) < 4 * standard_error)


def test_entry_exit_mean_residence_time_matches_first_passage_formula():
    velocity, peclet = BLENDER_LENGTH / 7.0, 8.0
    dispersion = velocity * BLENDER_LENGTH / peclet
    trajectories = synthetic_trajectories(
        3000, axial_velocity=velocity, dispersion_coefficient=dispersion, seed=6
    )
    times = np.array([tr.duration for tr in trajectories])
    assert all(tr.z[0] == 0 and tr.z[-1] >= BLENDER_LENGTH for tr in trajectories)
    assert all(np.all(tr.z[:-1] < BLENDER_LENGTH) for tr in trajectories)
    expected = BLENDER_LENGTH / velocity - dispersion / velocity**2 * (1 - math.exp(-peclet))
    # Exit is checked only at samples: the overshoot is about 0.58 sqrt(2 D h) / v
    # (Broadie-Glasserman-Kou continuity correction), on top of the statistical error.
    overshoot = 0.5826 * math.sqrt(2 * dispersion * PEPT_TIME_STEP) / velocity
    standard_error = times.std(ddof=1) / math.sqrt(times.size)
    assert abs(times.mean() - expected - overshoot) < 4 * standard_error


def test_path_length_of_noise_free_spiral_matches_helix_chords_and_arc_length():
    rpm, radius, velocity, duration = 200.0, 0.02, 0.01, 10.0
    angular_speed = 2 * math.pi * rpm / 60
    (fine,) = synthetic_trajectories(
        1, axial_velocity=velocity, dispersion_coefficient=0.0, boundary="free",
        duration=duration, time_step=PEPT_TIME_STEP / 20, impeller_speed_rpm=rpm,
        spiral_radius=radius, seed=7,
    )
    arc_length = duration * math.hypot(radius * angular_speed, velocity)
    assert path_length(fine) == pytest.approx(arc_length, rel=1e-4)
    lengths = []
    for step in SOURCE_TIME_STEPS:
        coarse_steps = math.floor(duration / step * (1 + 1e-12))
        measured = path_length(fine, time_step=step) * duration / (coarse_steps * step)
        exact = helix_polyline_length(coarse_steps * step, step, radius, angular_speed, velocity)
        exact *= duration / (coarse_steps * step)
        print(
            f"noise-free spiral, step {step} s: path {measured:.5f} m, helix chords "
            f"{exact:.5f} m, arc {arc_length:.5f} m"
        )
        # Resampled vertices lie on chords of the fine polyline, within r (omega h_fine)²/8
        # of the helix: a relative error below 1e-4.
        assert measured == pytest.approx(exact, rel=1e-4)
        lengths.append(measured)
    assert arc_length > lengths[0] > lengths[1] > lengths[2]


def test_path_length_with_noise_decreases_with_time_step_as_expected():
    rpm, radius, velocity, duration = 200.0, 0.02, 0.01, 20.0
    angular_speed = 2 * math.pi * rpm / 60
    means = []
    for step in SOURCE_TIME_STEPS:
        trajectories = synthetic_trajectories(
            20, axial_velocity=velocity, dispersion_coefficient=0.0, boundary="free",
            duration=duration, time_step=step, impeller_speed_rpm=rpm, spiral_radius=radius,
            position_noise=MEASUREMENT_NOISE, seed=8,
        )
        lengths = np.array([path_length(tr) for tr in trajectories])
        n_steps = trajectories[0].n_points - 1
        chord = math.hypot(2 * radius * math.sin(angular_speed * step / 2), velocity * step)
        expected = expected_noisy_path_length(chord, MEASUREMENT_NOISE, n_steps)
        standard_error = lengths.std(ddof=1) / math.sqrt(lengths.size)
        print(
            f"spiral + noise, step {step} s: path {lengths.mean():.4f} m "
            f"(expected {expected:.4f} m, noise-free chords {n_steps * chord:.4f} m)"
        )
        assert abs(lengths.mean() - expected) < 4 * standard_error
        means.append(lengths.mean())
    assert means[0] > means[1] > means[2]

    # Coarsening recorded data by keeping the nearest samples shows the same trend.
    (recorded,) = synthetic_trajectories(
        1, axial_velocity=velocity, dispersion_coefficient=0.0, boundary="free",
        duration=duration, time_step=SOURCE_TIME_STEPS[0], impeller_speed_rpm=rpm,
        spiral_radius=radius, position_noise=MEASUREMENT_NOISE, seed=9,
    )
    coarsened = [path_length(recorded, step, method="nearest") for step in SOURCE_TIME_STEPS]
    assert coarsened[0] == pytest.approx(path_length(recorded))
    assert coarsened[0] > coarsened[1] > coarsened[2]


# ----------------------------------------------------------------------------- files


def _write(tmp_path, text, name="track.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_read_trajectories_groups_ids_and_converts_millimetres(tmp_path):
    path = _write(
        tmp_path,
        "# PEPT export\nTime (s),X (mm),Y (mm),Z (mm),track\n"
        "0.0,1,2,0,a\n0.0,5,5,0,b\n0.1,1,2,10,a\n0.1,5,5,20,b\n0.2,1,2,30,a\n0.2,5,5,40,b\n",
    )
    trajectories = read_trajectories(path)
    assert [tr.trajectory_id for tr in trajectories] == ["a", "b"]
    np.testing.assert_allclose(trajectories[0].z, [0.0, 0.01, 0.03])
    np.testing.assert_allclose(trajectories[1].x, [0.005] * 3)
    with pytest.raises(ValueError, match="header states length unit 'mm'"):
        read_trajectories(path, length_unit="m")

    plain = _write(tmp_path, "t;x;y;z\n0;0;0;0\n1;0;0;5\n2;0;0;7\n", "plain.csv")
    (single,) = read_trajectories(plain, length_unit="mm")
    assert single.trajectory_id == "plain"
    np.testing.assert_allclose(single.z, [0.0, 0.005, 0.007])
    (metres,) = read_trajectories(plain)
    np.testing.assert_allclose(metres.z, [0.0, 5.0, 7.0])

    spaced = _write(tmp_path, "T  X_mm  Y_mm  Z_mm\n0 0 0 0\n1 0 0 5\n2 0 0 7\n", "spaced.txt")
    np.testing.assert_allclose(read_trajectories(spaced)[0].z, [0.0, 0.005, 0.007])


@pytest.mark.parametrize(
    ("text", "row", "problem"),
    [
        ("t,x,y\n0,0,0\n", 1, "missing column(s) z"),
        ("t,x,y,z\n0,0,0,0\n1,0,abc,1\n2,0,0,2\n", 3, "non-numeric cell 'abc' in column 'y'"),
        ("t,x,y,z\n0,0,0,0\n1,0,0,nan\n2,0,0,2\n", 3, "NaN in column 'z'"),
        ("t,x,y,z\n0,0,0,0\n1,0,0,1\n1,0,0,2\n", 4, "is not greater than the previous time"),
        ("t,x,y,z,id\n0,0,0,0,a\n1,0,0,1,a\n0,0,0,0,b\n2,0,0,2,a\n", 4, "has 1 point(s)"),
        ("t,x,y,z\n0,0,0,0\n1,0,,1\n2,0,0,2\n", 3, "empty cell in column 'y'"),
        ("t,x,y,z\n0,0,0,0\n1,0,0\n", 3, "expected 4 cells, found 3"),
        ("t,x,y,z\n", 1, "no data rows"),
    ],
    ids=["missing-column", "non-numeric", "nan", "time-not-increasing", "too-few-points",
         "empty-cell", "short-row", "no-data"],
)
def test_read_trajectories_rejects_bad_file_with_one_line_message(tmp_path, text, row, problem):
    path = _write(tmp_path, text, "bad.csv")
    with pytest.raises(ValueError) as raised:
        read_trajectories(path)
    message = str(raised.value)
    assert "\n" not in message
    assert str(path) in message
    if "no data rows" not in problem:
        assert f"row {row}" in message
    assert problem in message
