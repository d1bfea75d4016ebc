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
    step = time[1:] - time[:-1]
    density = np.clip(curve.value, 0.0, None)
    area = trapezoid(density, step)
    mean = trapezoid(time * density, step) / area
    variance = trapezoid((time - mean) ** 2 * density, step) / area
    return float(mean), float(variance)


def trapezoid(values: np.ndarray, steps: np.ndarray) -> np.float64:
    """``np.trapezoid(values, time)`` of 1-D arrays with ``steps = time[1:] - time[:-1]``:
    NumPy's operations in NumPy's order (the same bits), without its any-axis set-up, and
    the steps computed once for all the moments of a curve (units: values' times time's)."""
    return (steps * (values[1:] + values[:-1]) / 2.0).sum(-1)
