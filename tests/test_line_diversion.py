"""Tests of diversion windows and their uncertainty (axialmix.line)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq, curve_fit

from axialmix.line import (
    Disturbance,
    DiversionRefused,
    FittedRTD,
    FlowSchedule,
    Line,
    Unit,
    UnitModel,
    conservative_diversion_window,
    diversion_window,
    outlet_response,
    sample_units,
)

TAU = 10.0
TIMES = np.linspace(0.0, 150.0, 301)
LIMITS = {"target": 1.0, "lower": 0.95, "upper": 1.05}


def _tank_window(magnitude, duration, start, delta=0.05):
    """Exact exit and return times of a stirred tank's outlet after a square disturbance."""
    exit_time = start - TAU * np.log1p(-delta / abs(magnitude))
    peak = abs(magnitude) * -np.expm1(-duration / TAU)
    return exit_time, start + duration + TAU * np.log(peak / delta)


@pytest.mark.parametrize("magnitude", [0.2, -0.3])
def test_window_of_a_stirred_tank_is_exact(magnitude):
    unit = Unit.tanks(TAU, 1.0)
    window = diversion_window(unit, Disturbance.square(magnitude, 30.0, 5.0), TIMES, flow=12.0,
                              amount_unit="kg", **LIMITS)
    start, stop = _tank_window(magnitude, 30.0, 5.0)
    assert bool(window.diverts)
    assert float(window.start) == pytest.approx(start, rel=1e-12)
    assert float(window.stop) == pytest.approx(stop, rel=1e-12)
    assert float(window.diverted_amount) == pytest.approx(12.0 * (stop - start), rel=1e-12)
    assert window.amount_unit == "kg"
    assert window.to_dict()["stop"] == pytest.approx(stop, rel=1e-12)


def test_diverted_amount_follows_a_flow_trace():
    unit = Unit.tanks(TAU, 1.0)
    flow = FlowSchedule([0.0, 40.0, 80.0], [10.0, 16.0, 12.0])
    window = diversion_window(unit, Disturbance.square(0.2, 30.0, 5.0), TIMES, flow=flow,
                              **LIMITS)
    start, stop = _tank_window(0.2, 30.0, 5.0)
    expected = quad(lambda t: float(np.interp(t, [0.0, 40.0, 80.0], [10.0, 16.0, 12.0])),
                    start, stop, points=[40.0, 80.0])[0]
    assert float(window.diverted_amount) == pytest.approx(expected, rel=1e-12)


def test_window_cases_without_return_without_excursion_and_with_two_excursions():
    unit = Unit.tanks(TAU, 1.0)
    small = diversion_window(unit, Disturbance.square(0.04, 30.0, 5.0), TIMES, **LIMITS)
    assert not bool(small.diverts)
    assert np.isnan(float(small.start)) and float(small.diverted_amount) == 0.0
    # A lasting step leaves the content outside for good: the window has no end.
    lasting = diversion_window(unit, Disturbance.step(0.2, 5.0), TIMES, **LIMITS)
    assert float(lasting.stop) == np.inf and float(lasting.diverted_amount) == np.inf
    # A square ending after the scan: the scan is continued until the outlet settles, so
    # the window is the exact one, not cut at the last given time.
    late = diversion_window(unit, Disturbance.square(0.2, 200.0, 5.0), TIMES, **LIMITS)
    assert float(late.stop) == pytest.approx(_tank_window(0.2, 200.0, 5.0)[1], rel=1e-12)
    assert float(late.times[-1]) > 205.0
    twice = Disturbance.square(0.2, 10.0, 5.0) + Disturbance.square(0.2, 10.0, 60.0)
    window = diversion_window(unit, twice, TIMES, **LIMITS)

    def deviation(t):  # the two squares' closed-form responses, superposed
        def rise(x):
            return -np.expm1(-max(x, 0.0) / TAU)

        return 0.2 * (rise(t - 5.0) - rise(t - 15.0) + rise(t - 60.0) - rise(t - 70.0))

    first_start, _ = _tank_window(0.2, 10.0, 5.0)
    last_stop = brentq(lambda t: deviation(t) - 0.05, 71.0, 120.0, xtol=1e-14)
    assert deviation(40.0) < 0.05  # two excursions, one window from the first to the last
    assert float(window.start) == pytest.approx(first_start, rel=1e-12)
    assert float(window.stop) == pytest.approx(last_stop, rel=1e-12)


