"""The mean-field network model: conservation, RTD invariants, batch mixing, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from axialmix.network import (
    CompartmentNetwork,
    adm_chain,
    axial_radial_grid,
    compartment_amounts,
    cumulative_exit_age,
    exit_age,
    four_compartment,
    four_compartment_exit_age,
    generator_matrix,
    loading_amounts,
    outlet_response,
    residence_time_moments,
    species_fractions,
    step_matrix,
    tanks_in_series,
    v_blender,
    v_blender_species_amounts,
)


def branched_network(**changes):
    """An open network with a dead zone, a bypass, two inlets and two outlets."""
    spec = dict(
        compartments=["A", "B", "C", "D", "E"],
        connections=[
            ("A", "B", 0.8), ("B", "A", 0.3), ("B", "C", 0.6), ("C", "D", 0.9),
            ("D", "C", 0.2), ("B", "E", 0.15), ("E", "B", 0.1), ("A", "C", 0.25),
            ("E", "D", 0.05),
        ],
        inlets=[("A", 0.7), ("B", 0.3)],
        outlets=[("D", 0.5), ("C", 0.1)],
    )
    spec.update(changes)
    network = CompartmentNetwork(**spec)
    return network.with_holdups(network.steady_state_holdups(40.0))


def scipy_exit_age(network, times):
    """Independent reference: SciPy's expm of the generator assembled by hand."""
    n = network.n_compartments
    generator = np.zeros((n, n))
    for c in network.connections:
        i, j = network.index(c.source), network.index(c.target)
        generator[j, i] += c.rate
        generator[i, i] -= c.rate
    outflow = np.zeros(n)
    for o in network.outlets:
        outflow[network.index(o.compartment)] += o.rate
    generator -= np.diag(outflow)
    split = network.feed_split
    return np.array([outflow @ scipy.linalg.expm(generator * t) @ split for t in times])


# ---------------------------------------------------------------- conservation
@pytest.mark.parametrize(
    "network",
    [
        v_blender().continuous(),
        four_compartment(1.5, 0.5, 0.7, None),
        CompartmentNetwork(
            compartments=["a", "b", "c"],
            connections=[("a", "b", 2.0), ("b", "c", 0.5), ("c", "a", 1.0), ("b", "a", 0.1)],
        ),
    ],
)
def test_generator_columns_sum_to_zero_for_closed_networks(network):
    generator = np.asarray(generator_matrix(network))
    np.testing.assert_allclose(generator.sum(axis=0), 0.0, atol=1e-14)
    assert np.all(generator - np.diag(np.diag(generator)) >= 0)


def test_generator_columns_lose_exactly_the_outflow():
    network = branched_network()
    generator = np.asarray(generator_matrix(network))
    np.testing.assert_allclose(generator.sum(axis=0), -network.outflow_vector(), atol=1e-14)


def test_step_matrix_conserves_mass_in_a_closed_discrete_network():
    step = np.asarray(step_matrix(v_blender()))
    np.testing.assert_allclose(step.sum(axis=0), 1.0, atol=1e-15)
    assert np.all(step >= 0)


