"""Padded curve lengths: curves are padded with zero-weight points to 16, 32, 64, ...
samples, so curves of different lengths share compiled programs."""

from __future__ import annotations

import numpy as np


def padded_length(size: int) -> int:
    """The length a curve of `size` samples is padded to: 16, 32, 64, ... (zero weights).

    **Arguments:** `size`: the number of samples.

    **Returns:** the smallest power of two that is at least `size` and 16.
    """
    return max(16, 1 << max(int(size) - 1, 0).bit_length())


def pad_curve(time, observed, weights, length: int):
    """`time`, `observed`, `weights` padded to `length` with zero-weight points, the times
    continuing the last spacing."""
    time = np.asarray(time, dtype=float)
    extra = length - time.shape[-1]
    if extra == 0:
        return time, np.asarray(observed, dtype=float), np.asarray(weights, dtype=float)
    spacing = time[-1] - time[-2] if time.shape[-1] >= 2 else 1.0
    more = time[-1] + spacing * np.arange(1, extra + 1)
    return (np.concatenate([time, more]),
            np.concatenate([np.asarray(observed, dtype=float), np.zeros(extra)]),
            np.concatenate([np.asarray(weights, dtype=float), np.zeros(extra)]))
