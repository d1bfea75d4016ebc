"""axialmix: differentiable residence-time models of continuous powder mixers.

Importing :mod:`axialmix` switches JAX to double precision
(``jax.config.update("jax_enable_x64", True)``): every model in the package is
written and tested in float64, and tolerances of 1e-8 and tighter need it.

The subpackages (:mod:`~axialmix.analytic`, :mod:`~axialmix.adm`, :mod:`~axialmix.line`,
:mod:`~axialmix.network`, :mod:`~axialmix.particles`, :mod:`~axialmix.reference`,
:mod:`~axialmix.rtd`, :mod:`~axialmix.trajectories`) are loaded on first use, so
``import axialmix`` costs only the import of JAX.
"""

import importlib

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

_SUBPACKAGES = (
    "adm", "analytic", "line", "network", "particles", "reference", "rtd", "trajectories"
)

__all__ = ["__version__", *_SUBPACKAGES]


def __getattr__(name: str):
    if name in _SUBPACKAGES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_SUBPACKAGES))
