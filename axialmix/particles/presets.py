"""Particle versions of the project's standard networks (built from :mod:`axialmix.network`).

Each ``particle_*`` function returns a :class:`ParticleNetwork` (and
:func:`v_blender_loading` the initial species counts of a batch blender), so the simulator
runs on exactly the description the mean-field model uses. The ``particle_`` prefix keeps
them apart from the mean-field presets of :mod:`axialmix.network`, which return compartment
networks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from axialmix import network as mean_field
from axialmix.particles.description import ParticleNetwork

__all__ = [
    "particle_axial_radial_grid",
    "particle_four_compartment",
    "particle_v_blender",
    "v_blender_loading",
]


def particle_v_blender(
    particles: int = 1_000_000, exchanges: Sequence[int] = (1000, 100, 100, 1000)
) -> ParticleNetwork:
    """The source's batch V-blender chain V1 ... V5 with `particles` in all.

    **Arguments:**

    - `particles`: total particles (a multiple of 5; 1,000,000 in the source).
    - `exchanges`: particles exchanged both ways per step across V1-V2, V2-V3, V3-V4, V4-V5.

    **Returns:** a batch :class:`ParticleNetwork`.
    """
    if particles <= 0 or particles % 5:
        raise ValueError(f"particles must be a positive multiple of 5, got {particles}.")
    network = mean_field.v_blender(
        particles_per_compartment=particles // 5, exchanges=tuple(exchanges)
    )
    return ParticleNetwork.from_network(network)


def v_blender_loading(network: ParticleNetwork, loading: str | Sequence[float] = "E") -> np.ndarray:
    """Initial species counts of a V-blender: column 0 is species 1, column 1 species 2.

    **Arguments:**

    - `network`: a V-blender from :func:`particle_v_blender`.
    - `loading`: a name of :data:`axialmix.network.V_BLENDER_LOADINGS` (``"E"`` is the
      source's side-by-side loading 100, 100, 50, 0, 0 % species 1) or five percentages.

    **Returns:** integer array ``(5, 2)``.
    """
    amounts = mean_field.v_blender_species_amounts(loading, network.to_network())
    first = np.rint(amounts[:, 0]).astype(np.int64)
    return np.column_stack([first, network.holdups - first])


def particle_four_compartment(
    k_f: float = 2.125,
    k_r: float = 2.125,
    k_s: float = 0.625,
    k_out: float = 1.0,
    *,
    particles: int = 10_000,
    time_step: float = 0.01,
) -> ParticleNetwork:
    """The four-compartment continuous blender: steady hold-ups, moves rounded to whole particles.

    Defaults: the source's horizontal fit ``(k_f, k_r, k_s) = (2.125, 2.125, 0.625)`` 1/s
    with ``k_out = 1`` 1/s. Moves per step are rounded, so the simulated network is
    ``result.network.to_network()``, close to but not exactly the given rates.

    **Arguments:**

    - `k_f`, `k_r`, `k_s`, `k_out`: rates (1/s).
    - `particles`: total particles held.
    - `time_step`: step length (s).

    **Returns:** a continuous :class:`ParticleNetwork`.
    """
    network = mean_field.four_compartment(k_f, k_r, k_s, k_out, total_holdup=particles)
    return ParticleNetwork.from_network(network, time_step=time_step, round_moves=True)


def particle_axial_radial_grid(
    n_axial: int = 50,
    n_radial: int = 5,
    *,
    particles_per_compartment: int = 40,
    mean_residence_time: float = 100.0,
) -> ParticleNetwork:
    """An axial x radial continuous blender whose moves are exactly whole numbers of particles.

    Built with :func:`axialmix.network.axial_radial_grid` at the Peclet number, radial
    mixing rate and time step for which, per step, every outlet compartment discharges and
    every compartment exchanges radially ``h / 40`` particles, axial backflow is ``h / 40``
    and axial forward flow ``h / 20`` (``h`` = particles per compartment, a multiple of 40):
    ``Pe = n_axial / 1.5``, step ``tau / (40 n_axial)``. With 50 x 5 compartments and
    40 particles each this is the source's 10,000-particle, 250-compartment case.

    **Arguments:**

    - `n_axial`, `n_radial`: grid size (``n_axial >= 2``).
    - `particles_per_compartment`: hold-up of each compartment (a multiple of 40).
    - `mean_residence_time`: ``tau`` (s).

    **Returns:** a continuous :class:`ParticleNetwork`.
    """
    if particles_per_compartment <= 0 or particles_per_compartment % 40:
        raise ValueError(
            f"particles_per_compartment must be a positive multiple of 40, got "
            f"{particles_per_compartment}."
        )
    if n_axial < 2 or n_radial < 1:
        raise ValueError("the grid needs n_axial >= 2 and n_radial >= 1.")
    time_step = mean_residence_time / (40.0 * n_axial)
    radial_rate = 1.0 / (40.0 * n_radial**2 * time_step) if n_radial > 1 else 0.0
    network = mean_field.axial_radial_grid(
        n_axial,
        n_radial,
        mean_residence_time=mean_residence_time,
        peclet=n_axial / 1.5,
        radial_mixing_rate=radial_rate,
        total_holdup=particles_per_compartment * n_axial * n_radial,
    )
    return ParticleNetwork.from_network(network, time_step=time_step)
