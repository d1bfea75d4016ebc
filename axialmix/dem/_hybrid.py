"""The hybrid run: DEM where the impeller is, the compartment particle engine elsewhere.

The mixer is cut into equal axial regions (MODELS.md §9). The first ``n_dem`` regions (the
impeller end, ``z = 0``) are simulated by DEM in a vessel cut by a flat wall at the interface
(:meth:`BladedMixer.truncated`); the other regions are compartments of
:mod:`axialmix.particles` (the species-count engine) with the rates of a learned network.
Every ``exchange_interval`` both parts advance side by side and then exchange particles at
the interface the source's way (its §7.8): ``m`` spheres picked at random in the DEM region
next to the interface hand their species to the first compartment, and ``m`` particles drawn
at random from that compartment hand theirs to those spheres. Only identities change (a
sphere keeps its position, velocity and contacts), so the particles of each species are
conserved exactly; ``m`` is the learned interface flux ``k N dt`` (the mean of both
directions, which balance at steady state).

:func:`composition_errors` compares per-region counts with a reference (a full DEM run) by
the source's measures (its §7.9): ``e_ij = (E_ij - H_ij) / E_ij × 100`` and
``sigma_j² = (1/eta) sum_i (E_ij - H_ij)²``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .._progress import progress_bar
from ._analysis import region_counts
from ._config import BladedMixer, RunSettings
from ._engine import DEMEngine, DEMRun
from ._learn import LearnedNetwork

__all__ = ["CompositionErrors", "HybridRun", "composition_errors", "dem_noise_floor",
           "run_hybrid", "twin_tracer_counts"]


@dataclass(frozen=True, eq=False)
class HybridRun:
    """What a hybrid run recorded.

    **Fields:**

    - `times`: record times, s from the start of rotation.
    - `counts`: ``(times, regions, species)`` particles of each species in each region.
    - `n_dem`: regions simulated by DEM (the first ones).
    - `dem_cpu_seconds`, `compartment_cpu_seconds`: CPU time of each part, s (settling of
      the DEM part included in the first; the compartment engine's one-time compilation,
      about 0.3 s, not in the second).
    - `exchanged`: particles swapped at the interface in each interval.
    - `interrupted`: whether Ctrl-C stopped the run.
    """

    times: np.ndarray
    counts: np.ndarray
    n_dem: int
    dem_cpu_seconds: float
    compartment_cpu_seconds: float
    exchanged: np.ndarray
    interrupted: bool

    @property
    def compartment_share(self) -> float:
        """Share of the hybrid's CPU time spent in the compartment part."""
        total = self.dem_cpu_seconds + self.compartment_cpu_seconds
        return self.compartment_cpu_seconds / total if total else float("nan")


def _moves(rates: np.ndarray, holdups: np.ndarray, dt: float) -> np.ndarray:
    # Whole particles per step between neighbouring regions of the chain (the learned rates'
    # longer jumps are left out), equal both ways so that the hold-ups stay constant.
    n = holdups.size
    flows = rates * holdups[:, None] * dt
    np.fill_diagonal(flows, 0)
    # A closed chain at steady state: the flow i -> i+1 equals i+1 -> i in the mean.
    moves = np.zeros((n, n), np.int64)
    for i in range(n - 1):
        m = int(round((flows[i, i + 1] + flows[i + 1, i]) / 2))
        moves[i, i + 1] = moves[i + 1, i] = m
    return moves


