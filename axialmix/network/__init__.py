"""Compartment networks: structure → rate matrix → RTD and batch mixing (MODELS.md §3).

The description (:class:`CompartmentNetwork`) is plain, immutable and validated; the models
are JAX functions of its rates, differentiable and jit/vmap clean. The equivalent
axial dispersion model of a network is :func:`moment_matched_adm`; the four-compartment
structure is defined once (:data:`FOUR_COMPARTMENT_CONNECTIONS`).
"""

from ._chain import (
    backflow_chain_rates,
    backflow_chain_transport,
    backflow_ratio_for_peclet,
    chain_peclet,
)
from ._description import CompartmentNetwork, Connection, Inlet, Outlet
from ._equivalent import (
    TIME_UNITS,
    MomentMatchedADM,
    four_compartment_chain_transport,
    moment_matched_adm,
    moment_matched_adm_from_moments,
)
from ._four_compartment import (
    FOUR_COMPARTMENT_CONNECTIONS,
    FOUR_COMPARTMENT_INLET,
    FOUR_COMPARTMENT_OUTLET,
    FOUR_COMPARTMENT_RATES,
    FOUR_COMPARTMENTS,
    four_compartment_exit_age,
    four_compartment_generator,
)
from ._matrices import generator_matrix, step_matrix
from ._moments import ResidenceTimeMoments, residence_time_moments
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
from ._propagation import regular_grid
from ._responses import (
    compartment_amounts,
    cumulative_exit_age,
    exit_age,
    outlet_response,
    species_fractions,
)
from ._timevarying import (
    RateSchedule,
    ScheduleSolver,
    scheduled_amounts,
    scheduled_exit_age,
    scheduled_outlet_response,
)

__all__ = [
    "CompartmentNetwork",
    "Connection",
    "FOUR_COMPARTMENTS",
    "FOUR_COMPARTMENT_CONNECTIONS",
    "FOUR_COMPARTMENT_INLET",
    "FOUR_COMPARTMENT_OUTLET",
    "FOUR_COMPARTMENT_RATES",
    "Inlet",
    "MomentMatchedADM",
    "Outlet",
    "RateSchedule",
    "ResidenceTimeMoments",
    "ScheduleSolver",
    "TIME_UNITS",
    "V_BLENDER_LOADINGS",
    "adm_chain",
    "axial_radial_grid",
    "backflow_chain_rates",
    "backflow_chain_transport",
    "backflow_ratio_for_peclet",
    "chain_peclet",
    "compartment_amounts",
    "cumulative_exit_age",
    "exit_age",
    "four_compartment",
    "four_compartment_chain_transport",
    "four_compartment_exit_age",
    "four_compartment_generator",
    "generator_matrix",
    "loading_amounts",
    "moment_matched_adm",
    "moment_matched_adm_from_moments",
    "outlet_response",
    "regular_grid",
    "residence_time_moments",
    "scheduled_amounts",
    "scheduled_exit_age",
    "scheduled_outlet_response",
    "species_fractions",
    "step_matrix",
    "tanks_in_series",
    "v_blender",
    "v_blender_species_amounts",
]
