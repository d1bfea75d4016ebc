"""axialmix: differentiable residence-time models of continuous powder mixers.

Importing :mod:`axialmix` switches JAX to double precision
(``jax.config.update("jax_enable_x64", True)``): every model in the package is
written and tested in float64, and tolerances of 1e-8 and tighter need it.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
