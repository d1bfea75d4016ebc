"""Per-trajectory analysis and the summary of many trajectories."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..analytic.inverse import peclet_from_physical
from ._dispersion import DispersionFit, axial_dispersion, median_step, pooled_axial_dispersion
from ._path import path_length
from ._residence import residence_time, zone_residence_times
from ._trajectory import Trajectory, check_positive


def _peclet(velocity: float, length: float, dispersion: float) -> float:
    # Pe = v L / D_z where both are positive and finite; NaN where a fit failed.
    if not all(math.isfinite(x) and x > 0 for x in (velocity, length, dispersion)):
        return math.nan
    return float(peclet_from_physical(velocity, dispersion, length))


@dataclass(frozen=True)
class TrajectoryAnalysis:
    """What one trajectory tells: residence, zones, velocity, dispersion, path, Pe.

    **Fields:**

    - `trajectory_id`: label of the trajectory.
    - `residence_time`: exit minus entry time, s.
    - `zone_residence_times`: time in each equal axial zone, s (sums to `residence_time`).
    - `mean_axial_velocity`: ``(z_exit - z_entry) / residence_time``, m/s.
    - `dispersion`: the :class:`DispersionFit` (D_z in m²/s and its window).
    - `path_length`: total path length at the analysed time step, m.
    - `peclet`: ``v L / D_z`` with this trajectory's v and D_z.
    """

    trajectory_id: str
    residence_time: float
    zone_residence_times: np.ndarray
    mean_axial_velocity: float
    dispersion: DispersionFit
    path_length: float
    peclet: float


@dataclass(frozen=True)
class TrajectorySummary:
    """Ensemble results over a set of trajectories.

    **Fields:**

    - `analyses`: the per-trajectory :class:`TrajectoryAnalysis` results.
    - `blender_length`: L, m.
    - `mean_residence_time`, `residence_time_std`: over trajectories, s.
    - `mean_zone_residence_times`: mean time in each zone, s.
    - `mean_axial_velocity`: pooled ``Σ (z_exit - z_entry) / Σ T``, m/s (``L`` over the
      mean residence time when every trajectory runs from inlet to outlet).
    - `mean_dispersion_coefficient`: mean of the per-trajectory D_z, m²/s, over the
      trajectories long enough to reach the fitting window.
    - `dispersion_standard_error`: standard error of that mean, m²/s.
    - `n_dispersion_fits`: number of trajectories in that mean (the others are too short
      for the window; their D_z and Pe are NaN).
    - `pooled_dispersion`: the :class:`DispersionFit` of the pooled MSD.
    - `peclet`: ``v L / D_z`` from the pooled velocity and pooled D_z.
    - `mean_path_length`: mean path length, m.
    """

    analyses: tuple[TrajectoryAnalysis, ...]
    blender_length: float
    mean_residence_time: float
    residence_time_std: float
    mean_zone_residence_times: np.ndarray
    mean_axial_velocity: float
    mean_dispersion_coefficient: float
    dispersion_standard_error: float
    n_dispersion_fits: int
    pooled_dispersion: DispersionFit
    peclet: float
    mean_path_length: float

    def report(self) -> str:
        """A short plain-text table of the ensemble results (mm²/s for D_z)."""
        zones = ", ".join(f"{value:.2f}" for value in self.mean_zone_residence_times)
        pooled = self.pooled_dispersion
        lines = [
            f"trajectories                  {len(self.analyses)}",
            f"mean residence time           {self.mean_residence_time:.3f} s "
            f"(std {self.residence_time_std:.3f} s)",
            f"mean zone residence times     [{zones}] s",
            f"mean axial velocity           {self.mean_axial_velocity * 1e3:.3f} mm/s",
            f"D_z, mean of trajectories     {self.mean_dispersion_coefficient * 1e6:.2f} "
            f"± {self.dispersion_standard_error * 1e6:.2f} mm²/s "
            f"({self.n_dispersion_fits} trajectories long enough for the window)",
            f"D_z, pooled MSD               {pooled.dispersion_coefficient * 1e6:.2f} mm²/s "
            f"(window {pooled.window_start:.3f}-{pooled.window_end:.3f} s, "
            f"{'flat' if pooled.window_is_flat else 'NOT flat'})",
            f"Peclet number v L / D_z       {self.peclet:.1f}",
            f"mean path length              {self.mean_path_length:.4f} m",
        ]
        return "\n".join(lines)


def _reaches_window(
    trajectory: Trajectory, window: tuple[float, float], min_independent_displacements: int
) -> bool:
    """Whether a trajectory's MSD has at least two lags inside a given fitting window."""
    step = median_step([trajectory])
    largest = min(trajectory.duration / min_independent_displacements, float(window[1]))
    first = math.ceil(float(window[0]) / step - 1e-9)
    last = math.floor(largest / step + 1e-9)
    return last - max(first, 1) + 1 >= 2


