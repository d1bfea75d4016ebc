"""What a continuous blender is fed each step: constant, scheduled or fluctuating compositions.

A feed schedule is an integer array ``(steps, inlets, species)``: the particles of each
species entering each inlet compartment (``network.inlets()``, in that order) at the end of
each step. Its totals per inlet must equal the network's feed per step, so hold-ups stay
constant; only the composition varies. Tracer pulses are not part of the feed: see
:class:`axialmix.particles.simulate.TracerPulse`.
"""

from __future__ import annotations

import numba
import numpy as np

from axialmix.particles.description import ParticleNetwork

__all__ = ["constant_feed", "feeder_feed", "check_feed_schedule"]


@numba.njit(cache=True)
def _split_by_fractions(fractions: np.ndarray, totals: np.ndarray) -> np.ndarray:
    # Largest-remainder apportionment with the rounding error carried to the next step:
    # every step feeds exactly totals[q] particles into inlet q, and each species' running
    # count stays within about one particle of its running share.
    # fractions: (steps, inlets, species); totals: (inlets,).
    steps, n_inlets, n_species = fractions.shape
    counts = np.zeros((steps, n_inlets, n_species), np.int64)
    carry = np.zeros((n_inlets, n_species))
    target = np.empty(n_species)
    for k in range(steps):
        for q in range(n_inlets):
            assigned = 0
            for s in range(n_species):
                target[s] = carry[q, s] + fractions[k, q, s] * totals[q]
                counts[k, q, s] = max(int(np.floor(target[s])), 0)
                assigned += counts[k, q, s]
            while assigned < totals[q]:
                best = 0
                for s in range(1, n_species):
                    if target[s] - counts[k, q, s] > target[best] - counts[k, q, best]:
                        best = s
                counts[k, q, best] += 1
                assigned += 1
            while assigned > totals[q]:
                worst = -1
                for s in range(n_species):
                    if counts[k, q, s] > 0 and (
                        worst < 0
                        or target[s] - counts[k, q, s] < target[worst] - counts[k, q, worst]
                    ):
                        worst = s
                counts[k, q, worst] -= 1
                assigned -= 1
            for s in range(n_species):
                carry[q, s] = target[s] - counts[k, q, s]
    return counts


def constant_feed(network: ParticleNetwork, fractions, steps: int) -> np.ndarray:
    """A feed of constant composition for ``steps`` steps.

    **Arguments:**

    - `network`: the continuous blender.
    - `fractions`: number fraction of each species in the feed (sums to 1).
    - `steps`: number of steps.

    **Returns:** integer schedule ``(steps, inlets, species)``; counts are rounded
    cumulatively, so over any run the fed composition is exact to within one particle.
    """
    fractions = np.asarray(fractions, dtype=float)
    if fractions.ndim != 1 or fractions.size == 0 or np.any(~np.isfinite(fractions)):
        raise ValueError("fractions must be a 1-D array of finite species fractions.")
    if np.any(fractions < 0) or abs(fractions.sum() - 1.0) > 1e-9:
        raise ValueError(f"fractions must be non-negative and sum to 1, got {fractions.tolist()}.")
    if steps < 0:
        raise ValueError(f"steps must not be negative, got {steps}.")
    totals = network.feed[network.inlets()]
    per_step = np.ascontiguousarray(
        np.broadcast_to(fractions, (steps, totals.size, fractions.size))
    )
    return _split_by_fractions(per_step, totals.astype(np.float64))


def feeder_feed(
    network: ParticleNetwork,
    mean_rates,
    rate_deviations,
    steps: int,
    *,
    hold_steps: int = 1,
    seed: int = 0,
) -> np.ndarray:
    """A feed whose composition fluctuates like real loss-in-weight feeders, one per species.

    Each feeder's mass rate is drawn from a normal distribution (truncated at zero) and held
    for ``hold_steps`` steps; species s makes up ``rate_s / sum(rates)`` of the particles fed
    in that period (particles of equal mass). The source measured 12.16 +- 2.46 g/s lactose
    and 6.55 +- 1.16 g/s pre-blend (MODELS.md section 4).

    **Arguments:**

    - `network`: the continuous blender.
    - `mean_rates`, `rate_deviations`: mean and standard deviation of each feeder's rate
      (any mass-per-time unit, the same for all).
    - `steps`: number of steps.
    - `hold_steps`: steps a drawn rate is held (the feeder's correlation time in steps).
    - `seed`: seed of the rate fluctuations.

    **Returns:** integer schedule ``(steps, inlets, species)``.
    """
    mean_rates = np.asarray(mean_rates, dtype=float)
    rate_deviations = np.asarray(rate_deviations, dtype=float)
    if mean_rates.shape != rate_deviations.shape or mean_rates.ndim != 1:
        raise ValueError("mean_rates and rate_deviations must be 1-D and of equal length.")
    if np.any(~(mean_rates > 0)) or np.any(~(rate_deviations >= 0)):
        raise ValueError("feeder mean rates must be positive and deviations non-negative.")
    if hold_steps < 1:
        raise ValueError(f"hold_steps must be at least 1, got {hold_steps}.")
    rng = np.random.default_rng(seed)
    periods = -(-steps // hold_steps)
    rates = np.maximum(rng.normal(mean_rates, rate_deviations, (periods, mean_rates.size)), 0.0)
    totals = rates.sum(axis=1, keepdims=True)
    rates = np.where(
        totals > 0, rates / np.where(totals > 0, totals, 1.0), mean_rates / mean_rates.sum()
    )
    fractions = np.repeat(rates, hold_steps, axis=0)[:steps]
    inlet_totals = network.feed[network.inlets()]
    per_step = np.ascontiguousarray(
        np.broadcast_to(fractions[:, None, :], (steps, inlet_totals.size, mean_rates.size))
    )
    return _split_by_fractions(per_step, inlet_totals.astype(np.float64))


def check_feed_schedule(
    network: ParticleNetwork, schedule, steps: int, n_species: int
) -> np.ndarray:
    """Validate a feed schedule against a network and return it as an int64 array.

    Raises ``ValueError`` if its shape is not ``(steps, inlets, species)``, a count is
    negative, or a step's feed into an inlet differs from the network's feed per step.
    """
    inlet_totals = network.feed[network.inlets()]
    if schedule is None:
        if network.is_continuous:
            raise ValueError("a continuous blender needs a feed schedule.")
        return np.zeros((steps, 0, n_species), np.int64)
    schedule = np.asarray(schedule)
    expected = (steps, inlet_totals.size, n_species)
    if schedule.ndim != 3 or schedule.shape[1:] != expected[1:] or schedule.shape[0] < steps:
        raise ValueError(
            f"feed schedule must have shape (steps, inlets, species) = {expected}, "
            f"got {schedule.shape}."
        )
    schedule = schedule[:steps].astype(np.int64)
    if np.any(schedule < 0):
        raise ValueError("feed schedule counts must not be negative.")
    bad = np.nonzero(np.any(schedule.sum(axis=2) != inlet_totals[None, :], axis=1))[0]
    if bad.size:
        raise ValueError(
            f"feed at step {int(bad[0])} does not add up to the network's feed per step "
            f"{inlet_totals.tolist()}."
        )
    return np.ascontiguousarray(schedule)
