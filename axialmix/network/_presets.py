"""Ready-made networks of MODELS.md §3: four compartments, axial × radial grid, V-blender chain,
tanks in series with backflow and the chain that represents an ADM."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ._chain import Scheme, backflow_chain_rates, backflow_ratio_for_peclet
from ._description import CompartmentNetwork, Connection
from ._four_compartment import (
    FOUR_COMPARTMENT_CONNECTIONS,
    FOUR_COMPARTMENT_INLET,
    FOUR_COMPARTMENT_OUTLET,
    FOUR_COMPARTMENTS,
)

__all__ = [
    "V_BLENDER_LOADINGS",
    "adm_chain",
    "axial_radial_grid",
    "four_compartment",
    "loading_amounts",
    "tanks_in_series",
    "v_blender",
    "v_blender_species_amounts",
]


def _non_negative(value: float, name: str) -> float:
    number = float(value)
    if not math.isfinite(number) or number < 0:
        raise ValueError(f"{name} must be non-negative and finite, got {value}.")
    return number


def _positive(value: float, name: str) -> float:
    number = float(value)
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be positive and finite, got {value}.")
    return number


def _finish(network: CompartmentNetwork, total_holdup: float | None) -> CompartmentNetwork:
    if total_holdup is None:
        return network
    return network.with_holdups(network.steady_state_holdups(_positive(total_holdup,
                                                                       "total_holdup")))


def four_compartment(
    k_f: float,
    k_r: float,
    k_s: float,
    k_out: float | None,
    *,
    total_holdup: float | None = None,
    time_step: float | None = None,
) -> CompartmentNetwork:
    """The source's four-compartment model: a 2 × 2 layout, C1 inlet, C4 outlet (MODELS.md §3).

    Compartments ``C1 C2`` (first row) and ``C3 C4`` (second row); forward ``k_f`` for
    C1→C2 and C3→C4, backward ``k_r`` for C2→C1 and C4→C3, side exchange ``k_s`` both ways
    for C1↔C3 and C2↔C4; feed into C1, outflow ``k_out`` from C4. The structure is the
    table :data:`axialmix.network.FOUR_COMPARTMENT_CONNECTIONS`, shared with
    :func:`four_compartment_generator`.

    **Arguments:**

    - `k_f`, `k_r`, `k_s`: rates (1/time; fractions per step if `time_step` is given).
    - `k_out`: outflow rate of C4; ``None`` or 0 gives the closed (batch) network without
      feed or outflow.
    - `total_holdup`: if given, holdups are the steady state of the flows (feed = outflow)
      scaled to this total, so a particle simulation keeps compartment sizes constant.
    - `time_step`: ``None`` for continuous time, else the step length of a discrete network.

    **Returns:**

    A :class:`CompartmentNetwork`.
    """
    k_f, k_r, k_s = (_non_negative(v, n) for v, n in ((k_f, "k_f"), (k_r, "k_r"), (k_s, "k_s")))
    k_out = 0.0 if k_out is None else _non_negative(k_out, "k_out")
    value = {"k_f": k_f, "k_r": k_r, "k_s": k_s}
    connections = [(source, target, value[rate])
                   for source, target, rate in FOUR_COMPARTMENT_CONNECTIONS]
    closed = k_out == 0
    network = CompartmentNetwork(
        compartments=FOUR_COMPARTMENTS,
        connections=connections,
        inlets=() if closed else ((FOUR_COMPARTMENT_INLET, 1.0),),
        outlets=() if closed else ((FOUR_COMPARTMENT_OUTLET, k_out),),
        time_step=time_step,
        description=f"four-compartment model k_f={k_f:g}, k_r={k_r:g}, k_s={k_s:g}, "
        f"k_out={k_out:g}",
    )
    return _finish(network, total_holdup)


def tanks_in_series(
    n_tanks: int,
    mean_residence_time: float,
    backflow_ratio: float = 0.0,
    *,
    total_holdup: float = 1.0,
    time_step: float | None = None,
) -> CompartmentNetwork:
    """Tanks in series with backflow: ``T1 … Tn``, feed into T1, outflow from Tn.

    With throughput ``Q`` and tank holdup ``H = total / n``, the forward flow is
    ``(1 + beta) Q`` and the backflow ``beta Q``: rates ``a = (1 + beta) n / tau``,
    ``b = beta n / tau``, ``k_out = n / tau``. Holdups are uniform and steady; the mean
    residence time is `mean_residence_time` for every beta, and ``Pe = 2 n / (1 + 2 beta)``
    (see :func:`chain_peclet`).

    **Arguments:**

    - `n_tanks`: number of tanks (≥ 1).
    - `mean_residence_time`: ``tau`` (s), total holdup / throughput.
    - `backflow_ratio`: ``beta`` ≥ 0, backflow as a multiple of the throughput.
    - `total_holdup`: total amount held (particles, kg).
    - `time_step`: if given, a discrete network with fractions ``rate * time_step`` per step.

    **Returns:**

    A :class:`CompartmentNetwork`.
    """
    if int(n_tanks) != n_tanks or n_tanks < 1:
        raise ValueError(f"n_tanks must be a positive integer, got {n_tanks}.")
    n = int(n_tanks)
    tau = _positive(mean_residence_time, "mean_residence_time")
    beta = _non_negative(backflow_ratio, "backflow_ratio")
    total = _positive(total_holdup, "total_holdup")
    throughput_rate = n / tau
    names = [f"T{i + 1}" for i in range(n)]
    connections = [(names[i], names[i + 1], (1 + beta) * throughput_rate) for i in range(n - 1)]
    if beta > 0:
        connections += [(names[i + 1], names[i], beta * throughput_rate) for i in range(n - 1)]
    network = CompartmentNetwork(
        compartments=names,
        connections=connections,
        inlets=((names[0], 1.0),),
        outlets=((names[-1], throughput_rate),),
        holdups=[total / n] * n,
        description=f"{n} tanks in series, tau={tau:g}, backflow ratio {beta:g}",
    )
    return network.discretised(time_step) if time_step is not None else network


def adm_chain(
    mean_residence_time: float,
    peclet: float,
    n_cells: int,
    *,
    scheme: Scheme = "central",
    total_holdup: float = 1.0,
    time_step: float | None = None,
) -> CompartmentNetwork:
    """The chain of cells that discretises the closed–closed ADM (tau, Pe) in `n_cells` cells.

    Cells of width ``L / n`` with Danckwerts boundaries (see :mod:`axialmix.network._chain`):
    ``scheme="central"`` keeps ``v`` and ``D_z`` exact (needs ``n_cells >= Pe / 2``),
    ``"upwind"`` is the upwind finite-volume scheme (equivalent ``D_z`` larger by
    ``v dx / 2``). It is :func:`tanks_in_series` with backflow ratio
    :func:`backflow_ratio_for_peclet`.

    **Arguments:**

    - `mean_residence_time`: ``tau = L / v`` (s).
    - `peclet`: ``Pe = v L / D_z``.
    - `n_cells`: number of cells.
    - `scheme`: ``"central"`` or ``"upwind"``.
    - `total_holdup`: total amount held.
    - `time_step`: if given, the discrete-step version.

    **Returns:**

    A :class:`CompartmentNetwork` with cells ``T1 … Tn``.
    """
    beta = backflow_ratio_for_peclet(peclet, n_cells, scheme)
    return tanks_in_series(
        n_cells, mean_residence_time, beta, total_holdup=total_holdup, time_step=time_step
    )


def axial_radial_grid(
    n_axial: int,
    n_radial: int,
    *,
    mean_residence_time: float,
    peclet: float,
    radial_mixing_rate: float = 0.0,
    scheme: Scheme = "central",
    total_holdup: float = 1.0,
    time_step: float | None = None,
) -> CompartmentNetwork:
    """An ``n_axial`` × ``n_radial`` grid for a continuous blender, with grid-independent physics.

    Compartment ``A{i}R{j}`` is axial slice i (1 = feed end) and radial position j. Each radial
    column is an ADM chain (:func:`adm_chain`): with length ``L`` (= 1), ``v = L / tau`` and
    ``D_z = v L / Pe`` held fixed, the slice width ``dx = L / n_axial`` sets

        a = D_z / dx² + v / (2 dx),   b = D_z / dx² - v / (2 dx)   (central),
        k_out = v / dx,

    so ``(a - b) dx = v`` and ``(a + b) dx² / 2 = D_z`` are invariant when ``n_axial``
    changes: refining the grid does not change the physics (MODELS.md §3), it converges to
    the ADM. Neighbouring radial compartments of a slice exchange at rate
    ``radial_mixing_rate * n_radial²`` both ways (a radial dispersion ``D_r = rate · W²`` over
    the width W, also invariant under refinement). The feed is split equally over the first
    slice and every compartment of the last slice discharges at ``k_out``.

    **Arguments:**

    - `n_axial`, `n_radial`: grid size.
    - `mean_residence_time`: ``tau`` (s).
    - `peclet`: axial Péclet number.
    - `radial_mixing_rate`: ``D_r / W²`` (1/s); 0 leaves the radial columns unconnected.
    - `scheme`: ``"central"`` (exact; needs ``n_axial >= Pe / 2``) or ``"upwind"``.
    - `total_holdup`: total amount held, spread uniformly (the steady state).
    - `time_step`: if given, the discrete-step version.

    **Returns:**

    A :class:`CompartmentNetwork`.
    """
    for value, name in ((n_axial, "n_axial"), (n_radial, "n_radial")):
        if int(value) != value or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value}.")
    n_a, n_r = int(n_axial), int(n_radial)
    tau = _positive(mean_residence_time, "mean_residence_time")
    pe = _positive(peclet, "peclet")
    radial = _non_negative(radial_mixing_rate, "radial_mixing_rate") * n_r**2
    total = _positive(total_holdup, "total_holdup")
    dx = 1.0 / n_a
    velocity = 1.0 / tau
    forward, backward = backflow_chain_rates(velocity, velocity / pe, dx, scheme)

    def name(i: int, j: int) -> str:
        return f"A{i + 1}R{j + 1}"

    connections: list[Connection | tuple[str, str, float]] = []
    for j in range(n_r):
        for i in range(n_a - 1):
            connections.append((name(i, j), name(i + 1, j), forward))
            if backward > 0:
                connections.append((name(i + 1, j), name(i, j), backward))
    if radial > 0:
        for i in range(n_a):
            for j in range(n_r - 1):
                connections.append((name(i, j), name(i, j + 1), radial))
                connections.append((name(i, j + 1), name(i, j), radial))
    names = [name(i, j) for i in range(n_a) for j in range(n_r)]
    network = CompartmentNetwork(
        compartments=names,
        connections=connections,
        inlets=[(name(0, j), 1.0 / n_r) for j in range(n_r)],
        outlets=[(name(n_a - 1, j), velocity / dx) for j in range(n_r)],
        holdups=[total / len(names)] * len(names),
        description=f"{n_a} x {n_r} axial-radial grid, tau={tau:g}, Pe={pe:g}, "
        f"radial mixing rate {radial_mixing_rate:g}",
    )
    return network.discretised(time_step) if time_step is not None else network


V_BLENDER_LOADINGS: dict[str, tuple[float, ...]] = {
    "E": (100.0, 100.0, 50.0, 0.0, 0.0),
    "end": (100.0, 0.0, 0.0, 0.0, 0.0),
    "centre": (0.0, 0.0, 100.0, 0.0, 0.0),
    "top_bottom": (100.0, 0.0, 0.0, 0.0, 100.0),
    "uniform": (50.0, 50.0, 50.0, 50.0, 50.0),
}
"""Named V-blender loadings: percentage of species 1 in V1 … V5.

