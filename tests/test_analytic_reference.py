"""The JAX closed–closed E and F against the extended-precision eigenfunction series."""

import numpy as np
import pytest

import axialmix.analytic as analytic
from axialmix.analytic import highprecision

pytest.importorskip("mpmath")

THETA = np.linspace(0.0, 3.0, 301)


@pytest.mark.parametrize("peclet", [0.1, 1.0, 10.0, 100.0, 1000.0])
def test_closed_closed_exit_age_matches_series_reference(peclet):
    reference = highprecision.exit_age_closed_series(THETA, peclet)
    exit_age = np.asarray(analytic.exit_age_closed(THETA, 1.0, peclet))
    error = np.max(np.abs(exit_age - reference)) / np.max(reference)
    print(f"Pe={peclet:g}: max|E - E_ref| / max E_ref = {error:.2e}")
    # The requirement is 1e-6; the inversion is exact to round-off (about 1e-15), so a much
    # tighter bound is asserted to catch any loss of accuracy.
    assert error <= 1e-12


@pytest.mark.parametrize("peclet", [0.01, 100.0])
def test_closed_closed_exit_age_matches_series_at_early_and_late_times(peclet):
    theta = np.concatenate([[1e-3, 3e-3, 1e-2, 3e-2], np.linspace(0.1, 3.0, 12), [5.0, 10.0]])
    reference = highprecision.exit_age_closed_series(theta, peclet)
    exit_age = np.asarray(analytic.exit_age_closed(theta, 1.0, peclet))
    assert np.max(np.abs(exit_age - reference)) <= 1e-13 * np.max(reference)
    # Pointwise relative accuracy wherever the reference itself (absolute error 1e-30) is good.
    resolved = reference > 1e-20
    assert np.all(np.abs(exit_age - reference)[resolved] <= 1e-10 * reference[resolved])


@pytest.mark.parametrize("peclet", [0.1, 7.5, 100.0])
def test_closed_closed_step_response_matches_series_reference(peclet):
    theta = np.concatenate([[0.01, 0.05], np.linspace(0.1, 3.0, 30), [6.0]])
    reference = highprecision.step_response_closed_series(theta, peclet)
    step_response = np.asarray(analytic.step_response_closed(theta, 1.0, peclet))
    assert np.max(np.abs(step_response - reference)) <= 1e-13


def test_series_reference_reproduces_published_values():
    values = highprecision.exit_age_closed_series([0.3, 1.0, 2.0], 7.5)
    np.testing.assert_allclose(values, [0.159598, 0.828505, 0.100113], atol=5e-7)
    assert abs(highprecision.exit_age_closed_series([1.0], 1.0)[0] - 0.433554) <= 5e-7
    assert abs(highprecision.exit_age_closed_series([1.0], 20.0)[0] - 1.294782) <= 5e-7


def test_eigenvalues_solve_the_characteristic_equation():
    import mpmath

    peclet = 7.5
    roots = highprecision.eigenvalues_closed(peclet, 12, digits=40)
    with mpmath.workdps(40):
        for n, lam in enumerate(roots, start=1):
            assert (n - 1) * mpmath.pi < lam < n * mpmath.pi
            residual = (4 * lam**2 - peclet**2) * mpmath.sin(lam) - 4 * lam * peclet * mpmath.cos(
                lam
            )
            assert abs(residual) < 1e-35 * (4 * lam**2 + peclet**2)
