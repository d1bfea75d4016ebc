"""Exact ADM results: invariants, moments, closed forms, inverse relations, gradients, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

import axialmix.analytic as analytic

PECLETS = [0.1, 1.0, 10.0, 100.0, 1000.0]


def _moment_grid(peclet, theta_max=None):
    """Nodes and weights on theta = u² (resolves the sharp early rise at small Pe)."""
    if theta_max is None:
        theta_max = 60.0 if peclet < 5 else (15.0 if peclet < 50 else 4.0)
    u = np.linspace(0.0, np.sqrt(theta_max), 20001)
    weights = np.full(u.size, u[1] - u[0]) * 2.0 * u
    weights[[0, -1]] *= 0.5
    return u**2, weights


def _cumulative_integrals(function, theta_ends, order=20, max_width=0.01):
    """Return ∫_0^x function for each x in theta_ends (increasing), by Gauss–Legendre panels.

    Integrates in u = sqrt(theta) (theta = u², dtheta = 2u du) so that the sharp early rise of
    the low-Pe curves is resolved; all nodes form one increasing array, so the curve is
    evaluated in a single vectorised call.
    """
    x, w = np.polynomial.legendre.leggauss(order)
    edges_u = np.sqrt(np.concatenate([[0.0], theta_ends]))
    nodes, weights, owners = [], [], []
    for index, (start, stop) in enumerate(zip(edges_u[:-1], edges_u[1:], strict=True)):
        sub_edges = np.linspace(start, stop, int(np.ceil((stop - start) / max_width)) + 1)
        for a, b in zip(sub_edges[:-1], sub_edges[1:], strict=True):
            u = 0.5 * (a + b) + 0.5 * (b - a) * x
            nodes.append(u**2)
            weights.append(0.5 * (b - a) * w * 2.0 * u)
            owners.append(np.full(order, index))
    values = np.asarray(function(np.concatenate(nodes)))
    per_interval = np.bincount(
        np.concatenate(owners), np.concatenate(weights) * values, minlength=len(theta_ends)
    )
    return np.cumsum(per_interval)


def _central_difference(function, x, relative_step=1e-5):
    step = relative_step * x
    return (function(x + step) - function(x - step)) / (2.0 * step)


# --- closed–closed -----------------------------------------------------------------------


def test_closed_closed_exit_age_reproduces_published_values():
    t = jnp.array([0.3, 1.0, 2.0]) * 10.0
    np.testing.assert_allclose(
        analytic.exit_age_closed(t, 10.0, 7.5) * 10.0, [0.159598, 0.828505, 0.100113], atol=5e-7
    )
    assert abs(analytic.exit_age_closed(jnp.array([1.0]), 1.0, 1.0)[0] - 0.433554) <= 5e-7
    assert abs(analytic.exit_age_closed(jnp.array([1.0]), 1.0, 20.0)[0] - 1.294782) <= 5e-7


@pytest.mark.parametrize("peclet", PECLETS)
def test_closed_closed_moments_match_exact_formulas(peclet):
    theta, weights = _moment_grid(peclet)
    exit_age = np.asarray(analytic.exit_age_closed(theta, 1.0, peclet))
    area = np.sum(weights * exit_age)
    mean = np.sum(weights * theta * exit_age)
    variance = np.sum(weights * (theta - mean) ** 2 * exit_age)
    assert abs(area - 1.0) <= 1e-12
    assert abs(mean - float(analytic.mean_closed(1.0, peclet))) <= 1e-12
    assert abs(variance / float(analytic.variance_closed(1.0, peclet)) - 1.0) <= 1e-11


def test_closed_closed_exit_age_scales_with_tau():
    theta = jnp.linspace(0.0, 3.0, 31)
    dimensionless = analytic.exit_age_closed(theta, 1.0, 12.0)
    np.testing.assert_allclose(
        analytic.exit_age_closed(theta * 45.0, 45.0, 12.0) * 45.0, dimensionless, rtol=1e-13
    )


@pytest.mark.parametrize("peclet", [0.01, 0.1, 10.0, 1000.0, 1e4])
def test_closed_closed_step_response_is_the_integral_of_exit_age(peclet):
    theta = np.linspace(0.05, 3.0, 15)
    integrals = _cumulative_integrals(lambda x: analytic.exit_age_closed(x, 1.0, peclet), theta)
    step_response = np.asarray(analytic.step_response_closed(theta, 1.0, peclet))
    np.testing.assert_allclose(step_response, integrals, atol=1e-12)
    # F' = E through automatic differentiation, to round-off.
    slope = jax.vmap(jax.grad(lambda t: analytic.step_response_closed(t[None], 1.0, peclet)[0]))(
        jnp.asarray(theta)
    )
    exit_age_values = analytic.exit_age_closed(theta, 1.0, peclet)
    np.testing.assert_allclose(slope, exit_age_values, atol=1e-11 * float(exit_age_values.max()))


@pytest.mark.parametrize("peclet", [0.01, 1.0, 100.0, 1e4])
def test_closed_closed_step_response_limits(peclet):
    theta = jnp.array([-1.0, 0.0, 1e-9, 1e3])
    step_response = analytic.step_response_closed(theta, 1.0, peclet)
    np.testing.assert_allclose(step_response, [0.0, 0.0, 0.0, 1.0], atol=1e-14)
    late = analytic.step_response_closed(jnp.linspace(0.0, 50.0, 501), 1.0, peclet)
    assert np.all(np.diff(np.asarray(late)) >= -1e-15)


def test_closed_closed_exit_age_is_finite_and_nonnegative_at_all_times():
    theta = jnp.concatenate([jnp.array([-1.0, 0.0]), jnp.logspace(-12, 2, 300)])
    for peclet in [1e-3, 0.1, 1.0, 10.0, 100.0, 1000.0, 1e4, 1e5]:
        exit_age = np.asarray(analytic.exit_age_closed(theta, 1.0, peclet))
        step_response = np.asarray(analytic.step_response_closed(theta, 1.0, peclet))
        assert np.all(np.isfinite(exit_age)) and np.all(np.isfinite(step_response))
        assert np.all(exit_age >= -1e-14 * exit_age.max())
        assert np.all(exit_age[:2] == 0.0)


def test_closed_closed_laplace_transform_of_exit_age_is_transfer_function():
    peclet = 4.0
    theta, weights = _moment_grid(peclet)
    exit_age = np.asarray(analytic.exit_age_closed(theta, 1.0, peclet))
    for s in [0.3, 1.0, 5.0]:
        transform = np.sum(weights * np.exp(-s * theta) * exit_age)
        q = np.sqrt(1.0 + 4.0 * s / peclet)
        textbook = (
            4.0
            * q
            * np.exp(peclet / 2.0)
            / ((1.0 + q) ** 2 * np.exp(q * peclet / 2.0) - (1.0 - q) ** 2 * np.exp(-q * peclet / 2))
        )
        transfer = complex(analytic.transfer_function_closed(s, peclet))
        assert abs(transform - textbook) <= 1e-12
        assert abs(transfer - textbook) <= 1e-14


def test_transfer_function_is_finite_where_the_textbook_form_overflows():
    assert complex(analytic.transfer_function_closed(0.0, 3.0)) == pytest.approx(1.0, abs=1e-15)
    # q = 0 (s = -Pe/4): removable singularity with value 4 e^{Pe/2} / (4 + Pe).
    value = complex(analytic.transfer_function_closed(-0.75, 3.0))
    assert value == pytest.approx(4.0 * np.exp(1.5) / 7.0, rel=1e-13)
    large = analytic.transfer_function_closed(jnp.array([1.0, 10.0j, 100.0 + 5.0j]), 5000.0)
    assert np.all(np.isfinite(np.asarray(large)))


def test_variance_ratio_closed_matches_extended_precision():
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 50
    for peclet in [1e-8, 1e-3, 0.3, 0.999, 1.0, 1.001, 5.0, 300.0, 1e6]:
        x = mpmath.mpf(peclet)
        exact = float(2 / x - 2 / x**2 * (1 - mpmath.exp(-x)))
        assert float(analytic.variance_ratio_closed(peclet)) == pytest.approx(exact, rel=2e-15)


# --- open–open ---------------------------------------------------------------------------


@pytest.mark.parametrize("peclet", [0.5, 5.0, 50.0, 500.0])
def test_open_open_moments_match_exact_formulas(peclet):
    theta, weights = _moment_grid(peclet, theta_max=400.0 if peclet < 1 else 30.0)
    exit_age = np.asarray(analytic.exit_age_open(theta, 1.0, peclet))
    mean = np.sum(weights * theta * exit_age)
    assert abs(np.sum(weights * exit_age) - 1.0) <= 1e-10
    assert mean == pytest.approx(float(analytic.mean_open(1.0, peclet)), rel=1e-10)
    # The open–open variance is normalised by tau = L/v, about the mean (1 + 2/Pe) tau.
    variance = np.sum(weights * (theta - mean) ** 2 * exit_age)
    assert variance == pytest.approx(float(analytic.variance_open(1.0, peclet)), rel=1e-9)


@pytest.mark.parametrize("peclet", [0.1, 2.0, 30.0, 800.0])
def test_open_open_step_response_is_the_integral_of_exit_age(peclet):
    theta = np.array([0.05, 0.5, 0.9, 1.0, 1.2, 2.0, 5.0])
    integrals = _cumulative_integrals(lambda x: analytic.exit_age_open(x, 1.0, peclet), theta)
    step_response = analytic.step_response_open(theta, 1.0, peclet)
    np.testing.assert_allclose(step_response, integrals, atol=1e-13)
    assert float(analytic.step_response_open(jnp.array([1e6]), 1.0, peclet)[0]) == pytest.approx(
        1.0, abs=1e-14
    )


def test_open_open_step_response_does_not_overflow_at_large_peclet():
    values = analytic.step_response_open(jnp.linspace(0.0, 3.0, 61), 1.0, 1e5)
    assert np.all(np.isfinite(np.asarray(values)))
    assert float(values[-1]) == pytest.approx(1.0, abs=1e-15)


# --- tanks in series ---------------------------------------------------------------------


@pytest.mark.parametrize("n_tanks", [0.7, 1.0, 2.5, 40.0, 2000.0])
def test_tanks_match_the_gamma_distribution(n_tanks):
    tau = 20.0
    t = np.linspace(0.0, 5.0, 101)[1:] * tau
    reference = stats.gamma(a=n_tanks, scale=tau / n_tanks)
    exit_age = np.asarray(analytic.exit_age_tanks(t, tau, n_tanks))
    np.testing.assert_allclose(exit_age, reference.pdf(t), rtol=1e-11, atol=1e-300)
    np.testing.assert_allclose(
        analytic.step_response_tanks(t, tau, n_tanks), reference.cdf(t), rtol=1e-11, atol=1e-15
    )
    assert float(analytic.mean_tanks(tau, n_tanks)) == pytest.approx(reference.mean(), rel=1e-14)
    assert float(analytic.variance_tanks(tau, n_tanks)) == pytest.approx(reference.var(), rel=1e-13)


# n = 1 is left to the gamma comparison above: its density jumps at t = 0, which the
# endpoint-free trapezoidal moments below would resolve only to O(h²).
@pytest.mark.parametrize("n_tanks", [2.5, 40.0, 2000.0])
def test_tanks_moments_match_exact_formulas(n_tanks):
    theta, weights = _moment_grid(1.0, theta_max=8.0 if n_tanks > 10 else 60.0)
    exit_age = np.asarray(analytic.exit_age_tanks(theta, 1.0, n_tanks))
    mean = np.sum(weights * theta * exit_age)
    assert np.sum(weights * exit_age) == pytest.approx(1.0, abs=1e-10)
    assert mean == pytest.approx(float(analytic.mean_tanks(1.0, n_tanks)), rel=1e-10)
    variance = np.sum(weights * (theta - 1.0) ** 2 * exit_age)
    assert variance == pytest.approx(float(analytic.variance_tanks(1.0, n_tanks)), rel=1e-9)


def test_one_tank_is_an_exponential():
    t = jnp.linspace(0.0, 50.0, 11)
    np.testing.assert_allclose(
        analytic.exit_age_tanks(t, 5.0, 1.0), np.exp(-np.asarray(t) / 5.0) / 5.0, rtol=1e-14
    )


# --- inverse relations -------------------------------------------------------------------


def test_peclet_from_moments_round_trip():
    peclet = np.logspace(-2, 4, 61)
    tau = 37.0
    variance = np.asarray(analytic.variance_closed(tau, peclet))
    recovered = analytic.peclet_from_moments(tau, variance)
    # Conditioning: near Pe = 0 the ratio is 1 - Pe/3, so Pe carries a relative error of
    # about 3 eps / Pe from rounding the ratio (7e-14 at Pe = 0.01).
    np.testing.assert_allclose(recovered, peclet, rtol=1e-12)


def test_approximate_peclet_is_the_newton_start_and_within_five_percent():
    from axialmix.analytic.inverse import _starting_peclet

    peclet = np.logspace(-3, 5, 161)
    ratio = np.asarray(analytic.variance_ratio_closed(peclet))
    approximate = analytic.approximate_peclet_from_variance_ratio(ratio)
    assert isinstance(approximate, np.ndarray)
    # The same rational inversion as the JAX Newton start, in NumPy.
    np.testing.assert_allclose(approximate, np.asarray(_starting_peclet(jnp.asarray(ratio))),
                               rtol=1e-14)
    assert np.max(np.abs(approximate / peclet - 1)) < 0.05
    outside = analytic.approximate_peclet_from_variance_ratio([0.0, 1.0, 1.5, -0.2])
    assert np.all(np.isnan(outside))
    # One number (a start value per curve) takes a path without arrays: the same bits.
    for number in [*ratio.tolist(), 0.5, 0.0, 1.0, 1.5, -0.2, float("nan")]:
        for given in (number, np.float64(number)):
            alone = analytic.approximate_peclet_from_variance_ratio(given)
            assert isinstance(alone, np.ndarray) and alone.shape == ()
            together = analytic.approximate_peclet_from_variance_ratio(np.array([number]))[0]
            assert alone.tobytes() == together.tobytes(), number


def test_peclet_from_moments_gradient_matches_finite_differences():
    mean, variance = 30.0, 30.0**2 * float(analytic.variance_ratio_closed(17.0))
    gradient = jax.grad(analytic.peclet_from_moments, argnums=(0, 1))(mean, variance)
    d_mean = _central_difference(lambda m: float(analytic.peclet_from_moments(m, variance)), mean)
    d_var = _central_difference(lambda v: float(analytic.peclet_from_moments(mean, v)), variance)
    assert float(gradient[0]) == pytest.approx(d_mean, rel=1e-7)
    assert float(gradient[1]) == pytest.approx(d_var, rel=1e-7)
    # Implicit-function derivative: dPe/dr = 1 / (d ratio / dPe).
    slope = jax.grad(analytic.variance_ratio_closed)(17.0)
    d_ratio = jax.grad(analytic.peclet_from_variance_ratio)(variance / mean**2)
    assert float(d_ratio) == pytest.approx(1.0 / float(slope), rel=1e-13)


def test_peclet_from_moments_jits_and_vmaps():
    ratios = analytic.variance_ratio_closed(jnp.array([0.5, 5.0, 50.0]))
    peclets = jax.jit(jax.vmap(analytic.peclet_from_moments))(jnp.ones(3), ratios)
    np.testing.assert_allclose(peclets, [0.5, 5.0, 50.0], rtol=1e-13)
    # Out-of-range traced input gives NaN instead of an exception.
    assert np.isnan(float(jax.jit(analytic.peclet_from_variance_ratio)(1.5)))


@pytest.mark.parametrize(
    ("mean", "variance", "message"),
    [(1.0, 1.0, "below 1"), (1.0, 2.0, "below 1"), (-1.0, 0.1, "mean"), (1.0, 0.0, "variance")],
)
def test_peclet_from_moments_rejects_impossible_moments(mean, variance, message):
    with pytest.raises(ValueError, match=message):
        analytic.peclet_from_moments(mean, variance)


def test_sherritt_estimate_is_exact_for_the_inverse_gaussian():
    length, velocity, dispersion = 0.31, 0.004, 1.7e-4  # m, m/s, m²/s
    mean_time = length / velocity
    # First-passage time of drift v and dispersion D over L: inverse Gaussian with mean L/v
    # and shape L² / (2 D) (a time), density sqrt(λ/(2π t³)) exp(-λ (t-μ)² / (2 μ² t)).
    shape = length**2 / (2.0 * dispersion)

    def density(t):
        exponent = -shape * (t - mean_time) ** 2 / (2.0 * mean_time**2 * t)
        return np.sqrt(shape / (2.0 * np.pi * t**3)) * np.exp(exponent)

    options = {"epsabs": 0.0, "epsrel": 1e-13, "limit": 400, "points": [mean_time]}
    upper = 40.0 * mean_time
    mean = integrate.quad(lambda t: t * density(t), 0.0, upper, **options)[0]
    variance = integrate.quad(lambda t: (t - mean) ** 2 * density(t), 0.0, upper, **options)[0]
    estimate = float(analytic.sherritt_dispersion(length, mean, variance))
    assert estimate == pytest.approx(dispersion, rel=1e-10)
    expected_peclet = float(analytic.peclet_from_physical(velocity, dispersion, length))
    assert float(analytic.sherritt_peclet(mean, variance)) == pytest.approx(
        expected_peclet, rel=1e-10
    )


def test_sherritt_estimate_error_is_order_one_over_peclet_for_closed_closed():
    scaled_errors = []
    for peclet in [10.0, 100.0, 1000.0, 1e4]:
        variance = float(analytic.variance_closed(1.0, peclet))
        error = float(analytic.sherritt_peclet(1.0, variance)) / peclet - 1.0
        scaled_errors.append(error * peclet)
    # Pe_Sherritt = Pe / (1 - 1/Pe + e^{-Pe}/Pe), so Pe * error -> 1.
    assert all(0.5 < e < 1.5 for e in scaled_errors)
    assert abs(scaled_errors[-1] - 1.0) < 1e-3


def test_physical_helpers():
    assert float(analytic.tau_from_physical(0.005, 0.31)) == pytest.approx(62.0)
    assert float(analytic.peclet_from_physical(0.005, 1.7e-4, 0.31)) == pytest.approx(
        0.005 * 0.31 / 1.7e-4
    )


# --- differentiation, transformations, validation ----------------------------------------

CURVES = [
    (analytic.exit_age_closed, 8.0),
    (analytic.step_response_closed, 8.0),
    (analytic.exit_age_closed, 300.0),
    (analytic.step_response_closed, 0.3),
    (analytic.exit_age_open, 8.0),
    (analytic.step_response_open, 8.0),
    (analytic.exit_age_tanks, 4.5),
    (analytic.step_response_tanks, 4.5),
]


@pytest.mark.parametrize(("curve", "shape"), CURVES)
def test_curve_gradients_match_central_differences(curve, shape):
    t = jnp.linspace(0.0, 60.0, 61)
    tau = 20.0

    def total(tau, shape):
        # A weighted sum, so one scalar derivative checks every time point.
        return jnp.sum(jnp.cos(0.1 * t) * curve(t, tau, shape))

    d_tau, d_shape = jax.grad(total, argnums=(0, 1))(tau, shape)
    fd_tau = _central_difference(lambda x: float(total(x, shape)), tau)
    fd_shape = _central_difference(lambda x: float(total(tau, x)), shape)
    assert float(d_tau) == pytest.approx(fd_tau, rel=1e-6, abs=1e-9)
    assert float(d_shape) == pytest.approx(fd_shape, rel=1e-6, abs=1e-9)


def test_closed_closed_second_derivative_matches_finite_differences():
    t = jnp.array([10.0, 20.0, 35.0])

    def value(peclet):
        return analytic.exit_age_closed(t, 20.0, peclet)[1]

    second = jax.grad(jax.grad(value))(8.0)
    fd = _central_difference(lambda p: float(jax.grad(value)(p)), 8.0)
    assert float(second) == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("peclet", [0.01, 0.3, 8.0, 137.0, 1e3, 1e4])
def test_closed_closed_slopes_equal_differentiated_quadrature(peclet):
    # E's custom JVP sums the theta and Pe derivatives of the integrand on the quadrature's
    # nodes; differentiating the E of closed_closed_curves (plain JAX arithmetic, no custom
    # rule) is an independent route to the same Jacobian and Hessian.
    from axialmix.analytic._contour import closed_closed_curves, closed_closed_exit_age

    theta = jnp.linspace(0.0, 3.0, 61)

    def curve(f):
        return lambda x: x[2] * f(theta / x[0], x[1])

    plain = curve(lambda th, pe: closed_closed_curves(th, pe)[0])
    fast = curve(closed_closed_exit_age)
    x = jnp.array([1.3, peclet, 0.7])
    # The same quadrature, its denominator written without exprel: equal to round-off.
    np.testing.assert_allclose(fast(x), plain(x), rtol=0, atol=1e-14 * np.max(plain(x)))
    for jacobian in (jax.jacfwd, jax.jacrev):
        expected = np.asarray(jax.jacfwd(plain)(x))
        got = np.asarray(jacobian(fast)(x))
        scale = np.max(np.abs(expected), axis=0)
        assert np.max(np.abs(got - expected) / scale) < 1e-11
    weights = jnp.cos(theta)
    expected = np.asarray(jax.hessian(lambda x: weights @ plain(x))(x))
    got = np.asarray(jax.hessian(lambda x: weights @ fast(x))(x))
    assert np.max(np.abs(got - expected)) < 1e-10 * np.max(np.abs(expected))


def test_closed_closed_curves_jit_and_vmap():
    t = jnp.linspace(0.0, 100.0, 301)
    peclets = jnp.array([0.5, 5.0, 50.0, 500.0])
    taus = jnp.array([20.0, 25.0, 30.0, 35.0])
    batched = jax.jit(jax.vmap(analytic.exit_age_closed, in_axes=(None, 0, 0)))(t, taus, peclets)
    for row, tau, peclet in zip(batched, taus, peclets, strict=True):
        np.testing.assert_allclose(row, analytic.exit_age_closed(t, tau, peclet), rtol=1e-13)
    over_times = jax.vmap(lambda x: analytic.step_response_closed(x, 20.0, 5.0))(t)
    np.testing.assert_allclose(over_times, analytic.step_response_closed(t, 20.0, 5.0), atol=1e-15)


def test_gradient_at_time_zero_is_finite():
    t = jnp.array([-1.0, 0.0, 1.0])
    for curve, shape in CURVES:
        jacobian = jax.jacfwd(curve, argnums=(1, 2))(t, 2.0, shape)
        assert all(np.all(np.isfinite(np.asarray(j))) for j in jacobian)


@pytest.mark.parametrize(
    "curve",
    [
        analytic.exit_age_closed,
        analytic.step_response_closed,
        analytic.exit_age_open,
        analytic.exit_age_tanks,
    ],
)
@pytest.mark.parametrize(
    ("t", "tau", "shape", "message"),
    [
        ([0.0, 1.0], -1.0, 5.0, "tau must be positive"),
        ([0.0, 1.0], 0.0, 5.0, "tau must be positive"),
        ([0.0, 1.0], float("nan"), 5.0, "tau must not be NaN"),
        ([0.0, 1.0], 1.0, 0.0, "must be positive"),
        ([0.0, 1.0], 1.0, float("nan"), "must not be NaN"),
        ([0.0, 2.0, 1.0], 1.0, 5.0, "t must be strictly increasing"),
        ([0.0, 1.0, 1.0], 1.0, 5.0, "t must be strictly increasing"),
        ([0.0, float("nan")], 1.0, 5.0, "t must not be NaN"),
        ([[0.0, 1.0]], 1.0, 5.0, "t must be a one-dimensional"),
    ],
)
def test_bad_arguments_raise_value_error_naming_the_argument(curve, t, tau, shape, message):
    with pytest.raises(ValueError, match=message):
        curve(np.asarray(t), tau, shape)


def test_shape_argument_is_named_in_errors():
    with pytest.raises(ValueError, match="peclet"):
        analytic.exit_age_closed(jnp.array([1.0]), 1.0, -2.0)
    with pytest.raises(ValueError, match="n_tanks"):
        analytic.exit_age_tanks(jnp.array([1.0]), 1.0, -2.0)


def test_too_few_quadrature_nodes_are_rejected():
    with pytest.raises(ValueError, match="nodes"):
        analytic.exit_age_closed(jnp.array([1.0]), 1.0, 2.0, nodes=4)


def test_negative_times_are_allowed_and_give_zero():
    t = jnp.array([-5.0, -1.0, 0.0])
    for curve, shape in CURVES:
        assert np.all(np.asarray(curve(t, 2.0, shape)) == 0.0)
    # A single stirred tank jumps to 1/tau at t = 0 (right limit).
    np.testing.assert_allclose(analytic.exit_age_tanks(t, 2.0, 1.0), [0.0, 0.0, 0.5])



def test_closed_closed_curves_of_many_points_are_evaluated_in_blocks_with_the_same_values():
    # More points than one block: the blocked evaluation (lax.map of checkpointed blocks) must
    # give what one evaluation of all the points gives, with the same derivatives in both
    # modes (reverse mode recomputes each block).
    from axialmix.analytic import _contour

    t = jnp.linspace(0.0, 90.0, _contour.AT_ONCE + 123)  # blocks, the last one padded

    def blocked(p):
        return jnp.stack(_contour.closed_closed_curves(t / p[0], p[1]))

    def at_once(p):
        peclet = jnp.full(t.shape, p[1])
        return jnp.stack(_contour._curves(t / p[0], peclet, _contour.DEFAULT_NODES))

    def sum_of_squares(curves):
        return lambda p: jnp.sum(curves(p) ** 2)

    # Equal to round-off: XLA may order the 25-term quadrature sums differently, and evaluate
    # exp in its vectorised or its scalar form, in arrays of other shapes (vector widths): a
    # few units in the last place of each curve's (or Jacobian column's) largest value.
    # Measured: 1.5e-14 of the column's largest value at most. (Relative to each entry the same
    # round-off is unbounded where a derivative crosses zero.)
    p = jnp.array([20.0, 7.0])
    for transform in (jax.jit, lambda f: jax.jit(jax.jacfwd(f)),
                      lambda f: jax.jit(jax.grad(sum_of_squares(f)))):
        got, want = np.asarray(transform(blocked)(p)), np.asarray(transform(at_once)(p))
        scale = np.max(np.abs(want), axis=-2, keepdims=True) if want.ndim == 3 else (
            np.max(np.abs(want), axis=-1, keepdims=True))
        assert np.all(np.abs(got - want) <= 1e-13 * scale), np.max(np.abs(got - want) / scale)


@pytest.mark.parametrize("peclet", [1e-3, 0.1, 7.0, 137.0, 1e5])
def test_line_factors_equal_the_complex_exponentials_they_replace(peclet):
    # e^phi (one real exponential times a fixed array), e^{-q Pe} - 1 (expm1 and half-angle
    # powers) and e^{-q Pe} (powers of one rotation) against the complex exponentials on the
    # same nodes, each to its own relative precision (also where |q Pe| is small, Pe 1e-3, and
    # where e^{-q Pe} is tiny, Pe 1e5); and their derivatives against those of the exponentials.
    from axialmix.analytic import _contour

    theta = jnp.geomspace(1e-3, 20.0, 101)
    pe = jnp.full(theta.shape, peclet)
    nodes = _contour.DEFAULT_NODES
    growth, change, decay = _contour._factors(theta, pe, nodes)
    theta_n, pe_n, q, *_ = _contour._geometry(theta, pe, nodes)
    phi = _contour._phi(theta_n, pe_n, q)
    for got, want in ((growth, jnp.exp(phi)), (change, jnp.expm1(-q * pe_n)),
                      (decay, jnp.exp(-q * pe_n))):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-11, atol=1e-300)

    def direct(theta, pe):
        # (The tangents only: JAX differentiates expm1(x) as (expm1(x) + 1) dx, which loses
        # the digits of a tiny e^x; exp(x) - 1 has the tangent e^x dx itself.)
        theta_n, pe_n, q, *_ = _contour._geometry(theta, pe, nodes)
        return (jnp.exp(_contour._phi(theta_n, pe_n, q)), jnp.exp(-q * pe_n) - 1.0,
                jnp.exp(-q * pe_n))

    point = (jnp.asarray([0.7]), jnp.asarray([peclet]))
    tangent = (jnp.asarray([0.3]), jnp.asarray([0.2 * peclet]))
    _, fast = jax.jvp(lambda a, b: _contour._factors(a, b, nodes), point, tangent)
    _, slow = jax.jvp(direct, point, tangent)
    for got, want in zip(fast, slow, strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-9,
                                   atol=1e-12 * float(np.max(np.abs(np.asarray(want)))))


def test_closed_closed_gradient_memory_grows_only_with_the_results():
    # XLA's own account of the compiled gradient's scratch memory (deterministic, no timing):
    # evaluated at once, a million points held 3.8 GB of quadrature arrays; in blocks, each
    # further point costs a few float64 values (results, tangents), not 33 complex nodes x 20
    # arrays (about 10 kB).
    def scratch(n):
        t = jnp.linspace(0.0, 90.0, n)
        loss = jax.grad(lambda p: jnp.sum(analytic.exit_age_closed(t, p[0], p[1]) ** 2))
        compiled = jax.jit(loss).lower(jnp.array([20.0, 7.0])).compile()
        return compiled.memory_analysis().temp_size_in_bytes

    small, large = 64 * 4096, 128 * 4096  # both above AT_ONCE
    per_point = (scratch(large) - scratch(small)) / (large - small)
    assert per_point < 100, f"{per_point:.0f} bytes of scratch memory per point"


def test_closed_form_quantities_of_plain_numbers_are_numpy_and_equal_the_jax_ones():
    # A record evaluates the means and (v, D_z) on plain numbers once per curve: NumPy there
    # (no JAX dispatch), JAX arrays given JAX arrays and inside a trace; the same numbers.
    cases = [(analytic.mean_closed, (12.0, 7.0)), (analytic.mean_open, (12.0, 7.0)),
             (analytic.transport_from_dimensionless, (12.0, 7.0, 0.5))]
    for function, arguments in cases:
        plain = function(*arguments)
        on_jax = function(*(jnp.asarray(a) for a in arguments))
        traced = jax.jit(function)(*arguments)
        for got in jax.tree.leaves(plain):
            assert isinstance(got, np.ndarray | np.generic) and not isinstance(got, jax.Array)
        for got in jax.tree.leaves((on_jax, traced)):
            assert isinstance(got, jax.Array)
        for a, b, c in zip(jax.tree.leaves(plain), jax.tree.leaves(on_jax),
                           jax.tree.leaves(traced), strict=True):
            assert float(a) == float(b) == float(c)
    with pytest.raises(ValueError, match="tau must be positive"):
        analytic.mean_open(-1.0, 7.0)
