"""Run the particle process on a network with either engine; one interface, one result type.

Two engines implement the same random process (described in
:mod:`axialmix.particles.description`):

* ``"count"`` keeps species counts per compartment. Choosing ``L`` particles at random
  without replacement from a compartment matters only through how many of each species are
  chosen, a multivariate hypergeometric draw, so this is the same random process at a cost
  independent of the number of particles (a few draws per connection per step).
* ``"identity"`` keeps every particle (an array of particle codes per compartment) and
  selects by a partial Fisher-Yates shuffle, at a cost proportional to particles moved. It
  gives per-particle histories: every move of a tracked species is recorded.

Long runs are driven in chunks: progress is reported after every report interval, and a
``KeyboardInterrupt`` (Ctrl-C) ends the run after the current chunk, returning everything
done so far (``result.interrupted`` is then true).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from axialmix.particles import _kernels
from axialmix.particles._random import seed_generator, xoshiro_state
from axialmix.particles.description import ParticleNetwork
from axialmix.particles.feed import check_feed_schedule
from axialmix.particles.schedule import _move_table, check_move_schedule

__all__ = [
    "ENGINES",
    "MAX_SEED",
    "MemoryEstimate",
    "SimulationResult",
    "TracerPulse",
    "memory_estimate",
    "simulate",
]

ENGINES = ("count", "identity")
MAX_SEED = 2**32 - 1
"""Largest seed: the compiled kernels draw from numpy's legacy generator, seeded with 32 bits."""
_MAX_CHUNK_STEPS = 10_000
_EVENT_BLOCK = 1 << 20


@dataclass(frozen=True)
class TracerPulse:
    """An ideal tracer pulse: particles in the inlet compartment(s) relabelled as tracer.

    At the start of step ``step``, ``particles`` particles chosen at random in the inlet
    compartments (split in proportion to their feed) get the species ``species``. This is
    the unit pulse into the inlet compartment of MODELS.md section 3, so the exit counts of
    the tracer divided by ``particles`` estimate the network's RTD.

    **Arguments:**

    - `step`: step at whose start the tracer appears.
    - `particles`: number of tracer particles.
    - `species`: species index given to them (usually a species not otherwise fed).
    """

    step: int
    particles: int
    species: int

    def __post_init__(self) -> None:
        if self.step < 0:
            raise ValueError(f"tracer pulse step must not be negative, got {self.step}.")
        if self.particles <= 0:
            raise ValueError(f"tracer pulse needs a positive particle count, got {self.particles}.")
        if self.species < 0:
            raise ValueError(f"tracer species must not be negative, got {self.species}.")


@dataclass
class SimulationResult:
    """What a particle simulation produced (everything up to the last completed step).

    **Fields:**

    - `engine`, `seed`: how it was run.
    - `steps_requested`, `steps_completed`: the run's length, and how far it got.
    - `interrupted`: whether it was stopped early (Ctrl-C or a progress callback raising
      ``KeyboardInterrupt``).
    - `report_steps`: steps (after that many steps) at which counts were recorded.
    - `counts`: species counts ``(reports, compartments, species)`` at `report_steps`.
    - `outflow`: species counts that left over the weir during each step ``(steps, species)``
      (zero rows for a batch blender).
    - `fed`: the feed schedule actually used ``(steps, inlets, species)``.
    - `tracer`: the tracer pulse, if any.
    - `events`: identity engine only: ``(events, 4)`` rows ``(particle, step, from, to)`` for
      every move of a tracked species; ``from = -1`` fed in, ``from = -2`` tagged as tracer
      in place, ``to = -1`` left over the weir.
    - `wall_seconds`: time spent in the simulation loop.
    - `moves`: the move schedule used ``(steps, connections)``, or ``None`` when every step
      moved the network's own numbers (see :mod:`axialmix.particles.schedule`).
    """

    engine: str
    seed: int
    network: ParticleNetwork
    steps_requested: int
    steps_completed: int
    interrupted: bool
    report_steps: np.ndarray
    counts: np.ndarray
    outflow: np.ndarray
    fed: np.ndarray
    tracer: TracerPulse | None
    events: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    wall_seconds: float = 0.0
    moves: np.ndarray | None = None

    @property
    def final_counts(self) -> np.ndarray:
        """Species counts per compartment after the last completed step."""
        return self.counts[-1]

    def particles_moved(self) -> int:
        """Particles moved in the completed steps (over connections and the weir)."""
        if self.moves is None:
            return self.steps_completed * self.network.moves_per_step
        done = self.moves[: self.steps_completed]
        return int(done.sum() + self.steps_completed * self.network.outflow.sum())

    def exit_steps(self) -> np.ndarray:
        """Identity engine: the step during which each tracked particle left (``-1`` if still in).

        **Returns:** ``(particles, 2)`` integer array of rows ``(particle number, exit step)``.
        """
        if self.events.shape[0] == 0:
            return np.zeros((0, 2), np.int64)
        particles = np.unique(self.events[:, 0])
        exits = np.full(particles.size, -1, np.int64)
        left = self.events[self.events[:, 3] == _kernels.WEIR]
        exits[np.searchsorted(particles, left[:, 0])] = left[:, 1]
        return np.column_stack([particles, exits])

    def history(self, particle: int) -> tuple[np.ndarray, np.ndarray]:
        """Identity engine: compartments a tracked particle visited and steps spent in each.

        **Returns:** ``(compartments, steps_spent)``; the last stay is counted up to its exit
        or to the last completed step.
        """
        rows = self.events[self.events[:, 0] == particle]
        if rows.shape[0] == 0:
            raise ValueError(f"particle {particle} was not tracked.")
        rows = rows[np.argsort(rows[:, 1], kind="stable")]
        # A particle tagged or fed during step k sits in its compartment from the end of step
        # k (fed) or the start of step k (tagged); a move during step k takes effect at its end.
        entered = np.where(rows[:, 2] == _kernels.TAGGED, rows[:, 1], rows[:, 1] + 1)
        places = rows[:, 3]
        stays = places >= 0
        ends = np.append(rows[1:, 1] + 1, self.steps_completed)
        if not stays[-1]:
            ends[-1] = rows[-1, 1] + 1
        return places[stays], (ends - entered)[stays]


