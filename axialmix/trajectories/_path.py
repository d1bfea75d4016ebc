"""Path length of a trajectory, of a helix, and its expected inflation by measurement noise."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy.special import erf

from ._residence import resample_trajectory
from ._trajectory import Trajectory


def path_length(
    trajectory: Trajectory,
    time_step: float | None = None,
    method: Literal["linear", "nearest"] = "linear",
) -> float:
    """Total path length ``Σ sqrt(Δx² + Δy² + Δz²)`` of a trajectory.

    The result depends on the time step: a coarser step cuts the corners of the curved
    path (shorter) and sees less of the measurement noise (also shorter), see
    :func:`helix_polyline_length` and :func:`expected_noisy_path_length`.

    **Arguments:**

    - `trajectory`: the tracked particle.
    - `time_step`: if given, resample first to this step, s (see :func:`resample_trajectory`).
    - `method`: resampling method when `time_step` is given.

    **Returns:**

    The path length, m.
    """
    if time_step is not None:
        trajectory = resample_trajectory(trajectory, time_step, method)
    steps = np.stack(
        [np.diff(trajectory.x), np.diff(trajectory.y), np.diff(trajectory.z)], axis=1
    )
    return float(np.sum(np.linalg.norm(steps, axis=1)))


def helix_polyline_length(
    duration: float,
    time_step: float,
    spiral_radius: float,
    angular_speed: float,
    axial_velocity: float,
) -> float:
    """Length of a helix sampled every ``time_step`` and joined by straight chords.

    Each chord spans ``sqrt((2 r sin(ω h / 2))² + (v h)²)``; as ``h -> 0`` the total tends to
    the arc length ``T sqrt((r ω)² + v²)`` from below. Used to check the time-step bias of
    :func:`path_length` on noise-free spiral trajectories.

    **Arguments:**

    - `duration`: time covered by the chords, s (a whole number of steps).
    - `time_step`: sampling step h, s.
    - `spiral_radius`: helix radius r, m.
    - `angular_speed`: angular speed ω, rad/s.
    - `axial_velocity`: axial speed v, m/s.

    **Returns:**

    The polyline length, m.
    """
    n_steps = round(duration / time_step)
    chord = math.hypot(
        2.0 * spiral_radius * math.sin(angular_speed * time_step / 2.0),
        axial_velocity * time_step,
    )
    return n_steps * chord


def expected_noisy_path_length(
    chord_length: float | np.ndarray, noise_std: float, n_steps: int
) -> float:
    """Expected path length of a polyline whose vertices carry isotropic Gaussian noise.

    A chord ``d`` between two vertices each displaced by independent ``N(0, σ²)`` noise per
    coordinate becomes ``d + e`` with ``e ~ N(0, 2σ² I₃)``; its expected length is the mean
    of a non-central chi distribution with three degrees of freedom,
    ``s sqrt(2/π) exp(-m²/(2s²)) + (m + s²/m) erf(m / (s sqrt 2))`` with ``m = |d|`` and
    ``s = σ sqrt 2``. Expectation is linear, so correlations between neighbouring chords
    (which share a vertex) do not matter.

    **Arguments:**

    - `chord_length`: noise-free chord length ``|d|``, m (a scalar used for every step, or one
      value per step).
    - `noise_std`: σ, standard deviation of the noise per coordinate, m.
    - `n_steps`: number of chords (used when `chord_length` is a scalar).

    **Returns:**

    The expected total path length, m.
    """
    m = np.broadcast_to(np.asarray(chord_length, dtype=float), (n_steps,))
    if noise_std == 0:
        return float(np.sum(m))
    s = noise_std * math.sqrt(2.0)
    safe_m = np.where(m > 0, m, 1.0)
    mean = np.where(
        m > 0,
        s * np.sqrt(2 / np.pi) * np.exp(-(m**2) / (2 * s**2))
        + (m + s**2 / safe_m) * erf(m / (s * np.sqrt(2))),
        2 * s * np.sqrt(2 / np.pi),
    )
    return float(np.sum(mean))
