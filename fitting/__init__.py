"""fitting: inverse problems on residence-time curves (data in, parameters and uncertainty out).

Layers, each importing only those before it: :mod:`~fitting.parameters`,
:mod:`~fitting.losses`, :mod:`~fitting.data`, :mod:`~fitting.models`,
:mod:`~fitting.measurement`, :mod:`~fitting.solve`, :mod:`~fitting.uncertainty`,
:mod:`~fitting.result`, :mod:`~fitting.physical`, :mod:`~fitting.fit`,
:mod:`~fitting.diagnostics`, :mod:`~fitting.gridsearch`, :mod:`~fitting.report`,
:mod:`~fitting.cli`. (The function ``fit`` is imported from its module,
``from fitting.fit import fit``: the attribute ``fitting.fit`` is that module.) The names
below are loaded on first use, so ``import fitting`` (and the command line's ``--help``)
does not import JAX; every module that uses JAX imports
:mod:`axialmix` first, which switches JAX to float64.
"""

import importlib

#: Public name -> the module that defines it.
_PUBLIC = {
    "Parameter": "fitting.parameters",
    "Parameters": "fitting.parameters",
    "Curve": "fitting.data",
    "DataError": "fitting.data",
    "DataWarning": "fitting.data",
    "read_rtd_csv": "fitting.data",
    "read_many": "fitting.data",
    "read_inlet_csv": "fitting.data",
    "Inlet": "fitting.measurement",
    "measured": "fitting.measurement",
    "CombinedErrors": "fitting.losses",
    "physical_quantities": "fitting.physical",
    "Model": "fitting.models",
    "MODELS": "fitting.models",
    "get_model": "fitting.models",
    "custom_model": "fitting.models",
    "network_model": "fitting.models",
    "Optimiser": "fitting.solve",
    "MultiStart": "fitting.solve",
    "Status": "fitting.solve",
    "FitResult": "fitting.result",
    "FitSettings": "fitting.result",
    "RelativeErrors": "fitting.result",
    "fit_many": "fitting.fit",
    "launch_many": "fitting.fit",
    "identifiability": "fitting.diagnostics",
    "profile_likelihood": "fitting.diagnostics",
    "grid_search": "fitting.gridsearch",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name in _PUBLIC:
        return getattr(importlib.import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module 'fitting' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