class MemoryEstimate(NamedTuple):
    """Memory a simulation will allocate, in bytes, split by what it grows with."""

    per_step: int
    """Bytes of the records that grow with the number of steps (feed schedule, outflow)."""
    per_particle: int
    """Bytes that grow with the number of particles (the identity engine's particle slots)."""
    fixed: int
    """Reports, tables and buffers."""

    @property
    def total(self) -> int:
        """All of it (bytes)."""
        return self.per_step + self.per_particle + self.fixed


def memory_estimate(
    network: ParticleNetwork,
    steps: int,
    n_species: int,
    *,
    engine: str = "count",
    reports: int = 2,
    tracked: bool = False,
) -> MemoryEstimate:
    """The memory :func:`simulate` allocates for a run, before running it.

    Counts the arrays the run creates: the feed schedule ``(steps, inlets, species)`` and
    the outflow record ``(steps, species)`` (int64 each, plus the float copy a feed builder
    makes), the counts at each report, and for the identity engine one slot code per
    particle (4 or 8 bytes, plus a byte while they are built) and the event buffer.

    **Arguments:**

    - `network`: the blender.
    - `steps`: number of steps.
    - `n_species`: number of species.
    - `engine`: ``"count"`` or ``"identity"``.
    - `reports`: number of recorded reports.
    - `tracked`: identity engine: whether some species' moves are recorded.

    **Returns:** a :class:`MemoryEstimate` (bytes).
    """
    steps, n_species = int(steps), int(n_species)
    inlets = int(network.inlets().size) if network.is_continuous else 0
    per_step = steps * n_species * 8 * (1 + 2 * inlets)
    per_particle = 0
    fixed = (reports + 2) * network.n_compartments * n_species * 8
    if engine == "identity":
        numbers = network.n_particles + network.throughput * steps
        fits = numbers << _kernels.species_bits(n_species) <= np.iinfo(np.int32).max
        per_particle = network.n_particles * ((4 if fits else 8) + 1)
        fixed += 8 * (network.moves_per_step + int(network.handed_out.max(initial=0)))
        if tracked:
            fixed += 32 * max(_EVENT_BLOCK, 2 * (network.moves_per_step + network.throughput))
    return MemoryEstimate(per_step, per_particle, fixed)


def _initial_counts(network: ParticleNetwork, initial_counts) -> np.ndarray:
    counts = np.asarray(initial_counts)
    if counts.ndim != 2 or counts.shape[0] != network.n_compartments or counts.shape[1] < 1:
        raise ValueError(
            f"initial_counts must have shape (compartments, species) with "
            f"{network.n_compartments} compartments, got {counts.shape}."
        )
    if not np.issubdtype(counts.dtype, np.integer):
        if np.any(np.rint(counts) != counts):
            raise ValueError("initial_counts must hold whole numbers of particles.")
    counts = counts.astype(np.int64)
    if np.any(counts < 0):
        raise ValueError("initial_counts must not be negative.")
    wrong = np.nonzero(counts.sum(axis=1) != network.holdups)[0]
    if wrong.size:
        i = int(wrong[0])
        raise ValueError(
            f"initial counts of compartment {i} add up to {counts[i].sum()}, "
            f"but its hold-up is {network.holdups[i]}."
        )
    return np.ascontiguousarray(counts)


