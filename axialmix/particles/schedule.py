"""Scheduled exchange: particles moved per step that change in time (an impeller speed ramp).

A move schedule is an integer array ``(steps, connections)``: the particles moved along each
connection of a :class:`ParticleNetwork` (in its order) during each step. Feed and weir stay
those of the network, so every step must keep every hold-up constant (particles in = particles
out) and no compartment may hand out more than it holds; :func:`check_move_schedule` says
which step and compartment break that. :func:`scheduled_moves` makes one from a
:class:`axialmix.network.RateSchedule` of the network's continuous rates, so the particle
process and the mean-field ODE ``dm/dt = K(t) m`` (solved with diffrax) run on the same
schedule: the rates of step k are those at its midpoint ``(k + 1/2) dt``, times the source's
hold-up and ``dt``, and each connection's running total is rounded (the rounding error is
carried, so over any run the moves are exact to one particle).
"""

from __future__ import annotations

import numpy as np

from axialmix.particles.description import ParticleNetwork, _rebalance

__all__ = ["check_move_schedule", "scheduled_moves"]

_BALANCE_TOLERANCE = 1e-6


def _net_inflow(network: ParticleNetwork, moves: np.ndarray) -> np.ndarray:
    """Particles each compartment gains per step, ``(steps, compartments)`` (zero if balanced)."""
    n = network.n_compartments
    incidence = np.zeros((moves.shape[1], n))
    incidence[np.arange(moves.shape[1]), network.targets] += 1.0
    incidence[np.arange(moves.shape[1]), network.sources] -= 1.0
    return moves @ incidence + (network.feed - network.outflow)[None, :]


def _handed_out(network: ParticleNetwork, moves: np.ndarray) -> np.ndarray:
    """Particles each compartment hands out per step, ``(steps, compartments)``."""
    n = network.n_compartments
    outgoing = np.zeros((moves.shape[1], n), moves.dtype)
    outgoing[np.arange(moves.shape[1]), network.sources] = 1
    return moves @ outgoing + network.outflow[None, :]


def check_move_schedule(network: ParticleNetwork, moves, steps: int) -> np.ndarray:
    """Validate a move schedule against a network and return it as an int64 array.

    **Arguments:**

    - `network`: the blender.
    - `moves`: particles moved per step along each connection, ``(steps, connections)``
      (more rows are cut to `steps`).
    - `steps`: number of steps of the run.

    **Returns:** the schedule, ``(steps, connections)`` int64. Raises ``ValueError`` with one
    sentence naming the step and compartment when counts are not whole or negative, a hold-up
    would change, or a compartment would hand out more particles than it holds.
    """
    moves = np.asarray(moves)
    connections = network.moves.size
    if moves.ndim != 2 or moves.shape[1] != connections or moves.shape[0] < steps:
        raise ValueError(
            f"moves must have shape (steps, connections) = ({steps}, {connections}), "
            f"got {moves.shape}."
        )
    moves = moves[:steps]
    if not np.issubdtype(moves.dtype, np.integer):
        if not np.all(np.isfinite(moves)) or np.any(np.rint(moves) != moves):
            raise ValueError("moves must hold whole numbers of particles.")
    moves = moves.astype(np.int64)
    if np.any(moves < 0):
        step = int(np.argwhere(moves < 0)[0, 0])
        raise ValueError(f"moves at step {step} are negative.")
    gained = _net_inflow(network, moves)
    if np.any(gained != 0):
        step, i = (int(x) for x in np.argwhere(gained != 0)[0])
        raise ValueError(
            f"moves at step {step} change the hold-up of compartment {network.names[i]} by "
            f"{int(gained[step, i]):+d} particles; each step must keep every hold-up constant."
        )
    over = _handed_out(network, moves) > network.holdups[None, :]
    if over.any():
        step, i = (int(x) for x in np.argwhere(over)[0])
        raise ValueError(
            f"moves at step {step} make compartment {network.names[i]} hand out more "
            f"particles than it holds ({network.holdups[i]})."
        )
    return np.ascontiguousarray(moves)


def _move_table(network: ParticleNetwork, moves: np.ndarray | None):
    """The engines' move table: ``(start, destination, count, handed_out)``.

    Moves grouped by source compartment as in :meth:`ParticleNetwork.outgoing_table`, with
    ``count`` ``(rows, entries)`` and ``handed_out`` ``(rows, compartments)``: one row (the
    network's own moves) when `moves` is None, else one row per step of a checked schedule
    (every connection kept, so a move that is zero at some steps keeps its place).
    """
    if moves is None:
        start, destination, count = network.outgoing_table()
        return start, destination, count[None, :], network.handed_out[None, :].copy()
    n = network.n_compartments
    rows: list[list[tuple[int, int]]] = [[] for _ in range(n)]
    for e, (s, t) in enumerate(zip(network.sources, network.targets, strict=True)):
        rows[int(s)].append((int(t), e))
    for i in range(n):
        if network.outflow[i] > 0:
            rows[i].append((-1, -1 - i))
    start = np.zeros(n + 1, np.int64)
    start[1:] = np.cumsum([len(r) for r in rows])
    destination = np.array([t for r in rows for t, _ in r], dtype=np.int64)
    columns = [e for r in rows for _, e in r]
    count = np.empty((moves.shape[0], len(columns)), np.int64)
    for k, e in enumerate(columns):
        count[:, k] = moves[:, e] if e >= 0 else network.outflow[-1 - e]
    return start, destination, np.ascontiguousarray(count), _handed_out(network, moves)


