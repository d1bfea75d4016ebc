"""Compartment networks: structure → rate matrix → RTD and batch mixing (MODELS.md §3).

The description (:class:`CompartmentNetwork`) is plain, immutable and validated; the models
are JAX functions of its rates, differentiable and jit/vmap clean.
"""

from ._chain import (
    backflow_chain_rates,
    backflow_chain_transport,
    backflow_ratio_for_peclet,
    chain_peclet,
)
from ._description import CompartmentNetwork, Connection, Inlet, Outlet
from ._presets import (
    V_BLENDER_LOADINGS,
    adm_chain,
    axial_radial_grid,
    four_compartment,
    loading_amounts,
    tanks_in_series,
    v_blender,
    v_blender_species_amounts,
)

__all__ = [
    "CompartmentNetwork",
    "Connection",
    "Inlet",
    "Outlet",
    "V_BLENDER_LOADINGS",
    "adm_chain",
    "axial_radial_grid",
    "backflow_chain_rates",
    "backflow_chain_transport",
    "backflow_ratio_for_peclet",
    "chain_peclet",
    "four_compartment",
    "loading_amounts",
    "tanks_in_series",
    "v_blender",
    "v_blender_species_amounts",
]