def _report_schedule(steps: int, report_every: int | None, report_steps) -> np.ndarray:
    if report_steps is not None:
        chosen = np.unique(np.asarray(report_steps, dtype=np.int64))
        if chosen.size and (chosen[0] < 0 or chosen[-1] > steps):
            raise ValueError(f"report_steps must lie between 0 and steps ({steps}).")
    elif report_every is not None:
        if report_every < 1:
            raise ValueError(f"report_every must be at least 1, got {report_every}.")
        chosen = np.arange(0, steps + 1, report_every, dtype=np.int64)
    else:
        chosen = np.array([0], np.int64)
    return np.union1d(chosen, [0, steps]).astype(np.int64)


def _apportion(total: int, weights: np.ndarray) -> np.ndarray:
    # Largest-remainder split of a whole number in proportion to weights.
    exact = total * weights / weights.sum()
    shares = np.floor(exact).astype(np.int64)
    order = np.argsort(shares - exact, kind="stable")
    shares[order[: total - shares.sum()]] += 1
    return shares


def _rows(array: np.ndarray, first: int) -> np.ndarray:
    """A move table's rows from step `first` on (a one-row table serves every step)."""
    return array if array.shape[0] == 1 else array[first:]


class _CountEngine:
    def __init__(
        self,
        network: ParticleNetwork,
        counts: np.ndarray,
        tracked: np.ndarray,
        seed: int,
        particle_numbers: int,
        table: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ) -> None:
        self.network = network
        self.counts = counts
        self.table = table
        self.inlets = network.inlets().astype(np.int64)
        # [steps done]: advanced in place by the kernel, so it is right even after Ctrl-C.
        self.progress = np.zeros(1, np.int64)

    @property
    def steps_done(self) -> int:
        return int(self.progress[0])

    def advance(self, schedule: np.ndarray, outflow: np.ndarray, n_steps: int) -> None:
        start, destination, count, handed_out = self.table
        _kernels.advance_counts(
            self.counts,
            self.network.holdups,
            start,
            destination,
            _rows(count, self.steps_done),
            _rows(handed_out, self.steps_done),
            self.inlets,
            schedule,
            outflow,
            n_steps,
            self.progress,
        )

    def tag(self, compartment: int, particles: int, species: int, rng: np.random.Generator) -> None:
        others = self.counts[compartment].copy()
        others[species] = 0
        chosen = rng.multivariate_hypergeometric(others, particles, method="marginals")
        self.counts[compartment] -= chosen
        self.counts[compartment, species] += particles

    def events(self) -> np.ndarray:
        return np.zeros((0, 4), np.int64)


