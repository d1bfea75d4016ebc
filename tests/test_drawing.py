"""The fit plot's drawing process: the same PNG bytes as drawing in this process, and a
fallback to this process when it fails."""

import numpy as np
import pytest

from fitting import drawing


def _spec(**changes):
    time = np.linspace(0.5, 10.0, 12)
    fine = np.linspace(0.05, 10.5, 50)
    spec = {
        "time": time, "observed": np.exp(-time / 3) / 3, "fine": fine,
        "curve": np.exp(-fine / 3) / 3, "grid_curve": None,
        "residual": 1e-3 * np.sin(time), "data_label": "data", "fit_label": "fit (tanks)",
        "grid_label": "", "ylabel": "E (1/s)", "title": "curve: model tanks",
        "annotation": "tau = 3 s, 95 % [2.9, 3.1]\nn = 1",
        "residual_label": "residual", "xlabel": "time (s)", "thinned": False,
    }
    spec.update(changes)
    return spec


@pytest.fixture
def worker():
    drawing.start_worker()
    yield drawing._worker
    drawing.stop_worker()


def test_the_drawing_process_draws_the_same_bytes(worker):
    assert worker is not None
    here = drawing.draw_fit(_spec())
    there = drawing.draw(_spec())
    assert there[:8] == b"\x89PNG\r\n\x1a\n"
    assert there == here
    assert drawing._worker is worker  # still running, for the next figure
    assert drawing.draw(_spec(title="second")) == drawing.draw_fit(_spec(title="second"))


def test_a_figure_that_fails_there_is_drawn_here_with_its_error(worker):
    bad = _spec(curve=np.ones(3))  # x and y of different lengths
    with pytest.raises(ValueError, match="same first dimension"):
        drawing.draw(bad)
    assert drawing._worker is None  # not used again after a failure


def test_a_drawing_process_that_died_falls_back_to_this_process(worker):
    worker.process.kill()
    worker.process.wait()
    assert drawing.draw(_spec()) == drawing.draw_fit(_spec())
    assert drawing._worker is None


def _hidden_points(figure):
    """The drawn points and curve vertices of the top panel under its legend's box, after the
    whole figure is drawn (as saved)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    top = figure.axes[0]
    box = top.get_legend().get_window_extent(canvas.get_renderer())
    hidden = 0
    for line in top.get_lines():
        shown = top.transData.transform(np.asarray(line.get_xydata(), float))
        hidden += int(np.sum((shown[:, 0] > box.x0) & (shown[:, 0] < box.x1)
                             & (shown[:, 1] > box.y0) & (shown[:, 1] < box.y1)))
    return hidden, box, top


def test_the_legend_with_the_parameters_hides_no_point_of_a_late_falling_curve():
    # A sparse curve cut on its falling side: the top right, where a box in a fixed corner
    # went, holds data. The box must find room that hides nothing.
    time = np.linspace(0.0, 9.6, 14)
    fine = np.linspace(0.0, 10.1, 300)
    shape = lambda t: 350 * (t / 4.5) ** 3 * np.exp(3 * (1 - t / 4.5))  # noqa: E731
    spec = _spec(time=time, observed=shape(time), fine=fine, curve=shape(fine),
                 residual=np.zeros(time.size),
                 annotation="tau = 6.18 min, 95 % [5.94, 6.43]\npeclet = 7.301, 95 % "
                 "[6.35, 8.39]\nerrors: combined")
    hidden, _, top = _hidden_points(drawing.fit_figure(spec))
    assert hidden == 0
    assert top.get_ylim()[1] < 1.1 * 350 * 1.05  # room found without raising the panel


def test_a_panel_full_of_data_is_raised_to_make_room_for_the_legend():
    rng = np.random.default_rng(0)
    time = np.sort(rng.uniform(0, 10, 400))
    observed = rng.uniform(0, 100, 400)
    spec = _spec(time=time, observed=observed, fine=np.linspace(0, 10, 100),
                 curve=np.full(100, 50.0), residual=observed - 50)
    hidden, box, top = _hidden_points(drawing.fit_figure(spec))
    assert hidden == 0
    low, high = top.get_ylim()
    assert high > 100 + 0.1 * (100 - low)  # raised above the data by about the box
    assert box.y1 > top.transData.transform((0, 100))[1]
