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