def test_window_of_a_line_uses_the_line_curves():
    line = Line(Unit.closed_closed(20.0, 40.0), Unit.tanks(5.0, 2.0))
    disturbance = Disturbance.square(0.25, 15.0, 5.0)
    window = diversion_window(line, disturbance, TIMES, **LIMITS)
    table = line.tabulate(TIMES[-1])
    # At the located times the outlet content sits on the limit.
    for edge in (window.start, window.stop):
        content = 1.0 + 0.25 * (table.cumulative(edge - 5.0) - table.cumulative(edge - 20.0))
        assert float(content) == pytest.approx(1.05, abs=1e-12)


def test_diversion_rejects_bad_limits():
    with pytest.raises(ValueError, match="must be below"):
        diversion_window(Unit.tanks(1.0, 1.0), Disturbance.step(1.0), TIMES, target=1.0,
                         lower=1.1, upper=0.9)


def test_sample_units_draws_from_the_stated_distribution():
    covariance = np.array([[4.0, 1.0], [1.0, 9.0]])
    units, drawn = sample_units(lambda p: Unit.closed_closed(p[0], p[1]), [60.0, 30.0],
                                covariance, 20000, seed=4)
    assert units.parameters["tau"].shape == (20000,)
    np.testing.assert_allclose(np.asarray(units.parameters["tau"]), np.asarray(drawn[:, 0]))
    np.testing.assert_allclose(np.mean(np.asarray(drawn), axis=0), [60.0, 30.0], atol=0.1)
    np.testing.assert_allclose(np.cov(np.asarray(drawn).T), covariance, rtol=0.05, atol=0.1)
    _, logs = sample_units(lambda p: Unit.tanks(p[0], p[1]), [60.0, 3.0],
                           np.diag([0.01, 0.04]), 20000, seed=5, scale="log")
    np.testing.assert_allclose(np.std(np.log(np.asarray(logs)), axis=0), [0.1, 0.2], rtol=0.03)


def _closed_closed(parameters):
    return Unit.closed_closed(parameters[0], parameters[1])


def _tank_exit_age(t, p, _):
    return jnp.where(t >= 0, jnp.exp(-jnp.maximum(t, 0.0) / p["tau"]) / p["tau"], 0.0)


def _tank_cumulative(t, p, _):
    return jnp.where(t > 0, -jnp.expm1(-jnp.maximum(t, 0.0) / p["tau"]), 0.0)


# A stirred tank written in elementary functions (the gamma unit's incomplete gamma function
# costs more than the thousands of windows of the next test need); it also exercises the
# plug-in route for models the package does not define.
STIRRED_TANK = UnitModel(name="stirred_tank", parameter_names=("tau",), positive=("tau",),
                         exit_age=_tank_exit_age, cumulative=_tank_cumulative)


def _stirred_tank(parameters):
    return Unit.from_model(STIRRED_TANK, {"tau": parameters[0]})


def test_conservative_windows_of_a_stirred_tank_follow_its_closed_form():
    # One parameter, tau ~ N(10, 0.5²); start and stop both grow with tau, so the region
    # window is the window at tau -/+ 1.96 sd (the region's two boundary points, exactly) and
    # the quantile window tends to the same: the 2.5 % quantile of 4000 draws has a standard
    # error of sqrt(0.025 · 0.975 / 4000) / phi(1.96) = 0.042 sd; 4 standard errors allowed.
    disturbance = Disturbance.square(0.2, 30.0, 5.0)
    sd = 0.5
    times = np.linspace(0.0, 150.0, 151)

    def closed_form(tau):
        exit_time = 5.0 - tau * np.log1p(-0.05 / 0.2)
        return exit_time, 35.0 + tau * np.log(0.2 * -np.expm1(-30.0 / tau) / 0.05)

    low, high = closed_form(TAU - 1.959963984540054 * sd), closed_form(TAU + 1.959963984540054 * sd)
    region = conservative_diversion_window(
        _stirred_tank, [TAU], [[sd**2]], disturbance, times, coverage=0.95, samples=64,
        flow=2.0, **LIMITS,
    )
    assert float(region.start) == pytest.approx(low[0], rel=1e-12)
    assert float(region.stop) == pytest.approx(high[1], rel=1e-12)
    assert float(region.diverted_amount) == pytest.approx(2.0 * (high[1] - low[0]), rel=1e-12)
    nominal = closed_form(TAU)
    assert float(region.nominal.start) == pytest.approx(nominal[0], rel=1e-12)
    summary = region.to_dict()
    assert summary["conservative"]["start"] == pytest.approx(low[0], rel=1e-12)
    assert (summary["method"], summary["coverage"]) == ("region", 0.95)
    quantile = conservative_diversion_window(
        _stirred_tank, [TAU], [[sd**2]], disturbance, times, coverage=0.95, samples=4000,
        method="quantile", seed=3, **LIMITS,
    )
    allowed = 4 * 0.042 * sd
    slope = closed_form(TAU + 1e-6)[0] - closed_form(TAU - 1e-6)[0]
    assert float(quantile.start) == pytest.approx(low[0], abs=allowed * abs(slope) / 2e-6)
    slope = closed_form(TAU + 1e-6)[1] - closed_form(TAU - 1e-6)[1]
    assert float(quantile.stop) == pytest.approx(high[1], abs=allowed * abs(slope) / 2e-6)


