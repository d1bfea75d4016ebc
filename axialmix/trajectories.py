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
* Peclet number ``Pe = v L / D_z``.

:func:`synthetic_trajectories` generates trajectories with known ``v`` and ``D_z`` (spiral
motion around the shaft, exact Gaussian axial increments, an optional short-time correlated
"ballistic" axial velocity and measurement noise) against which the estimators are tested.

Typical use::

    from axialmix.trajectories import analyse_trajectories, read_trajectories

    trajectories = read_trajectories("pept.csv", length_unit="mm")
    summary = analyse_trajectories(trajectories, blender_length=0.31)
    print(summary.report())
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.signal import lfilter
from scipy.special import erf

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
    "peclet_number",
    "pooled_axial_dispersion",
    "pooled_mean_square_displacement",
    "read_trajectories",
    "resample_trajectory",
    "residence_time",
    "synthetic_trajectories",
    "zone_residence_times",
]


# --------------------------------------------------------------------------------------
# Trajectory container
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Trajectory:
    """One tracked particle: sample times and positions from entry to exit.

    **Arguments:**

    - `time`: sample times, s, strictly increasing, shape ``(n,)`` with ``n >= 2``.
    - `x`, `y`: cross-sectional coordinates, m, shape ``(n,)``.
    - `z`: axial coordinate, m (0 at the inlet), shape ``(n,)``.
    - `trajectory_id`: label of the trajectory (from the file's id column).
    """

    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    trajectory_id: str = "0"

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("time", "x", "y", "z"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.ndim != 1:
                raise ValueError(f"Trajectory {self.trajectory_id!r}: {name} must be 1-D.")
            if not np.all(np.isfinite(value)):
                raise ValueError(
                    f"Trajectory {self.trajectory_id!r}: {name} contains NaN or infinity."
                )
            arrays[name] = value
        n = arrays["time"].size
        if any(a.size != n for a in arrays.values()):
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: time, x, y and z must have equal lengths."
            )
        if n < 2:
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: has {n} point(s); at least 2 are needed."
            )
        if np.any(np.diff(arrays["time"]) <= 0):
            i = int(np.argmax(np.diff(arrays["time"]) <= 0)) + 1
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: time is not strictly increasing at "
                f"sample {i} ({arrays['time'][i - 1]} s then {arrays['time'][i]} s)."
            )
        for name, value in arrays.items():
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def n_points(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.time[-1] - self.time[0])


# --------------------------------------------------------------------------------------
# Reading files
# --------------------------------------------------------------------------------------

_COLUMN_ALIASES = {
    "time": {"t", "time", "times", "timestamp"},
    "x": {"x", "xpos", "x_position", "position_x", "pos_x"},
    "y": {"y", "ypos", "y_position", "position_y", "pos_y"},
    "z": {"z", "zpos", "z_position", "position_z", "pos_z", "axial", "axial_position"},
    "id": {
        "id", "trajectory", "trajectory_id", "traj", "traj_id", "track", "track_id",
        "particle", "particle_id", "tracer", "tracer_id", "pid",
    },
}
_LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3}
_UNIT_IN_HEADER = re.compile(r"^(?P<name>.*?)\s*(?:\((?P<p>[^)]*)\)|\[(?P<b>[^\]]*)\])\s*$")


def _parse_header_cell(cell: str) -> tuple[str, str | None]:
    """Split a header cell such as ``'x (mm)'``, ``'x [mm]'``, ``'X_mm'`` into name and unit."""
    text = cell.strip().lstrip("\ufeff").strip().lower()
    match = _UNIT_IN_HEADER.match(text)
    if match:
        unit = (match.group("p") or match.group("b") or "").strip()
        return match.group("name").strip().replace(" ", "_"), unit or None
    if "/" in text:
        name, unit = text.rsplit("/", 1)
        return name.strip().replace(" ", "_"), unit.strip() or None
    text = text.replace(" ", "_")
    for unit in ("_mm", "_cm", "_ms", "_m", "_s"):
        stem = text[: -len(unit)]
        if text.endswith(unit) and any(stem in aliases for aliases in _COLUMN_ALIASES.values()):
            return stem, unit[1:]
    return text, None