``"E"`` is the source's side-by-side loading (one arm and half the apex). Defined here:
``"end"`` (species 1 only at the tip of one arm, the slowest case: it must cross both
narrow passages to reach V4, V5), ``"centre"`` (species 1 in the apex V3 only),
``"top_bottom"`` (species 1 at the tips of both arms, species 2 below; symmetric) and
``"uniform"`` (already mixed, a control whose fractions must stay constant)."""


def v_blender(
    *,
    particles_per_compartment: float = 200_000,
    exchanges: Sequence[float] = (1000, 100, 100, 1000),
    time_step: float = 1.0,
) -> CompartmentNetwork:
    """The source's batch V-blender chain V1 … V5 (closed, discrete steps).

    Every step, ``exchanges[k]`` particles move both ways across the k-th link
    (V1–V2, V2–V3, V3–V4, V4–V5): by default 1,000, 100, 100, 1,000 out of 200,000 per
    compartment, i.e. fractions 0.005 and 0.0005 per step. Sizes stay constant.

    **Arguments:**

    - `particles_per_compartment`: holdup of each compartment (particles).
    - `exchanges`: particles exchanged per step across the four links.
    - `time_step`: step length (the source counts steps; 1 by default).

    **Returns:**

    A closed discrete :class:`CompartmentNetwork`; load it with
    :func:`v_blender_species_amounts`.
    """
    size = _positive(particles_per_compartment, "particles_per_compartment")
    exchanges = [_non_negative(e, "exchanges") for e in exchanges]
    if len(exchanges) != 4:
        raise ValueError(f"exchanges must have 4 entries (one per link), got {len(exchanges)}.")
    names = [f"V{i + 1}" for i in range(5)]
    connections = []
    for k, count in enumerate(exchanges):
        connections.append((names[k], names[k + 1], count / size))
        connections.append((names[k + 1], names[k], count / size))
    return CompartmentNetwork(
        compartments=names,
        connections=connections,
        holdups=[size] * 5,
        time_step=time_step,
        description="batch V-blender chain V1-V5",
    )


def loading_amounts(
    network: CompartmentNetwork, percent_species_1: Sequence[float] | np.ndarray
) -> np.ndarray:
    """Initial amounts of two species from the percentage of species 1 in each compartment.

    **Arguments:**

    - `network`: a network with holdups.
    - `percent_species_1`: percentage (0–100) of species 1 in each compartment.

    **Returns:**

    Array ``(n_compartments, 2)``: amounts of species 1 and species 2 (holdup units).
    """
    percent = np.asarray(percent_species_1, dtype=float)
    if percent.shape != (network.n_compartments,):
        raise ValueError(
            f"percent_species_1 must have {network.n_compartments} entries, got {percent.size}."
        )
    if not np.all(np.isfinite(percent)) or np.any((percent < 0) | (percent > 100)):
        raise ValueError("percent_species_1 must lie between 0 and 100.")
    if network.holdups is None:
        raise ValueError("The network has no holdups; loadings need them.")
    holdups = np.asarray(network.holdups)
    first = holdups * percent / 100
    return np.stack([first, holdups - first], axis=1)


def v_blender_species_amounts(
    loading: str | Sequence[float] = "E", network: CompartmentNetwork | None = None
) -> np.ndarray:
    """Initial species amounts of a V-blender for a named loading or explicit percentages.

    **Arguments:**

    - `loading`: a key of :data:`V_BLENDER_LOADINGS` or five percentages of species 1.
    - `network`: the V-blender (default :func:`v_blender`).

    **Returns:**

    Array ``(5, 2)``: particles of species 1 and 2 in V1 … V5.
    """
    if isinstance(loading, str):
        if loading not in V_BLENDER_LOADINGS:
            raise ValueError(
                f"Unknown V-blender loading {loading!r}; known: {', '.join(V_BLENDER_LOADINGS)}."
            )
        loading = V_BLENDER_LOADINGS[loading]
    return loading_amounts(network if network is not None else v_blender(), loading)
