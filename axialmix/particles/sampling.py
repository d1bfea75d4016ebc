"""Sampling a simulated blender, and the homogeneity statistics of the source (MODELS.md §1, §4).

Sampling is part of the model: homogeneity numbers depend on where samples are taken, how
many, how many particles each holds and when. A sample is a set of particles drawn without
replacement; the particles within a compartment (or within the outflow of a few steps) are
exchangeable, so a sample is a multivariate hypergeometric draw from the species counts,
for either engine. Samples taken at one time from one location are disjoint (drawn one
after the other from what is left); sampling only observes, it removes nothing from the
simulation.

Statistics, with ``X_k`` the fraction of a species in sample k:
``RSD = sqrt(sum (X_k - mean)^2 / (n - 1)) / mean``;
``variance = sum (X_k - mean)^2 / n``; ``VRR = variance_in / variance_out``;
``chi^2 = sum_i (N_O,i - N_E,i)^2 / N_E,i`` over compartments, with ``N_E,i`` the count of
the species compartment i would hold if perfectly mixed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "chi_square",
    "exit_age_from_outflow",
    "relative_standard_deviation",
    "sample_compartments",
    "sample_outflow",
    "sample_variance",
    "species_fraction",
    "variance_reduction_ratio",
]


def _draw_disjoint(
    pool: np.ndarray, n_samples: int, particles: int, rng: np.random.Generator
) -> np.ndarray:
    pool = np.asarray(pool, dtype=np.int64).copy()
    if n_samples * particles > pool.sum():
        raise ValueError(
            f"{n_samples} samples of {particles} particles need more than the "
            f"{pool.sum()} particles available."
        )
    out = np.empty((n_samples, pool.size), np.int64)
    for k in range(n_samples):
        out[k] = rng.multivariate_hypergeometric(pool, particles, method="marginals")
        pool -= out[k]
    return out


def sample_compartments(
    counts,
    locations: Sequence[int],
    samples_per_location: int,
    particles_per_sample: int,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """Draw samples of particles from compartments (a thief probe at a given time).

    **Arguments:**

    - `counts`: species counts ``(compartments, species)`` at the sampling time (e.g.
      ``result.counts[r]``).
    - `locations`: compartment indices sampled.
    - `samples_per_location`: samples from each location (disjoint within a location).
    - `particles_per_sample`: particles in each sample (``m``).
    - `seed`: seed or numpy Generator.

    **Returns:** integer array ``(samples, species)`` of species counts, location by location.
    """
    counts = np.asarray(counts)
    if particles_per_sample < 1 or samples_per_location < 1:
        raise ValueError("samples_per_location and particles_per_sample must be at least 1.")
    rng = np.random.default_rng(seed)
    rows = [
        _draw_disjoint(counts[int(i)], samples_per_location, particles_per_sample, rng)
        for i in locations
    ]
    return np.concatenate(rows) if rows else np.zeros((0, counts.shape[1]), np.int64)


def sample_outflow(
    outflow,
    sample_steps: Sequence[int],
    particles_per_sample: int,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """Draw samples from the outflow stream, each from the particles leaving just before a step.

    Sample k holds `particles_per_sample` particles drawn from the outflow of the fewest
    steps ending with step ``sample_steps[k]`` that hold that many particles.

    **Arguments:**

    - `outflow`: species counts leaving per step ``(steps, species)`` (``result.outflow``).
    - `sample_steps`: steps whose outflow ends each sample (increasing, windows must not
      overlap, so samples are disjoint).
    - `particles_per_sample`: particles per sample.
    - `seed`: seed or numpy Generator.

    **Returns:** integer array ``(samples, species)``.
    """
    outflow = np.asarray(outflow, dtype=np.int64)
    rng = np.random.default_rng(seed)
    per_step = outflow.sum(axis=1)
    cumulative = np.concatenate([[0], np.cumsum(per_step)])
    out = np.empty((len(sample_steps), outflow.shape[1]), np.int64)
    previous_start = np.inf
    for k, step in reversed(list(enumerate(sample_steps))):
        step = int(step)
        if not 0 <= step < outflow.shape[0]:
            raise ValueError(f"sample step {step} is outside the simulated steps.")
        # first step of the window: the latest one whose window holds enough particles
        first = (
            int(np.searchsorted(cumulative, cumulative[step + 1] - particles_per_sample, "right"))
            - 1
        )
        if first < 0:
            raise ValueError(f"not enough outflow before step {step} for a sample.")
        if step >= previous_start:
            raise ValueError("outflow samples overlap; space the sample steps further apart.")
        previous_start = first
        pool = outflow[first : step + 1].sum(axis=0)
        out[k] = rng.multivariate_hypergeometric(pool, particles_per_sample, method="marginals")
    return out


def species_fraction(samples, species: int) -> np.ndarray:
    """Fraction ``X_k`` of one species in each sample (rows of species counts)."""
    samples = np.asarray(samples, dtype=float)
    return samples[:, species] / samples.sum(axis=1)


def relative_standard_deviation(fractions) -> float:
    """``RSD = sqrt(sum (X_k - mean)^2 / (n - 1)) / mean`` (dimensionless)."""
    x = np.asarray(fractions, dtype=float)
    if x.size < 2:
        raise ValueError("the RSD needs at least two samples.")
    return float(np.std(x, ddof=1) / np.mean(x))


def sample_variance(fractions) -> float:
    """``sigma^2 = sum (X_k - mean)^2 / n``, the source's variance for feed damping."""
    x = np.asarray(fractions, dtype=float)
    if x.size < 1:
        raise ValueError("the variance needs at least one sample.")
    return float(np.var(x))


def variance_reduction_ratio(inflow_fractions, outflow_fractions) -> float:
    """``VRR = sigma^2_in / sigma^2_out`` (larger means better damping of feed fluctuations)."""
    return sample_variance(inflow_fractions) / sample_variance(outflow_fractions)


def chi_square(counts, species: int = 0) -> float:
    """The source's homogeneity statistic ``sum_i (N_O,i - N_E,i)^2 / N_E,i`` over compartments.

    **Arguments:**

    - `counts`: species counts ``(compartments, species)``.
    - `species`: the species counted (0 = species 1).

    **Returns:** chi-square (compartments where the expected count is zero are skipped).
    """
    counts = np.asarray(counts, dtype=float)
    held = counts.sum(axis=1)
    expected = held * counts[:, species].sum() / held.sum()
    keep = expected > 0
    return float(np.sum((counts[keep, species] - expected[keep]) ** 2 / expected[keep]))


def exit_age_from_outflow(
    outflow, tracer_species: int, pulse_step: int, tracer_particles: int, step_seconds: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """The measured RTD of a tracer pulse from the simulated outflow.

    A tracer leaving during step k (pulse at the start of step ``pulse_step``) is given the
    residence time ``(k - pulse_step + 1) * step_seconds``, the convention of
    :func:`axialmix.network.exit_age` for discrete networks.

    **Arguments:**

    - `outflow`: species counts leaving per step ``(steps, species)``.
    - `tracer_species`, `pulse_step`, `tracer_particles`: the pulse.
    - `step_seconds`: step length (s).

    **Returns:** ``(times, exit_age)``: times (s) and E (1/s), normalised by the particles
    injected (so its integral is the fraction that has left).
    """
    counts = np.asarray(outflow)[pulse_step:, tracer_species]
    times = (np.arange(counts.size) + 1) * step_seconds
    return times, counts / (tracer_particles * step_seconds)
