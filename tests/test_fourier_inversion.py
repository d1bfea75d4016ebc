"""The Fourier-series inversion on a uniform grid against the exact (saddle-point) inversion."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from axialmix.analytic import exit_age, step_response
from axialmix.analytic.fourier import grid_inversion, truncation_estimates
from axialmix.analytic.transfer import ClosedClosedADM, ExchangeZone, TanksInSeries

INTERVALS = 256
MAX_TERMS = 2**17


def _exchange(tau, peclet, beta, k_d):
    return ExchangeZone(ClosedClosedADM(tau, peclet), beta, k_d)


CASES = {
    "Pe 0.1": (_exchange(2.5, 0.1, 1.5, 0.5), 120.0),
    "Pe 5": (_exchange(2.5, 5.0, 1.5, 0.5), 120.0),
    "Pe 1000": (_exchange(2.5, 1000.0, 1.5, 0.5), 60.0),
    "slow exchange": (_exchange(2.5, 20.0, 5.0, 0.02), 2000.0),
    "three tanks": (ExchangeZone(TanksInSeries(2.5, 3.0), 0.3, 0.5), 60.0),
}


#: Rounding: the series' sums are amplified by up to e^{DAMPING/2} (2e5) at the horizon, which
#: the estimate (a difference of two series) does not see; about 1e-8 at Pe 1000, where E is
#: large and its spectrum wide.
ROUNDING = 3e-8


@pytest.mark.parametrize("name", list(CASES))
def test_the_estimate_bounds_the_error_against_the_exact_inversion(name):
    """At every term count whose estimate is below 1e-3 the error at every node, against the
    saddle-point inversion, is within ten times the estimate plus rounding."""
    unit, horizon = CASES[name]
    estimates = np.asarray(truncation_estimates(unit.transfer, horizon, INTERVALS, MAX_TERMS))
    t = jnp.linspace(0.0, horizon, INTERVALS + 1)[1:]
    exact_f = np.asarray(step_response(unit, t))
    exact_e = np.asarray(exit_age(unit, t))
    checked = np.flatnonzero(estimates <= 1e-3)
    assert checked.size  # every case converges within MAX_TERMS
    for level in checked:
        terms = 4 * INTERVALS * 2**int(level)
        cumulative, density, estimate = grid_inversion(unit.transfer, horizon, INTERVALS,
                                                       terms)
        assert float(estimate) == pytest.approx(estimates[level], rel=1e-6, abs=1e-15)
        error = max(np.max(np.abs(np.asarray(cumulative)[1:] - exact_f)),
                    horizon * np.max(np.abs(np.asarray(density)[1:] - exact_e)))
        assert error <= 10.0 * estimates[level] + ROUNDING, (terms, error, estimates[level])
        # The aliased copies weigh e^-24 (4e-11): F starts at 0 up to them and truncation.
        assert abs(float(cumulative[0])) < 1e-9 + 10.0 * estimates[level]


def test_a_jump_at_zero_shows_in_the_estimate():
    """One tank: E jumps at t = 0 and the series converges only algebraically; its estimate
    says so at every term count, so a caller never takes it for a converged table."""
    unit = ExchangeZone(TanksInSeries(2.5, 1.0), 1.5, 0.5)
    estimates = np.asarray(truncation_estimates(unit.transfer, 120.0, INTERVALS, MAX_TERMS))
    assert estimates.min() > 1e-3
    cumulative, density, _ = grid_inversion(unit.transfer, 120.0, INTERVALS, MAX_TERMS)
    t = jnp.linspace(0.0, 120.0, INTERVALS + 1)[1:]
    error = 120.0 * np.max(np.abs(np.asarray(density)[1:] - np.asarray(exit_age(unit, t))))
    assert error <= estimates[-1]


def test_terms_must_fit_the_grid():
    unit = _exchange(2.5, 5.0, 1.5, 0.5)
    with pytest.raises(ValueError, match="multiple of 4"):
        grid_inversion(unit.transfer, 10.0, 64, 100)
