"""The network description: validation, files, particle moves and presets (MODELS.md §3)."""

import numpy as np
import pytest

from axialmix.network import (
    V_BLENDER_LOADINGS,
    CompartmentNetwork,
    adm_chain,
    axial_radial_grid,
    backflow_chain_transport,
    chain_peclet,
    four_compartment,
    tanks_in_series,
    v_blender,
    v_blender_species_amounts,
)


def small_network(**changes):
    spec = dict(
        compartments=["A", "B", "C"],
        connections=[("A", "B", 0.2), ("B", "C", 0.3), ("C", "B", 0.1)],
        inlets=["A"],
        outlets=[("C", 0.25)],
        holdups=[10.0, 20.0, 30.0],
    )
    spec.update(changes)
    return CompartmentNetwork(**spec)


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (dict(connections=[("A", "B", -0.1), ("B", "C", 0.3)]), "Negative rate -0.1"),
        (dict(connections=[("A", "B", 0.2), ("B", "D", 0.3)]), "missing compartment 'D'"),
        (dict(compartments=["A", "B", "A"]), "Duplicate compartment name 'A'"),
        (dict(connections=[("A", "B", 0.2)]), "Outlet 'C' cannot be reached from the inlet"),
        (dict(connections=[("A", "B", 1.5), ("B", "C", 0.3)], time_step=1.0),
         "Per-step fraction 1.5 of connection A -> B is above 1"),
        (dict(connections=[("A", "B", 0.2), ("B", "C", 0.7), ("B", "A", 0.6)], time_step=0.5),
         "Total fraction 1.3 leaving compartment 'B' in one step is above 1"),
        (dict(outlets=[("C", 0.9)], connections=[("A", "B", 0.2), ("B", "C", 0.3),
                                                  ("C", "B", 0.2)], time_step=1.0),
         "Total fraction 1.1 leaving compartment 'C'"),
        (dict(outlets=[("C", 1.2)], time_step=1.0), "outflow fraction 1.2 of outlet C is above 1"),
        (dict(outlets=[("C", -1.0)]), "Negative outflow rate -1.0 for outlet C"),
        (dict(inlets=[("A", 0.5), ("B", 0.3)]), "feed fractions must sum to 1"),
        (dict(inlets=["Z"]), "Inlet refers to missing compartment 'Z'"),
        (dict(outlets=[("Z", 1.0)]), "Outlet refers to missing compartment 'Z'"),
        (dict(holdups=[1.0, -2.0, 3.0]), "Holdup of compartment 'B' must be positive"),
        (dict(holdups=[1.0, 2.0]), "holdups has 2 entries for 3 compartments"),
        (dict(time_step=0.0), "time_step must be positive"),
        (dict(connections=[("A", "B", float("nan"))]), "must be finite"),
        (dict(connections=[("A", "A", 0.1)]), "connects a compartment to itself"),
        (dict(connections=[("A", "B", 0.1), ("A", "B", 0.2)]), "Duplicate connection A -> B"),
    ],
)
def test_invalid_network_is_rejected_with_one_line_message(changes, message):
    with pytest.raises(ValueError, match=message) as info:
        small_network(**changes)
    assert "\n" not in str(info.value)


def test_total_leaving_exactly_one_per_step_is_accepted():
    network = small_network(
        connections=[("A", "B", 1.0), ("B", "C", 0.5), ("C", "B", 0.5)],
        outlets=[("C", 0.5)],
        time_step=1.0,
    )
    assert network.step_fractions().sum(axis=1)[0] == 1.0


def test_network_is_immutable_and_hashable():
    network = small_network()
    with pytest.raises(AttributeError):
        network.time_step = 2.0  # type: ignore[misc]
    assert hash(network) == hash(small_network())
    assert network == small_network()
    assert network != small_network(outlets=[("C", 0.5)])


# ---------------------------------------------------------------- files
def test_json_round_trip_keeps_the_network(tmp_path):
    network = small_network(time_step=0.5, description="three cells")
    path = tmp_path / "net.json"
    network.to_json(path)
    again = CompartmentNetwork.from_json(path)
    assert again == network
    assert again.description == "three cells"
    assert CompartmentNetwork.from_json(network.to_json()) == network


def test_json_round_trip_of_presets_and_network_without_holdups(tmp_path):
    for network in (four_compartment(0.5, 0.5, 2.0, 1.0), v_blender(),
                    axial_radial_grid(4, 2, mean_residence_time=3.0, peclet=5.0,
                                      radial_mixing_rate=0.1)):
        assert CompartmentNetwork.from_json(network.to_json()) == network


def test_toml_file_reads_like_json(tmp_path):
    path = tmp_path / "net.toml"
    path.write_text(
        """
description = "three cells"
[[compartments]]
name = "A"
holdup = 10.0
[[compartments]]
name = "B"
holdup = 20.0
[[compartments]]
name = "C"
holdup = 30.0
[[connections]]
source = "A"
target = "B"
rate = 0.2
[[connections]]
source = "B"
target = "C"
rate = 0.3
[[connections]]
source = "C"
target = "B"
rate = 0.1
[[inlets]]
compartment = "A"
fraction = 1.0
[[outlets]]
compartment = "C"
rate = 0.25
"""
    )
    assert CompartmentNetwork.from_toml(path) == small_network()


