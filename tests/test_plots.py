"""The plots answer their question: the funnel's specification contour lies where a closed
form puts it, the diversion plot marks both windows, the fit plot is in the data's units
with the intervals the fit reports."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from axialmix.line import (  # noqa: E402
    Disturbance,
    Unit,
    conservative_diversion_window,
    diversion_window,
    funnel,
    plot_diversion,
    plot_funnel,
)

TAU = 10.0


def test_the_funnel_map_is_fine_and_its_specification_contour_is_the_closed_form():
    tank = Unit.tanks(TAU, 1.0)
    coarse = funnel(tank, np.array([2.0, 60.0]), np.array([5.0, 20.0]), magnitude_unit="%")
    figure, ax = plt.subplots()
    plot_funnel(coarse, ax=ax, rtd=tank, limit=5.0)
    (contour,) = [c for c in ax.collections if hasattr(c, "levels") and list(c.levels) == [5.0]]
    vertices = np.concatenate([path.vertices for path in contour.get_paths()])
    assert len(vertices) > 50  # drawn on the fine map, not on the 2 x 2 grid asked for
    duration, magnitude = vertices[:, 0], vertices[:, 1]
    # A stirred tank's funnel is M (1 - exp(-d / tau)): the contour is M = 5 / (1 - e^{-d/tau}).
    np.testing.assert_allclose(magnitude, 5.0 / (1 - np.exp(-duration / TAU)), rtol=1e-2)
    assert ax.get_title()
    assert any("5%" in text.get_text() for text in ax.get_legend().get_texts())
    plt.close(figure)


def test_the_diversion_plot_marks_both_windows_and_the_amounts():
    tank = Unit.tanks(TAU, 1.0)
    times = np.linspace(0.0, 120.0, 1201)
    square = Disturbance.square(20.0, 10.0, 15.0)
    window = conservative_diversion_window(
        lambda p: Unit.tanks(p[0], 1.0), np.array([TAU]), np.array([[1.0]]), square, times,
        target=100.0, lower=95.0, upper=105.0, flow=2.0, samples=64, amount_unit="kg")
    figure, ax = plt.subplots()
    plot_diversion(window, ax=ax)
    edges = {round(float(line.get_xdata()[0]), 6) for line in ax.lines
             if len(set(np.atleast_1d(line.get_xdata()))) == 1 and len(line.get_xdata()) == 2}
    for when in (window.nominal.start, window.nominal.stop, window.start, window.stop):
        assert round(float(when), 6) in edges
    texts = " ".join(text.get_text() for text in ax.texts)
    assert f"{float(window.nominal.diverted_amount):.4g} kg diverted" in texts
    assert f"{float(window.diverted_amount):.4g} kg diverted" in texts
    plt.close(figure)
    nominal = diversion_window(tank, square, times, target=100.0, lower=95.0, upper=105.0)
    figure, ax = plt.subplots()
    plot_diversion(nominal, ax=ax)  # a window without uncertainty draws too
    assert "nominal" in " ".join(text.get_text() for text in ax.texts)
    plt.close(figure)


def test_the_fit_figure_is_in_the_units_of_the_data_with_the_fitted_intervals():
    from axialmix import analytic
    from fitting.data import Curve
    from fitting.fit import fit
    from fitting.measurement import Inlet, measured
    from fitting.report import fit_figure

    t = np.linspace(1.0, 150.0, 30)
    signal = 2.5 * np.asarray(analytic.exit_age_closed(t, 40.0, 12.0))  # g/L, raw signal
    curve = Curve("run", t, signal, value_unit="g/L")
    result = fit(measured("adm", Inlet.pulse(), ()), curve)
    spec = fit_figure(result)
    np.testing.assert_array_equal(spec["observed"], signal)  # the data as measured
    values = result.values  # the model in the data's unit: A E(t), not E
    np.testing.assert_allclose(spec["curve"], values["amplitude"] * np.asarray(
        analytic.exit_age_closed(spec["fine"], values["tau"], values["peclet"])),
        rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(spec["residual"], np.asarray(result.predicted) - signal)
    assert "g/L" in spec["ylabel"] and "g/L" in spec["residual_label"]
    for name in ("tau", "peclet"):
        low, high = result.ci95[name]
        line = next(line for line in spec["annotation"].splitlines()
                    if line.startswith(name + " "))
        assert line.endswith(f"95 % [{low:.3g}, {high:.3g}]")
    assert "amplitude" not in spec["annotation"]  # the detector's, not the mixer's