def _rates_at(schedule, times: np.ndarray) -> np.ndarray:
    """Connection rates of a RateSchedule at many times (numpy; held outside the knots)."""
    knots = np.asarray(schedule.times, float)
    rates = np.asarray(schedule.rates, float)
    if knots.size == 1:
        return np.broadcast_to(rates[0], (times.size, rates.shape[1]))
    if schedule.interpolation == "previous":
        index = np.clip(np.searchsorted(knots, times, side="right") - 1, 0, knots.size - 1)
        return rates[index]
    return np.stack([np.interp(times, knots, rates[:, j]) for j in range(rates.shape[1])],
                    axis=1)


def scheduled_moves(network: ParticleNetwork, schedule, steps: int) -> np.ndarray:
    """Particles moved per step for a schedule of the network's continuous exchange rates.

    The mean-field reading of the network (``network.to_network().continuous()``) has rate
    ``moves_ij / (N_i dt)`` on connection i -> j; a :class:`axialmix.network.RateSchedule` of
    such rates (in the network's connection order, time in seconds from the start of step 0)
    gives ``k_ij((k + 1/2) dt) N_i dt`` particles at step k, rounded with the error carried
    from step to step. The outflow rate of the schedule must stay the network's (the feed and
    weir are fixed, so hold-ups stay constant), and the rates must keep each hold-up constant
    (for example, raise the exchange both ways across a connection by the same number of
    particles per step); a step that rounding leaves one particle out of balance is balanced
    by sending the particle along the network (as :meth:`ParticleNetwork.from_network` does).

    **Arguments:**

    - `network`: the continuous blender.
    - `schedule`: an :class:`axialmix.network.RateSchedule` (rates in 1/s).
    - `steps`: number of steps.

    **Returns:** the move schedule ``(steps, connections)`` int64 (checked by
    :func:`check_move_schedule`). Raises ``ValueError`` with one sentence otherwise.
    """
    from axialmix.network import RateSchedule

    if not isinstance(schedule, RateSchedule):
        raise ValueError(f"schedule must be a RateSchedule, got {type(schedule).__name__}.")
    if not network.is_continuous:
        raise ValueError("a rate schedule needs a continuous blender (one with feed).")
    if int(steps) != steps or steps < 1:
        raise ValueError(f"steps must be a positive whole number, got {steps}.")
    steps = int(steps)
    connections = network.moves.size
    if np.shape(schedule.rates)[1] != connections:
        raise ValueError(
            f"the schedule has {np.shape(schedule.rates)[1]} connection rates, the particle "
            f"network {connections}."
        )
    dt = network.step_seconds
    outlets = np.nonzero(network.outflow)[0]
    weir = network.outflow[outlets] / (network.holdups[outlets] * dt)
    outflow_rates = np.asarray(schedule.outflow_rates, float)
    if outflow_rates.shape[1] != outlets.size or not np.allclose(
        outflow_rates, weir[None, :], rtol=1e-9, atol=0.0
    ):
        raise ValueError(
            f"the schedule's outflow rates must stay the network's weir rates "
            f"{weir.tolist()} 1/s: a particle network's feed and weir are fixed."
        )
    midpoints = (np.arange(steps) + 0.5) * dt
    real = _rates_at(schedule, midpoints) * network.holdups[network.sources][None, :] * dt
    gained = _net_inflow(network, real)
    scale = np.maximum(1.0, real.max(initial=0.0))
    if np.any(np.abs(gained) > _BALANCE_TOLERANCE * scale):
        step, i = (int(x) for x in np.argwhere(np.abs(gained) > _BALANCE_TOLERANCE * scale)[0])
        raise ValueError(
            f"the scheduled rates at t = {midpoints[step]:g} s change the hold-up of "
            f"compartment {network.names[i]} by {gained[step, i]:+.3g} particles per step; "
            "exchange must change by the same number of particles both ways."
        )
    running = np.floor(np.cumsum(real, axis=0) + 0.5)
    moves = np.diff(np.concatenate([np.zeros((1, connections)), running]), axis=0)
    moves = moves.astype(np.int64)
    unbalanced = np.nonzero(np.any(_net_inflow(network, moves) != 0, axis=1))[0]
    for step in unbalanced:
        moves[step] = _rebalance(network.n_compartments, network.sources, network.targets,
                                 moves[step], network.feed, network.outflow)
    return check_move_schedule(network, moves, steps)
