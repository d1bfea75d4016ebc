"""The network a particle simulation runs on: compartments, hold-ups, moves per step, feed, weir.

This is the particle-level reading of a compartment network (MODELS.md sections 3 and 4):
integer numbers of particles held in each compartment and integer numbers moved per time
step along each connection. :class:`ParticleNetwork` holds only plain integer arrays, so the
engines need nothing else; :mod:`axialmix.particles.presets` builds the project's standard
networks.

The random process on a network, one time step (the semantics every engine implements):

1. All selections are drawn simultaneously from the contents at the START of the step.
   Compartment i hands out ``L_i = sum_j moves_ij + outflow_i`` distinct particles, chosen
   uniformly at random without replacement, and partitions them uniformly at random among
   its destinations (``moves_ij`` to each connection i -> j, ``outflow_i`` over the weir);
   so a particle is selected by at most one outgoing connection per step.
2. The selected particles arrive at their destinations; those sent over the weir leave.
3. The feed of the step (``feed_i`` particles into each inlet compartment) arrives.

Each particle therefore follows the Markov chain with transition probabilities
``moves_ij / N_i``, and the expected species counts obey the discrete mean-field network
``m_{k+1} = (I + Q) m_k + f_k`` with ``Q_ji = moves_ij / N_i`` and ``Q_ii = -L_i / N_i``
(:meth:`ParticleNetwork.step_matrix`). Every compartment must be balanced (particles in per
step = particles out per step), so hold-ups stay constant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ParticleNetwork"]


def _integer_array(name: str, values, shape_hint: str) -> np.ndarray:
    array = np.asarray(values)
    if array.size and not np.issubdtype(array.dtype, np.integer):
        rounded = np.rint(array)
        if not np.all(np.isfinite(array)) or np.any(rounded != array):
            raise ValueError(f"{name} must hold whole numbers of particles ({shape_hint}).")
        array = rounded
    array = array.astype(np.int64)
    if np.any(array < 0):
        raise ValueError(f"{name} must not be negative.")
    return array


def _rebalance(n, sources, targets, moves, feed, outflow) -> np.ndarray:
    # Rounding moves separately can leave a compartment receiving a particle more or less
    # than it hands out. Each unit of surplus at u is sent one particle further along the
    # shortest path of connections to a compartment in deficit: every compartment on the
    # path stays balanced, u and the end of the path become balanced. Changes are one
    # particle per step per connection used, the size of the rounding itself.
    moves = moves.copy()
    outgoing: list[list[int]] = [[] for _ in range(n)]
    for e, s in enumerate(sources):
        outgoing[int(s)].append(e)
    while True:
        surplus = (
            np.bincount(targets, weights=moves, minlength=n)
            + feed
            - np.bincount(sources, weights=moves, minlength=n)
            - outflow
        )
        start = np.nonzero(surplus > 0)[0]
        if start.size == 0:
            return moves
        u = int(start[0])
        previous = {u: -1}
        queue = [u]
        end = -1
        while queue and end < 0:
            node = queue.pop(0)
            for e in outgoing[node]:
                t = int(targets[e])
                if t not in previous:
                    previous[t] = e
                    if surplus[t] < 0:
                        end = t
                        break
                    queue.append(t)
        if end < 0:
            raise ValueError(f"rounding left compartment {u} unbalanced and no path can fix it.")
        node = end
        while node != u:
            e = previous[node]
            moves[e] += 1
            node = int(sources[e])


@dataclass(frozen=True, eq=False)
class ParticleNetwork:
    """Compartments holding whole particles, with whole numbers of particles moved per step.

    **Arguments:**

    - `holdups`: particles held in each compartment, shape ``(compartments,)``.
    - `sources`, `targets`: compartment indices (from 0) of each connection ``i -> j``.
    - `moves`: particles moved along each connection per time step.
    - `feed`: particles fed into each compartment per step (zero except at the inlets);
      ``None`` for a batch blender.
    - `outflow`: particles leaving each compartment over the weir per step (zero except at
      the outlet); ``None`` for a batch blender.
    - `names`: optional compartment names.
    - `step_seconds`: physical duration of one step in seconds (for RTD times).

    Raises ``ValueError`` with one sentence when the description is inconsistent: an index
    out of range, a self-connection, a compartment asked to hand out more particles than it
    holds, or one whose inflow per step differs from its outflow.
    """

    holdups: np.ndarray
    sources: np.ndarray
    targets: np.ndarray
    moves: np.ndarray
    feed: np.ndarray
    outflow: np.ndarray
    names: tuple[str, ...]
    step_seconds: float

    def __init__(
        self,
        holdups,
        sources,
        targets,
        moves,
        feed=None,
        outflow=None,
        names=None,
        step_seconds: float = 1.0,
    ) -> None:
        holdups = _integer_array("holdups", holdups, "one per compartment")
        if holdups.ndim != 1 or holdups.size == 0:
            raise ValueError("holdups must be a non-empty 1-D array, one per compartment.")
        n = holdups.size
        sources = _integer_array("sources", sources, "compartment indices").reshape(-1)
        targets = _integer_array("targets", targets, "compartment indices").reshape(-1)
        moves = _integer_array("moves", moves, "particles per step").reshape(-1)
        if not (sources.size == targets.size == moves.size):
            raise ValueError("sources, targets and moves must have one entry per connection.")
        if np.any(sources >= n) or np.any(targets >= n):
            raise ValueError(f"connection indices must be below the number of compartments ({n}).")
        if np.any(sources == targets):
            raise ValueError("a connection must join two different compartments.")
        pairs = set(zip(sources.tolist(), targets.tolist(), strict=True))
        if len(pairs) != sources.size:
            raise ValueError("each connection i -> j may appear only once.")
        feed = np.zeros(n, np.int64) if feed is None else _integer_array("feed", feed, "per step")
        outflow = (
            np.zeros(n, np.int64)
            if outflow is None
            else _integer_array("outflow", outflow, "per step")
        )
        if feed.shape != (n,) or outflow.shape != (n,):
            raise ValueError("feed and outflow must have one entry per compartment.")
        if feed.sum() != outflow.sum():
            raise ValueError(
                f"feed per step ({feed.sum()}) must equal outflow per step ({outflow.sum()})."
            )
        out_total = np.bincount(sources, weights=moves, minlength=n).astype(np.int64) + outflow
        in_total = np.bincount(targets, weights=moves, minlength=n).astype(np.int64) + feed
        over = np.nonzero(out_total > holdups)[0]
        if over.size:
            i = int(over[0])
            raise ValueError(
                f"compartment {i} hands out {out_total[i]} particles per step "
                f"but holds {holdups[i]}."
            )
        unbalanced = np.nonzero(out_total != in_total)[0]
        if unbalanced.size:
            i = int(unbalanced[0])
            raise ValueError(
                f"compartment {i} receives {in_total[i]} particles per step but hands out "
                f"{out_total[i]}; hold-ups must stay constant."
            )
        if not (np.isfinite(step_seconds) and step_seconds > 0):
            raise ValueError(f"step_seconds must be positive, got {step_seconds}.")
        if names is None:
            names = tuple(f"C{i + 1}" for i in range(n))
        names = tuple(str(x) for x in names)
        if len(names) != n:
            raise ValueError("names must have one entry per compartment.")
        for key, value in (
            ("holdups", holdups),
            ("sources", sources),
            ("targets", targets),
            ("moves", moves),
            ("feed", feed),
            ("outflow", outflow),
        ):
            value.setflags(write=False)
            object.__setattr__(self, key, value)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "step_seconds", float(step_seconds))

    @property
    def n_compartments(self) -> int:
        """Number of compartments."""
        return int(self.holdups.size)

    @property
    def n_particles(self) -> int:
        """Particles held in the blender (constant in time)."""
        return int(self.holdups.sum())

    @property
    def throughput(self) -> int:
        """Particles fed (and leaving over the weir) per step; zero for a batch blender."""
        return int(self.feed.sum())

    @property
    def is_continuous(self) -> bool:
        """Whether particles are fed and leave over the weir."""
        return self.throughput > 0

    @property
    def handed_out(self) -> np.ndarray:
        """Particles each compartment hands out per step (connections plus weir)."""
        n = self.n_compartments
        moved = np.bincount(self.sources, weights=self.moves, minlength=n).astype(np.int64)
        return moved + self.outflow

    @property
    def moves_per_step(self) -> int:
        """Particles moved per step, over connections and the weir (the feed not counted)."""
        return int(self.moves.sum() + self.outflow.sum())

    def step_matrix(self) -> np.ndarray:
        """The matrix ``I + Q`` of the discrete mean-field network ``m_{k+1} = (I + Q) m_k + f_k``.

        **Returns:** ``(compartments, compartments)`` float array; column i says where the
        content of compartment i is, in expectation, after one step.
        """
        n = self.n_compartments
        fractions = self.moves / self.holdups[self.sources]
        matrix = np.eye(n) - np.diag(self.handed_out / self.holdups)
        np.add.at(matrix, (self.targets, self.sources), fractions)
        return matrix

    def outflow_fractions(self) -> np.ndarray:
        """Fraction of each compartment's content leaving over the weir per step."""
        return self.outflow / self.holdups

    def outgoing_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Outgoing moves grouped by source compartment, for the engines.

        **Returns:** ``(start, destination, count)``: the moves of compartment i are entries
        ``start[i]:start[i+1]``; a destination of ``-1`` means over the weir.
        """
        n = self.n_compartments
        rows: list[list[tuple[int, int]]] = [[] for _ in range(n)]
        for s, t, m in zip(self.sources, self.targets, self.moves, strict=True):
            if m > 0:
                rows[int(s)].append((int(t), int(m)))
        for i in range(n):
            if self.outflow[i] > 0:
                rows[i].append((-1, int(self.outflow[i])))
        start = np.zeros(n + 1, np.int64)
        start[1:] = np.cumsum([len(r) for r in rows])
        destination = np.array([t for r in rows for t, _ in r], dtype=np.int64)
        count = np.array([m for r in rows for _, m in r], dtype=np.int64)
        return start, destination, count

    def inlets(self) -> np.ndarray:
        """Indices of the compartments that receive feed."""
        return np.nonzero(self.feed > 0)[0]

    @classmethod
    def from_network(
        cls,
        network,
        *,
        total_particles: int | None = None,
        time_step: float | None = None,
        round_moves: bool = False,
    ) -> ParticleNetwork:
        """The particle reading of an :class:`axialmix.network.CompartmentNetwork`.

        Hold-ups come from the network (scaled to `total_particles` if given); moves per step
        are ``lambda_ij = f_ij N_i`` with the network's per-step fractions; the feed replaces
        the outflow and is split by the inlets' feed fractions.

        **Arguments:**

        - `network`: a network with hold-ups (discrete, or continuous with `time_step`).
        - `total_particles`: total number of particles (default: the network's hold-ups).
        - `time_step`: step length (s) for a continuous network.
        - `round_moves`: if false (default), every hold-up and move must already be a whole
          number (to 1e-6); if true they are rounded to the nearest one, and the simulated
          network is the rounded one (compare with :meth:`to_network`, not the original).

        **Returns:** a :class:`ParticleNetwork`. Raises ``ValueError`` if the numbers are not
        whole (without `round_moves`) or if rounding leaves a compartment unbalanced.
        """
        if network.holdups is None:
            raise ValueError("the network has no hold-ups; a particle simulation needs them.")
        holdups = np.asarray(network.holdups, dtype=float)
        if total_particles is not None:
            holdups = holdups * (total_particles / holdups.sum())
        dt = None if network.is_discrete else time_step
        if dt is None and not network.is_discrete:
            raise ValueError("a continuous network needs a time_step for particle moves.")
        moves = network.particle_moves(holdups, dt)
        sources, targets = network.sources, network.targets
        per_connection = moves[sources, targets]
        outflow = network.outflow_per_step(holdups, dt)
        feed = network.feed_per_step(holdups, dt)

        def whole(name: str, values: np.ndarray) -> np.ndarray:
            rounded = np.rint(values)
            off = np.abs(values - rounded) > 1e-6 * np.maximum(1.0, np.abs(values))
            if off.any() and not round_moves:
                k = int(np.argmax(off))
                raise ValueError(
                    f"{name} {values[k]:.6g} (entry {k}) is not a whole number of particles; "
                    "choose the particle total or time step to make it whole, or round_moves=True."
                )
            return rounded.astype(np.int64)

        int_holdups = whole("hold-up", holdups)
        int_moves = whole("particles moved per step", per_connection)
        int_outflow = whole("outflow per step", outflow)
        int_feed = whole("feed per step", feed)
        if int_feed.sum() != int_outflow.sum():
            # Rounding the feed split separately can lose a particle; give it to the inlets
            # with the largest remainders so feed equals outflow exactly.
            split = network.feed_split * int_outflow.sum()
            int_feed = np.floor(split).astype(np.int64)
            order = np.argsort(int_feed - split, kind="stable")
            int_feed[order[: int_outflow.sum() - int_feed.sum()]] += 1
        if round_moves:
            int_moves = _rebalance(
                int_holdups.size, sources, targets, int_moves, int_feed, int_outflow
            )
        keep = int_moves > 0
        step_seconds = network.time_step if network.is_discrete else time_step
        try:
            return cls(
                int_holdups,
                sources[keep],
                targets[keep],
                int_moves[keep],
                feed=int_feed,
                outflow=int_outflow,
                names=network.compartments,
                step_seconds=1.0 if step_seconds is None else step_seconds,
            )
        except ValueError as err:
            raise ValueError(f"rounded particle network is not consistent: {err}") from None

    def to_network(self):
        """The discrete :class:`axialmix.network.CompartmentNetwork` this particle network realises.

        Its per-step fractions are ``moves_ij / N_i`` exactly, so its mean-field model is the
        expectation of this particle process (the reference for checking simulations).
        """
        from axialmix.network import CompartmentNetwork

        names = self.names
        connections = [
            (names[s], names[t], m / self.holdups[s])
            for s, t, m in zip(self.sources, self.targets, self.moves, strict=True)
        ]
        inlets = [(names[i], self.feed[i] / self.throughput) for i in self.inlets()]
        outlets = [
            (names[i], self.outflow[i] / self.holdups[i]) for i in np.nonzero(self.outflow)[0]
        ]
        return CompartmentNetwork(
            compartments=names,
            connections=connections,
            inlets=inlets,
            outlets=outlets,
            holdups=self.holdups.astype(float).tolist(),
            time_step=self.step_seconds,
            description="particle network",
        )
