"""Chains with backflow and their link to the axial dispersion model (MODELS.md §3).

A chain of cells of width ``dx`` with forward rate ``a`` and backward rate ``b`` (1/time)
is, per unit cross-section, the flux ``a c_i - b c_{i+1}`` across each face. Its moments
match the ADM with

    v = (a - b) dx,      D_z = (a + b) dx² / 2

(the drift and half the jump variance rate of one particle's random walk). Inverting,

    a = D_z / dx² + v / (2 dx),      b = D_z / dx² - v / (2 dx),

which is the *central* finite-volume discretisation of the ADM; it needs ``b >= 0``, i.e. a
cell Péclet number ``v dx / D_z <= 2``. The *upwind* finite-volume discretisation has
``a = v / dx + D_z / dx²``, ``b = D_z / dx²``: the same kind of chain, whose equivalent
dispersion is ``D_z + v dx / 2`` (the known numerical diffusion of upwinding).

Danckwerts (closed–closed) boundaries in the chain: the feed enters the first cell and
nothing flows back out of it (the total flux through the inlet face is the convective feed
``v c_in``), and the last cell discharges ``v c_N`` only (``dc/dz = 0``), i.e.
``k_out = v / dx``. With these, the steady state is uniform, the mean residence time is
exactly ``L / v = tau`` for any cell count, and the chain's RTD converges to the exact
closed–closed ADM RTD as cells are added (second order for the central chain, first order
for the upwind one).
"""

from __future__ import annotations

import math
from typing import Literal

__all__ = [
    "backflow_chain_rates",
    "backflow_chain_transport",
    "backflow_ratio_for_peclet",
    "chain_peclet",
]

Scheme = Literal["central", "upwind"]


def _positive(value: float, name: str) -> float:
    number = float(value)
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be positive and finite, got {value}.")
    return number


def backflow_chain_transport(
    forward_rate: float, backward_rate: float, cell_width: float
) -> tuple[float, float]:
    """Velocity and axial dispersion coefficient of a chain with backflow.

    **Arguments:**

    - `forward_rate`: ``a``, fraction of a cell moved to the next cell per unit time (1/s).
    - `backward_rate`: ``b``, fraction moved to the previous cell per unit time (1/s).
    - `cell_width`: ``dx``, axial length of one cell (m).

    **Returns:**

    ``(v, D_z)`` with ``v = (a - b) dx`` (m/s) and ``D_z = (a + b) dx² / 2`` (m²/s). Works on
    JAX arrays too (plain arithmetic).
    """
    return (forward_rate - backward_rate) * cell_width, (
        (forward_rate + backward_rate) * cell_width**2 / 2
    )


def chain_peclet(forward_rate: float, backward_rate: float, n_cells: int) -> float:
    """Péclet number ``v L / D_z = 2 n (a - b) / (a + b)`` of a chain of `n_cells` cells."""
    return 2 * n_cells * (forward_rate - backward_rate) / (forward_rate + backward_rate)


def backflow_chain_rates(
    velocity: float,
    dispersion: float,
    cell_width: float,
    scheme: Scheme = "central",
) -> tuple[float, float]:
    """Forward and backward rates of the chain that discretises the ADM on cells of `cell_width`.

    **Arguments:**

    - `velocity`: ``v``, axial velocity (m/s), positive.
    - `dispersion`: ``D_z``, axial dispersion coefficient (m²/s), positive.
    - `cell_width`: ``dx`` (m).
    - `scheme`: ``"central"`` (exact ``v`` and ``D_z``; needs ``v dx / D_z <= 2``) or
      ``"upwind"`` (always valid; equivalent dispersion ``D_z + v dx / 2``).

    **Returns:**

    ``(a, b)`` in 1/s.
    """
    v = _positive(velocity, "velocity")
    d = _positive(dispersion, "dispersion")
    dx = _positive(cell_width, "cell_width")
    if scheme == "central":
        cell_peclet = v * dx / d
        if cell_peclet > 2 * (1 + 1e-12):
            raise ValueError(
                f"Cell Peclet number {cell_peclet:.4g} is above 2: the central chain would need "
                "a negative backward rate; use more cells or scheme='upwind'."
            )
        return d / dx**2 + v / (2 * dx), max(d / dx**2 - v / (2 * dx), 0.0)
    if scheme == "upwind":
        return v / dx + d / dx**2, d / dx**2
    raise ValueError(f"scheme must be 'central' or 'upwind', got {scheme!r}.")


def backflow_ratio_for_peclet(peclet: float, n_cells: int, scheme: Scheme = "central") -> float:
    """Backflow ratio ``beta = b / k_out`` of the `n_cells` chain that represents an ADM.

    With throughput rate ``k_out = n / tau`` per cell, the chain has ``a = (1 + beta) n / tau``
    and ``b = beta n / tau``, so ``Pe = 2 n / (1 + 2 beta)`` (central) gives
    ``beta = n / Pe - 1/2``; the upwind discretisation gives ``beta = n / Pe``.

    **Returns:**

    ``beta`` (dimensionless, non-negative).
    """
    pe = _positive(peclet, "peclet")
    if n_cells < 1:
        raise ValueError(f"n_cells must be at least 1, got {n_cells}.")
    if scheme == "central":
        beta = n_cells / pe - 0.5
        if beta < -1e-12:
            raise ValueError(
                f"{n_cells} cells cannot represent Pe = {pe:g} with the central chain "
                f"(needs n_cells >= Pe / 2 = {pe / 2:g}); use more cells or scheme='upwind'."
            )
        return max(beta, 0.0)
    if scheme == "upwind":
        return n_cells / pe
    raise ValueError(f"scheme must be 'central' or 'upwind', got {scheme!r}.")
