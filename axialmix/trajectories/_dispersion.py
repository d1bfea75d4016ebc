"""Mean-square displacement and the axial dispersion coefficient (Einstein relation)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._trajectory import Trajectory, check_positive


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


def median_step(trajectories: list[Trajectory]) -> float:
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
    time_step = median_step(trajectories)
    limits = np.array([tr.duration / min_independent_displacements for tr in trajectories])
    limits = np.minimum(
        limits,
        _DEFAULT_MAX_LAG_STEPS * time_step if max_lag_time is None
        else check_positive("max_lag_time", max_lag_time),
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
