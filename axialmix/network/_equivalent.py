"""Reporting networks as an equivalent axial dispersion model (MODELS.md §2–3).

Two readings, both documented because they answer different questions:

* **Moment matching** (:func:`equivalent_adm`, any open network): the closed–closed ADM with
  the network's exact mean residence time and variance, ``sigma²/tau² = 2/Pe - 2/Pe² (1 -
  e^{-Pe})``. Always meaningful when the network's variance ratio is below 1 (a single
  stirred tank, the Pe → 0 limit, has ratio 1; bypassing or dead zones can exceed it, and
  then no closed–closed ADM matches: Pe is NaN).
* **Axial chain** (:func:`backflow_chain_transport`): a chain with forward ``a`` and
  backward ``b`` has ``v = (a - b) dx``, ``D_z = (a + b) dx² / 2``. For the four-compartment
  model (:func:`four_compartment_chain_transport`) the chain is the two axial stages (C1/C3
  and C2/C4, ``dx = L / 2``) with forward ``k_f`` and backward ``k_r``; the side exchange
  ``k_s`` mixes radially and does not enter. This is the reading of the fluxes themselves,
  but in the source's model the throughput is not part of ``k_f - k_r`` (it leaves only
  through ``k_out``), so with ``k_f = k_r`` — every fit the source reported — the chain
  velocity is 0 and ``D_z = k_f L² / 4``; the moment-matched values then describe the
  RTD, the chain values the exchange intensity.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from jax.typing import ArrayLike
from scipy.optimize import brentq

from ._chain import backflow_chain_transport
from ._description import CompartmentNetwork
from ._dynamics import residence_time_moments

__all__ = [
    "EquivalentADM",
    "equivalent_adm",
    "four_compartment_chain_transport",
    "peclet_from_variance_ratio",
]


class EquivalentADM(NamedTuple):
    """The closed–closed ADM with the same mean and variance as a network."""

    mean_residence_time: float
    """``tau`` (time units)."""
    variance: float
    """Variance of the residence time (time²)."""
    variance_ratio: float
    """``sigma² / tau²``."""
    peclet: float
    """``Pe`` (NaN when the variance ratio is not below 1)."""
    velocity: float
    """``v = L / tau`` (length / time)."""
    axial_dispersion: float
    """``D_z = v L / Pe`` (length² / time)."""


def _variance_ratio(peclet: float) -> float:
    if peclet < 1e-2:
        # Series of 2/Pe - 2/Pe² (1 - e^{-Pe}); the closed form cancels catastrophically.
        return 1 - peclet / 3 + peclet**2 / 12 - peclet**3 / 60
    return 2 / peclet - 2 / peclet**2 * (-math.expm1(-peclet))


def peclet_from_variance_ratio(variance_ratio: float) -> float:
    """Closed–closed Péclet number with ``2/Pe - 2/Pe² (1 - e^{-Pe}) = sigma²/tau²``.

    **Arguments:**

    - `variance_ratio`: ``sigma² / tau²`` (dimensionless).

    **Returns:**

    ``Pe``; NaN when the ratio is not in (0, 1) (no closed–closed ADM has it).
    """
    ratio = float(variance_ratio)
    if not math.isfinite(ratio) or ratio <= 0 or ratio >= 1:
        return math.nan
    low, high = 1e-9, 1e9
    if ratio >= _variance_ratio(low) or ratio <= _variance_ratio(high):
        return math.nan
    log_peclet = brentq(
        lambda log_pe: _variance_ratio(math.exp(log_pe)) - ratio,
        math.log(low),
        math.log(high),
        xtol=1e-14,
        rtol=1e-14,
    )
    return math.exp(log_peclet)


def equivalent_adm(
    network: CompartmentNetwork,
    length: float = 1.0,
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> EquivalentADM:
    """The closed–closed ADM with the network's exact mean residence time and variance.

    **Arguments:**

    - `network`: an open network.
    - `length`: blender length ``L`` (m), to express ``v`` and ``D_z``.
    - `rates`, `outflow_rates`: optional rates (e.g. fitted values) in network order.

    **Returns:**

    :class:`EquivalentADM` with ``tau``, ``sigma²``, ``sigma²/tau²``, ``Pe``, ``v``, ``D_z``.
    """
    moments = residence_time_moments(network, rates, outflow_rates)
    tau = float(moments.mean)
    variance = float(moments.variance)
    ratio = variance / tau**2
    peclet = peclet_from_variance_ratio(ratio)
    velocity = length / tau
    return EquivalentADM(tau, variance, ratio, peclet, velocity, velocity * length / peclet)


def four_compartment_chain_transport(
    k_f: float, k_r: float, length: float = 1.0
) -> tuple[float, float, float]:
    """Velocity, dispersion and Péclet number of the four-compartment model's axial chain.

    Two axial stages of width ``L / 2`` with forward ``k_f`` and backward ``k_r`` (see the
    module notes for why this differs from :func:`equivalent_adm`).

    **Arguments:**

    - `k_f`, `k_r`: forward and backward rates (1/s).
    - `length`: blender length ``L`` (m).

    **Returns:**

    ``(v, D_z, Pe)``: ``v = (k_f - k_r) L / 2`` (m/s), ``D_z = (k_f + k_r) L² / 8`` (m²/s),
    ``Pe = v L / D_z = 4 (k_f - k_r) / (k_f + k_r)``.
    """
    velocity, dispersion = backflow_chain_transport(k_f, k_r, length / 2)
    peclet = velocity * length / dispersion if dispersion > 0 else math.nan
    return velocity, dispersion, peclet