def run_hybrid(
    mixer: BladedMixer,
    learned: LearnedNetwork,
    initial_counts: np.ndarray,
    n_dem: int,
    settings: RunSettings,
    *,
    exchange_interval: float = 0.1,
    seed: int = 0,
    progress: bool | None = None,
) -> HybridRun:
    """Run the hybrid DEM + compartment simulation of the mixer.

    **Arguments:**

    - `mixer`: the full :class:`BladedMixer` (its regions are the learned network's cells:
      ``learned.n_cells`` equal axial regions).
    - `learned`: the region network (rates in 1/s) learned from a full DEM run.
    - `initial_counts`: ``(regions, species)`` counts at the start (from the reference run).
    - `n_dem`: the first `n_dem` regions are simulated by DEM (1 to regions - 1).
    - `settings`: :class:`RunSettings` (duration, record interval, settling, seed).
    - `exchange_interval`: time between interface exchanges (and compartment steps), s.
    - `seed`: seed of the compartment engine and the exchange draws.
    - `progress`: progress bar on standard error (default: when it is a terminal).

    **Returns:** a :class:`HybridRun`; Ctrl-C returns what was recorded.
    """
    from ..particles import ParticleNetwork, simulate

    n_regions = learned.n_cells
    initial_counts = np.asarray(initial_counts, np.int64)
    if initial_counts.shape != (n_regions, len(mixer.particles)):
        raise ValueError(f"initial_counts must have shape ({n_regions}, species).")
    if not 1 <= n_dem < n_regions:
        raise ValueError(f"n_dem must be between 1 and {n_regions - 1}, got {n_dem}.")
    width = mixer.length / n_regions
    dem_counts = initial_counts[:n_dem].sum(axis=0)
    part = mixer.truncated(n_dem * width, tuple(int(c) for c in dem_counts))
    comp = initial_counts[n_dem:].copy()
    holdups = comp.sum(axis=1)
    if np.any(holdups == 0):
        raise ValueError("every compartment region needs particles at the start.")
    dt = float(exchange_interval)
    moves = _moves(learned.rates[n_dem:, n_dem:], holdups.astype(float), dt)
    sources, targets = np.nonzero(moves)
    network = ParticleNetwork(holdups, sources, targets, moves[sources, targets],
                              step_seconds=dt)
    interface = learned.rates[n_dem - 1, n_dem] * learned.holdups[n_dem - 1]
    interface = (interface + learned.rates[n_dem, n_dem - 1] * learned.holdups[n_dem]) / 2 * dt
    rng = np.random.default_rng([seed, 7])
    # The engine's one-time compilation (about 0.3 s) is done before the clock starts.
    simulate(network, comp, 1, engine="count", seed=0)
    comp_cpu = 0.0
    steps_per_record = max(1, round(settings.record_interval / dt))
    n_exchanges = int(math.floor(settings.duration / dt + 1e-9))
    times, records, exchanged = [], [], []
    interrupted = False
    with DEMEngine(part, settings) as engine:
        engine.settle()
        chunk = max(1, round(dt / engine.time_step))
        layer_lo = (n_dem - 1) * width

        def record(step):
            x, _ = engine.state()
            cells = np.clip((x[:, 2] / width).astype(int), 0, n_dem - 1)
            dem = np.zeros((n_dem, len(mixer.particles)), np.int64)
            np.add.at(dem, (cells, engine.species), 1)
            times.append(step * chunk * engine.time_step)
            records.append(np.concatenate([dem, comp]))

        record(0)
        bar = progress_bar(total=n_exchanges, description="hybrid", unit="exchange",
                           enabled=progress)
        try:
            for step in range(1, n_exchanges + 1):
                engine.advance(chunk)
                clock = time.process_time()
                result = simulate(network, comp, 1, engine="count",
                                  seed=int(rng.integers(0, 2**32 - 1)))
                comp[:] = result.final_counts
                # Interface exchange by identity swap.
                m = int(rng.poisson(interface)) if interface > 0 else 0
                x, _ = engine.state()
                near = np.nonzero(x[:, 2] >= layer_lo)[0]
                m = min(m, near.size, int(comp[0].sum()))
                if m:
                    picked = rng.choice(near, size=m, replace=False)
                    leaving = np.bincount(engine.species[picked], minlength=comp.shape[1])
                    entering = rng.multivariate_hypergeometric(comp[0], m)
                    comp[0] += leaving - entering
                    engine.species[picked] = rng.permutation(
                        np.repeat(np.arange(comp.shape[1]), entering))
                exchanged.append(m)
                comp_cpu += time.process_time() - clock
                if step % steps_per_record == 0 or step == n_exchanges:
                    record(step)
                bar.update(1)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            bar.close()
        dem_cpu = engine.cpu_seconds
    return HybridRun(
        times=np.array(times), counts=np.array(records), n_dem=n_dem,
        dem_cpu_seconds=dem_cpu, compartment_cpu_seconds=comp_cpu,
        exchanged=np.array(exchanged), interrupted=interrupted,
    )


