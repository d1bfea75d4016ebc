"""Gradient fits: parameter recovery, poor starts, gradients, fixed/tied/bounded parameters.

Each distinct model and parameter layout compiles one solver (seconds), so the tests batch
their cases into few `fit_many` calls.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from axialmix.analytic import exit_age_closed, exit_age_open, exit_age_tanks
from fitting.fit import fit, fit_many
from fitting.losses import mean_absolute_error, sum_of_squares
from fitting.models import MODELS, custom_model, get_model
from fitting.parameters import Parameter, Parameters
from fitting.solve import MultiStart, Optimiser
from fitting.uncertainty import effective_degrees_of_freedom

TAU = 10.0
TIME = np.linspace(0.0, 3 * TAU, 60)
PECLETS = (0.5, 5.0, 50.0, 500.0)
EXACT = {"adm": exit_age_closed, "adm-open": exit_age_open, "tanks": exit_age_tanks}
SECOND = {"adm": "peclet", "adm-open": "peclet", "tanks": "n_tanks"}
# Tank numbers below 1 make E(0) infinite, so the tanks model uses its own range.
SECOND_VALUES = {"adm": PECLETS, "adm-open": PECLETS, "tanks": (1.0, 5.0, 50.0, 500.0)}
POOR_FACTORS = ((10.0, 10.0), (0.1, 0.1), (10.0, 0.1), (0.1, 10.0))


def _curve(model_name, second):
    return TIME, np.asarray(EXACT[model_name](TIME, TAU, second))


def _poor_cases(model_name):
    """(curve, start values 10x off, true second parameter) for every value and direction."""
    cases = []
    for second in SECOND_VALUES[model_name]:
        for tau_factor, second_factor in POOR_FACTORS:
            start = {"tau": TAU * tau_factor, SECOND[model_name]: second * second_factor}
            cases.append((_curve(model_name, second), start, second))
    return cases


@pytest.fixture(scope="module")
def adm_single_start():
    """One batched L-BFGS call, one start each: moment starts for every Pe, then every 10x-off
    start on its own (``MultiStart(n_starts=1)``: no moment-estimate rescue)."""
    moment_cases = [(_curve("adm", pe), None, pe) for pe in PECLETS]
    cases = moment_cases + _poor_cases("adm")
    results = fit_many("adm", [c for c, _, _ in cases], [s for _, s, _ in cases],
                       multistart=MultiStart(n_starts=1))
    return cases, results


def _relative_errors(result, model_name, second):
    return (abs(result.values["tau"] / TAU - 1),
            abs(result.values[SECOND[model_name]] / second - 1))


def test_noise_free_adm_curves_give_back_tau_and_peclet_to_1e_6(adm_single_start):
    cases, results = adm_single_start
    for (_, _, peclet), result in zip(cases[:4], results[:4], strict=True):
        tau_error, peclet_error = _relative_errors(result, "adm", peclet)
        print(f"Pe={peclet:g}: tau error {tau_error:.1e}, Pe error {peclet_error:.1e}, "
              f"{result.n_evaluations} evaluations, {result.message}")
        assert result.converged
        assert tau_error < 1e-6 and peclet_error < 1e-6


def test_single_start_from_10x_off_never_claims_a_false_convergence(adm_single_start):
    # From 10x off, the model curve may not overlap the data at all (the loss is flat): no
    # local method can recover there, but the fit must then say it did not converge.
    cases, results = adm_single_start
    recovered = 0
    for (_, start, peclet), result in zip(cases[4:], results[4:], strict=True):
        right = max(_relative_errors(result, "adm", peclet)) < 1e-6
        recovered += right
        print(f"Pe={peclet:g} from {start}: converged={result.converged}, right={right}")
        assert result.converged == right
    print(f"{recovered} of {len(cases) - 4} single starts 10x off recovered the parameters")
    assert recovered > 0


# Each model compiles its own solver (tens of seconds on two shared cores; the finite-volume
# model minutes), so all but the exact closed-closed model run with the slow studies.
@pytest.mark.parametrize("model_name", [
    "adm",
    pytest.param("adm-open", marks=pytest.mark.slow),
    pytest.param("tanks", marks=pytest.mark.slow),
])
def test_fits_from_10x_off_converge_with_default_starts(model_name):
    # Default settings: the 10x-off start values and the moment estimate, as one batch.
    cases = _poor_cases(model_name)
    results = fit_many(model_name, [c for c, _, _ in cases], [s for _, s, _ in cases])
    for (_, start, second), result in zip(cases, results, strict=True):
        tau_error, second_error = _relative_errors(result, model_name, second)
        print(f"{model_name} {SECOND[model_name]}={second:g} from {start}: "
              f"errors {tau_error:.1e} {second_error:.1e}, {result.n_starts} starts, "
              f"{result.n_evaluations} evaluations")
        assert result.n_starts == 2
        assert result.converged, result.message
        assert tau_error < 1e-6 and second_error < 1e-6


# A finite-volume fit takes about 0.2 s per evaluation (a pulse response on a fine grid for
# every value and gradient) plus about 20 s of compilation, so this is an opt-in study.
@pytest.mark.study
def test_finite_volume_fits_from_10x_off_converge_with_default_starts():
    # Every Peclet number, from 10x off in both directions (both too large, both too small).
    cases = [c for i, c in enumerate(_poor_cases("adm")) if i % 4 in (0, 1)]
    results = fit_many("adm-fv", [c for c, _, _ in cases], [s for _, s, _ in cases])
    for (_, start, peclet), result in zip(cases, results, strict=True):
        tau_error, peclet_error = _relative_errors(result, "adm", peclet)
        print(f"adm-fv Pe={peclet:g} from {start}: errors {tau_error:.1e} {peclet_error:.1e}, "
              f"{result.n_evaluations} evaluations, {result.message}")
        assert result.converged, result.message
        # The FV model's own error (about 1e-4 of the peak) bounds the recovery.
        assert tau_error < 1e-3 and peclet_error < 1e-2


# Compiles the four-compartment solver and its Hessian (about half a minute).
@pytest.mark.slow
def test_minimum_on_the_four_compartment_mirror_line_is_confirmed_by_the_full_hessian():
    from pathlib import Path

    from axialmix.network import four_compartment_exit_age
    from fitting.data import read_rtd_csv

    curve = read_rtd_csv(Path(__file__).parents[1] / "examples" / "data" / "horizontal.csv")
    result = fit("four-compartment", curve, {"k_out": Parameter(0.8, vary=False)})
    print(result.message)
    assert result.status == 8 and result.converged
    names = ("k_f", "k_r", "k_s")
    point = np.log([result.values[n] for n in names])

    def sse(log_rates):
        model = np.asarray(four_compartment_exit_age(curve.time, *np.exp(log_rates), 0.8))
        return float(np.sum((model - curve.value) ** 2))

    # Independent check by central differences: the Gauss-Newton matrix is singular along
    # the mirror direction, the full Hessian positive definite, the gradient negligible.
    step = 1e-4
    hessian = np.empty((3, 3))
    gradient = np.empty(3)
    for i in range(3):
        e_i = np.eye(3)[i] * step
        gradient[i] = (sse(point + e_i) - sse(point - e_i)) / (2 * step)
        for j in range(3):
            e_j = np.eye(3)[j] * step
            hessian[i, j] = (sse(point + e_i + e_j) - sse(point + e_i - e_j)
                             - sse(point - e_i + e_j) + sse(point - e_i - e_j)) / (4 * step**2)
    jacobian = np.stack([
        (np.asarray(four_compartment_exit_age(curve.time, *np.exp(point + np.eye(3)[i] * step),
                                              0.8))
         - np.asarray(four_compartment_exit_age(curve.time,
                                                *np.exp(point - np.eye(3)[i] * step), 0.8)))
        / (2 * step) for i in range(3)], axis=1)
    gauss_newton = np.linalg.eigvalsh(jacobian.T @ jacobian)
    assert gauss_newton[0] < 1e-6 * gauss_newton[-1]
    eigenvalues = np.linalg.eigvalsh(0.5 * (hessian + hessian.T))
    # Positive definite: the smallest eigenvalue (about 5e-4 of the largest, the curvature
    # along the mirror direction) lies far above the differences' error (about 1e-8 of it).
    assert eigenvalues[0] > 1e-5 * eigenvalues[-1]
    newton_fall = 0.5 * gradient @ np.linalg.solve(hessian, gradient)
    assert newton_fall < 1e-8 * result.sse


@pytest.mark.parametrize("model_name", ["adm", "adm-open", "tanks", "four-compartment"])
def test_objective_gradient_matches_central_differences(model_name):
    model = get_model(model_name)
    rng = np.random.default_rng(3)
    time = jnp.linspace(0.0, 30.0, 25)
    if model_name == "four-compartment":
        truth = {"k_f": 0.3, "k_r": 0.1, "k_s": 0.2, "k_out": 0.25}
    else:
        truth = {"tau": TAU, SECOND[model_name]: 8.0}
    observed = model(time, truth) * (1 + 0.05 * rng.normal(size=time.shape))
    point = {name: value * 1.1 for name, value in truth.items()}

    for loss in (sum_of_squares, mean_absolute_error):
        @jax.jit
        def objective(values, loss=loss):
            return loss(model(time, values) - observed)

        gradient = jax.grad(objective)(point)
        for name, value in point.items():
            step = 1e-6 * value
            up = objective({**point, name: value + step})
            down = objective({**point, name: value - step})
            central = (up - down) / (2 * step)
            assert float(gradient[name]) == pytest.approx(float(central), rel=1e-6, abs=1e-12)


def _two_exponentials(t, p):
    """A mixture of two exponential residence-time densities, scaled by `amplitude`."""
    first = jnp.exp(-t / p["tau_1"]) / p["tau_1"]
    second = jnp.exp(-t / p["tau_2"]) / p["tau_2"]
    return p["amplitude"] * (p["fraction"] * first + (1 - p["fraction"]) * second)


def test_fixed_tied_and_bounded_parameters_behave():
    model = custom_model("two-exponentials", _two_exponentials, {
        "tau_1": Parameter(1.0, min=0.0), "tau_2": Parameter(1.0, min=0.0),
        "fraction": Parameter(0.5, min=0.0, max=1.0), "amplitude": Parameter(1.0, min=0.0),
    })
    params = Parameters()
    params.add("tau_1", 2.0, min=0.0)
    params.add("tau_2", 4.0, expr="2*tau_1")
    params.add("fraction", 0.1, min=0.0, max=0.3)
    params.add("amplitude", 1.0, vary=False)
    time = np.linspace(0.0, 40.0, 50)
    inside = {"tau_1": 3.0, "tau_2": 6.0, "fraction": 0.2, "amplitude": 1.0}
    outside = {**inside, "fraction": 0.5}  # the best fraction lies above the upper bound
    curves = [(time, np.asarray(_two_exponentials(time, truth))) for truth in (inside, outside)]
    recovered, bounded = fit_many(model, curves, params)

    assert recovered.converged
    for name in ("tau_1", "fraction"):
        assert recovered.values[name] == pytest.approx(inside[name], rel=1e-6)
    for result in (recovered, bounded):
        assert result.values["tau_2"] == 2 * result.values["tau_1"]
        assert result.values["amplitude"] == 1.0 and result.stderr["amplitude"] is None
        assert result.free_names == ("tau_1", "fraction")
        # The tied parameter's error is propagated through its expression.
        assert result.stderr["tau_2"] == pytest.approx(2 * result.stderr["tau_1"], rel=1e-9)
    assert 0.0 < bounded.values["fraction"] <= 0.3
    assert bounded.values["fraction"] > 0.299  # pressed against the bound it may not cross


def test_adam_on_the_mean_absolute_error_finds_the_exponential_time_constant():
    model = custom_model("exponential", lambda t, p: jnp.exp(-t / p["tau"]) / p["tau"],
                         {"tau": Parameter(1.0, min=0.0)})
    time = np.linspace(0.0, 30.0, 40)
    result = fit(model, (time, np.exp(-time / 7.0) / 7.0), {"tau": 2.0}, loss="mae",
                 optimiser=Optimiser(method="adam", max_steps=3000))
    # Adam at a fixed step size ends in a small oscillation around the optimum of the
    # non-smooth MAE, hence the 1e-3 tolerance; the best point visited is returned.
    assert result.values["tau"] == pytest.approx(7.0, rel=1e-3)
    assert result.loss_name == "mae" and result.method == "adam"
    assert result.n_evaluations <= 3000


def test_result_report_and_json_summary(adm_single_start):
    _, results = adm_single_start
    result = results[1]
    summary = json.loads(json.dumps(result.to_dict()))
    assert summary["model"] == "adm"
    assert set(summary["parameters"]) == {"tau", "peclet"}
    assert summary["parameters"]["tau"]["value"] == pytest.approx(result.values["tau"])
    assert summary["converged"] is True and summary["n_evaluations"] == result.n_evaluations
    report = result.report()
    assert "[[Variables]]" in report and "peclet:" in report and "evaluations" in report


def test_registry_and_argument_errors():
    assert set(MODELS) == {"adm", "adm-fv", "adm-open", "tanks", "four-compartment",
                           "adm-exchange", "tanks-exchange", "adm-tank"}
    with pytest.raises(ValueError, match="unknown model 'adm2'"):
        get_model("adm2")
    curve = (TIME, np.asarray(exit_age_closed(TIME, TAU, 5.0)))
    with pytest.raises(ValueError, match="loss must be one of"):
        fit("adm", curve, loss="l1")
    with pytest.raises(ValueError, match="unknown parameter"):
        fit("adm", curve, {"peclet": Parameter(5.0, expr="2*pe")})
    with pytest.raises(ValueError, match="cycle"):
        fit("adm", curve, {"tau": Parameter(1.0, expr="peclet"),
                           "peclet": Parameter(1.0, expr="tau")})
    with pytest.raises(ValueError, match="outside its bounds"):
        Parameter(-1.0, min=0.0)
    with pytest.raises(ValueError, match="cannot determine 2 free parameters"):
        fit("adm", (TIME[:2], np.ones(2)))
    with pytest.raises(ValueError, match="only numbers, parameter names"):
        Parameter(1.0, expr="__import__('os')")
    # A seed is checked when it is given, whether or not a random start is drawn.
    for seed in (-1, 1.5, True):
        with pytest.raises(ValueError, match="seed must be a non-negative integer"):
            MultiStart(n_starts=1, seed=seed)
    assert MultiStart(seed=3).seed == 3


def test_an_infinite_start_value_keeps_the_moment_estimate_as_a_second_start():
    # Only an equal number is close to an infinite one (as in np.allclose): the moment
    # estimate differs from a start of inf, so the fit starts from both.
    from fitting.data import Curve
    from fitting.fit import prepare

    curve = Curve(name="c", time=TIME, value=np.asarray(exit_age_closed(TIME, TAU, 5.0)),
                  time_unit="s")
    infinite = prepare("adm", curve, {"peclet": Parameter(math.inf, min=0.0)}, None, None, 0)
    assert infinite.starts.shape[0] == 2
    # By default the start values are the moment estimates themselves: one start.
    assert prepare("adm", curve, None, None, None, 0).starts.shape[0] == 1


def test_relative_errors_fit_is_weighted_by_its_own_model_curve():
    rng = np.random.default_rng(8)
    time = np.linspace(3.0, 90.0, 15)
    exact = np.asarray(exit_age_closed(time, 30.0, 20.0))
    curves = [(time, exact * (1 + 0.02 * rng.standard_normal(time.size))) for _ in range(3)]
    results = fit_many("adm", curves, relative_errors=True)
    for curve, result in zip(curves, results, strict=True):
        assert result.converged, result.message
        assert "relative errors" in result.method
        # The fixed point of the reweighting: weights 1 / max(|model|, floor)^2 of the fit's
        # own curve, and the fit with those weights does not move from it.
        size = np.maximum(np.abs(result.predicted), 1e-3 * np.max(np.abs(result.predicted)))
        np.testing.assert_allclose(result.weights, 1 / size**2, rtol=1e-6)
        again = fit("adm", curve, {"tau": result.values["tau"],
                                   "peclet": result.values["peclet"]},
                    weights=result.weights, multistart=MultiStart(n_starts=1))
        # Its standard errors differ only by the degrees of freedom: three of the 15 points
        # (0.1 tau and the last tail points) lie below the weight floor, hold little
        # residual and are not counted as whole degrees of freedom.
        factors = result.weights * np.asarray(result.predicted) ** 2
        assert result.dof == pytest.approx(
            effective_degrees_of_freedom(result.jacobian, result.weights, factors), rel=1e-12)
        assert again.dof == 13 and 10 < result.dof < 11
        for name in ("tau", "peclet"):
            assert again.values[name] == pytest.approx(result.values[name], rel=1e-7)
            rescaled = again.stderr[name] * math.sqrt(again.dof / result.dof)
            assert rescaled == pytest.approx(result.stderr[name], rel=1e-5)
        unweighted = fit("adm", curve)
        assert result.n_evaluations > unweighted.n_evaluations
    with pytest.raises(ValueError, match="relative_errors"):
        fit_many("adm", curves, weights=[None] * 3, relative_errors=True)


def test_intervals_of_positive_parameters_are_symmetric_in_the_logarithm():
    time = np.linspace(0.5, 30.0, 12)
    rng = np.random.default_rng(2)
    observed = np.asarray(exit_age_closed(time, 10.0, 2.0)) * (1 + 0.3 * rng.normal(size=12))
    result = fit("adm", (time, np.abs(observed)))
    for name in ("tau", "peclet"):
        low, high = result.ci95[name]
        value, error = result.values[name], result.stderr[name]
        assert low > 0
        assert math.log(high / value) == pytest.approx(math.log(value / low), rel=1e-12)
        # The half-width in ln p is t * (relative standard error).
        half = math.log(high / value)
        from scipy import stats

        assert half == pytest.approx(stats.t.ppf(0.975, result.dof) * error / value, rel=1e-12)
