"""fitting: inverse problems on residence-time curves (data in, parameters and uncertainty out).

Imports :mod:`axialmix`, which switches JAX to float64.
"""

import axialmix  # noqa: F401  (enables float64 before any JAX array is made)