class _IdentityEngine:
    def __init__(
        self,
        network: ParticleNetwork,
        counts: np.ndarray,
        tracked: np.ndarray,
        seed: int,
        particle_numbers: int,
        table: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ) -> None:
        self.network = network
        self.counts = counts
        self.tracked = tracked
        # 32-bit slot codes while every particle number of the run fits (a billion with two
        # species): half the memory traffic of the random selections, about 30 % faster.
        self.bits = _kernels.species_bits(counts.shape[1])
        fits = particle_numbers << self.bits <= np.iinfo(np.int32).max
        code_type = np.int32 if fits else np.int64
        self.table = table
        self.inlets = network.inlets().astype(np.int64)
        n_species = counts.shape[1]
        self.offsets = np.zeros(network.n_compartments + 1, np.int64)
        self.offsets[1:] = np.cumsum(network.holdups)
        # Build the slot codes in place: peak memory is the slots plus one byte per particle.
        species = np.repeat(
            np.tile(np.arange(n_species, dtype=np.int8), network.n_compartments), counts.ravel()
        )
        self.slots = np.arange(self.offsets[-1], dtype=code_type)
        np.left_shift(self.slots, self.bits, out=self.slots)
        np.bitwise_or(self.slots, species, out=self.slots)
        del species
        # [steps done, events in the buffer, next particle number]
        self.progress = np.array([0, 0, self.offsets[-1]], np.int64)
        moves_per_step = int(table[2].sum(axis=1).max(initial=0))
        block = max(_EVENT_BLOCK, 2 * (moves_per_step + network.throughput))
        self.buffer = np.zeros((block if tracked.any() else 0, 4), np.int64)
        self.blocks: list[np.ndarray] = []
        self.moved = np.empty(moves_per_step, code_type)
        self.picks = np.empty(int(table[3].max(initial=0)), np.int64)
        self.write = np.empty(network.n_compartments, np.int64)
        self.generator = xoshiro_state(seed)

    @property
    def steps_done(self) -> int:
        return int(self.progress[0])

    def _flush(self) -> None:
        self.blocks.append(self.buffer[: self.progress[1]].copy())
        self.progress[1] = 0

    def advance(self, schedule: np.ndarray, outflow: np.ndarray, n_steps: int) -> None:
        start, destination, count, handed_out = self.table
        first = self.steps_done
        while self.steps_done - first < n_steps:
            offset = self.steps_done - first
            _kernels.advance_identities(
                self.slots,
                self.offsets,
                self.counts,
                start,
                destination,
                _rows(count, self.steps_done),
                _rows(handed_out, self.steps_done),
                self.inlets,
                schedule[offset:],
                outflow[offset:],
                self.steps_done,
                n_steps - offset,
                self.tracked,
                self.buffer,
                self.moved,
                self.picks,
                self.write,
                self.generator,
                self.progress,
            )
            if self.steps_done - first < n_steps:
                self._flush()

    def tag(self, compartment: int, particles: int, species: int, rng: np.random.Generator) -> None:
        lo, hi = self.offsets[compartment], self.offsets[compartment + 1]
        codes = self.slots[lo:hi]
        mask = (1 << self.bits) - 1
        candidates = np.nonzero((codes & mask) != species)[0]
        chosen = rng.choice(candidates, size=particles, replace=False)
        old_species = codes[chosen] & mask
        numbers = codes[chosen] >> self.bits
        codes[chosen] = (numbers << self.bits) | species
        self.counts[compartment] -= np.bincount(old_species, minlength=self.counts.shape[1])
        self.counts[compartment, species] += particles
        if self.tracked[species]:
            rows = np.column_stack(
                [
                    numbers,
                    np.full(particles, self.steps_done),
                    np.full(particles, _kernels.TAGGED),
                    np.full(particles, compartment),
                ]
            )
            self.blocks.append(rows.astype(np.int64))

    def events(self) -> np.ndarray:
        parts = [*self.blocks, self.buffer[: self.progress[1]]]
        every = np.concatenate(parts) if parts else np.zeros((0, 4), np.int64)
        # Rows are unique (a particle makes at most one move per step, plus perhaps being
        # tagged at its start), so sorting out duplicates left by an interrupted flush is safe.
        every = np.unique(every, axis=0)
        return every[np.lexsort((every[:, 2] != _kernels.TAGGED, every[:, 1], every[:, 0]))]


