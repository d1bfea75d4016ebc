"""Curves of a network told what grid their traced times are (``regular``, see
axialmix.network.regular_grid): only that grid's propagation is compiled, with the values
of the program that compiles both; fitting's programs tell the built-in network models."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from axialmix.network import (
    cumulative_exit_age,
    four_compartment,
    four_compartment_exit_age,
    four_compartment_generator,
    generator_matrix,
    regular_grid,
)
from axialmix.network._propagation import continuous_states
from fitting.models import MODELS
from fitting.models.base import traced_on_time_grid, traced_time_grid
from fitting.solve.programs import Program

RATES = jnp.array([2.125, 1.3, 0.625, 0.8])
# Decimal times as a file gives them: 0.005, 0.015, ... (spacings differ by ~1e-13 of 0.01).
GRID = np.array([float(f"{0.005 + 0.01 * j:.3f}") for j in range(1500)])


def _exit_age_and_slopes(regular):
    def both(rates, shift, times):
        def curve(r, s):
            return four_compartment_exit_age(times - s, *r, regular=regular)

        return curve(rates, shift), jax.jacfwd(curve, argnums=(0, 1))(rates, shift)

    return jax.jit(both)


@pytest.mark.parametrize("shift", [0.0, 0.1234, 7.0, 40.0])
def test_a_regular_grid_gives_the_values_and_slopes_of_the_general_program(shift):
    # A shift clips the first times at zero (a dead time): increments 0, ..., 0, a, h, ...
    times = jnp.asarray(GRID)
    general = _exit_age_and_slopes(None)(RATES, shift, times)
    regular = _exit_age_and_slopes(True)(RATES, shift, times)
    peak = float(jnp.max(jnp.abs(general[0])))
    for told, both in zip(jax.tree.leaves(regular), jax.tree.leaves(general), strict=True):
        # Unshifted, both run the same products; shifted, the general program takes one
        # exponential per interval: products of 1,500 steps agree to round-off.
        np.testing.assert_allclose(told, both, rtol=0, atol=1e-12 * max(peak, 1.0))
    # Against the matrix exponential at each time, independently.
    generator = four_compartment_generator(*RATES)
    direct = jax.vmap(lambda x: jax.scipy.linalg.expm(generator * x)[3, 0])(
        jnp.maximum(times - shift, 0.0))
    exact = np.where(np.asarray(times - shift) >= 0, RATES[3] * direct, 0.0)
    np.testing.assert_allclose(regular[0], exact, rtol=0, atol=1e-11 * max(peak, 1e-300))


def test_an_irregular_grid_gives_the_values_of_the_general_program():
    times = jnp.asarray(np.sort(np.random.default_rng(3).uniform(0.0, 20.0, 300)))
    general = _exit_age_and_slopes(None)(RATES, 0.37, times)
    irregular = _exit_age_and_slopes(False)(RATES, 0.37, times)
    for told, both in zip(jax.tree.leaves(irregular), jax.tree.leaves(general), strict=True):
        np.testing.assert_allclose(told, both, rtol=1e-14, atol=1e-300)
    # Against the matrix exponential at each time, independently.
    generator = four_compartment_generator(*RATES)
    direct = jax.vmap(lambda x: jax.scipy.linalg.expm(generator * x)[3, 0])(
        jnp.maximum(times - 0.37, 0.0))
    exact = np.where(np.asarray(times - 0.37) >= 0, RATES[3] * direct, 0.0)
    np.testing.assert_allclose(irregular[0], exact, rtol=0,
                               atol=1e-12 * float(np.max(np.abs(exact))))


def test_times_that_break_the_promise_give_nan_not_a_wrong_value():
    jittered = GRID + np.r_[0.0, np.random.default_rng(5).uniform(-2e-3, 2e-3, GRID.size - 2), 0.0]
    assert not regular_grid(jittered)
    values = _exit_age_and_slopes(True)(RATES, 0.0, jnp.asarray(jittered))[0]
    assert np.all(np.isnan(values))
    # A spacing that changes once, and a zero interval after the first positive one.
    for times in (np.r_[np.arange(10.0), 9.5 + np.arange(1.0, 6.0)],
                  np.r_[0.0, 1.0, 1.0, 2.0, 3.0]):
        value = jax.jit(lambda t: four_compartment_exit_age(t, *RATES, regular=True))(times)
        assert np.all(np.isnan(value))


def test_the_cumulative_curve_and_states_of_several_species_on_a_regular_grid():
    times = jnp.asarray(GRID[:400])
    network = four_compartment(*map(float, RATES))

    def cumulative(regular):
        return jax.jit(lambda t, s: cumulative_exit_age(network, t - s, regular=regular))

    for shift in (0.0, 0.5):
        np.testing.assert_allclose(cumulative(True)(times, shift), cumulative(None)(times, shift),
                                   rtol=0, atol=1e-12)
    loading = jnp.array([[1.0, 0.0], [0.0, 2.0], [0.5, 0.5], [0.0, 0.0]])  # two species
    generator = generator_matrix(network)

    def states(regular):
        return jax.jit(lambda t: continuous_states(generator, loading, t, None, regular))

    np.testing.assert_allclose(states(True)(times), states(None)(times), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="regular must be"):
        continuous_states(generator, loading, times, None, "yes")


def test_regular_grids_are_told_from_others():
    assert regular_grid(GRID)
    assert regular_grid(np.vstack([GRID, GRID + 3.0]))
    assert not regular_grid(np.vstack([GRID, GRID * 1.5 + np.r_[np.zeros(1499), 1.0]]))
    assert not regular_grid([0.0, 1.0])
    assert not regular_grid([0.0, 1.0, 1.0, 2.0])
    assert not regular_grid([3.0, 2.0, 1.0])
    assert not regular_grid([0.0, 1.0, np.nan])
    assert not regular_grid(np.r_[np.arange(16.0), 18.0, 22.0])  # a sparse tail


def test_a_program_keeps_its_regular_and_irregular_forms_apart():
    # One Program of the built-in model, fed a regular curve and then an irregular one of
    # the same shape: each gets the program its grid needs (a regular-only program would
    # give NaN on the second).
    model = MODELS["four-compartment"]
    seen = []

    def curve(rates, time):
        seen.append(traced_time_grid())
        values = {name: rates[j] for j, name in enumerate(model.parameter_names)}
        return model.function(time - rates[4], values)

    program = Program(curve, "test-grid", ("test-grid",), times=1)
    regular = np.linspace(0.0, 30.0, 64)
    irregular = np.sort(np.random.default_rng(8).uniform(0.0, 30.0, 64))
    rates = np.array([*np.asarray(RATES), 0.25])  # and a dead time of 0.25
    general = jax.jit(curve)
    for times in (regular, irregular, regular):
        executable, _ = program.executable((rates, times))
        np.testing.assert_allclose(executable(rates, times), general(rates, times),
                                   rtol=0, atol=1e-13)
    assert len(program.executables) == 2
    assert seen == [True, None, False]  # each traced once; outside a program: not said
    with traced_on_time_grid(True):
        assert traced_time_grid() is True
    assert traced_time_grid() is None
    # A program without a key (a user's model) is traced without being told.
    seen.clear()
    untold = Program(curve, "test-untold", None, times=1)
    for times in (regular, irregular):
        executable, _ = untold.executable((rates, times))
        np.testing.assert_allclose(executable(rates, times), general(rates, times),
                                   rtol=0, atol=1e-13)
    assert set(seen) <= {None} and len(untold.executables) == 1
