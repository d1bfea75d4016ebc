"""Residence time, spatial residence time in axial zones, and resampling of a trajectory."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from ._trajectory import Trajectory, check_positive


def residence_time(trajectory: Trajectory) -> float:
    """Residence time of a tracked particle: exit (last sample) minus entry (first sample).

    **Arguments:**

    - `trajectory`: the tracked particle, from entry to exit.

    **Returns:**

    The residence time, s.
    """
    return trajectory.duration


def zone_residence_times(
    trajectory: Trajectory, blender_length: float, n_zones: int = 5
) -> np.ndarray:
    """Time a particle spends in each of ``n_zones`` equal axial zones of the blender.

    The axis ``[0, L]`` is cut into equal zones (five zones of 0.062 m for L = 0.31 m in the
    source work). Between samples the axial position is taken as linear in time, so each
    zone crossing is timed exactly rather than rounded to a sample. Positions before the
    inlet (z < 0) count in the first zone and beyond the outlet (z > L) in the last, so the
    zone times always sum to the residence time.

    **Arguments:**

    - `trajectory`: the tracked particle.
    - `blender_length`: blender length L, m.
    - `n_zones`: number of equal zones.

    **Returns:**

    Time spent in each zone, s, shape ``(n_zones,)``, from inlet to outlet.
    """
    length = check_positive("blender_length", blender_length)
    if int(n_zones) != n_zones or n_zones < 1:
        raise ValueError(f"n_zones must be a positive integer, got {n_zones!r}.")
    n_zones = int(n_zones)
    edges = np.linspace(0.0, length, n_zones + 1)
    lower = np.concatenate([[-np.inf], edges[1:-1]])
    upper = np.concatenate([edges[1:-1], [np.inf]])
    z0, z1 = trajectory.z[:-1, None], trajectory.z[1:, None]
    dt = np.diff(trajectory.time)
    low, high = np.minimum(z0, z1), np.maximum(z0, z1)
    span = high - low
    moving = span[:, 0] > 0
    # Fraction of a segment spent in [lower, upper): overlap of the zone with the segment's
    # z-range over the range (z is linear in t within a segment).
    overlap = np.clip(upper, low, high) - np.clip(lower, low, high)
    fraction = np.where(
        moving[:, None],
        overlap / np.where(span > 0, span, 1.0),
        ((z0 >= lower) & (z0 < upper)).astype(float),
    )
    return fraction.T @ dt


def resample_trajectory(
    trajectory: Trajectory,
    time_step: float,
    method: Literal["linear", "nearest"] = "linear",
) -> Trajectory:
    """Resample a trajectory on a uniform time grid ``t0, t0 + h, t0 + 2h, ...``.

    **Arguments:**

    - `trajectory`: the tracked particle.
    - `time_step`: the new time step h, s. The grid stops at the last time ``<= t_end``.
    - `method`: ``"linear"`` interpolates positions linearly between samples (this also
      averages measurement noise at interpolated points); ``"nearest"`` keeps, for each grid
      time, the original sample closest in time (a slower detector frame rate), dropping
      repeated samples, so the kept noise is that of the raw data.

    **Returns:**

    The resampled trajectory (same id).
    """
    step = check_positive("time_step", time_step)
    t = trajectory.time
    n = int(math.floor((t[-1] - t[0]) / step * (1 + 1e-12))) + 1
    if n < 2:
        raise ValueError(
            f"time_step {step:g} s is longer than trajectory {trajectory.trajectory_id!r} "
            f"({trajectory.duration:g} s)."
        )
    grid = t[0] + step * np.arange(n)
    if method == "linear":
        return Trajectory(
            time=grid,
            x=np.interp(grid, t, trajectory.x),
            y=np.interp(grid, t, trajectory.y),
            z=np.interp(grid, t, trajectory.z),
            trajectory_id=trajectory.trajectory_id,
        )
    if method == "nearest":
        right = np.clip(np.searchsorted(t, grid), 1, t.size - 1)
        nearest = np.where(grid - t[right - 1] <= t[right] - grid, right - 1, right)
        keep = np.unique(nearest)
        return Trajectory(
            time=t[keep], x=trajectory.x[keep], y=trajectory.y[keep], z=trajectory.z[keep],
            trajectory_id=trajectory.trajectory_id,
        )
    raise ValueError(f"method must be 'linear' or 'nearest', got {method!r}.")