def simulate(
    network: ParticleNetwork,
    initial_counts,
    steps: int,
    *,
    engine: str = "count",
    seed: int = 0,
    feed=None,
    tracer: TracerPulse | None = None,
    report_every: int | None = None,
    report_steps: Sequence[int] | None = None,
    tracked_species: Sequence[int] | None = None,
    progress: Callable[[int, int, float], None] | None = None,
    moves=None,
) -> SimulationResult:
    """Simulate the stochastic particle process on a network for a number of steps.

    **Arguments:**

    - `network`: the blender (:class:`ParticleNetwork`).
    - `initial_counts`: species counts per compartment at step 0, ``(compartments,
      species)``; each row must add up to the compartment's hold-up.
    - `steps`: number of time steps.
    - `engine`: ``"count"`` or ``"identity"`` (same random process; see the module).
    - `seed`: seed of the run, 0 to :data:`MAX_SEED`; the same seed, engine and inputs give
      the same result.
    - `feed`: feed schedule ``(steps, inlets, species)`` for a continuous blender (see
      :mod:`axialmix.particles.feed`); ``None`` for a batch blender.
    - `tracer`: optional :class:`TracerPulse`.
    - `report_every`: record counts (and call `progress`) every this many steps.
    - `report_steps`: or record counts exactly at these steps. Step 0 and the last step are
      always recorded.
    - `tracked_species`: identity engine: species whose every move is recorded (default:
      the tracer's species, if there is a tracer).
    - `progress`: called as ``progress(step, steps, elapsed_seconds)`` at each report (for
      example to update an :func:`axialmix._progress.progress_bar`). A
      ``KeyboardInterrupt`` raised there or by Ctrl-C stops the run after the current chunk
      and returns what was done.
    - `moves`: optional move schedule ``(steps, connections)``: the particles moved along
      each connection at each step (scheduled exchange rates, e.g. from
      :func:`axialmix.particles.scheduled_moves`); every step must keep the hold-ups
      constant. Default: the network's own moves at every step.

    **Returns:** a :class:`SimulationResult`.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}.")
    if int(steps) != steps or steps < 0:
        raise ValueError(f"steps must be a non-negative whole number, got {steps}.")
    steps = int(steps)
    if int(seed) != seed or not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seed must be a whole number from 0 to {MAX_SEED}, got {seed}.")
    seed = int(seed)
    counts = _initial_counts(network, initial_counts)
    n_species = counts.shape[1]
    if tracer is not None:
        if tracer.step >= steps:
            raise ValueError(
                f"tracer pulse step {tracer.step} must be before the last step ({steps})."
            )
        if not network.is_continuous:
            raise ValueError("a tracer pulse needs a continuous blender (one with feed).")
        if tracer.species >= n_species:
            raise ValueError(
                f"tracer species {tracer.species} is not below the number of species {n_species}."
            )
        inlets = network.inlets()
        too_big = _apportion(tracer.particles, network.feed[inlets]) > network.holdups[inlets]
        if too_big.any():
            raise ValueError(
                f"tracer pulse of {tracer.particles} particles does not fit in the inlet "
                f"compartment(s) holding {network.holdups[inlets].tolist()} particles."
            )
    if tracked_species is None:
        tracked_species = (tracer.species,) if tracer is not None and engine == "identity" else ()
    tracked = np.zeros(n_species, np.bool_)
    for s in tracked_species:
        if not 0 <= s < n_species:
            raise ValueError(f"tracked species {s} is not a species index below {n_species}.")
        tracked[s] = True
    if tracked.any() and engine != "identity":
        raise ValueError("tracked_species needs the identity engine.")
    if engine == "identity":
        if n_species > _kernels.MAX_SPECIES:
            raise ValueError(f"the identity engine handles at most {_kernels.MAX_SPECIES} species.")
        numbers = network.n_particles + network.throughput * steps
        if numbers >= 1 << (63 - _kernels.species_bits(n_species)):
            raise ValueError("too many particles over the run for the identity engine.")
    schedule = check_feed_schedule(network, feed, steps, n_species)
    if moves is not None:
        moves = check_move_schedule(network, moves, steps)
    table = _move_table(network, moves)
    reports = _report_schedule(steps, report_every, report_steps)
    boundaries = np.union1d(reports, [] if tracer is None else [tracer.step])
    outflow = np.zeros((steps, n_species), np.int64)
    rng = np.random.default_rng([seed, 1])
    seed_generator(seed)
    engine_type = _CountEngine if engine == "count" else _IdentityEngine
    state = engine_type(
        network, counts, tracked, seed, network.n_particles + network.throughput * steps, table
    )

    recorded_steps = [0]
    recorded_counts = [counts.copy()]
    interrupted = False
    clock = time.perf_counter()
    try:
        while state.steps_done < steps:
            done = state.steps_done
            if tracer is not None and done == tracer.step:
                inlets = network.inlets()
                for j, share in zip(
                    inlets, _apportion(tracer.particles, network.feed[inlets]), strict=True
                ):
                    available = network.holdups[j] - counts[j, tracer.species]
                    if share > available:
                        raise ValueError(
                            f"tracer pulse of {tracer.particles} particles does not fit in the "
                            f"inlet compartment(s) ({share} > {available} in compartment {j})."
                        )
                    state.tag(int(j), int(share), tracer.species, rng)
            target = min(int(boundaries[boundaries > done][0]), done + _MAX_CHUNK_STEPS)
            state.advance(schedule[done:target], outflow[done:target], target - done)
            done = state.steps_done
            if done in reports:
                recorded_steps.append(done)
                recorded_counts.append(counts.copy())
                if progress is not None:
                    progress(done, steps, time.perf_counter() - clock)
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - clock
    done = state.steps_done
    if recorded_steps[-1] != done:
        recorded_steps.append(done)
        recorded_counts.append(counts.copy())
    return SimulationResult(
        engine=engine,
        seed=seed,
        network=network,
        steps_requested=steps,
        steps_completed=done,
        interrupted=interrupted,
        report_steps=np.array(recorded_steps, np.int64),
        counts=np.array(recorded_counts),
        outflow=outflow[:done],
        fed=schedule[:done],
        tracer=tracer,
        events=state.events(),
        wall_seconds=wall,
        moves=None if moves is None else moves[:done],
    )