def analyse_trajectory(
    trajectory: Trajectory,
    blender_length: float,
    *,
    n_zones: int = 5,
    path_time_step: float | None = None,
    min_independent_displacements: int = 10,
    tolerance: float = 0.02,
    window: tuple[float, float] | None = None,
) -> TrajectoryAnalysis:
    """Residence time, zone times, velocity, D_z, path length and Pe of one trajectory.

    **Arguments:**

    - `trajectory`: the tracked particle, from entry to exit.
    - `blender_length`: blender length L, m.
    - `n_zones`: number of equal axial zones.
    - `path_time_step`: time step for the path length, s (``None``: as sampled).
    - `min_independent_displacements`, `tolerance`, `window`: see :func:`axial_dispersion`.

    **Returns:**

    A :class:`TrajectoryAnalysis` (SI units).
    """
    length = check_positive("blender_length", blender_length)
    if window is not None and not _reaches_window(
        trajectory, window, min_independent_displacements
    ):
        dispersion = DispersionFit(
            dispersion_coefficient=float("nan"), intercept=float("nan"),
            window_start=float(window[0]), window_end=float(window[1]),
            window_is_flat=False, slope_spread=float("nan"),
            drift_velocity=float(trajectory.z[-1] - trajectory.z[0]) / trajectory.duration,
        )
    else:
        dispersion = axial_dispersion(
            trajectory,
            min_independent_displacements=min_independent_displacements,
            tolerance=tolerance,
            window=window,
        )
    velocity = float(trajectory.z[-1] - trajectory.z[0]) / trajectory.duration
    return TrajectoryAnalysis(
        trajectory_id=trajectory.trajectory_id,
        residence_time=residence_time(trajectory),
        zone_residence_times=zone_residence_times(trajectory, length, n_zones),
        mean_axial_velocity=velocity,
        dispersion=dispersion,
        path_length=path_length(trajectory, path_time_step),
        peclet=_peclet(velocity, length, dispersion.dispersion_coefficient),
    )


def analyse_trajectories(
    trajectories: list[Trajectory],
    blender_length: float,
    *,
    n_zones: int = 5,
    path_time_step: float | None = None,
    min_independent_displacements: int = 10,
    tolerance: float = 0.02,
) -> TrajectorySummary:
    """Analyse every trajectory and summarise the ensemble, including a pooled D_z.

    The MSD fitting window is chosen once, on the MSD pooled over all trajectories (where
    the end of the short-time regime can be located precisely), and every trajectory's D_z
    is fitted on that same window; a trajectory whose own largest lag
    (``T / min_independent_displacements``) does not reach two lags of the window gets a
    NaN D_z and Pe and is left out of the mean.

    **Arguments:**

    - `trajectories`: the tracked particles.
    - `blender_length`: blender length L, m.
    - `n_zones`, `path_time_step`, `min_independent_displacements`, `tolerance`: see
      :func:`analyse_trajectory`.

    **Returns:**

    A :class:`TrajectorySummary` (SI units); ``print(summary.report())`` shows it.
    """
    trajectories = list(trajectories)
    if not trajectories:
        raise ValueError("trajectories is empty; at least one trajectory is needed.")
    pooled = pooled_axial_dispersion(
        trajectories, min_independent_displacements=min_independent_displacements,
        tolerance=tolerance,
    )
    analyses = tuple(
        analyse_trajectory(
            trajectory, blender_length, n_zones=n_zones, path_time_step=path_time_step,
            min_independent_displacements=min_independent_displacements, tolerance=tolerance,
            window=(pooled.window_start, pooled.window_end),
        )
        for trajectory in trajectories
    )
    times = np.array([a.residence_time for a in analyses])
    coefficients = np.array([a.dispersion.dispersion_coefficient for a in analyses])
    coefficients = coefficients[np.isfinite(coefficients)]
    velocity = float(sum(tr.z[-1] - tr.z[0] for tr in trajectories) / times.sum())
    n = len(analyses)
    n_fits = coefficients.size
    return TrajectorySummary(
        analyses=analyses,
        blender_length=float(blender_length),
        mean_residence_time=float(times.mean()),
        residence_time_std=float(times.std(ddof=1)) if n > 1 else 0.0,
        mean_zone_residence_times=np.mean([a.zone_residence_times for a in analyses], axis=0),
        mean_axial_velocity=velocity,
        mean_dispersion_coefficient=float(coefficients.mean()) if n_fits else float("nan"),
        dispersion_standard_error=float(coefficients.std(ddof=1) / math.sqrt(n_fits))
        if n_fits > 1 else float("nan"),
        n_dispersion_fits=n_fits,
        pooled_dispersion=pooled,
        peclet=_peclet(velocity, blender_length, pooled.dispersion_coefficient),
        mean_path_length=float(np.mean([a.path_length for a in analyses])),
    )
