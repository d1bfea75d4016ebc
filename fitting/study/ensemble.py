"""Particle-simulation ensembles as studies: settings × seeds, simulated in chunks (or on Dask).

An :class:`Ensemble` is a design over the rates of the four-compartment continuous blender
simulated by the particle simulator (:mod:`axialmix.particles`, MODELS.md section 4): each
setting is run once per seed, a tracer pulse at step 0, and the tracer's outflow becomes an
RTD curve (the exit-age density, :func:`axialmix.particles.exit_age_from_outflow`, averaged
over bins of ``bin_steps`` steps, at the bins' mean residence times). :func:`run_ensemble`
simulates the runs in chunks through :func:`fitting.study.batch.map_chunks`, the path the fits
of a study take (in this process, on a local Dask cluster, or on a scheduler), and returns a
:class:`~fitting.study.input.Study` whose factors are the rates and the seed, ready for
:class:`~fitting.study.batch.StudyRun`. A run depends only on its setting and seed, so the
curves are the same wherever they were simulated.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import numpy as np

from axialmix.particles import (
    TracerPulse,
    constant_feed,
    exit_age_from_outflow,
    particle_four_compartment,
    simulate,
)
from fitting.data import Curve
from fitting.study.batch import map_chunks
from fitting.study.input import Study

__all__ = ["ENSEMBLE_RATES", "Ensemble", "run_ensemble", "simulate_chunk"]

#: The rates (1/s) a setting of an ensemble may give; the others keep their defaults.
ENSEMBLE_RATES = ("k_f", "k_r", "k_s", "k_out")


class Ensemble(eqx.Module):
    """Particle simulations of the four-compartment blender: every setting with every seed.

    **Arguments:**

    - `settings`: per setting, ``((rate, value), ...)`` pairs (1/s) of :data:`ENSEMBLE_RATES`;
      every setting names the same rates.
    - `seeds`: the seeds each setting is run with.
    - `particles`: particles held by the blender.
    - `tracer`: tracer particles injected at step 0.
    - `time_step`: step length (s).
    - `steps`: steps simulated per run (long enough for the tracer to leave).
    - `bin_steps`: steps averaged into one sample of a curve.
    """

    settings: tuple[tuple[tuple[str, float], ...], ...]
    seeds: tuple[int, ...]
    particles: int = 20_000
    tracer: int = 5_000
    time_step: float = 0.01
    steps: int = 4_000
    bin_steps: int = 50

    def __check_init__(self):
        if not self.settings or not self.seeds:
            raise ValueError("an ensemble needs at least one setting and one seed")
        names = [name for name, _ in self.settings[0]]
        unknown = [n for n in names if n not in ENSEMBLE_RATES]
        if unknown:
            raise ValueError(f"unknown rate {unknown[0]!r}; a setting gives "
                             f"{', '.join(ENSEMBLE_RATES)}")
        if any([name for name, _ in setting] != names for setting in self.settings):
            raise ValueError("every setting of an ensemble must name the same rates, in order")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError("the seeds of an ensemble must be distinct")
        if not 0 < self.tracer < self.particles:
            raise ValueError(f"the tracer ({self.tracer} particles) must be fewer than the "
                             f"particles held ({self.particles})")
        if self.steps < 5 * self.bin_steps or self.bin_steps < 1:
            raise ValueError(f"{self.steps} steps in bins of {self.bin_steps} give fewer than "
                             "five samples per curve")

    @property
    def factors(self) -> tuple[str, ...]:
        """The factor names of the ensemble's study: the rates, then ``seed``."""
        return (*(name for name, _ in self.settings[0]), "seed")

    def runs(self) -> list[tuple[int, int]]:
        """Every run as ``(setting index, seed)``, settings first."""
        return [(index, seed) for index in range(len(self.settings)) for seed in self.seeds]


def simulate_chunk(ensemble: Ensemble, runs: Sequence[tuple[int, int]]) -> list[Curve]:
    """Simulate runs of an ensemble and return their tracer curves.

    This is the task a Dask worker runs; the one-process run calls it too.

    **Arguments:** `ensemble`, the :class:`Ensemble`; `runs`, ``(setting index, seed)`` pairs.

    **Returns:** one :class:`~fitting.data.Curve` per run: the exit-age density (1/s), averaged
    over bins of ``bin_steps`` steps, at the bins' mean residence times (s); named
    ``s<setting>-seed<seed>``.
    """
    curves = []
    size = ensemble.bin_steps
    for index, seed in runs:
        network = particle_four_compartment(**dict(ensemble.settings[index]),
                                            particles=ensemble.particles,
                                            time_step=ensemble.time_step)
        feed = constant_feed(network, [1.0, 0.0], ensemble.steps)
        initial = np.column_stack([network.holdups, np.zeros(network.holdups.size, np.int64)])
        pulse = TracerPulse(step=0, particles=ensemble.tracer, species=1)
        result = simulate(network, initial, ensemble.steps, seed=seed, feed=feed, tracer=pulse)
        times, density = exit_age_from_outflow(result.outflow, 1, 0, ensemble.tracer,
                                               ensemble.time_step)
        count = density.size // size
        curves.append(Curve(
            f"s{index}-seed{seed}", times[:count * size].reshape(count, size).mean(axis=1),
            density[:count * size].reshape(count, size).mean(axis=1), time_unit="s",
            source="particle ensemble"))
    return curves


def run_ensemble(ensemble: Ensemble, *, chunk: int = 4, workers: int | None = None,
                 scheduler: str | None = None) -> Study:
    """Simulate an ensemble in chunks of runs and return it as a study.

    **Arguments:**

    - `ensemble`: the :class:`Ensemble`.
    - `chunk`: runs per chunk (one Dask task).
    - `workers`, `scheduler`: as in :func:`fitting.study.batch.map_chunks`.

    **Returns:** a :class:`~fitting.study.input.Study` with one curve per run (settings
    first, then seeds) and the factors :attr:`Ensemble.factors`.
    """
    if chunk < 1:
        raise ValueError(f"chunk must be at least 1 run, got {chunk}")
    runs = ensemble.runs()
    pieces = [runs[start:start + chunk] for start in range(0, len(runs), chunk)]
    found: dict[int, list[Curve]] = {}
    map_chunks(simulate_chunk, ((i, (ensemble, piece)) for i, piece in enumerate(pieces)),
               workers, scheduler, lambda: False, found.__setitem__)
    curves = [curve for i in range(len(pieces)) for curve in found[i]]
    levels = tuple((*(repr(float(v)) for _, v in ensemble.settings[index]), str(seed))
                   for index, seed in runs)
    return Study(tuple(curves), ensemble.factors, levels, tuple(None for _ in curves),
                 "particle ensemble")
