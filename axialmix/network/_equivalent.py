"""Reporting networks as an equivalent axial dispersion model (MODELS.md §2–3).

Two readings, both documented because they answer different questions:

* **Moment matching** (:func:`moment_matched_adm`, any open network): the closed–closed ADM with
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

import equinox as eqx
from jax.typing import ArrayLike

from ..analytic.inverse import peclet_from_variance_ratio as _peclet_from_ratio
from ._chain import backflow_chain_transport
from ._description import CompartmentNetwork
from ._moments import residence_time_moments

__all__ = [
    "TIME_UNITS",
    "MomentMatchedADM",
    "four_compartment_chain_transport",
    "moment_matched_adm",
]

TIME_UNITS = {"ms": 1e-3, "s": 1.0, "min": 60.0, "h": 3600.0}
"""Seconds in each time unit a network's rates may be given in (rates in 1/unit)."""


class MomentMatchedADM(eqx.Module):
    """The closed–closed ADM with the same mean and variance as a network, with its units.

    Times are in the network's time unit (:attr:`time_unit`); velocity and dispersion are
    in SI (m/s, m²/s) whatever that unit, and ``None`` when no length was given.
    """

    mean_residence_time: float
    """``tau``, in :attr:`time_unit`."""
    variance: float
    """Variance of the residence time, in :attr:`time_unit` squared."""
    variance_ratio: float
    """``sigma² / tau²`` (dimensionless)."""
    peclet: float
    """``Pe`` (dimensionless; NaN when the variance ratio is not in (0, 1))."""
    time_unit: str
    """Unit of the times (and 1/unit of the rates): one of :data:`TIME_UNITS`."""
    length: float | None
    """Blender length ``L`` (m), or ``None``."""
    velocity: float | None
    """``v = L / tau`` (m/s), or ``None`` without a length."""
    axial_dispersion: float | None
    """``D_z = v L / Pe = L² / (tau Pe)`` (m²/s), or ``None`` without a length."""

    def as_dict(self) -> dict[str, float | str | None]:
        """The values with their units in the keys (NaN given as ``None``, for JSON)."""

        def finite(value):
            return None if value is None or not math.isfinite(value) else float(value)

        unit = self.time_unit
        return {
            f"tau_{unit}": finite(self.mean_residence_time),
            f"variance_{unit}2": finite(self.variance),
            "variance_ratio": finite(self.variance_ratio),
            "peclet": finite(self.peclet),
            "length_m": self.length,
            "velocity_m_per_s": finite(self.velocity),
            "dispersion_m2_per_s": finite(self.axial_dispersion),
        }


def moment_matched_adm(
    network: CompartmentNetwork,
    length: float | None,
    *,
    time_unit: str = "s",
    rates: ArrayLike | None = None,
    outflow_rates: ArrayLike | None = None,
) -> MomentMatchedADM:
    """The closed–closed ADM with the network's exact mean residence time and variance.

    ``tau`` is the mean, ``Pe`` solves ``sigma²/tau² = 2/Pe - 2/Pe² (1 - e^{-Pe})``
    (:func:`axialmix.analytic.peclet_from_variance_ratio`), and with a length
    ``v = L / tau``, ``D_z = v L / Pe``, converted to SI from the rates' time unit.

    **Arguments:**

    - `network`: an open network.
    - `length`: blender length ``L`` (m), or ``None`` for ``tau`` and ``Pe`` only; there
      is no default, since ``v`` and ``D_z`` scale with it.
    - `time_unit`: the unit of time of the rates (rates in 1/unit): ``"ms"``, ``"s"``,
      ``"min"`` or ``"h"``.
    - `rates`, `outflow_rates`: optional rates (e.g. fitted values) in network order.

    **Returns:**

    :class:`MomentMatchedADM` (``tau``, ``sigma²``, ``sigma²/tau²``, ``Pe`` in the time
    unit; ``v`` in m/s and ``D_z`` in m²/s).
    """
    moments = residence_time_moments(network, rates, outflow_rates)
    return moment_matched_adm_from_moments(moments.mean, moments.variance, length,
                                           time_unit=time_unit)


def moment_matched_adm_from_moments(mean: float, variance: float, length: float | None, *,
                                    time_unit: str = "s") -> MomentMatchedADM:
    """The closed–closed ADM with a given mean residence time and variance.

    What :func:`moment_matched_adm` does once it has the network's moments (for callers that
    compute the moments themselves, e.g. in one compiled program for many rate sets).

    **Arguments:** `mean` (time unit) and `variance` (time unit²) of the residence time;
    `length` and `time_unit` as in :func:`moment_matched_adm`.

    **Returns:** :class:`MomentMatchedADM`.
    """
    if time_unit not in TIME_UNITS:
        raise ValueError(f"time_unit must be one of {sorted(TIME_UNITS)}, got {time_unit!r}.")
    if length is not None:
        length = float(length)
        if not (math.isfinite(length) and length > 0):
            raise ValueError(f"length must be positive and finite (m), got {length}.")
    tau = float(mean)
    variance = float(variance)
    ratio = variance / tau**2
    peclet = float(_peclet_from_ratio(ratio))
    velocity = dispersion = None
    if length is not None:
        velocity = length / (tau * TIME_UNITS[time_unit])
        dispersion = velocity * length / peclet
    return MomentMatchedADM(
        mean_residence_time=tau,
        variance=variance,
        variance_ratio=ratio,
        peclet=peclet,
        time_unit=time_unit,
        length=length,
        velocity=velocity,
        axial_dispersion=dispersion,
    )


def four_compartment_chain_transport(
    k_f: float, k_r: float, length: float = 1.0
) -> tuple[float, float, float]:
    """Velocity, dispersion and Péclet number of the four-compartment model's axial chain.

    Two axial stages of width ``L / 2`` with forward ``k_f`` and backward ``k_r`` (see the
    module notes for why this differs from :func:`moment_matched_adm`).

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

