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
from ._dynamics import (
    ResidenceTimeMoments,
    compartment_amounts,
    cumulative_exit_age,
    exit_age,
    four_compartment_exit_age,
    four_compartment_generator,
    generator_matrix,
    outlet_response,
    residence_time_moments,
    species_fractions,
    step_matrix,
)
from ._equivalent import (
    EquivalentADM,
    equivalent_adm,
    four_compartment_chain_transport,
    peclet_from_variance_ratio,
)
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
    "EquivalentADM",
    "Inlet",
    "Outlet",
    "ResidenceTimeMoments",
    "V_BLENDER_LOADINGS",
    "adm_chain",
    "axial_radial_grid",
    "backflow_chain_rates",
    "backflow_chain_transport",
    "backflow_ratio_for_peclet",
    "chain_peclet",
    "compartment_amounts",
    "cumulative_exit_age",
    "equivalent_adm",
    "exit_age",
    "four_compartment",
    "four_compartment_chain_transport",
    "four_compartment_exit_age",
    "four_compartment_generator",
    "generator_matrix",
    "loading_amounts",
    "outlet_response",
    "peclet_from_variance_ratio",
    "residence_time_moments",
    "species_fractions",
    "step_matrix",
    "tanks_in_series",
    "v_blender",
    "v_blender_species_amounts",
]
