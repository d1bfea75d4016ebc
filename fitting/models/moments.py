"""The moments of a measured curve, which the models' method-of-moments start values are
built on."""

from __future__ import annotations

import numpy as np

from fitting.data import Curve


def moment_estimates(curve: Curve) -> tuple[float, float]:
    """Mean residence time and variance of a measured curve (trapezoid rule).

    Negative samples (noise around a subtracted baseline) are set to zero first, so the
    moments of a noisy curve stay those of a density.

    **Arguments:**

    - `curve`: a measured curve (need not be normalised).

    **Returns:**

    ``(mean, variance)`` in the curve's time unit and its square.
    """
    # The same trapezoid moments as axialmix.rtd.moments, in NumPy: start values are computed
    # per curve in Python, where eager JAX dispatch would dominate the cost of a fit.
    time = curve.time
    density = np.clip(curve.value, 0.0, None)
    area = np.trapezoid(density, time)
    mean = np.trapezoid(time * density, time) / area
    variance = np.trapezoid((time - mean) ** 2 * density, time) / area
    return float(mean), float(variance)