# ---------------------------------------------------------------- RTD invariants
def test_exit_age_matches_independent_scipy_expm():
    network = branched_network()
    times = np.array([0.1, 0.5, 1.3, 2.0, 4.5, 9.0, 20.0])
    np.testing.assert_allclose(exit_age(network, times), scipy_exit_age(network, times),
                               rtol=1e-11, atol=1e-14)
    uniform = np.linspace(0.0, 20.0, 61)
    np.testing.assert_allclose(exit_age(network, uniform)[1:], scipy_exit_age(network, uniform)[1:],
                               rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("n_tanks", [1, 2, 5, 40])
def test_tanks_in_series_without_backflow_give_the_erlang_rtd(n_tanks):
    times = np.linspace(0.0, 20.0, 61)
    tau = 4.0
    rate = n_tanks / tau
    with np.errstate(divide="ignore"):
        power = (n_tanks - 1) * np.log(times) if n_tanks > 1 else 0.0
    # One tank: E(0) = 1 / tau, the pulse starts leaving at once.
    log_erlang = n_tanks * np.log(rate) + power - rate * times - math.lgamma(n_tanks)
    # Non-uniform times too: each interval then has its own matrix exponential, the first of
    # norm 2 n t / tau = 200 for 40 tanks (seven squarings).
    uneven = np.concatenate([times[:1], times[20:]])
    for grid in (times, uneven):
        expected = np.exp(log_erlang)[np.isin(times, grid)]
        np.testing.assert_allclose(exit_age(tanks_in_series(n_tanks, tau), grid), expected,
                                   rtol=1e-10, atol=1e-15)


def test_exit_age_vmaps_over_rates():
    network = branched_network()
    times = np.linspace(0.0, 20.0, 61)
    scales = np.array([0.5, 1.0, 2.0])
    batched = jax.vmap(lambda c: exit_age(network, times, network.rates * c,
                                          network.outflow_rates * c))(jnp.asarray(scales))
    for row, c in zip(np.asarray(batched), scales, strict=True):
        # Scaling every rate by c is a change of time unit: E_c(t) = c E(c t).
        np.testing.assert_allclose(row, c * scipy_exit_age(network, c * times), rtol=1e-10,
                                   atol=1e-14)


@pytest.mark.parametrize(
    "network",
    [
        branched_network(),
        four_compartment(2.125, 2.125, 0.625, 0.8, total_holdup=15.0),
        tanks_in_series(4, 3.0, 0.7),
        axial_radial_grid(5, 2, mean_residence_time=2.0, peclet=4.0, radial_mixing_rate=0.3),
    ],
)
def test_rtd_is_normalised_and_mean_is_holdup_over_throughput(network):
    # Stated invariant: with steady holdups, mean residence time = total holdup / throughput.
    expected_mean = sum(network.holdups) / network.throughput
    moments = residence_time_moments(network)
    assert float(moments.total) == pytest.approx(1.0, rel=1e-12)
    assert float(moments.mean) == pytest.approx(expected_mean, rel=1e-10)
    # Numerical quadrature of the curve itself (Simpson on a fine grid up to ~40 means).
    times = np.linspace(0.0, 40 * expected_mean, 8001)
    values = np.asarray(exit_age(network, times))
    h = times[1] - times[0]
    weights = np.ones_like(times)
    weights[1:-1:2], weights[2:-1:2] = 4.0, 2.0
    weights *= h / 3
    # Simpson's error shrinks as h⁴ (measured 1.7e-7 at this grid for the four-compartment
    # case, 1e-8 at half the step): 1e-6 tests the curve, not the quadrature.
    assert weights @ values == pytest.approx(1.0, abs=1e-6)
    assert weights @ (times * values) == pytest.approx(expected_mean, rel=1e-6)
    second = weights @ (times**2 * values)
    assert second - expected_mean**2 == pytest.approx(float(moments.variance), rel=1e-5)


def test_cumulative_exit_age_is_the_integral_of_exit_age():
    network = branched_network()
    times = np.linspace(0.0, 30.0, 8001)
    values = np.asarray(exit_age(network, times))
    h = times[1] - times[0]
    trapezoid = np.concatenate([[0.0], np.cumsum((values[1:] + values[:-1]) / 2 * h)])
    cumulative = np.asarray(cumulative_exit_age(network, times))
    # Trapezoid error ~ h² max|E''| T / 12 with h = 0.00375: below 1e-6.
    np.testing.assert_allclose(cumulative, trapezoid, atol=1e-6)


def test_outlet_response_matches_ode_solution_with_linear_inlet():
    network = branched_network()
    times = np.linspace(0.0, 12.0, 61)
    signal = np.exp(-((times - 2.0) ** 2)) + 0.3 * (times > 5)

    generator = np.asarray(generator_matrix(network))
    split = network.feed_split

    def rhs(t, m):
        return generator @ m + split * np.interp(t, times, signal)

    reference = solve_ivp(rhs, (0.0, 12.0), np.zeros(5), t_eval=times, rtol=1e-11, atol=1e-13,
                          max_step=0.05, method="LSODA")
    expected = network.outflow_vector() @ reference.y
    np.testing.assert_allclose(outlet_response(network, times, signal), expected, atol=1e-9)


def test_outlet_response_on_uneven_samples_equals_even_samples():
    network = four_compartment(0.9, 0.4, 1.1, 0.7)
    even = np.linspace(0.0, 10.0, 41)
    signal = np.sin(even) ** 2
    uneven = np.sort(np.concatenate([even, [0.13, 3.3, 7.77]]))
    response_even = outlet_response(network, even, signal)
    response_uneven = outlet_response(network, uneven, np.interp(uneven, even, signal))
    # The inserted samples lie on the same piecewise-linear signal: identical exact answers.
    np.testing.assert_allclose(np.interp(even, uneven, response_uneven)[[0, 10, 20, 40]],
                               np.asarray(response_even)[[0, 10, 20, 40]], atol=1e-13)


def test_step_response_is_outlet_response_to_a_unit_step():
    network = branched_network()
    times = np.linspace(0.0, 15.0, 61)
    np.testing.assert_allclose(
        outlet_response(network, times, np.ones_like(times)),
        cumulative_exit_age(network, times),
        atol=1e-13,
    )


# ---------------------------------------------------------------- discrete time
def test_discrete_exit_age_follows_the_step_recursion():
    network = branched_network().discretised(0.1)
    step = np.asarray(step_matrix(network))
    outflow = network.outflow_fractions()
    state = network.feed_split.copy()
    expected = [0.0]
    for _ in range(60):
        expected.append(outflow @ state / 0.1)
        state = step @ state
    times = np.arange(61) * 0.1
    np.testing.assert_allclose(exit_age(network, times), expected, rtol=1e-12, atol=1e-15)
    picked = times[[0, 3, 17, 40, 41, 60]]
    np.testing.assert_allclose(exit_age(network, picked),
                               np.array(expected)[[0, 3, 17, 40, 41, 60]], rtol=1e-12, atol=1e-15)


def test_discrete_and_continuous_exit_age_agree_as_step_shrinks():
    network = branched_network()
    times = np.linspace(0.0, 18.0, 61)
    exact = np.asarray(exit_age(network, times))
    errors = []
    for dt in (0.1, 0.05, 0.025, 0.0125):
        discrete = network.discretised(dt)
        errors.append(np.abs(np.asarray(exit_age(discrete, times)) - exact).max())
    errors = np.array(errors)
    assert errors[-1] < 2e-3
    # First order in dt (explicit Euler expectation): each halving halves the error.
    np.testing.assert_allclose(errors[:-1] / errors[1:], 2.0, rtol=0.1)


def test_discrete_mean_is_holdup_over_throughput_and_matches_the_sum():
    network = branched_network().discretised(0.2)
    moments = residence_time_moments(network)
    expected_mean = sum(network.holdups) / network.throughput
    assert float(moments.mean) == pytest.approx(expected_mean, rel=1e-10)
    times = np.arange(0, 4001) * 0.2
    values = np.asarray(exit_age(network, times))
    assert values.sum() * 0.2 == pytest.approx(1.0, abs=1e-10)
    assert (times * values).sum() * 0.2 == pytest.approx(expected_mean, rel=1e-10)
    variance = (times**2 * values).sum() * 0.2 - expected_mean**2
    assert variance == pytest.approx(float(moments.variance), rel=1e-9)


def test_discrete_outlet_response_is_the_discrete_convolution():
    network = four_compartment(0.4, 0.2, 0.3, 0.25, time_step=1.0)
    times = np.arange(61.0)
    signal = np.where(times < 5, 1.0, 0.0) + 0.1 * np.cos(times)
    pulse = np.asarray(exit_age(network, times))
    expected = [sum(pulse[j - i] * signal[i] for i in range(j + 1)) for j in range(61)]
    np.testing.assert_allclose(outlet_response(network, times, signal), expected, atol=1e-13)


def test_discrete_times_must_be_multiples_of_the_step():
    with pytest.raises(ValueError, match="multiples of the time step 0.5"):
        exit_age(branched_network().discretised(0.5), [0.0, 0.7])


# ---------------------------------------------------------------- batch mixing
@pytest.mark.parametrize("loading", ["E", "end", "centre", "top_bottom"])
def test_v_blender_fractions_converge_to_the_well_mixed_average(loading):
    network = v_blender()
    initial = v_blender_species_amounts(loading)
    average = initial[:, 0].sum() / initial.sum()
    steps = np.array([0.0, 100.0, 1000.0, 20000.0, 60000.0])
    fractions = np.asarray(species_fractions(network, initial, steps))
    np.testing.assert_allclose(fractions[0, :, 0], initial[:, 0] / 200_000)
    np.testing.assert_allclose(fractions[-1, :, 0], average, atol=1e-6)
    spread = np.abs(fractions[:, :, 0] - average).max(axis=1)
    assert np.all(np.diff(spread) <= 1e-15)
    np.testing.assert_allclose(fractions.sum(axis=2), 1.0, atol=1e-14)


def test_v_blender_amounts_follow_the_step_recursion():
    network = v_blender()
    initial = v_blender_species_amounts("E")
    step = np.asarray(step_matrix(network))
    state = initial.copy()
    for _ in range(37):
        state = step @ state
    np.testing.assert_allclose(compartment_amounts(network, initial, [37.0])[0], state, rtol=1e-12)


def test_uniform_loading_stays_uniform():
    network = v_blender()
    fractions = species_fractions(network, v_blender_species_amounts("uniform"), [0.0, 500.0])
    np.testing.assert_allclose(fractions, 0.5, atol=1e-14)


def test_closed_network_with_unequal_holdups_mixes_to_the_average():
    network = four_compartment(1.5, 0.5, 0.7, None, total_holdup=100.0)
    assert max(network.holdups) / min(network.holdups) > 2.9
    initial = loading_amounts(network, [100.0, 0.0, 0.0, 100.0])
    average = initial[:, 0].sum() / initial.sum()
    fractions = np.asarray(species_fractions(network, initial, [0.0, 60.0]))
    np.testing.assert_allclose(fractions[-1, :, 0], average, atol=1e-10)
    amounts = np.asarray(compartment_amounts(network, initial, [0.0, 3.0, 60.0]))
    np.testing.assert_allclose(amounts.sum(axis=(1, 2)), 100.0, rtol=1e-12)
    np.testing.assert_allclose(amounts.sum(axis=2), np.tile(network.holdups, (3, 1)), rtol=1e-12)


# ---------------------------------------------------------------- four-compartment fast path
def test_four_compartment_exit_age_equals_the_network_model():
    times = np.linspace(0.0, 25.0, 61)
    for k in [(0.75, 0.75, 1.0, 0.6), (0.5, 0.5, 2.0, 1.3), (2.25, 0.1, 0.375, 0.2)]:
        network = four_compartment(*k)
        np.testing.assert_allclose(four_compartment_exit_age(times, *k),
                                   scipy_exit_age(network, times), rtol=1e-10, atol=1e-14)


def test_four_compartment_exit_age_vmaps_and_jits_over_parameters():
    times = np.linspace(0.0, 20.0, 61)
    grid = jnp.array([[0.75, 0.75, 1.0, 0.5], [0.5, 0.5, 2.0, 0.5], [2.125, 2.125, 0.625, 0.5]])
    batched = jax.jit(jax.vmap(lambda k: four_compartment_exit_age(times, *k)))(grid)
    for row, k in zip(np.asarray(batched), np.asarray(grid), strict=True):
        np.testing.assert_allclose(row, four_compartment_exit_age(times, *k),
                                   rtol=1e-12, atol=1e-15)
    traced_times = jax.jit(four_compartment_exit_age)(times, *grid[0])
    np.testing.assert_allclose(traced_times, batched[0], rtol=1e-10, atol=1e-14)


def test_four_compartment_exit_age_rejects_negative_rates():
    with pytest.raises(ValueError, match="k_s must be non-negative"):
        four_compartment_exit_age(np.linspace(0, 1, 5), 1.0, 1.0, -0.5, 1.0)
    with pytest.raises(ValueError, match="times must be strictly increasing"):
        four_compartment_exit_age(np.array([0.0, 2.0, 1.0]), 1.0, 1.0, 0.5, 1.0)


# ---------------------------------------------------------------- gradients
def central_difference(function, x, h=1e-6):
    x = np.asarray(x, dtype=float)
    gradient = np.zeros_like(x)
    for i in range(x.size):
        step = np.zeros_like(x)
        step[i] = h * (abs(x[i]) if x[i] != 0 else 1.0)
        gradient[i] = (function(x + step) - function(x - step)) / (2 * step[i])
    return gradient


WEIGHTS = np.sin(np.linspace(0.0, 7.0, 61)) + 1.5


@pytest.mark.parametrize("discrete", [False, True])
def test_exit_age_gradient_in_every_rate_matches_finite_differences(discrete):
    network = branched_network()
    if discrete:
        network = network.discretised(0.25)
    times = np.arange(61) * 0.25
    n_rates = len(network.connections)

    @jax.jit
    def loss(parameters):
        values = exit_age(network, times, parameters[:n_rates], parameters[n_rates:])
        return jnp.sum(WEIGHTS * values)

    parameters = np.concatenate([network.rates, network.outflow_rates])
    gradient = jax.grad(loss)(jnp.asarray(parameters))
    reference = central_difference(lambda p: float(loss(jnp.asarray(p))), parameters)
    np.testing.assert_allclose(gradient, reference, rtol=2e-6, atol=1e-8)
    assert np.all(np.abs(reference) > 1e-6)


def test_four_compartment_gradient_matches_finite_differences():
    times = np.linspace(0.0, 15.0, 61)

    @jax.jit
    def loss(k):
        return jnp.sum(WEIGHTS * four_compartment_exit_age(times, *k))

    k = np.array([2.125, 1.5, 0.625, 0.8])
    gradient = jax.grad(loss)(jnp.asarray(k))
    reference = central_difference(lambda p: float(loss(jnp.asarray(p))), k)
    np.testing.assert_allclose(gradient, reference, rtol=1e-6, atol=1e-9)


def test_response_and_batch_gradients_match_finite_differences():
    network = branched_network()
    times = np.linspace(0.0, 10.0, 61)
    signal = np.exp(-((times - 2.0) ** 2))
    n_rates = len(network.connections)

    @jax.jit
    def response_loss(parameters):
        values = outlet_response(network, times, signal, parameters[:n_rates], parameters[n_rates:])
        return jnp.sum(values**2) + residence_time_moments(
            network, parameters[:n_rates], parameters[n_rates:]).variance

    parameters = np.concatenate([network.rates, network.outflow_rates])
    np.testing.assert_allclose(
        jax.grad(response_loss)(jnp.asarray(parameters)),
        central_difference(lambda p: float(response_loss(jnp.asarray(p))), parameters),
        rtol=2e-6, atol=1e-8,
    )

    blender = v_blender()
    initial = v_blender_species_amounts("E")

    @jax.jit
    def mixing_loss(rates):
        fractions = species_fractions(blender, initial, np.array([0.0, 300.0, 900.0]), rates)
        return jnp.sum((fractions[:, :, 0] - 0.5) ** 2)

    rates = blender.rates
    np.testing.assert_allclose(
        jax.grad(mixing_loss)(jnp.asarray(rates)),
        central_difference(lambda r: float(mixing_loss(jnp.asarray(r))), rates, h=1e-5),
        rtol=1e-5,
    )


# ---------------------------------------------------------------- structure invariants
def test_radially_symmetric_grid_has_the_rtd_of_its_axial_chain():
    times = np.linspace(0.0, 4.0, 61)
    grid = axial_radial_grid(6, 3, mean_residence_time=1.5, peclet=5.0, radial_mixing_rate=0.4)
    chain = adm_chain(1.5, 5.0, 6)
    np.testing.assert_allclose(exit_age(grid, times), exit_age(chain, times), rtol=1e-11,
                               atol=1e-13)


def test_responses_need_an_open_network():
    with pytest.raises(ValueError, match="needs an open network"):
        exit_age(v_blender(), [0.0, 1.0])


def test_four_compartment_generator_is_the_written_out_matrix_of_models_section_3():
    import jax.numpy as jnp

    from axialmix.network import four_compartment_generator

    k_f, k_r, k_s, k_out = 0.9, 0.4, 1.1, 0.7
    written = jnp.array(
        [
            [-(k_f + k_s), k_r, k_s, 0.0],
            [k_f, -(k_r + k_s), 0.0, k_s],
            [k_s, 0.0, -(k_f + k_s), k_r],
            [0.0, k_s, k_f, -(k_s + k_r + k_out)],
        ]
    )
    np.testing.assert_array_equal(four_compartment_generator(k_f, k_r, k_s, k_out), written)
    np.testing.assert_array_equal(
        generator_matrix(four_compartment(k_f, k_r, k_s, k_out)), written
    )


def test_exit_age_at_many_traced_times_is_propagated_in_blocks_exactly():
    # Traced times (inside a fit) give each interval its own matrix; more intervals than one
    # block are propagated block by block (bounded memory). Against the matrix exponential
    # at each time, independently, and its gradient (reverse mode recomputes each block).
    from axialmix.network import four_compartment_generator
    from axialmix.network._propagation import BLOCK

    rng = np.random.default_rng(12)
    t = jnp.asarray(np.sort(rng.uniform(0.0, 25.0, 2 * BLOCK + 77)))  # uneven, padded block
    rates = jnp.array([2.125, 2.125, 0.625, 0.8])

    def blocked(r, times):
        return four_compartment_exit_age(times, *r)

    def direct(r, times):
        generator = four_compartment_generator(*r)
        states = jax.vmap(lambda x: jax.scipy.linalg.expm(generator * x)[:, 0])(times)
        return r[3] * states[:, 3]

    same = {"rtol": 1e-9, "atol": 1e-13}  # products of thousands of steps vs one exponential
    np.testing.assert_allclose(jax.jit(blocked)(rates, t), jax.jit(direct)(rates, t), **same)
    def gradient(f):
        return jax.jit(jax.grad(lambda r, times: jnp.sum(f(r, times) ** 2)))

    np.testing.assert_allclose(gradient(blocked)(rates, t), gradient(direct)(rates, t), **same)