@dataclass(frozen=True)
class CompositionErrors:
    """Per-region composition errors of a run against a reference (the source's §7.9).

    **Fields:** `relative` ``(regions, species)`` ``|e_ij|`` in % (NaN where the reference
    has none of species j); `variance` ``(species,)`` ``sigma_j²`` (particles²);
    `average` the mean of the finite ``|e_ij|``, %.
    """

    relative: np.ndarray
    variance: np.ndarray
    average: float


def composition_errors(reference: np.ndarray, other: np.ndarray) -> CompositionErrors:
    """``e_ij = (E_ij - H_ij) / E_ij × 100`` (reported as magnitudes) and ``sigma_j²``.

    **Arguments:** `reference` ``E`` and `other` ``H``, ``(regions, species)`` counts.
    """
    e = np.asarray(reference, float)
    h = np.asarray(other, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        relative = np.where(e > 0, np.abs(e - h) / e * 100, np.nan)
    variance = ((e - h) ** 2).mean(axis=0)
    return CompositionErrors(relative, variance, float(np.nanmean(relative)))


def dem_noise_floor(run: DEMRun, n_regions: int, frame: int = -1, seed: int = 0
                    ) -> CompositionErrors:
    """The DEM's own noise on the source's error measures, from one run.

    Two random halves of every species (:func:`twin_tracer_counts`), each scaled to the
    whole, differ by ``a - b`` with twice the standard deviation of the whole's sampling
    noise; two independent runs differ by ``sqrt(2)`` times it. So ``|a - b| / sqrt(2)`` is
    what an exact hybrid's difference from a full DEM run would be: ``e_ij`` is
    ``|a - b| / sqrt(2) / ((a + b) / 2) × 100`` and ``sigma_j²`` the mean of ``(a - b)² / 2``.

    **Arguments:** `run`, `n_regions`; `frame` compared (default the last); `seed` of the split.
    """
    a, b = twin_tracer_counts(run, n_regions, seed=seed)
    a, b = a[frame], b[frame]
    mean = (a + b) / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        relative = np.where(mean > 0, np.abs(a - b) / math.sqrt(2) / mean * 100, np.nan)
    variance = ((a - b) ** 2 / 2).mean(axis=0)
    return CompositionErrors(relative, variance, float(np.nanmean(relative)))


def twin_tracer_counts(run: DEMRun, n_regions: int, seed: int = 0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Per-region counts of two equivalent halves of every species of one DEM run.

    Each species is split at random into two halves; both start from the same distribution
    and follow the same flow, so their difference is the DEM's own sampling noise.

    **Returns:** two ``(frames, regions, species)`` arrays, each scaled by 2 to the whole.
    """
    rng = np.random.default_rng(seed)
    half = np.zeros(run.n_particles, bool)
    for s in range(run.n_species):
        members = np.nonzero(run.species == s)[0]
        half[rng.choice(members, size=members.size // 2, replace=False)] = True
    counts = []
    for mask in (half, ~half):
        sub = DEMRun(run.geometry, run.settings, run.time_step, run.times,
                     run.positions[:, mask], run.velocities[:, mask], run.species[mask],
                     run.cpu_seconds, run.steps)
        counts.append(region_counts(sub, n_regions) * run.n_particles / mask.sum())
    return counts[0], counts[1]
