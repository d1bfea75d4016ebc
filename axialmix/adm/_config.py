"""Grid and time-step settings of the finite-volume ADM solver, and their defaults per Peclet."""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np

__all__ = ["VERIFIED_PECLET_RANGE", "SolverConfig", "default_configs", "peclet_level_bounds"]

VERIFIED_PECLET_RANGE = (2e-3, 3500.0)
"""Peclet numbers for which the default settings are verified: max |E - E_exact| <= 1e-3 of
the peak. Measured against :func:`axialmix.analytic.exit_age_closed`: 1.9e-3 at Pe = 1e-3,
3.1e-4 at 1.5e-3, 1.3e-4 at 2e-3; 9.5e-4 at 3500, 1.0e-3 at 3580, 1.4e-3 at 4000, 1.9e-2 at
1e4 and 0.41 at 1e5 (with negative E). Outside it the default solver refuses (concrete Pe)
or returns NaN (traced Pe); an explicit :class:`SolverConfig` is not checked."""


class SolverConfig(eqx.Module):
    """Immutable grid and time-integration settings of the finite-volume ADM solver.

    Everything here is static (fixed at trace time), so a config can be passed to jitted
    functions and changes the compiled program only when its values change. Distances are
    in units of the mixer length ``L`` and times in units of ``tau``.

    **Arguments:**

    - `cells`: number of finite-volume cells of the coarse grid. With `richardson` the
      solution is also computed on ``2 * cells`` cells and the two are combined.
    - `max_step`: largest time step (in ``theta = t / tau``).
    - `first_step`: the first time step; steps then grow geometrically by `growth` up to
      `max_step` (the pulse start is the stiffest and least smooth part of the solution).
    - `horizon`: the last simulated ``theta``; beyond it the outlet curve continues with the
      decay rate it has there (the slowest mode of the discrete operator dominates).
    - `richardson`: combine grids of `cells` and ``2 * cells`` cells as
      ``(4 E_2N - E_N) / 3``, which cancels the second-order spatial error.
    - `growth`: ratio of consecutive time steps while they grow towards `max_step`.
    """

    cells: int = eqx.field(static=True)
    max_step: float = eqx.field(static=True)
    first_step: float = eqx.field(static=True)
    horizon: float = eqx.field(static=True)
    richardson: bool = eqx.field(static=True, default=True)
    growth: float = eqx.field(static=True, default=1.25)

    def __check_init__(self):
        if not isinstance(self.cells, int) or self.cells < 3:
            raise ValueError(f"cells must be an integer of at least 3, got {self.cells!r}")
        for name in ("max_step", "first_step", "horizon"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if self.first_step > self.max_step:
            raise ValueError(
                f"first_step ({self.first_step:g}) must not exceed max_step ({self.max_step:g})"
            )
        if self.max_step > self.horizon:
            raise ValueError(
                f"max_step ({self.max_step:g}) must not exceed horizon ({self.horizon:g})"
            )
        if not (isinstance(self.growth, int | float) and self.growth >= 1.0):
            raise ValueError(f"growth must be at least 1, got {self.growth!r}")

    @property
    def grids(self) -> tuple[int, ...]:
        """Cell counts of the grids that are solved (one, or two for Richardson)."""
        return (self.cells, 2 * self.cells) if self.richardson else (self.cells,)

    def time_nodes(self) -> np.ndarray:
        """Return the times ``theta_k`` (0 = first, `horizon` = last) where the solver stops.

        **Returns:**

        A strictly increasing numpy array starting at 0 and ending at `horizon`.
        """
        nodes = [0.0]
        step = self.first_step
        while nodes[-1] < self.horizon:
            nodes.append(min(nodes[-1] + step, self.horizon))
            step = min(step * self.growth, self.max_step)
        if len(nodes) > 2 and nodes[-1] - nodes[-2] < 0.25 * self.max_step:
            del nodes[-2]  # avoid a last sliver of a step
        return np.asarray(nodes)

    @classmethod
    def for_peclet(cls, peclet_max: float) -> SolverConfig:
        """Return the default settings that are accurate for every Peclet up to `peclet_max`.

        Use it for batches (``jax.vmap``) whose Peclet numbers span several default levels
        (with the defaults each needed level runs for the whole batch), or to keep a curve
        smooth in Pe across a level edge.

        **Arguments:**

        - `peclet_max`: the largest Peclet number to be solved (positive).

        **Returns:**

        The default :class:`SolverConfig` of the resolution level holding `peclet_max`.
        """
        if not (math.isfinite(peclet_max) and peclet_max > 0):
            raise ValueError(f"peclet_max must be a positive finite number, got {peclet_max!r}")
        bounds = peclet_level_bounds()
        index = int(np.searchsorted(bounds, peclet_max, side="left"))
        return default_configs()[min(index, len(bounds))]


# Resolution levels: (largest Peclet number of the level, settings). The edges avoid the
# round numbers users try first, because the curve jumps by ~1e-4 of its peak at an edge.
# Cells follow the fourth-order remainder of the Richardson-combined error, about
# C(Pe) / N^4 with C growing like Pe^3 at large Pe; steps follow the pulse width
# sqrt(2 / Pe); the horizon is where the slowest mode alone is left (low Pe) or the pulse
# has left the mixer (high Pe).
_LEVELS: tuple[tuple[float, SolverConfig], ...] = (
    (2.5, SolverConfig(cells=12, max_step=0.05, first_step=2e-4, horizon=5.0)),
    (25.0, SolverConfig(cells=32, max_step=0.04, first_step=1e-3, horizon=6.0)),
    (180.0, SolverConfig(cells=104, max_step=0.02, first_step=1e-3, horizon=3.0)),
    (1300.0, SolverConfig(cells=370, max_step=0.01, first_step=1e-3, horizon=1.9)),
    (math.inf, SolverConfig(cells=700, max_step=0.006, first_step=1e-3, horizon=1.5)),
)


def peclet_level_bounds() -> np.ndarray:
    """Upper Peclet bounds of the default resolution levels (the last level is unbounded)."""
    return np.asarray([bound for bound, _ in _LEVELS[:-1]])


def default_configs() -> tuple[SolverConfig, ...]:
    """The default settings of every resolution level, from low to high Peclet."""
    return tuple(config for _, config in _LEVELS)