def test_region_window_covers_the_windows_of_normal_draws_of_the_parameters():
    # Estimates drawn as a fit with the right covariance would give them: the region window
    # around each contains the true window whenever the truth is in its region (95 %).
    true = np.array([60.0, 30.0])
    covariance = np.array([[0.16, 0.2], [0.2, 2.0]])
    disturbance = Disturbance.square(0.2, 20.0, 10.0)
    times = np.linspace(0.0, 300.0, 151)
    reference = diversion_window(_closed_closed(true), disturbance, times, **LIMITS)
    estimates = np.random.default_rng(7).multivariate_normal(true, covariance, 10)
    inside = covered = 0
    for estimate in estimates:
        window = conservative_diversion_window(
            _closed_closed, estimate, covariance, disturbance, times, coverage=0.95,
            samples=64, **LIMITS,
        )
        distance = (true - estimate) @ np.linalg.solve(covariance, true - estimate)
        truth_in_region = distance <= 5.991464547107979  # chi²_2(0.95)
        contains = bool(window.start <= reference.start and window.stop >= reference.stop)
        inside += truth_in_region
        covered += contains
        assert contains or not truth_in_region
    assert covered >= inside


def _fit_adm(times, data):
    """Least-squares fit of (tau, Pe) to a noisy closed–closed RTD, with its covariance."""

    def model(t, tau, peclet):
        return np.asarray(_closed_closed_curve(jnp.asarray(t), tau, peclet))

    values, covariance = curve_fit(model, times, data, p0=[55.0, 25.0],
                                   bounds=([1.0, 1.0], [500.0, 500.0]))
    return values, covariance


@jax.jit
def _closed_closed_curve(t, tau, peclet):
    return Unit.closed_closed(tau, peclet).exit_age(t)


@pytest.mark.study
def test_conservative_window_covers_the_true_window_over_200_simulated_fits():
    # 200 simulated RTD experiments (closed–closed ADM, tau 60 s, Pe 30, 80 samples with
    # noise of 5 % of the peak), each fitted by least squares (scipy curve_fit); the 90 %
    # conservative window from each fit's covariance must contain the window of the true RTD
    # in at least 90 % of them. The quantile windows are counted too (reported, not asserted:
    # the fit's own 90 % ellipsoid holds the truth in fewer than 90 % of these fits).
    true = (60.0, 30.0)
    sample_times = np.linspace(3.0, 240.0, 80)
    truth = np.asarray(_closed_closed(true).exit_age(sample_times))
    disturbance = Disturbance.square(0.2, 20.0, 10.0)
    times = np.linspace(0.0, 300.0, 301)
    reference = diversion_window(_closed_closed(true), disturbance, times, **LIMITS)
    rng = np.random.default_rng(2024)
    counts = {"region": 0, "quantile": 0, "ellipsoid": 0}
    widths = {"region": [], "quantile": []}
    experiments = 200
    for _ in range(experiments):
        data = truth + rng.normal(0.0, 0.05 * truth.max(), truth.size)
        values, covariance = _fit_adm(sample_times, data)
        distance = (np.array(true) - values) @ np.linalg.solve(covariance, np.array(true) - values)
        counts["ellipsoid"] += distance <= 4.605170185988092  # chi²_2(0.9)
        seed = int(rng.integers(1 << 30))
        for method in ("region", "quantile"):
            window = conservative_diversion_window(
                _closed_closed, values, covariance, disturbance, times, coverage=0.9,
                samples=400, seed=seed, method=method, **LIMITS,
            )
            counts[method] += bool(
                window.start <= reference.start and window.stop >= reference.stop
            )
            widths[method].append(float(window.stop - window.start))
    print(
        f"\n{experiments} fits, nominal 0.90: region {counts['region'] / experiments:.3f}, "
        f"quantile {counts['quantile'] / experiments:.3f}, truth in the fit's 90 % ellipsoid "
        f"{counts['ellipsoid'] / experiments:.3f}; mean widths (s): region "
        f"{np.mean(widths['region']):.3f}, quantile {np.mean(widths['quantile']):.3f}, "
        f"true window {float(reference.stop - reference.start):.3f}"
    )
    assert counts["region"] / experiments >= 0.9


