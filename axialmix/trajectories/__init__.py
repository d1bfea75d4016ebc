"""Particle-tracking (PEPT) trajectory analysis: residence, zones, dispersion, path length.

A tracked particle is a sequence of samples ``(t, x, y, z)`` from its entry into the
blender to its exit over the weir (MODELS.md section 5). ``z`` is the axial coordinate
(0 at the inlet, ``L`` at the outlet), ``x`` and ``y`` span the cross-section around the
shaft. Units inside this module are SI throughout: times in seconds, positions in metres,
velocities in m/s, dispersion coefficients in m²/s; :func:`read_trajectories` converts
files written in millimetres or milliseconds.

What is derived from a trajectory:

* residence time, exit minus entry time;
* spatial residence time in ``n_zones`` equal axial zones over ``[0, L]`` (the source used
  five zones of 0.062 m for L = 0.31 m), with the position linearly interpolated between
  samples so that zone crossings are timed exactly;
* the drift-corrected mean-square displacement ``MSD(Δt) = <(Δz - v̄ Δt)²>`` and the axial
  dispersion coefficient ``D_z = slope / 2`` on its linear part (Einstein relation), the
  fitting window being chosen automatically (:func:`fit_dispersion_coefficient`);
* path length ``Σ sqrt(Δx² + Δy² + Δz²)``, optionally after resampling to a coarser time
  step (the source compared 0.0169, 0.0336 and 0.0472 s);
* Peclet number ``Pe = v L / D_z`` (:func:`axialmix.analytic.peclet_from_physical`).

:func:`synthetic_trajectories` generates trajectories with known ``v`` and ``D_z`` (spiral
motion around the shaft, exact Gaussian axial increments, an optional short-time correlated
"ballistic" axial velocity and measurement noise) against which the estimators are tested.

Typical use::

    from axialmix.trajectories import analyse_trajectories, read_trajectories

    trajectories = read_trajectories("pept.csv", length_unit="mm")
    summary = analyse_trajectories(trajectories, blender_length=0.31)
    print(summary.report())
"""

from ._analysis import (
    TrajectoryAnalysis,
    TrajectorySummary,
    analyse_trajectories,
    analyse_trajectory,
)
from ._dispersion import (
    DispersionFit,
    MeanSquareDisplacement,
    axial_dispersion,
    fit_dispersion_coefficient,
    mean_square_displacement,
    pooled_axial_dispersion,
    pooled_mean_square_displacement,
)
from ._path import expected_noisy_path_length, helix_polyline_length, path_length
from ._reading import read_trajectories
from ._residence import resample_trajectory, residence_time, zone_residence_times
from ._synthetic import synthetic_trajectories
from ._trajectory import Trajectory

__all__ = [
    "DispersionFit",
    "MeanSquareDisplacement",
    "Trajectory",
    "TrajectoryAnalysis",
    "TrajectorySummary",
    "analyse_trajectories",
    "analyse_trajectory",
    "axial_dispersion",
    "expected_noisy_path_length",
    "fit_dispersion_coefficient",
    "helix_polyline_length",
    "mean_square_displacement",
    "path_length",
    "pooled_axial_dispersion",
    "pooled_mean_square_displacement",
    "read_trajectories",
    "resample_trajectory",
    "residence_time",
    "synthetic_trajectories",
    "zone_residence_times",
]
