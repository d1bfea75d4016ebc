"""Chains with backflow and the axial dispersion model (MODELS.md §2–3)."""

import math

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed, peclet_from_variance_ratio, variance_ratio_closed
from axialmix.network import (
    adm_chain,
    backflow_chain_rates,
    backflow_chain_transport,
    exit_age,
    four_compartment,
    four_compartment_chain_transport,
    moment_matched_adm,
    residence_time_moments,
    tanks_in_series,
)

CELLS = (10, 20, 40, 80)
THETA = np.linspace(0.0, 3.0, 121)


def chain_errors(peclet, scheme, cells=CELLS):
    exact = np.asarray(exit_age_closed(THETA, 1.0, peclet))
    return np.array(
        [
            np.abs(np.asarray(exit_age(adm_chain(1.0, peclet, n, scheme=scheme), THETA))
                   - exact).max()
            for n in cells
        ]
    )


@pytest.mark.parametrize("peclet", [1.0, 7.5])
def test_central_chain_rtd_converges_to_closed_closed_adm_at_second_order(peclet):
    errors = chain_errors(peclet, "central")
    assert np.all(np.diff(errors) < 0)
    # Danckwerts boundaries represented consistently: halving dx divides the error by 4.
    np.testing.assert_allclose(errors[:-1] / errors[1:], 4.0, rtol=0.1)
    assert errors[-1] < 1e-3


def test_upwind_chain_converges_at_first_order():
    errors = chain_errors(7.5, "upwind")
    assert np.all(np.diff(errors) < 0)
    np.testing.assert_allclose(errors[:-1] / errors[1:], 2.0, rtol=0.15)


def test_high_peclet_chain_converges_once_cells_resolve_it():
    errors = chain_errors(50.0, "central", cells=(40, 80))
    assert errors[1] < errors[0] / 3.5
    # 80 cells at Pe = 50 (cell Peclet 0.6): 0.7 % of the peak height E(1) ~ 2.
    assert errors[1] / np.asarray(exit_age_closed(np.array([1.0]), 1.0, 50.0))[0] < 1e-2


def test_fine_chain_reproduces_reference_values_of_the_specification():
    values = np.asarray(exit_age(adm_chain(1.0, 7.5, 80), np.array([0.3, 1.0, 2.0])))
    # MODELS.md §2 reference values; the 80-cell chain is within its O(dx²) error (~1e-3).
    np.testing.assert_allclose(values, [0.159598, 0.828505, 0.100113], atol=1.5e-3)


def test_chain_moments_converge_to_adm_moments():
    ratios = []
    for n in CELLS:
        moments = residence_time_moments(adm_chain(2.0, 7.5, n))
        assert float(moments.mean) == pytest.approx(2.0, rel=1e-12)
        ratios.append(float(moments.variance) / 4.0)
    errors = np.abs(np.array(ratios) - float(variance_ratio_closed(7.5)))
    np.testing.assert_allclose(errors[:-1] / errors[1:], 4.0, rtol=0.05)


def test_transport_formulas_invert_the_chain_rates():
    for scheme, extra in (("central", 0.0), ("upwind", 0.5 * 0.2 * 0.05)):
        a, b = backflow_chain_rates(0.2, 6e-3, 0.05, scheme)
        velocity, dispersion = backflow_chain_transport(a, b, 0.05)
        assert velocity == pytest.approx(0.2)
        assert dispersion == pytest.approx(6e-3 + extra)
    with pytest.raises(ValueError, match="Cell Peclet number 4 is above 2"):
        backflow_chain_rates(0.2, 2.5e-3, 0.05)


def test_moment_matched_adm_recovers_peclet_of_a_fine_chain():
    report = moment_matched_adm(adm_chain(30.0, 20.0, 80), 0.31)
    assert report.mean_residence_time == pytest.approx(30.0, rel=1e-12)
    assert report.peclet == pytest.approx(20.0, rel=2e-3)
    assert report.velocity == pytest.approx(0.31 / 30.0)
    assert report.axial_dispersion == pytest.approx(0.31**2 / 30.0 / report.peclet)


@pytest.mark.parametrize("peclet", [1e-3, 0.5, 7.5, 300.0, 5e4])
def test_peclet_from_variance_ratio_inverts_the_closed_closed_formula(peclet):
    ratio = float(variance_ratio_closed(peclet))
    assert float(peclet_from_variance_ratio(ratio)) == pytest.approx(peclet, rel=1e-6)


def test_peclet_from_variance_ratio_is_nan_beyond_a_stirred_tank():
    assert math.isnan(float(peclet_from_variance_ratio(1.2)))
    # A single stirred tank has ratio exactly 1: the Pe -> 0 limit, not a finite Pe.
    assert math.isnan(moment_matched_adm(tanks_in_series(1, 5.0), None).peclet)


def test_four_compartment_axial_chain_reading():
    velocity, dispersion, peclet = four_compartment_chain_transport(2.25, 0.75, length=0.31)
    assert velocity == pytest.approx(1.5 * 0.155)
    assert dispersion == pytest.approx(3.0 * 0.155**2 / 2)
    assert peclet == pytest.approx(4 * 1.5 / 3.0)
    # The source's fits have k_f = k_r: the chain reading has no convection ...
    assert four_compartment_chain_transport(2.125, 2.125)[0] == 0.0
    # ... while the RTD of the network still has a finite moment-matched Pe.
    report = moment_matched_adm(four_compartment(2.125, 2.125, 0.625, 1.0), None)
    assert 0 < report.peclet < 10


def test_moment_matched_adm_reports_si_velocity_and_dispersion_in_any_time_unit():
    import axialmix.analytic as analytic

    network = four_compartment(2.125, 2.125, 0.625, 1.0)
    moments = residence_time_moments(network)
    tau, variance = float(moments.mean), float(moments.variance)
    report = moment_matched_adm(network, 0.5)
    assert report.mean_residence_time == pytest.approx(tau, rel=1e-12)
    assert report.peclet == pytest.approx(float(analytic.peclet_from_moments(tau, variance)))
    assert report.velocity == pytest.approx(0.5 / tau)
    assert report.axial_dispersion == pytest.approx(0.5**2 / (tau * report.peclet))
    # Rates per minute: the same tau and Pe in minutes, v and D_z 60 times slower in SI.
    minutes = moment_matched_adm(network, 0.5, time_unit="min")
    assert minutes.mean_residence_time == report.mean_residence_time
    assert minutes.peclet == report.peclet
    assert minutes.axial_dispersion == pytest.approx(report.axial_dispersion / 60)
    assert minutes.as_dict()["tau_min"] == pytest.approx(tau)
    expected = 0.25 / (tau * 60 * minutes.peclet)
    assert minutes.as_dict()["dispersion_m2_per_s"] == pytest.approx(expected)
    # Without a length: tau and Pe only.
    bare = moment_matched_adm(network, None)
    assert bare.velocity is None and bare.axial_dispersion is None
    assert bare.peclet == report.peclet


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"length": 0.0}, "length must be positive"), ({"length": 1.0, "time_unit": "d"},
                                                    "time_unit must be one of")],
)
def test_moment_matched_adm_rejects_nonsense(kwargs, message):
    with pytest.raises(ValueError, match=message):
        moment_matched_adm(tanks_in_series(3, 5.0), **kwargs)