def test_conservative_window_is_monotone_in_the_covariance():
    # Property: a larger covariance (the same one scaled by k > 1, the same seed) never gives
    # a narrower conservative window; once the samples reach parameters where the model has
    # no finite prediction the window is refused, never made of the samples that worked.
    disturbance = Disturbance.square(0.2, 20.0, 10.0)
    times = np.linspace(0.0, 300.0, 301)
    rng = np.random.default_rng(11)
    for case in range(2):
        root = rng.normal(size=(2, 2)) * [0.02, 0.05]
        covariance = root @ root.T + np.diag([1e-4, 1e-4])  # of log tau, log Pe
        values = [rng.uniform(40.0, 80.0), rng.uniform(10.0, 60.0)]
        previous = None
        for k in (1.0, 3.0, 100.0, 1e4, 1e8):
            try:
                window = conservative_diversion_window(
                    _closed_closed, values, k * covariance, disturbance, times,
                    samples=64, seed=case, scale="log", **LIMITS)
            except DiversionRefused as refused:
                assert refused.failed > 0.01 * 64
                break
            start, stop = float(window.start), float(window.stop)
            if previous is not None:
                assert start <= previous[0] and stop >= previous[1], (case, k, previous)
            previous = (start, stop)


def test_samples_that_never_settle_refuse_the_window_with_their_count():
    # Log-normal samples of tau with a standard deviation of 6 in log tau: many samples have
    # a tau far beyond the scan (hours against seconds) and settle at none of the scan's
    # candidate ends (the nominal scan's span doubled up to 2^6 times). The refusal counts
    # them; the count is checked here sample by sample with the unit's own F.
    disturbance = Disturbance.square(0.2, 20.0, 10.0)
    times = np.linspace(0.0, 300.0, 301)
    values, covariance = [60.0, 30.0], np.diag([36.0, 1e-4])
    with pytest.raises(DiversionRefused) as refused:
        conservative_diversion_window(_closed_closed, values, covariance, disturbance, times,
                                      samples=200, seed=4, scale="log", method="quantile",
                                      **LIMITS)
    nominal = diversion_window(Unit.closed_closed(*values), disturbance, times, **LIMITS)
    scan = np.asarray(nominal.times)
    ends = scan[0] + (scan[-1] - scan[0]) * 2.0 ** np.arange(7)
    _, drawn = sample_units(_closed_closed, values, covariance, 200, seed=4, scale="log")
    lags = ends - 20.0  # the square's last event: its end at 10 + 10 s
    never = [bool(np.all(1.0 - np.asarray(Unit.closed_closed(tau, peclet).cumulative(lags))
                         > 1e-4)) for tau, peclet in np.asarray(drawn)]
    assert refused.value.nonfinite == 0
    assert refused.value.unsettled == sum(never) > 0.01 * 200, (refused.value, sum(never))
    assert f"have not settled by {ends[-1]:g} s" in str(refused.value)


# ------------------------------------------------------------------ numerically inverted units
EXCHANGE = {"tau": 5.0, "peclet": 20.0, "beta": 0.3, "k_d": 0.5}


