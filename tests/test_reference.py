"""Tests of the FiPy closed–closed ADM reference against the exact solution.

FiPy assembles and solves a sparse system every time step (several ms each), so the grids
here are small and the time windows short; each refinement halves the cell width and the
time step. Backward Euler makes the error first order: halving both should halve it.
"""

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed, step_response_closed
from axialmix.reference import exit_age_fipy, step_response_fipy

TAU = 2.0  # s; a non-unit space time checks the scaling of t and E

# (peclet, last theta, [(n_cells, time step in units of tau), ...]) coarse to fine.
REFINEMENT_STUDIES = {
    1.0: (2.0, [(10, 0.04), (20, 0.02), (40, 0.01)]),
    10.0: (2.0, [(25, 0.04), (50, 0.02), (100, 0.01)]),
}


def peak_relative_errors(peclet, theta_end, levels):
    """Max |E_fipy - E_exact| / max E_exact on a common time grid, per refinement level."""
    time = TAU * np.linspace(0.0, theta_end, 101)
    exact = np.asarray(exit_age_closed(time, TAU, peclet))
    curves = [
        exit_age_fipy(time, TAU, peclet, n_cells=n_cells, dt=TAU * dtheta)
        for n_cells, dtheta in levels
    ]
    errors = np.array([np.max(np.abs(curve - exact)) for curve in curves]) / exact.max()
    return time, exact, curves, errors


@pytest.fixture(scope="module", params=sorted(REFINEMENT_STUDIES))
def refinement_study(request):
    peclet = request.param
    theta_end, levels = REFINEMENT_STUDIES[peclet]
    return (peclet, levels, *peak_relative_errors(peclet, theta_end, levels))


def test_fipy_exit_age_error_halves_when_grid_and_time_step_are_halved(refinement_study):
    peclet, _, _, _, _, errors = refinement_study
    print(f"Pe={peclet}: max error / peak = {errors}")
    assert np.all(np.diff(errors) < 0)
    # Backward Euler is first order in time and dominates: ratio 2 asymptotically; the
    # coarsest levels are still pre-asymptotic (measured 1.78-1.90).
    ratios = errors[:-1] / errors[1:]
    assert np.all((ratios > 1.6) & (ratios < 2.4)), ratios
    assert errors[-1] < 0.06


def test_fipy_exit_age_agrees_with_jax_solver_within_fipy_discretisation_error(refinement_study):
    from axialmix.adm import exit_age

    peclet, _, time, exact, curves, errors_vs_exact = refinement_study
    jax_curve = np.asarray(exit_age(time, TAU, peclet))
    errors_vs_jax = np.array([np.max(np.abs(curve - jax_curve)) for curve in curves])
    errors_vs_jax /= exact.max()
    print(f"Pe={peclet}: |FiPy-exact| = {errors_vs_exact}, |FiPy-JAX| = {errors_vs_jax}")
    # The JAX solver's own error (about 1e-4 of the peak) is below 1 % of FiPy's at these
    # grids, so two independent solvers of the same problem must differ by FiPy's error.
    np.testing.assert_allclose(errors_vs_jax, errors_vs_exact, rtol=0.05)
    assert np.all(np.diff(errors_vs_jax) < 0)


def test_fipy_step_response_converges_to_exact_and_reaches_one():
    peclet = 10.0
    time = TAU * np.linspace(0.0, 3.0, 61)
    exact = np.asarray(step_response_closed(time, TAU, peclet))
    errors = [
        np.max(np.abs(step_response_fipy(time, TAU, peclet, n_cells=n, dt=TAU * dtheta) - exact))
        for n, dtheta in [(25, 0.04), (50, 0.02)]
    ]
    assert errors[1] < errors[0] / 1.6
    assert errors[1] < 0.02
    # The tight LU solve lets the step response reach its plateau (FiPy's default stalls).
    final = step_response_fipy(TAU * np.array([6.0]), TAU, peclet, n_cells=25, dt=TAU * 0.04)
    np.testing.assert_allclose(final, 1.0, atol=1e-4)


@pytest.mark.slow
def test_fipy_exit_age_converges_at_high_peclet():
    levels = [(60, 0.02), (120, 0.01), (240, 0.005)]
    *_, errors = peak_relative_errors(100.0, 1.6, levels)
    print(f"Pe=100: max error / peak = {errors}")
    assert np.all(np.diff(errors) < 0)
    # A narrow peak (sigma ~ 0.14 tau) is pre-asymptotic here: measured ratios 1.6-1.75.
    assert np.all(errors[:-1] / errors[1:] > 1.4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"tau": -1.0, "peclet": 10.0}, "tau must be a positive"),
        ({"tau": 1.0, "peclet": float("nan")}, "peclet must be a positive"),
        ({"tau": 1.0, "peclet": 100.0, "n_cells": 40}, "n_cells must exceed peclet / 2"),
        ({"tau": 1.0, "peclet": 10.0, "dt": 0.0}, "dt must be a positive"),
    ],
)
def test_bad_arguments_raise_one_line_value_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        exit_age_fipy(np.linspace(0.0, 1.0, 5), **kwargs)


def test_negative_times_are_rejected():
    with pytest.raises(ValueError, match="t must be non-negative"):
        exit_age_fipy(np.array([-1.0, 0.0, 1.0]), 1.0, 10.0)


def test_importing_axialmix_loads_no_subpackage_and_the_reference_loads_fipy_only_when_called():
    import subprocess
    import sys

    code = (
        "import sys, axialmix, axialmix.reference\n"
        "heavy = [m for m in ('axialmix.network', 'axialmix.adm', 'axialmix.particles',\n"
        "         'axialmix.trajectories', 'fipy', 'numba', 'matplotlib') if m in sys.modules]\n"
        "assert heavy == [], heavy\n"
        "assert axialmix.network.four_compartment is not None\n"
        "assert 'axialmix.network' in sys.modules\n"
        "import jax.numpy as jnp\n"
        "assert jnp.asarray(1.0).dtype == jnp.float64\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
