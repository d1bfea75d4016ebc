"""The stochastic particle simulator: the independent checker of the network models (MODELS.md §4).

Particles with species labels move between well-mixed compartments: every step, for every
connection i -> j, ``moves_ij`` particles chosen at random among those in i move to j; a
continuous blender takes a feed into its inlet compartments and loses as many over the
weir. Its expectation is the discrete mean-field network of :mod:`axialmix.network`, but
nothing of that model's mathematics is used here. Exchange may change in time: a move
schedule (:func:`scheduled_moves`, from a :class:`axialmix.network.RateSchedule`) gives the
particles moved along each connection at each step. Two engines, same random process:
``"count"`` (species counts, multivariate hypergeometric draws, cost independent of the
number of particles) and ``"identity"`` (individual particles, per-particle histories).
"""

from axialmix.particles.description import ParticleNetwork
from axialmix.particles.feed import check_feed_schedule, constant_feed, feeder_feed
from axialmix.particles.presets import (
    particle_axial_radial_grid,
    particle_four_compartment,
    particle_v_blender,
    v_blender_loading,
)
from axialmix.particles.sampling import (
    chi_square,
    exit_age_from_outflow,
    relative_standard_deviation,
    sample_compartments,
    sample_outflow,
    sample_variance,
    species_fraction,
    variance_reduction_ratio,
)
from axialmix.particles.schedule import check_move_schedule, scheduled_moves
from axialmix.particles.simulate import (
    ENGINES,
    MAX_SEED,
    MemoryEstimate,
    SimulationResult,
    TracerPulse,
    memory_estimate,
    simulate,
)

__all__ = [
    "ENGINES",
    "MAX_SEED",
    "MemoryEstimate",
    "ParticleNetwork",
    "SimulationResult",
    "TracerPulse",
    "check_feed_schedule",
    "check_move_schedule",
    "chi_square",
    "constant_feed",
    "exit_age_from_outflow",
    "feeder_feed",
    "memory_estimate",
    "particle_axial_radial_grid",
    "particle_four_compartment",
    "particle_v_blender",
    "relative_standard_deviation",
    "sample_compartments",
    "sample_outflow",
    "sample_variance",
    "scheduled_moves",
    "simulate",
    "species_fraction",
    "v_blender_loading",
    "variance_reduction_ratio",
]