def _resolve_unit(
    path: Path, kind: str, requested: str | None, stated: set[str], table: dict[str, float]
) -> float:
    """Scale factor to SI for a quantity whose unit may be requested and/or stated in headers."""
    for unit in stated | ({requested} if requested else set()):
        if unit not in table:
            raise ValueError(
                f"{path}: row 1: unknown {kind} unit {unit!r} (known: {', '.join(table)})."
            )
    if len(stated) > 1:
        raise ValueError(f"{path}: row 1: {kind} columns state different units {sorted(stated)}.")
    if requested and stated and requested not in stated:
        raise ValueError(
            f"{path}: row 1: header states {kind} unit {next(iter(stated))!r} but "
            f"{kind}_unit={requested!r} was requested."
        )
    unit = requested or (next(iter(stated)) if stated else ("m" if kind == "length" else "s"))
    return table[unit]


def read_trajectories(
    path: str | Path,
    *,
    length_unit: Literal["m", "cm", "mm"] | None = None,
    time_unit: Literal["s", "ms"] | None = None,
    min_points: int = 3,
) -> list[Trajectory]:
    """Read tracked-particle trajectories from a CSV file into SI units.

    The file has a header row naming the columns ``t, x, y, z`` and optionally a trajectory
    id column; header spellings such as ``time``, ``T``, ``x (mm)``, ``x [mm]``, ``x_mm``,
    ``z/m``, ``trajectory_id``, ``track``, ``particle`` are recognised (case-insensitive) and
    extra columns are ignored. Cells are separated by commas, semicolons or tabs (or by
    spaces when the header has none of these; header names then have no spaces); blank
    lines and lines starting with ``#`` are skipped. Without an id column the whole file is
    one trajectory named after the file. Rows of one trajectory need not be contiguous but
    must have strictly increasing times. Errors are one-line ``ValueError`` messages naming
    the file, the row (the line number in the file, header = row 1, as in a spreadsheet)
    and the problem.

    **Arguments:**

    - `path`: the CSV file.
    - `length_unit`: unit of x, y, z in the file, ``"m"``, ``"cm"`` or ``"mm"``. ``None``
      (default) takes the unit stated in the header (``x (mm)``), else metres. A requested
      unit that contradicts the header is an error.
    - `time_unit`: unit of t in the file, ``"s"`` or ``"ms"``; ``None`` as for lengths,
      default seconds.
    - `min_points`: fewest samples accepted per trajectory (at least 2).

    **Returns:**

    The trajectories in order of first appearance, times in s and positions in m.
    """
    path = Path(path)
    if int(min_points) != min_points or min_points < 2:
        raise ValueError(f"min_points must be an integer of at least 2, got {min_points!r}.")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror}).") from None
    numbered = [
        (number, line)
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise ValueError(f"{path}: the file is empty (a header row t, x, y, z is needed).")
    header_row, header_line = numbered[0]
    delimiter = max([",", ";", "\t"], key=header_line.count)

    def split_cells(line: str) -> list[str]:
        if header_line.count(delimiter) == 0:
            return line.split()
        return next(csv.reader([line], delimiter=delimiter))

    header = split_cells(header_line)
    parsed = [_parse_header_cell(cell) for cell in header]

    columns: dict[str, int] = {}
    units: dict[str, str | None] = {}
    for index, (name, unit) in enumerate(parsed):
        for role, aliases in _COLUMN_ALIASES.items():
            if name in aliases:
                if role in columns:
                    raise ValueError(
                        f"{path}: row {header_row}: two columns give {role!r} "
                        f"({header[columns[role]].strip()!r} and {header[index].strip()!r})."
                    )
                columns[role] = index
                units[role] = unit
    missing = [role for role in ("time", "x", "y", "z") if role not in columns]
    if missing:
        found = ", ".join(cell.strip() for cell in header)
        raise ValueError(
            f"{path}: row {header_row}: missing column(s) {', '.join(missing)} "
            f"(found: {found}); expected t, x, y, z and optionally a trajectory id."
        )
    length_scale = _resolve_unit(
        path, "length", length_unit,
        {units[r] for r in ("x", "y", "z") if units[r] is not None}, _LENGTH_UNITS,
    )
    time_scale = _resolve_unit(
        path, "time", time_unit,
        {units["time"]} if units["time"] is not None else set(), _TIME_UNITS,
    )

    records: dict[str, list[tuple[int, float, float, float, float]]] = {}
    default_id = path.stem
    for row, line in numbered[1:]:
        cells = split_cells(line)
        if len(cells) < len(header):
            raise ValueError(
                f"{path}: row {row}: expected {len(header)} cells, found {len(cells)}."
            )
        values = []
        for role in ("time", "x", "y", "z"):
            cell = cells[columns[role]].strip()
            column = header[columns[role]].strip()
            if not cell:
                raise ValueError(f"{path}: row {row}: column {column!r} is empty.")
            try:
                value = float(cell)
            except ValueError:
                raise ValueError(
                    f"{path}: row {row}: column {column!r} is not a number: {cell!r}."
                ) from None
            if not math.isfinite(value):
                raise ValueError(
                    f"{path}: row {row}: column {column!r} is {cell!r}; finite numbers needed."
                )
            values.append(value)
        if "id" in columns:
            trajectory_id = cells[columns["id"]].strip()
            if not trajectory_id:
                column = header[columns["id"]].strip()
                raise ValueError(f"{path}: row {row}: column {column!r} is empty.")
        else:
            trajectory_id = default_id
        previous = records.setdefault(trajectory_id, [])
        if previous and values[0] <= previous[-1][1]:
            raise ValueError(
                f"{path}: row {row}: time {values[0]:g} of trajectory {trajectory_id!r} is not "
                f"greater than the previous time {previous[-1][1]:g} (row {previous[-1][0]})."
            )
        previous.append((row, *values))
    if not records:
        raise ValueError(f"{path}: the file has a header but no data rows.")

    trajectories = []
    for trajectory_id, rows in records.items():
        if len(rows) < min_points:
            raise ValueError(
                f"{path}: row {rows[0][0]}: trajectory {trajectory_id!r} has {len(rows)} "
                f"point(s) (rows {rows[0][0]}-{rows[-1][0]}); at least {min_points} are needed."
            )
        data = np.array([r[1:] for r in rows], dtype=float)
        trajectories.append(
            Trajectory(
                time=data[:, 0] * time_scale,
                x=data[:, 1] * length_scale,
                y=data[:, 2] * length_scale,
                z=data[:, 3] * length_scale,
                trajectory_id=trajectory_id,
            )
        )
    return trajectories


# --------------------------------------------------------------------------------------
# Residence time, zones, path length
# --------------------------------------------------------------------------------------


def _check_positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")
    return value


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
    length = _check_positive("blender_length", blender_length)
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
    step = _check_positive("time_step", time_step)
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

    - `chord_length`: noise-free chord length |d|, m (a scalar used for every step, or one
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


def peclet_number(axial_velocity: float, blender_length: float, dispersion_coefficient: float
                  ) -> float:
    """Peclet number ``Pe = v L / D_z`` of the axial dispersion model (MODELS.md section 2).

    **Arguments:**

    - `axial_velocity`: mean axial velocity v, m/s.
    - `blender_length`: blender length L, m.
    - `dispersion_coefficient`: axial dispersion coefficient D_z, m²/s.

    **Returns:**

    Pe, dimensionless.
    """
    return float(axial_velocity) * float(blender_length) / float(dispersion_coefficient)


# --------------------------------------------------------------------------------------
# Mean-square displacement and dispersion coefficient
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MeanSquareDisplacement:
    """Drift-corrected axial mean-square displacement against lag time.

    **Fields:**

    - `lag_time`: mean lag of each lag bin, s, shape ``(n_lags,)``.
    - `msd`: ``<(Δz - v̄ Δt)²>`` in each bin, m², bridge-corrected when `bridge_corrected`.
    - `pair_count`: number of sample pairs in each bin.
    - `time_step`: the lag bin width (median sampling step), s.
    - `drift_velocity`: the drift v̄ removed, m/s (for a pooled MSD, the mean over trajectories).
    - `bridge_corrected`: whether each squared displacement was divided by ``1 - Δt/T``.
    - `max_lag_time`: largest lag kept, s.
    - `trajectory_msd`: MSDs of independent parts of the data on the same lag bins, m²,
      NaN where a part has no pairs: each trajectory's own MSD for a pooled MSD, or, for a
      single trajectory, the MSDs of its 8 consecutive segments (pairs within a segment,
      same drift). Their spread gives the statistical error used by
      :func:`fit_dispersion_coefficient`. Shape ``(n_parts, n_lags)``.
    """

    lag_time: np.ndarray
    msd: np.ndarray
    pair_count: np.ndarray
    time_step: float
    drift_velocity: float
    bridge_corrected: bool
    max_lag_time: float
    trajectory_msd: np.ndarray


@dataclass(frozen=True)
class DispersionFit:
    """Axial dispersion coefficient fitted on the linear part of a mean-square displacement.

    **Fields:**

    - `dispersion_coefficient`: D_z = slope / 2, m²/s.
    - `intercept`: intercept of the fitted line, m² (positive from measurement noise,
      negative after a short-time ballistic regime).
    - `window_start`, `window_end`: lag range of the fit, s.
    - `window_is_flat`: whether the local slope met the flatness rule at the window (True
      also when the window was given by the caller); False means no start met it and the
      flattest one was used.
    - `slope_spread`: relative change of the local slope across the window (the flatness
      measure, dimensionless; NaN when the window was given).
    - `drift_velocity`: the drift removed before the fit, m/s.
    """

    dispersion_coefficient: float
    intercept: float
    window_start: float
    window_end: float
    window_is_flat: bool
    slope_spread: float
    drift_velocity: float


_SINGLE_TRAJECTORY_SEGMENTS = 8
_DEFAULT_MAX_LAG_STEPS = 2000


def _median_step(trajectories: list[Trajectory]) -> float:
    return float(np.median(np.concatenate([np.diff(tr.time) for tr in trajectories])))


def _binned_sums(
    time: np.ndarray,
    detrended: np.ndarray,
    time_step: float,
    n_bins: int,
    max_lag_time: float,
    bridge_duration: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Binned sums of squared displacements, of lags and pair counts of one detrended path.

    Bin ``k - 1`` holds pairs with lag closest to ``k · time_step``, k = 1..n_bins. With
    `bridge_duration` T each squared displacement is divided by ``1 - Δt/T``.
    """
    sum_sq = np.zeros(n_bins)
    sum_lag = np.zeros(n_bins)
    count = np.zeros(n_bins)
    n = time.size
    if n < 2:
        return sum_sq, sum_lag, count
    dt = np.diff(time)
    if np.all(np.abs(dt - time_step) <= 1e-6 * time_step):
        # Uniform sampling: all lags at once from the autocorrelation (FFT),
        # Σ_i (y_{i+k} - y_i)² = Σ_{i>=k} y_i² + Σ_{i<n-k} y_i² - 2 Σ_i y_i y_{i+k}.
        y = detrended - detrended.mean()
        n_lags = min(n_bins, int(math.floor(max_lag_time / time_step * (1 + 1e-9))), n - 1)
        size = 1 << int(math.ceil(math.log2(2 * n)))
        spectrum = np.fft.rfft(y, size)
        autocorrelation = np.fft.irfft(spectrum * np.conj(spectrum), size)[1 : n_lags + 1]
        squares = np.concatenate([[0.0], np.cumsum(y**2)])
        k = np.arange(1, n_lags + 1)
        pairs = n - k
        sums = (squares[n] - squares[k]) + squares[n - k] - 2.0 * autocorrelation
        lag = k * time_step
        if bridge_duration is not None:
            sums = sums / (1.0 - lag / bridge_duration)
        sum_sq[:n_lags] = sums
        sum_lag[:n_lags] = lag * pairs
        count[:n_lags] = pairs
        return sum_sq, sum_lag, count
    for offset in range(1, n):
        lag = time[offset:] - time[:-offset]
        keep = lag <= max_lag_time * (1 + 1e-9)
        if not np.any(keep):
            break
        lag = lag[keep]
        squared = (detrended[offset:][keep] - detrended[:-offset][keep]) ** 2
        if bridge_duration is not None:
            squared = squared / (1.0 - lag / bridge_duration)
        bins = np.rint(lag / time_step).astype(int)
        inside = (bins >= 1) & (bins <= n_bins)
        bins = bins[inside] - 1
        sum_sq += np.bincount(bins, squared[inside], n_bins)
        sum_lag += np.bincount(bins, lag[inside], n_bins)
        count += np.bincount(bins, None, n_bins)
    return sum_sq, sum_lag, count


def _msd_sums(
    trajectory: Trajectory,
    time_step: float,
    n_bins: int,
    max_lag_time: float,
    drift_velocity: float | None,
    segments: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """Binned MSD sums of one trajectory, and of its `segments` consecutive pieces.

    Returns the sums of squared displacements, of lags and the pair counts (each of shape
    ``(n_bins,)``), the drift removed, and the squared-displacement sums and counts of each
    segment (shape ``(segments, n_bins)``; pairs within a segment only, same detrending).
    """
    t, z = trajectory.time, trajectory.z
    dt = np.diff(t)
    if np.max(dt) > 3.0 * time_step:
        raise ValueError(
            f"Trajectory {trajectory.trajectory_id!r}: a gap of {np.max(dt):g} s exceeds three "
            f"time steps ({time_step:g} s); split the trajectory or resample it first."
        )
    # With v̄ estimated from the same path, E[(Δz - v̄Δt)²] = 2 D Δt (1 - Δt/T) for Brownian
    # motion (a Brownian bridge); dividing by (1 - Δt/T) removes this bias.
    bridge = drift_velocity is None
    velocity = (z[-1] - z[0]) / trajectory.duration if bridge else float(drift_velocity)
    bridge_duration = trajectory.duration if bridge else None
    detrended = z - z[0] - velocity * (t - t[0])
    sum_sq, sum_lag, count = _binned_sums(
        t, detrended, time_step, n_bins, max_lag_time, bridge_duration
    )
    edges = np.linspace(0, t.size, segments + 1).astype(int)
    pieces = [
        _binned_sums(t[a:b], detrended[a:b], time_step, n_bins, max_lag_time, bridge_duration)
        for a, b in zip(edges[:-1], edges[1:], strict=True)
    ]
    segment_sq = np.array([piece[0] for piece in pieces])
    segment_count = np.array([piece[2] for piece in pieces])
    return sum_sq, sum_lag, count, velocity, segment_sq, segment_count


def mean_square_displacement(
    trajectory: Trajectory,
    *,
    drift_velocity: float | None = None,
    min_independent_displacements: int = 10,
    max_lag_time: float | None = None,
) -> MeanSquareDisplacement:
    """Drift-corrected axial mean-square displacement ``MSD(Δt) = <(Δz - v̄ Δt)²>``.

    Every pair of samples with lag ``Δt <= max_lag_time`` contributes; lags are binned on the
    median sampling step ``h`` (bin k holds lags nearest to ``k h``), so slightly irregular
    PEPT sampling is handled without resampling (uniform sampling takes an FFT shortcut).
    With the default drift ``v̄ = (z_exit - z_entry) / T`` estimated from the trajectory
    itself, each squared displacement is divided by ``1 - Δt/T``: for Brownian motion with
    drift the uncorrected MSD is ``2 D Δt (1 - Δt/T)`` (a Brownian bridge), so the
    corrected one is exactly ``2 D Δt`` in expectation.

    **Arguments:**

    - `trajectory`: the tracked particle (no gap longer than three sampling steps).
    - `drift_velocity`: drift to remove, m/s; ``None`` uses the trajectory's own mean axial
      velocity and applies the bridge correction; a given value (e.g. the ensemble mean
      velocity) is removed as is, without correction.
    - `min_independent_displacements`: the largest lag is ``T / min_independent_displacements``
      so that the MSD at every lag still averages at least that many non-overlapping
      displacements.
    - `max_lag_time`: a smaller largest lag, s. By default lags also stop at 2000 sampling
      steps (34 s at 0.0169 s), far beyond any short-time regime of a blender; give a
      larger value to go further.

    **Returns:**

    A :class:`MeanSquareDisplacement`, lags in s and MSD in m².
    """
    return _pooled_msd([trajectory], drift_velocity, min_independent_displacements, max_lag_time)


def pooled_mean_square_displacement(
    trajectories: list[Trajectory],
    *,
    drift_velocity: float | None = None,
    min_independent_displacements: int = 10,
    max_lag_time: float | None = None,
) -> MeanSquareDisplacement:
    """Mean-square displacement pooled over trajectories (ensemble average over all pairs).

    Each trajectory is drift-corrected as in :func:`mean_square_displacement` and
    contributes its pairs up to its own largest lag ``T_i / min_independent_displacements``;
    the pooled MSD at a lag is the mean over all pairs from all trajectories in that lag
    bin. The pooled largest lag is the median of the per-trajectory ones, so at least half
    of the trajectories contribute at every lag.

    **Arguments:**

    - `trajectories`: the tracked particles (sampled with about the same time step).
    - `drift_velocity`, `min_independent_displacements`, `max_lag_time`: as in
      :func:`mean_square_displacement`.

    **Returns:**

    A :class:`MeanSquareDisplacement` whose `drift_velocity` is the mean drift removed and
    whose `trajectory_msd` holds the per-trajectory MSDs.
    """
    return _pooled_msd(list(trajectories), drift_velocity, min_independent_displacements,
                       max_lag_time)


def _pooled_msd(
    trajectories: list[Trajectory],
    drift_velocity: float | None,
    min_independent_displacements: int,
    max_lag_time: float | None,
    min_lags: int = 4,
) -> MeanSquareDisplacement:
    if not trajectories:
        raise ValueError("trajectories is empty; at least one trajectory is needed.")
    if min_independent_displacements < 1:
        raise ValueError(
            "min_independent_displacements must be at least 1, "
            f"got {min_independent_displacements!r}."
        )
    time_step = _median_step(trajectories)
    limits = np.array([tr.duration / min_independent_displacements for tr in trajectories])
    limits = np.minimum(
        limits,
        _DEFAULT_MAX_LAG_STEPS * time_step if max_lag_time is None
        else _check_positive("max_lag_time", max_lag_time),
    )
    pooled_limit = float(np.median(limits))
    n_bins = int(math.floor(pooled_limit / time_step * (1 + 1e-9)))
    if n_bins < min_lags:
        raise ValueError(
            f"trajectories are too short for a mean-square displacement: the largest lag "
            f"{pooled_limit:g} s spans {n_bins} time step(s) of {time_step:g} s ({min_lags} "
            "are needed); lower min_independent_displacements or supply longer trajectories."
        )
    # A single trajectory is cut into segments whose MSDs estimate its statistical error.
    segments = _SINGLE_TRAJECTORY_SEGMENTS if len(trajectories) == 1 else 1
    sums = [
        _msd_sums(trajectory, time_step, n_bins, min(limit, pooled_limit), drift_velocity,
                  segments)
        for trajectory, limit in zip(trajectories, limits, strict=True)
    ]
    sum_sq = np.array([s[0] for s in sums])
    count = np.array([s[2] for s in sums])
    total_count = count.sum(axis=0)
    filled = total_count > 0
    if segments > 1:
        row_sq, row_count = sums[0][4], sums[0][5]
    else:
        row_sq, row_count = sum_sq, count
    with np.errstate(invalid="ignore", divide="ignore"):
        trajectory_msd = np.where(row_count > 0, row_sq / row_count, np.nan)[:, filled]
    return MeanSquareDisplacement(
        lag_time=np.sum([s[1] for s in sums], axis=0)[filled] / total_count[filled],
        msd=sum_sq.sum(axis=0)[filled] / total_count[filled],
        pair_count=total_count[filled].astype(int),
        time_step=time_step,
        drift_velocity=float(np.mean([s[3] for s in sums])),
        bridge_corrected=drift_velocity is None,
        max_lag_time=pooled_limit,
        trajectory_msd=trajectory_msd,
    )


def _line_fit(lag: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares slopes and intercepts of values(lag) along the last axis (NaN-aware)."""
    mask = np.isfinite(values)
    n = mask.sum(axis=-1)
    x = np.where(mask, lag, 0.0)
    y = np.where(mask, values, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        x_mean = x.sum(axis=-1) / n
        y_mean = y.sum(axis=-1) / n
        dx = np.where(mask, lag - x_mean[..., None], 0.0)
        slope = (dx * y).sum(axis=-1) / (dx**2).sum(axis=-1)
    return slope, y_mean - slope * x_mean


def fit_dispersion_coefficient(
    msd: MeanSquareDisplacement,
    *,
    tolerance: float = 0.02,
    window_ratio: float = 4.0,
    window: tuple[float, float] | None = None,
) -> DispersionFit:
    """Fit ``MSD = a + 2 D_z Δt`` by least squares on the linear part of an MSD.

    Window rule. The local slope at lag ``Δt`` is the least-squares slope of the MSD over
    ``[Δt, 2 Δt]``. The window starts at the shortest lag ``Δt_s`` from which the local
    slope stays within ``tolerance`` (relative) of its value at ``Δt_s`` for every lag up
    to ``2 Δt_s``: inside the short-time regime (ballistic or otherwise correlated motion)
    the local slope still changes, in the linear regime it does not. A change is also
    accepted when it is within twice its standard error, estimated from the spread of the
    same change over the independent parts in `msd.trajectory_msd` (trajectories, or
    segments of a single trajectory), so that statistical noise is not mistaken for
    curvature; with few data the rule therefore cannot see a short-time regime weaker than
    the noise. Candidate starts are every lag at first, then lags a factor 2^(1/8) apart.
    The window
    is ``[Δt_s, window_ratio · Δt_s]``, the range over which flatness was checked for the
    default ratio 4, capped at the largest lag of the MSD (already limited so that enough
    independent displacements remain, see :func:`mean_square_displacement`). A short
    window keeps the statistical error small: the variance of an MSD estimate grows about
    as the cube of the lag. If no start meets the rule, the flattest one is used and
    `window_is_flat` is False. The free intercept absorbs the constant offset from
    measurement noise (``+2σ²``) and from a finished ballistic regime (negative).

    **Arguments:**

    - `msd`: the mean-square displacement (of one trajectory or pooled).
    - `tolerance`: largest relative change of the local slope accepted.
    - `window_ratio`: ratio of window end to window start.
    - `window`: ``(start, end)`` lag range in s to fit instead of choosing one.

    **Returns:**

    A :class:`DispersionFit`, D_z in m²/s, window in s.
    """
    lag, values = msd.lag_time, msd.msd
    if window is not None:
        start, end = float(window[0]), float(window[1])
        inside = (lag >= start * (1 - 1e-9)) & (lag <= end * (1 + 1e-9))
        if inside.sum() < 2:
            raise ValueError(
                f"window ({start:g}, {end:g}) s holds {int(inside.sum())} lag(s) of the MSD "
                f"(lags {lag[0]:g}-{lag[-1]:g} s); at least 2 are needed."
            )
        slope, intercept = _line_fit(lag[inside], values[inside])
        return DispersionFit(
            dispersion_coefficient=float(slope / 2.0),
            intercept=float(intercept),
            window_start=float(lag[inside][0]),
            window_end=float(lag[inside][-1]),
            window_is_flat=True,
            slope_spread=float("nan"),
            drift_velocity=msd.drift_velocity,
        )
    if lag.size < 4:
        raise ValueError(
            f"the mean-square displacement has {lag.size} lags; at least 4 are needed."
        )
    # Local slopes over [lag_j, 2 lag_j], for the pooled MSD and for each row of
    # trajectory_msd, at candidate lags spaced by a factor 2^(1/8) (every lag at first).
    n_local = int(np.searchsorted(lag, lag[-1] / 2.0, side="right"))
    n_grid = 8 * int(math.log2(n_local) + 1)
    candidates = np.unique(np.geomspace(1, n_local, n_grid).astype(int)) - 1
    local = np.full(candidates.size, np.nan)
    row_local = np.full((msd.trajectory_msd.shape[0], candidates.size), np.nan)
    for position, j in enumerate(candidates):
        inside = (lag >= lag[j]) & (lag <= 2.0 * lag[j] * (1 + 1e-9))
        local[position] = _line_fit(lag[inside], values[inside])[0]
        row_local[:, position] = _line_fit(lag[inside], msd.trajectory_msd[:, inside])[0]
    candidate_lag = lag[candidates]
    n_start = max(1, int(np.searchsorted(candidate_lag, candidate_lag[-1] / 2.0, "right")))
    spreads = np.full(n_start, np.inf)
    allowed = np.full(n_start, np.inf)
    for i in range(n_start):
        further = (candidate_lag >= candidate_lag[i]) & (
            candidate_lag <= 2.0 * candidate_lag[i] * (1 + 1e-9)
        )
        if not local[i] > 0:
            continue
        spreads[i] = float(np.max(np.abs(local[further] - local[i])) / local[i])
        allowed[i] = tolerance
        # Standard error of each change of local slope, from its spread over the rows.
        changes = row_local[:, further] - row_local[:, [i]]
        counts = np.sum(np.isfinite(changes), axis=0)
        if np.all(counts > 1):
            change_se = np.nanstd(changes, axis=0, ddof=1) / np.sqrt(counts)
            allowed[i] = max(tolerance, 2.0 * float(np.max(change_se)) / local[i])
    flat = np.flatnonzero(spreads <= allowed)
    chosen_candidate = int(flat[0]) if flat.size else int(np.argmin(spreads / allowed))
    chosen = int(candidates[chosen_candidate])
    inside = (lag >= lag[chosen]) & (lag <= window_ratio * lag[chosen] * (1 + 1e-9))
    slope, intercept = _line_fit(lag[inside], values[inside])
    return DispersionFit(
        dispersion_coefficient=float(slope / 2.0),
        intercept=float(intercept),
        window_start=float(lag[inside][0]),
        window_end=float(lag[inside][-1]),
        window_is_flat=bool(flat.size),
        slope_spread=float(spreads[chosen_candidate]),
        drift_velocity=msd.drift_velocity,
    )


def axial_dispersion(
    trajectory: Trajectory,
    *,
    drift_velocity: float | None = None,
    min_independent_displacements: int = 10,
    tolerance: float = 0.02,
    window: tuple[float, float] | None = None,
) -> DispersionFit:
    """Axial dispersion coefficient of one trajectory from its mean-square displacement.

    Combines :func:`mean_square_displacement` and :func:`fit_dispersion_coefficient`. A
    single short trajectory gives a noisy MSD in which the end of the short-time regime
    cannot be located well; for an ensemble, choose the window on the pooled MSD and pass
    it here (as :func:`analyse_trajectories` does).

    **Arguments:**

    - `trajectory`: the tracked particle.
    - `drift_velocity`, `min_independent_displacements`: see
      :func:`mean_square_displacement`.
    - `tolerance`: flatness tolerance of the window rule.
    - `window`: ``(start, end)`` lag range in s to fit instead of choosing one.

    **Returns:**

    A :class:`DispersionFit`, D_z in m²/s.
    """
    if window is None:
        msd = mean_square_displacement(
            trajectory,
            drift_velocity=drift_velocity,
            min_independent_displacements=min_independent_displacements,
        )
        return fit_dispersion_coefficient(msd, tolerance=tolerance)
    msd = _pooled_msd(
        [trajectory], drift_velocity, min_independent_displacements, float(window[1]),
        min_lags=1,
    )
    return fit_dispersion_coefficient(msd, window=window)


def pooled_axial_dispersion(
    trajectories: list[Trajectory],
    *,
    drift_velocity: float | None = None,
    min_independent_displacements: int = 10,
    tolerance: float = 0.02,
) -> DispersionFit:
    """Ensemble axial dispersion coefficient from the MSD pooled over trajectories.

    **Arguments:**

    - `trajectories`: the tracked particles.
    - `drift_velocity`, `min_independent_displacements`: see
      :func:`pooled_mean_square_displacement`.
    - `tolerance`: flatness tolerance of the window rule.

    **Returns:**

    A :class:`DispersionFit`, D_z in m²/s.
    """
    msd = pooled_mean_square_displacement(
        trajectories,
        drift_velocity=drift_velocity,
        min_independent_displacements=min_independent_displacements,
    )
    return fit_dispersion_coefficient(msd, tolerance=tolerance)


# --------------------------------------------------------------------------------------
# Per-trajectory analysis and summary
# --------------------------------------------------------------------------------------


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
    step = _median_step([trajectory])
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
    length = _check_positive("blender_length", blender_length)
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
        peclet=peclet_number(velocity, length, dispersion.dispersion_coefficient),
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
        peclet=peclet_number(velocity, blender_length, pooled.dispersion_coefficient),
        mean_path_length=float(np.mean([a.path_length for a in analyses])),
    )


# --------------------------------------------------------------------------------------
# Synthetic trajectories
# --------------------------------------------------------------------------------------


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
    length = _check_positive("blender_length", blender_length)
    step = _check_positive("time_step", time_step)
    if not 0.0 <= ballistic_fraction < 1.0:
        raise ValueError(f"ballistic_fraction must be in [0, 1), got {ballistic_fraction!r}.")
    if ballistic_fraction > 0:
        _check_positive("ballistic_time", ballistic_time)
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
        max_steps = int(round(_check_positive("duration", duration) / step))

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
