"""Synthetic trajectories with known velocity and dispersion, to test the estimators against."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from scipy.signal import lfilter

from ._trajectory import Trajectory, check_positive


def synthetic_trajectories(
    n_trajectories: int,
    *,
    axial_velocity: float,
    dispersion_coefficient: float,
    blender_length: float = 0.31,
    boundary: Literal["entry_exit", "reflecting", "free"] = "entry_exit",
    duration: float | None = None,
    time_step: float = 0.0169,
    impeller_speed_rpm: float = 100.0,
    angular_speed_ratio: float = 1.0,
    spiral_radius: float = 0.02,
    ballistic_fraction: float = 0.0,
    ballistic_time: float = 0.05,
    position_noise: float = 0.0,
    seed: int = 0,
) -> list[Trajectory]:
    """Simulate tracked particles with known axial velocity and dispersion coefficient.

    Cross-section: the particle circles the shaft at radius ``r`` with angular speed
    ``ω = angular_speed_ratio · 2π · rpm / 60`` from a random phase (a helix once combined
    with the axial motion). Axial motion: drift ``v`` plus dispersion with long-time
    coefficient ``D_z``, split into an uncorrelated Brownian part with exact Gaussian
    increments ``Δz = v Δt + sqrt(2 (1 - f) D_z Δt) N(0, 1)`` and, when
    ``f = ballistic_fraction > 0``, the displacement of an Ornstein-Uhlenbeck velocity with
    variance ``f D_z / τ_b`` and correlation time ``τ_b = ballistic_time``, sampled exactly
    (joint Gaussian update of velocity and displacement). The correlated part moves
    ballistically for lags below ``τ_b`` and diffusively with coefficient ``f D_z`` above,
    so the MSD is ``2 D_z Δt - 2 f D_z τ_b (1 - exp(-Δt/τ_b))``: slope ``2 D_z`` only for
    lags of several ``τ_b``. Measurement noise ``N(0, σ²)`` per coordinate is added last.

    Boundaries: ``"entry_exit"`` starts at z = 0, reflects at the inlet and stops at the
    first sample with z >= L (the exit; the mean residence time is then the first-passage
    time ``L/v - (D_z/v²)(1 - exp(-Pe))`` of the continuous process, plus a small overshoot
    from checking the exit only at samples); ``"reflecting"`` starts at a uniform
    random position in ``[0, L]`` and reflects at both ends for `duration`; ``"free"``
    starts at z = 0 and is unbounded for `duration`.

    **Arguments:**

    - `n_trajectories`: number of trajectories.
    - `axial_velocity`: drift v, m/s.
    - `dispersion_coefficient`: long-time axial dispersion coefficient D_z, m²/s.
    - `blender_length`: L, m.
    - `boundary`: ``"entry_exit"``, ``"reflecting"`` or ``"free"``.
    - `duration`: simulated time, s (required unless ``"entry_exit"``).
    - `time_step`: sampling step, s (0.0169 s as in the source's PEPT data).
    - `impeller_speed_rpm`: impeller speed, revolutions per minute.
    - `angular_speed_ratio`: particle angular speed over impeller angular speed.
    - `spiral_radius`: radius of the circular motion, m.
    - `ballistic_fraction`: share f of D_z carried by the correlated velocity, in [0, 1).
    - `ballistic_time`: correlation time τ_b of that velocity, s.
    - `position_noise`: standard deviation σ of the measurement noise per coordinate, m.
    - `seed`: seed of the random generator (results are reproducible).

    **Returns:**

    The trajectories, ids ``"0"``, ``"1"``, ..., times in s and positions in m.
    """
    if int(n_trajectories) != n_trajectories or n_trajectories < 1:
        raise ValueError(f"n_trajectories must be a positive integer, got {n_trajectories!r}.")
    velocity = float(axial_velocity)
    if not math.isfinite(velocity):
        raise ValueError(f"axial_velocity must be finite, got {axial_velocity!r}.")
    dispersion = float(dispersion_coefficient)
    if not (math.isfinite(dispersion) and dispersion >= 0):
        raise ValueError(
            f"dispersion_coefficient must be non-negative, got {dispersion_coefficient!r}."
        )
    length = check_positive("blender_length", blender_length)
    step = check_positive("time_step", time_step)
    if not 0.0 <= ballistic_fraction < 1.0:
        raise ValueError(f"ballistic_fraction must be in [0, 1), got {ballistic_fraction!r}.")
    if ballistic_fraction > 0:
        check_positive("ballistic_time", ballistic_time)
    if position_noise < 0:
        raise ValueError(f"position_noise must be non-negative, got {position_noise!r}.")
    if boundary not in ("entry_exit", "reflecting", "free"):
        raise ValueError(
            f"boundary must be 'entry_exit', 'reflecting' or 'free', got {boundary!r}."
        )
    if boundary == "entry_exit":
        if velocity <= 0:
            raise ValueError("axial_velocity must be positive for boundary='entry_exit'.")
        # Guard against endless runs: 50 mean residence times (plus diffusive time).
        max_steps = int(math.ceil(50 * (length / velocity) / step)) + 10
    else:
        if duration is None:
            raise ValueError(f"duration is required for boundary={boundary!r}.")
        max_steps = int(round(check_positive("duration", duration) / step))

    rng = np.random.default_rng(seed)
    n = int(n_trajectories)
    brownian_std = math.sqrt(2.0 * (1.0 - ballistic_fraction) * dispersion * step)
    if ballistic_fraction > 0:
        # Exact update of an OU velocity u and its integral over one step (Gillespie 1996).
        tau = float(ballistic_time)
        variance = ballistic_fraction * dispersion / tau
        decay = math.exp(-step / tau)
        var_u = variance * (1 - decay**2)
        var_x = variance * tau**2 * (2 * step / tau - 3 + 4 * decay - decay**2)
        cov_ux = variance * tau * (1 - decay) ** 2
        chol = np.linalg.cholesky(np.array([[var_u, cov_ux], [cov_ux, var_x]]) + 1e-300)
        u = rng.normal(0.0, math.sqrt(variance), n)
    exit_step = np.full(n, max_steps)
    if boundary == "free":
        # No walls: all increments at once; the OU velocity is a first-order linear filter.
        dz = velocity * step + brownian_std * rng.standard_normal((max_steps, n))
        if ballistic_fraction > 0:
            xi = np.einsum("ij,sjn->sin", chol, rng.standard_normal((max_steps, 2, n)))
            u_next = lfilter([1.0], [1.0, -decay], xi[:, 0], axis=0, zi=decay * u[None, :])[0]
            u_start = np.concatenate([u[None, :], u_next[:-1]])
            dz += tau * (1 - decay) * u_start + xi[:, 1]
        axial = np.concatenate([np.zeros((1, n)), np.cumsum(dz, axis=0)])
    else:
        z = rng.uniform(0.0, length, n) if boundary == "reflecting" else np.zeros(n)
        positions = [z.copy()]
        active = np.ones(n, dtype=bool)
        chunk = 1024
        for k in range(1, max_steps + 1):
            if (k - 1) % chunk == 0:
                brownian = brownian_std * rng.standard_normal((chunk, n))
                if ballistic_fraction > 0:
                    xi = np.einsum("ij,sjn->sin", chol, rng.standard_normal((chunk, 2, n)))
            dz = velocity * step + brownian[(k - 1) % chunk]
            if ballistic_fraction > 0:
                dz += tau * (1 - decay) * u + xi[(k - 1) % chunk, 1]
                u = decay * u + xi[(k - 1) % chunk, 0]
            z = z + dz
            if boundary == "entry_exit":
                mirrored = z < 0
                z = np.abs(z)
                exited = active & (z >= length)
                exit_step[exited] = k
                active &= ~exited
            else:
                z = np.mod(z, 2 * length)
                mirrored = z > length
                z = np.where(mirrored, 2 * length - z, z)
            if ballistic_fraction > 0:
                # A particle bouncing off an end wall reverses its correlated velocity too.
                u = np.where(mirrored, -u, u)
            positions.append(z.copy())
            if boundary == "entry_exit" and not active.any():
                break
        axial = np.array(positions)
        if boundary == "entry_exit" and active.any():
            raise ValueError(
                f"{int(active.sum())} particle(s) did not reach the outlet within "
                f"{max_steps * step:g} s; check axial_velocity and dispersion_coefficient."
            )

    angular_speed = angular_speed_ratio * 2.0 * math.pi * impeller_speed_rpm / 60.0
    trajectories = []
    for i in range(n):
        n_samples = int(exit_step[i]) + 1
        t = step * np.arange(n_samples)
        phase = rng.uniform(0.0, 2.0 * math.pi) + angular_speed * t
        x = spiral_radius * np.cos(phase)
        y = spiral_radius * np.sin(phase)
        zi = axial[:n_samples, i]
        if position_noise > 0:
            x = x + rng.normal(0.0, position_noise, n_samples)
            y = y + rng.normal(0.0, position_noise, n_samples)
            zi = zi + rng.normal(0.0, position_noise, n_samples)
        trajectories.append(Trajectory(time=t, x=x, y=y, z=zi, trajectory_id=str(i)))
    return trajectories
