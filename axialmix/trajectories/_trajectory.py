"""The trajectory container: samples ``(t, x, y, z)`` of one tracked particle (SI)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trajectory:
    """One tracked particle: sample times and positions from entry to exit.

    **Arguments:**

    - `time`: sample times, s, strictly increasing, shape ``(n,)`` with ``n >= 2``.
    - `x`, `y`: cross-sectional coordinates, m, shape ``(n,)``.
    - `z`: axial coordinate, m (0 at the inlet), shape ``(n,)``.
    - `trajectory_id`: label of the trajectory (from the file's id column).
    """

    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    trajectory_id: str = "0"

    def __post_init__(self) -> None:
        arrays = {}
        for name in ("time", "x", "y", "z"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.ndim != 1:
                raise ValueError(f"Trajectory {self.trajectory_id!r}: {name} must be 1-D.")
            if not np.all(np.isfinite(value)):
                raise ValueError(
                    f"Trajectory {self.trajectory_id!r}: {name} contains NaN or infinity."
                )
            arrays[name] = value
        n = arrays["time"].size
        if any(a.size != n for a in arrays.values()):
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: time, x, y and z must have equal lengths."
            )
        if n < 2:
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: has {n} point(s); at least 2 are needed."
            )
        if np.any(np.diff(arrays["time"]) <= 0):
            i = int(np.argmax(np.diff(arrays["time"]) <= 0)) + 1
            raise ValueError(
                f"Trajectory {self.trajectory_id!r}: time is not strictly increasing at "
                f"sample {i} ({arrays['time'][i - 1]} s then {arrays['time'][i]} s)."
            )
        for name, value in arrays.items():
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def n_points(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.time[-1] - self.time[0])


def check_positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")
    return value
