"""The finite-volume solver states its own accuracy: the difference to a refined solve,
checked against the exact closed–closed solution, and carried into the record of a fit."""

import jax.numpy as jnp
import numpy as np
import pytest

from axialmix import adm, analytic


@pytest.mark.parametrize("peclet", [1.0, 100.0])  # two resolution levels
def test_the_estimate_matches_the_true_error_of_the_exit_age(peclet):
    tau = 40.0
    t = jnp.linspace(0.1, 160.0 if peclet < 50 else 80.0, 400)
    estimate = adm.error_estimate(t, tau, peclet)
    exact = analytic.exit_age_closed(t, tau, peclet)
    np.testing.assert_array_equal(estimate.values, adm.exit_age(t, tau, peclet))
    true = float(jnp.max(jnp.abs(estimate.values - exact)) / jnp.max(exact))
    # The refined solve still has about 1/16 of the error, so the difference underestimates
    # the true error a little: measured 1.03 to 1.16 times over Pe 0.01 to 3400.
    assert 0.9 <= true / float(estimate.relative_error) <= 1.3
    assert float(estimate.relative_error) < 1e-3  # the verified default accuracy


def test_the_estimate_of_the_step_response_matches_its_true_error():
    t = jnp.linspace(0.1, 160.0, 300)
    estimate = adm.error_estimate(t, 40.0, 12.0, response="step")
    exact = analytic.step_response_closed(t, 40.0, 12.0)
    true = float(jnp.max(jnp.abs(estimate.values - exact)))
    assert 0.9 <= true / float(estimate.max_error) <= 1.3


def test_the_refined_grid_doubles_the_cells_and_halves_the_steps():
    config = adm.SolverConfig.for_peclet(25.0)
    finer = adm.refined_config(config)
    assert finer.cells == 2 * config.cells
    assert finer.max_step == config.max_step / 2 and finer.first_step == config.first_step / 2
    assert len(finer.time_nodes()) > len(config.time_nodes())


def test_bad_requests_are_refused_in_words():
    with pytest.raises(ValueError, match="response must be one of"):
        adm.error_estimate(jnp.ones(3), 1.0, 5.0, response="ramp")
    with pytest.raises(ValueError, match="outside the range"):
        adm.error_estimate(jnp.linspace(0.1, 1, 3), 1.0, 1e5)


def test_a_finite_volume_fit_record_carries_the_solver_accuracy():
    from fitting.fit import fit
    from fitting.report import fit_record, fit_table

    t = np.linspace(2.0, 120.0, 25)
    y = np.asarray(analytic.exit_age_closed(t, 40.0, 12.0))
    result = fit("adm-fv", (t, y))
    record = fit_record(result)
    direct = adm.error_estimate(np.asarray(result.time), result.values["tau"],
                                result.values["peclet"]).to_dict()
    assert record["solver_accuracy"] == {**direct, "unit": "1/s"}
    assert 0 < record["solver_accuracy"]["relative_error"] < 1e-3
    assert "FV solver error" in fit_table(result)
    assert "solver_accuracy" not in fit_record(fit("adm", (t, y)))  # exact: nothing to say