def test_table_of_an_exchange_unit_agrees_with_its_exact_curves():
    from axialmix.line import TabulatedRTD

    unit = Unit.closed_closed_exchange(**EXCHANGE)
    table = TabulatedRTD.from_unit(unit, 60.0, 512)
    t = np.random.default_rng(3).uniform(0.0, 60.0, 64)
    np.testing.assert_allclose(np.asarray(table.cumulative(t)), np.asarray(unit.cumulative(t)),
                               atol=1e-6)
    peak = float(np.max(unit.exit_age(np.linspace(0.01, 60.0, 400))))
    np.testing.assert_allclose(np.asarray(table.exit_age(t)), np.asarray(unit.exit_age(t)),
                               atol=1e-5 * peak)
    # The ramp response from the Hermite rule against the unit's exact ramp.
    np.testing.assert_allclose(np.asarray(table.ramp_response(t)),
                               np.asarray(unit.ramp_response(t)), atol=1e-6 * 60.0)


@pytest.mark.study
def test_conservative_window_of_an_exchange_fit_on_tables_equals_the_exact_samples():
    """The samples' tables against each sample evaluated on the unit itself (minutes)."""
    import axialmix.line._diversion as diversion

    names = ("tau", "peclet", "beta", "k_d")
    values = np.array([EXCHANGE[n] for n in names])
    covariance = np.diag((0.03 * values) ** 2)
    factory = FittedRTD.from_parameters("closed_closed_exchange", EXCHANGE, free=names,
                                        covariance=covariance)
    disturbance = Disturbance.square(20.0, 3.0, 1.0, value_unit="%")
    times = np.linspace(0.0, 60.0, 401)
    limits = {"target": 100.0, "lower": 95.0, "upper": 105.0}
    tabled = conservative_diversion_window(factory, values, covariance, disturbance, times,
                                           samples=64, seed=1, **limits)
    assert tabled.table_intervals is not None
    assert tabled.table_difference <= diversion.TABLE_TOLERANCE * 10.0
    # The nominal window on its fine table against roots located on the unit itself.
    nominal = tabled.nominal
    assert nominal.table_error < 1e-6
    exact_unit = factory(values)
    for end in (float(nominal.start), float(nominal.stop)):
        outlet = float(100.0 + outlet_response(exact_unit, disturbance, [end]).outlet[0])
        assert min(abs(outlet - 95.0), abs(outlet - 105.0)) < 1e-7
    original = diversion._choose_table
    try:
        diversion._choose_table = lambda *args: (None, float("nan"), float("nan"))
        exact = conservative_diversion_window(factory, values, covariance, disturbance, times,
                                              samples=64, seed=1, **limits)
    finally:
        diversion._choose_table = original
    length = float(exact.stop - exact.start)
    print(f"\ntables ({tabled.table_intervals} intervals): {float(tabled.start):.9f}–"
          f"{float(tabled.stop):.9f}; exact samples: {float(exact.start):.9f}–"
          f"{float(exact.stop):.9f}")
    assert abs(float(tabled.start - exact.start)) < 1e-4 * length
    assert abs(float(tabled.stop - exact.stop)) < 1e-4 * length


def test_exchange_samples_on_series_tables_equal_those_on_exact_tables(monkeypatch):
    """Each sample's table from the Fourier series (checked at 16 nodes against the exact
    inversion) against the table of its exact values at every node, which a tolerance of 0
    forces for every sample (through the fallback that recomputes missed samples)."""
    import axialmix.line._diversion as diversion

    names = ("tau", "peclet", "beta", "k_d")
    values = np.array([EXCHANGE[n] for n in names])
    covariance = np.diag((0.03 * values) ** 2)
    factory = FittedRTD.from_parameters("closed_closed_exchange", EXCHANGE, free=names,
                                        covariance=covariance)
    disturbance = Disturbance.square(20.0, 3.0, 1.0, value_unit="%")
    times = np.linspace(0.0, 60.0, 401)
    limits = {"target": 100.0, "lower": 95.0, "upper": 105.0}
    series = conservative_diversion_window(factory, values, covariance, disturbance, times,
                                           samples=16, seed=2, **limits)
    assert series.tables.terms is not None and series.tables.exact == 0
    assert series.tables.error <= diversion.FOURIER_TOLERANCE
    assert series.to_dict()["sample_table"]["method"] == "fourier series"
    monkeypatch.setattr(diversion, "FOURIER_TOLERANCE", 0.0)
    exact = conservative_diversion_window(factory, values, covariance, disturbance, times,
                                          samples=16, seed=2, **limits)
    assert exact.tables.exact == 16 and np.isnan(exact.tables.error)
    np.testing.assert_allclose(np.asarray(series.sample_starts), np.asarray(exact.sample_starts),
                               rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(series.sample_stops), np.asarray(exact.sample_stops),
                               rtol=0, atol=1e-6)


