"""What a recorded DEM run says: transport (v, D_z, Pe), tracer spreading, and partitions.

* :func:`dem_transport`: the DEM tracks go through :mod:`axialmix.trajectories` like PEPT
  tracks: the mean axial velocity, the drift-corrected mean-square displacement pooled over
  the spheres, ``D_z`` fitted on its linear part, and the apparent ``D_z(lag) = MSD / (2 lag)``
  at chosen lags (it depends on the lag where the motion has memory, such as blade passage).
* :func:`cells_of_run`: the cell of every sphere in every frame (axial × radial rings ×
  angular sectors), the cells the networks are learned on.
* :func:`tracer_spreading`: spheres in chosen cells at a start frame are a tracer; their
  distribution over the cells later, in the DEM and as a learned network predicts it
  (``p(t) = p(0) exp(Q t)``), with the DEM's own noise floor from two random halves of the
  tracer.
* :func:`flux_partition` (the source's partition method I, its §7.6): the net count change of
  every species in every region per interval, ``(N(i, t + dt) - N(i, t)) / dt``; the regions
  whose flux varies most over time (standard deviation) go to DEM.
* :func:`velocity_partition` (method II, §7.7): the variance of the spheres' velocities in
  each region over the run; the regions of high variance go to DEM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ._learn import LearnedNetwork, axial_cells, equal_occupancy_sectors

__all__ = [
    "DEMTransport",
    "Partition",
    "RunCells",
    "TracerSpreading",
    "cells_of_run",
    "dem_transport",
    "flux_partition",
    "independent_mean_error",
    "region_counts",
    "tracer_fractions",
    "tracer_spreading",
    "velocity_partition",
]


@dataclass(frozen=True)
class DEMTransport:
    """Axial transport of a DEM run from its tracks (SI units).

    **Fields:** `velocity` mean axial velocity (m/s); `dispersion` D_z fitted on the linear
    part of the pooled MSD (m²/s) and its `window` (s); `lags` (s) and `lag_dispersion` the
    apparent ``MSD / (2 lag)`` there (m²/s); `peclet` ``v L / D_z`` for `blender_length` (m).
    """

    velocity: float
    dispersion: float
    window: tuple[float, float]
    lags: np.ndarray
    lag_dispersion: np.ndarray
    blender_length: float
    peclet: float


def dem_transport(run, lags=(0.05, 0.1, 0.25, 0.5, 1.0, 2.0), blender_length: float = 0.74
                  ) -> DEMTransport:
    """v, D_z and Pe of a DEM run through :mod:`axialmix.trajectories`.

    **Arguments:**

    - `run`: a :class:`axialmix.dem.DEMRun` (``z`` unwrapped for a periodic section).
    - `lags`: lags (s) at which the apparent ``D_z(lag)`` is reported (the nearest whole
      number of frames; NaN beyond a fifth of the run).
    - `blender_length`: length for the Peclet number, m (0.74 m: blender 1 of MODELS.md §1).

    **Returns:** a :class:`DEMTransport`.
    """
    from ..analytic import peclet_from_physical
    from ..trajectories import fit_dispersion_coefficient, pooled_mean_square_displacement

    tracks = run.trajectories()
    z = run.positions[:, :, 2].astype(float)
    duration = float(run.times[-1] - run.times[0])
    velocity = float(np.mean(z[-1] - z[0]) / duration)
    lags = np.asarray(lags, float)
    # Lags up to the largest asked for, each averaging at least 5 independent displacements.
    independent = int(max(5, min(10, duration // max(lags.max(), run.frame_interval))))
    msd = pooled_mean_square_displacement(tracks, drift_velocity=velocity,
                                          min_independent_displacements=independent,
                                          max_lag_time=lags.max() + run.frame_interval)
    fit = fit_dispersion_coefficient(msd)
    # The MSD bin nearest each lag (bins are one frame wide); NaN beyond the largest lag.
    nearest = np.abs(msd.lag_time[None, :] - lags[:, None]).argmin(axis=1)
    close = np.abs(msd.lag_time[nearest] - lags) <= run.frame_interval / 2
    at = np.where(close, msd.msd[nearest] / (2 * msd.lag_time[nearest]), np.nan)
    return DEMTransport(
        velocity=velocity,
        dispersion=float(fit.dispersion_coefficient),
        window=(float(fit.window_start), float(fit.window_end)),
        lags=lags,
        lag_dispersion=at,
        blender_length=float(blender_length),
        peclet=float(peclet_from_physical(abs(velocity), fit.dispersion_coefficient,
                                          blender_length)),
    )


@dataclass(frozen=True)
class TracerSpreading:
    """A tracer's distribution over cells in the DEM and as a network predicts it.

    **Fields:** `times` after the start (s); `dem` and `predicted` ``(times, cells)`` tracer
    fractions; `halves` ``(2, times, cells)`` the fractions of two random halves of the
    tracer; `error` mean over cells of ``|dem - predicted|`` at each time; `floor` the mean
    of ``|half_1 - half_2| / 2`` over random splits, the DEM's own sampling noise on the
    whole tracer's fractions (each half has twice its variance), what `error` would be for
    an exact network; both in tracer fraction.
    """

    times: np.ndarray
    dem: np.ndarray
    predicted: np.ndarray
    halves: np.ndarray
    error: np.ndarray
    floor: np.ndarray

    @property
    def ratio(self) -> float:
        """Mean error over the mean noise floor (about 1 for a network that is exact).

        NaN when the floor is zero: the tracer's halves never differ (it stayed in its cells
        over the delays compared), and nothing can be judged against it.
        """
        floor = float(self.floor.mean())
        return float(self.error.mean() / floor) if floor > 0 else float("nan")


@dataclass(frozen=True)
class RunCells:
    """The cells of a DEM run (SI units).

    **Fields:** `cells` ``(frames, spheres)`` cell index (:func:`axial_cells`: every axial
    layer a block of `per_layer` consecutive indices); `n_axial`, `n_radial`, `n_sectors`;
    `sector_edges` the angular edges, rad (``None`` without sectors); `centres`
    ``(n_cells,)`` axial centre of every cell, m; `names` (``z3r2s1``: axial layer 3, ring 2,
    sector 1).
    """

    cells: np.ndarray
    n_axial: int
    n_radial: int
    n_sectors: int
    sector_edges: np.ndarray | None
    centres: np.ndarray
    names: tuple[str, ...]

    @property
    def per_layer(self) -> int:
        """Cells in one axial layer (rings × sectors)."""
        return self.n_radial * self.n_sectors

    @property
    def n_cells(self) -> int:
        """All cells."""
        return self.n_axial * self.per_layer


def cells_of_run(run, n_axial: int, *, n_radial: int = 1, n_sectors: int = 1,
                 sector_edges: np.ndarray | None = None, edge_frames: slice | None = None
                 ) -> RunCells:
    """The cell of every sphere in every frame of a DEM run.

    **Arguments:**

    - `run`: a :class:`axialmix.dem.DEMRun` (a periodic section is wrapped axially).
    - `n_axial`: equal axial cells over the geometry's length.
    - `n_radial`: equal-area rings per axial cell.
    - `n_sectors`: angular sectors per ring, placed by :func:`equal_occupancy_sectors` on
      the angles of the frames `edge_frames` (default all); or give `sector_edges` (rad)
      to use the sectors of another run or window (then `n_sectors` is taken from them).

    **Returns:** a :class:`RunCells`.

    **Raises:** ``ValueError`` for counts that are not positive whole numbers, or sectors the
    angles cannot fill.
    """
    if int(n_sectors) != n_sectors or n_sectors < 1:
        raise ValueError(f"n_sectors must be a positive whole number, got {n_sectors}.")
    g = run.geometry
    p = run.positions
    # Angles only where there are sectors (an array the size of the run).
    angle = (np.arctan2(p[:, :, 1], p[:, :, 0])
             if sector_edges is not None or n_sectors > 1 else None)
    if sector_edges is None and n_sectors > 1:
        window = angle if edge_frames is None else angle[edge_frames]
        sector_edges = equal_occupancy_sectors(window, n_sectors)
    if sector_edges is not None:
        sector_edges = np.asarray(sector_edges, dtype=float)
        n_sectors = sector_edges.size - 1
    cells = axial_cells(p[:, :, 2], g.length, n_axial, periodic=g.periodic,
                        radius=np.hypot(p[:, :, 0], p[:, :, 1]), vessel_radius=g.radius,
                        n_radial=n_radial, angle=angle, sector_edges=sector_edges)
    per_layer = int(n_radial) * int(n_sectors)
    centres = np.repeat((np.arange(n_axial) + 0.5) * g.length / n_axial, per_layer)
    names = tuple(f"z{a + 1}" + (f"r{k + 1}" if n_radial > 1 else "")
                  + (f"s{j + 1}" if n_sectors > 1 else "")
                  for a in range(n_axial) for k in range(n_radial) for j in range(n_sectors))
    return RunCells(cells=cells, n_axial=int(n_axial), n_radial=int(n_radial),
                    n_sectors=int(n_sectors), sector_edges=sector_edges, centres=centres,
                    names=names)


def tracer_fractions(axial: np.ndarray, n_axial: int, start, delays,
                     mask: np.ndarray | None = None) -> np.ndarray:
    """A DEM tracer's fractions over axial cells: the spheres in axial cell 0 at each start
    frame are the tracer; the share of them in each axial cell `delays` frames later,
    averaged over the starts (the phase-averaged spreading a network describes).

    **Arguments:** `axial` ``(frames, particles)`` axial cell of every sphere (0 to
    ``n_axial - 1``); `start` frame or frames; `delays` frames after each start; `mask`
    ``(particles,)`` the spheres that may be tracer (default all).

    **Returns:** ``(delays, n_axial)`` fractions (each row sums to 1).

    **Raises:** ``ValueError`` when a start plus a delay runs past the frames, or no sphere
    of `mask` is in axial cell 0 at a start.
    """
    starts = np.atleast_1d(np.asarray(start, dtype=int))
    delays = np.atleast_1d(np.asarray(delays, dtype=int))
    if starts.max() + delays.max() >= axial.shape[0]:
        raise ValueError("the last start plus the longest delay runs past the recorded frames.")
    if mask is None:
        mask = np.ones(axial.shape[1], bool)
    out = np.zeros((delays.size, int(n_axial)))
    for s0 in starts:
        members = np.nonzero((axial[s0] == 0) & mask)[0]
        if members.size == 0:
            raise ValueError(f"no tracer sphere in the first cell at frame {s0}.")
        for k, d in enumerate(delays):
            out[k] += np.bincount(axial[s0 + d, members], minlength=n_axial) / members.size
    return out / starts.size


def tracer_spreading(cells: np.ndarray, learned: LearnedNetwork, frame_interval: float,
                     start, delays: tuple[int, ...], cells_per_layer: int = 1, seed: int = 0,
                     splits: int = 20) -> TracerSpreading:
    """Compare a DEM tracer with the learned network's prediction.

    **Arguments:**

    - `cells`: ``(frames, particles)`` cell of every sphere (the network's cells; every
      axial layer a block of `cells_per_layer` consecutive indices, as :func:`axial_cells`
      and :func:`cells_of_run` number them).
    - `learned`: the :class:`LearnedNetwork` (from other frames of the run).
    - `frame_interval`: s.
    - `start`: frame (or frames) at which the spheres in axial cell 0 become the tracer.
      With several start frames (spread over the blade phases) the DEM fractions are the
      mean over starts: the phase-averaged spreading a network describes.
    - `delays`: frames after each start to compare.
    - `cells_per_layer`: cells per axial layer (rings × sectors); the tracer starts in them
      as the DEM has it, and fractions are compared per axial layer.
    - `seed`, `splits`: seed and number of the random splits of the spheres into two halves
      whose differences, averaged, give the noise floor (`halves` keeps the first split).

    **Returns:** a :class:`TracerSpreading` (fractions per axial cell).
    """
    n = learned.n_cells
    if cells_per_layer < 1 or n % cells_per_layer:
        raise ValueError(f"{n} cells do not split into layers of {cells_per_layer}.")
    n_axial = n // cells_per_layer
    axial = cells // cells_per_layer
    starts = np.atleast_1d(np.asarray(start, dtype=int))
    delays = np.asarray(delays)

    def fractions(mask):
        return tracer_fractions(axial, n_axial, starts, delays, mask)

    everyone = np.ones(cells.shape[1], bool)
    dem = fractions(everyone)
    rng = np.random.default_rng(seed)
    floors, halves = [], None
    for _ in range(int(splits)):
        mask = np.zeros(cells.shape[1], bool)
        mask[rng.permutation(cells.shape[1])[: cells.shape[1] // 2]] = True
        pair = np.stack([fractions(mask), fractions(~mask)])
        halves = pair if halves is None else halves
        floors.append((np.abs(pair[0] - pair[1]) / 2).mean(axis=1))
    p0 = np.zeros(n)
    for s0 in starts:
        members = axial[s0] == 0
        p0 += np.bincount(cells[s0][members], minlength=n) / members.sum()
    p0 /= starts.size
    predicted = np.stack([p0 @ scipy.linalg.expm(learned.rates * d * frame_interval)
                          for d in delays])
    predicted = predicted.reshape(delays.size, n_axial, cells_per_layer).sum(axis=2)
    return TracerSpreading(
        times=delays * frame_interval, dem=dem, predicted=predicted, halves=halves,
        error=np.abs(dem - predicted).mean(axis=1), floor=np.mean(floors, axis=0),
    )


def repeat_floor(*spreadings: TracerSpreading) -> np.ndarray:
    """The DEM's own noise floor from equivalent measurements of one tracer's spreading.

    Independent DEM runs of the same system (other seeds), or one run's tracer released
    over two windows, measure the same expected fractions with independent errors; the mean
    of ``|dem_1 - dem_2|`` over cells is then ``sqrt(2)`` times the mean error of an exact
    prediction of either, so this floor is that mean over ``sqrt(2)``, averaged over every
    pair of the measurements given. Unlike :attr:`TracerSpreading.floor` (two halves of the
    spheres of one window: their sampling noise alone), it holds what the whole bed shares:
    its slow fluctuations (a drift that wanders by a tenth over seconds) and, between runs,
    the run-to-run differences of the packing.

    **Arguments:** two or more :class:`TracerSpreading` of the same cells, starts and delays
    (their `dem` fractions are compared; their predictions are not used).

    **Returns:** ``(delays,)`` floor in tracer fraction, comparable with `error`.
    """
    if len(spreadings) < 2:
        raise ValueError("a repeat floor needs at least two measurements.")
    first = spreadings[0]
    for other in spreadings[1:]:
        if other.dem.shape != first.dem.shape or not np.array_equal(other.times, first.times):
            raise ValueError("the spreadings must share their cells and delays.")
    pairs = [np.abs(a.dem - b.dem).mean(axis=1)
             for k, a in enumerate(spreadings) for b in spreadings[k + 1:]]
    return np.mean(pairs, axis=0) / np.sqrt(2.0)


def independent_mean_error(spreading: TracerSpreading,
                           *others: TracerSpreading) -> np.ndarray:
    """How far a run's tracer is from the mean tracer of independent runs.

    The mean of the `others`' DEM fractions (other seeds, same cells, starts and delays) is
    the best prediction data from other runs can give, with no network in between; its error
    on `spreading`'s DEM fractions says how much of any prediction's error is the run itself.
    For ``m`` independent runs of equal noise its expected value is ``sqrt(1 + 1/m)`` times
    an exact prediction's (the mean of ``m`` runs keeps ``1/m`` of their variance).

    **Returns:** ``(delays,)`` mean over cells of ``|dem - mean of others' dem|``, in tracer
    fraction, comparable with :attr:`TracerSpreading.error` and :func:`repeat_floor`.
    """
    if not others:
        raise ValueError("the mean of independent runs needs at least one other run.")
    for other in others:
        if other.dem.shape != spreading.dem.shape or not np.array_equal(other.times,
                                                                         spreading.times):
            raise ValueError("the spreadings must share their cells and delays.")
    mean = np.mean([other.dem for other in others], axis=0)
    return np.abs(spreading.dem - mean).mean(axis=1)


def region_counts(run, n_regions: int) -> np.ndarray:
    """Spheres of each species in each of `n_regions` equal axial regions per frame.

    **Returns:** ``(frames, regions, species)`` integer array.
    """
    cells = axial_cells(run.positions[:, :, 2], run.geometry.length, n_regions,
                        periodic=run.geometry.periodic)
    keys = cells * run.n_species + run.species[None, :]
    counts = np.stack([np.bincount(k, minlength=n_regions * run.n_species) for k in keys])
    return counts.reshape(run.n_frames, n_regions, run.n_species)


@dataclass(frozen=True)
class Partition:
    """A partition of the regions between DEM and compartments.

    **Fields:** `method` ("flux" or "velocity"); `measure` ``(regions, species)`` for the
    flux method (standard deviation of the net flux, particles/s) or ``(regions,)`` for the
    velocity method (velocity variance, m²/s²); `score` ``(regions,)`` the value ranked;
    `dem_regions` the regions recommended for DEM (0-based, ascending).
    """

    method: str
    measure: np.ndarray
    score: np.ndarray
    dem_regions: tuple[int, ...]

    def table(self) -> str:
        """The partition as a text table."""
        lines = [f"partition by {self.method}: DEM in regions "
                 + ", ".join(str(i + 1) for i in self.dem_regions)]
        for i, s in enumerate(self.score):
            mark = "DEM" if i in self.dem_regions else "compartment"
            extra = ("  " + " ".join(f"{m:8.3f}" for m in np.atleast_1d(self.measure[i]))
                     if self.measure.ndim == 2 else "")
            lines.append(f"region {i + 1:2d}  {s:10.4g}{extra}  {mark}")
        return "\n".join(lines)


def _choose(score: np.ndarray, n_dem: int | None) -> tuple[int, ...]:
    if n_dem is None:
        chosen = np.nonzero(score > score.mean())[0]  # above the mean over regions
    else:
        if not 0 < n_dem <= score.size:
            raise ValueError(f"n_dem must be between 1 and {score.size}, got {n_dem}.")
        chosen = np.sort(np.argsort(score)[::-1][:n_dem])
    return tuple(int(i) for i in chosen)


def flux_partition(run, n_regions: int = 10, interval: float = 0.5,
                   n_dem: int | None = None) -> Partition:
    """The source's partition method I: regions whose net particle flux varies most go to DEM.

    **Arguments:**

    - `run`: a :class:`axialmix.dem.DEMRun`.
    - `n_regions`: equal axial regions (the source: 10 of 0.05 m).
    - `interval`: time between the counts whose differences are the fluxes, s.
    - `n_dem`: regions to put in DEM (the highest scores); default: every region whose score
      is above the mean.

    The score of a region is the larger of its species' flux standard deviations.
    **Returns:** a :class:`Partition`.
    """
    every = max(1, round(interval / run.frame_interval))
    counts = region_counts(run, n_regions)[::every].astype(float)
    if counts.shape[0] < 3:
        raise ValueError("the run is too short for fluxes over that interval (3 counts needed).")
    flux = np.diff(counts, axis=0) / (every * run.frame_interval)
    sd = flux.std(axis=0, ddof=1)
    score = sd.max(axis=1)
    return Partition("flux", sd, score, _choose(score, n_dem))


def velocity_partition(run, n_regions: int = 10, n_dem: int | None = None) -> Partition:
    """The source's partition method II: regions of high particle-velocity variance go to DEM.

    **Arguments:** as :func:`flux_partition`; the score of a region is the variance of the
    velocities (sum over the three components) of the spheres in it, over all frames, m²/s².

    **Returns:** a :class:`Partition`.
    """
    cells = axial_cells(run.positions[:, :, 2], run.geometry.length, n_regions,
                        periodic=run.geometry.periodic).ravel()
    v = run.velocities.reshape(-1, 3).astype(float)
    count = np.bincount(cells, minlength=n_regions).astype(float)
    mean = np.stack([np.bincount(cells, v[:, k], n_regions) for k in range(3)], 1)
    mean /= np.maximum(count, 1)[:, None]
    square = np.stack([np.bincount(cells, v[:, k] ** 2, n_regions) for k in range(3)], 1)
    variance = (square / np.maximum(count, 1)[:, None] - mean**2).sum(axis=1)
    return Partition("velocity", variance, variance, _choose(variance, n_dem))