def test_bad_network_file_gives_one_line_error(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"compartments": [{"name": "A"}], "connections": [{"source": "A"}]}')
    with pytest.raises(ValueError, match="Missing key 'target'"):
        CompartmentNetwork.from_json(path)
    path.write_text('{"compartments": ["A"], "pipes": []}')
    with pytest.raises(ValueError, match="Unknown network keys: pipes"):
        CompartmentNetwork.from_json(path)


# ---------------------------------------------------------------- particle moves
def test_particle_moves_are_fraction_times_content():
    network = small_network(time_step=1.0)
    moves = network.particle_moves()
    assert moves[0, 1] == pytest.approx(0.2 * 10.0)
    assert moves[1, 2] == pytest.approx(0.3 * 20.0)
    assert moves[2, 1] == pytest.approx(0.1 * 30.0)
    assert np.count_nonzero(moves) == 3
    assert network.outflow_per_step()[2] == pytest.approx(0.25 * 30.0)
    assert network.feed_per_step()[0] == pytest.approx(0.25 * 30.0)


def test_continuous_network_moves_scale_with_time_step():
    network = small_network()
    np.testing.assert_allclose(
        network.particle_moves(time_step=0.1), network.discretised(0.1).particle_moves()
    )
    with pytest.raises(ValueError, match="needs a time_step"):
        network.particle_moves()


def test_v_blender_moves_are_the_source_exchanges():
    moves = v_blender().particle_moves()
    expected = np.zeros((5, 5))
    for k, count in enumerate([1000, 100, 100, 1000]):
        expected[k, k + 1] = expected[k + 1, k] = count
    np.testing.assert_allclose(moves, expected)
    np.testing.assert_allclose(v_blender().holdup_balance(), 0.0, atol=1e-9)


def test_v_blender_loadings_match_percentages():
    amounts = v_blender_species_amounts("E")
    np.testing.assert_allclose(amounts[:, 0] / 200_000 * 100, V_BLENDER_LOADINGS["E"])
    np.testing.assert_allclose(amounts.sum(axis=1), 200_000)
    assert V_BLENDER_LOADINGS["E"] == (100, 100, 50, 0, 0)
    with pytest.raises(ValueError, match="Unknown V-blender loading 'Q'"):
        v_blender_species_amounts("Q")


@pytest.mark.parametrize(
    "network",
    [
        four_compartment(1.5, 0.7, 0.375, 1.2, total_holdup=500.0),
        tanks_in_series(6, 30.0, 0.4),
        axial_radial_grid(7, 3, mean_residence_time=20.0, peclet=8.0, radial_mixing_rate=0.05),
        v_blender(),
    ],
)
def test_preset_holdups_are_steady_under_the_flows(network):
    balance = network.holdup_balance(time_step=None if network.is_discrete else 0.01)
    scale = max(network.holdups) * 0.01
    np.testing.assert_allclose(balance / scale, 0.0, atol=1e-12)


def test_four_compartment_structure_matches_the_equations():
    network = four_compartment(0.3, 0.2, 0.7, 1.1)
    rates = network.connection_matrix()
    expected = np.array(
        [[0, 0.3, 0.7, 0], [0.2, 0, 0, 0.7], [0.7, 0, 0, 0.3], [0, 0.7, 0.2, 0]]
    )
    np.testing.assert_allclose(rates, expected)
    np.testing.assert_allclose(network.outflow_vector(), [0, 0, 0, 1.1])
    np.testing.assert_allclose(network.feed_split, [1, 0, 0, 0])
    assert four_compartment(0.3, 0.2, 0.7, None).is_closed
    assert four_compartment(0.3, 0.2, 0.7, 0.0).is_closed


def test_grid_keeps_axial_velocity_and_dispersion_when_refined():
    for n_axial in (5, 10, 40):
        grid = axial_radial_grid(n_axial, 2, mean_residence_time=2.0, peclet=6.0)
        a = grid.connections[0].rate
        b = grid.connections[1].rate
        v, d = backflow_chain_transport(a, b, 1.0 / n_axial)
        assert v == pytest.approx(0.5)
        assert d == pytest.approx(0.5 / 6.0)
        assert chain_peclet(a, b, n_axial) == pytest.approx(6.0)


def test_adm_chain_needs_enough_cells_for_central_scheme():
    with pytest.raises(ValueError, match="cannot represent Pe = 50"):
        adm_chain(1.0, 50.0, 10)
    upwind = adm_chain(1.0, 50.0, 10, scheme="upwind")
    a, b = upwind.connections[0].rate, upwind.connections[-1].rate
    # Upwind: equivalent Pe = 2n/(1 + 2 n/Pe).
    assert chain_peclet(a, b, 10) == pytest.approx(20 / (1 + 2 * 10 / 50))


def test_tanks_in_series_peclet_follows_backflow_ratio():
    network = tanks_in_series(8, 5.0, 1.5)
    a, b = network.connections[0].rate, network.connections[-1].rate
    assert chain_peclet(a, b, 8) == pytest.approx(2 * 8 / (1 + 2 * 1.5))
    assert network.throughput == pytest.approx(1.0 / 5.0)