@pytest.mark.parametrize("model, values", [
    ("four_compartment", {"k_f": 1.358, "k_r": 1.359, "k_s": 0.7752, "k_out": 0.8}),
    ("closed_closed", {"tau": 7.0, "peclet": 0.6}),
])
def test_samples_split_among_concurrent_calls_give_the_numbers_of_one_call(monkeypatch, model,
                                                                             values):
    """On the CPU the covariance samples run as one call per core, at once: every sample's
    numbers, and so the conservative window, equal those of one call over all samples, bit
    for bit, whatever the number of calls (448 samples: 7 batches of 64, split 1, 2 and 3
    ways: calls of 4 and 3 batches, with 1 and 2 batches of padding; the split never
    leaves a call of one batch, which rounds differently)."""
    import axialmix.line._diversion as diversion

    names = tuple(values)
    covariance = np.diag((0.05 * np.array([values[n] for n in names])) ** 2)
    fitted = FittedRTD.from_parameters(model, values, free=names, covariance=covariance)
    disturbance = Disturbance.square(20.0, 5.0, 10.0, value_unit="%")
    times = np.linspace(0.0, 60.0, 241)
    limits = {"target": 100.0, "lower": 95.0, "upper": 105.0}
    evaluated = diversion._evaluate_samples
    seen, windows = {}, {}
    for parts in (1, 2, 3):
        monkeypatch.setattr(diversion, "_cpu_parts", lambda batches, parts=parts: parts)

        def record(*arguments, parts=parts, **keywords):
            seen[parts] = evaluated(*arguments, **keywords)
            return seen[parts]

        monkeypatch.setattr(diversion, "_evaluate_samples", record)
        window = conservative_diversion_window(
            fitted, np.array([values[n] for n in names]), covariance, disturbance, times,
            samples=448, seed=5, flow=2.0, **limits)
        windows[parts] = window.to_dict()
    assert all(len(seen[parts][0]) == 448 for parts in seen)
    for parts in (2, 3):
        for one, split in zip(seen[1], seen[parts], strict=True):
            np.testing.assert_array_equal(np.asarray(split), np.asarray(one))
        assert windows[parts] == windows[1]
    # A window that diverts, wider than the nominal one (the samples decided it).
    conservative, nominal = windows[1]["conservative"], windows[1]["nominal"]
    assert nominal["diverts"]
    assert conservative["start"] < nominal["start"] < nominal["stop"] < conservative["stop"]


def test_samples_run_as_one_call_per_cpu_core_of_two_batches_or_more():
    import os

    import axialmix.line._diversion as diversion

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    on_cpu = jax.default_backend() == "cpu"
    for batches in range(1, 40):
        parts = diversion._cpu_parts(batches)
        assert parts == (max(1, min(cores, batches // 2)) if on_cpu else 1)
        assert parts == 1 or batches // parts >= 2  # never a call of one batch


def test_exact_sample_curves_split_among_concurrent_calls_give_the_numbers_of_one_call(
        monkeypatch):
    """The exact F and E of each sample of an inverted unit (its tables' nodes), as one call
    and as two at once: equal bit for bit (8 samples in 4 batches of 2)."""
    import axialmix.line._diversion as diversion

    names = ("tau", "peclet", "beta", "k_d")
    values = np.array([EXCHANGE[n] for n in names])
    factory = FittedRTD.from_parameters("closed_closed_exchange", EXCHANGE, free=names,
                                        covariance=np.diag((0.03 * values) ** 2))
    vectors = values * np.random.default_rng(4).lognormal(0.0, 0.03, (8, 4))
    nodes = np.linspace(0.0, 30.0, 16)
    curves = {}
    for parts in (1, 2):
        monkeypatch.setattr(diversion, "_cpu_parts", lambda batches, parts=parts: parts)
        curves[parts] = diversion._exact_sample_curves(factory, vectors, nodes, True, 2)
    for one, split in zip(curves[1], curves[2], strict=True):
        assert one.shape == (8, 16)
        np.testing.assert_array_equal(split, one)
    # The curves are those of each sample's own unit (a CDF rising to near 1 by 6 tau).
    assert np.all(np.diff(curves[1][0], axis=1) >= -1e-12)
    assert np.all(curves[1][0][:, -1] > 0.99)
