"""The line's compiled programs: network curves propagated along grids, program identities,
and ``divert``/``funnel`` programs kept across processes.

A network's E, F and ramp response on a uniform grid (powers of one exponential) equal the
curves evaluated time by time, to round-off, also before the origin; the outlet response on
a grid equals the one at each time, for networks and closed-form units alike. A program's
identity names its static values stably and refuses a model it cannot name. With the
cache on, a second ``divert`` (and ``funnel``) process prints the same and traces none of
the line's programs: they come from the exported files the first one wrote.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.special import gammaincinv

from axialmix.line import (
    CLOSED_CLOSED,
    Disturbance,
    FittedRTD,
    Unit,
    UnitModel,
    program_identity,
)
from axialmix.line._disturbance import grid_curve, response_at, response_on_grid
from axialmix.line._diversion import _window_program, chi_square_quantile

RATES = {"k_f": 1.36, "k_r": 1.36, "k_s": 0.78, "k_out": 0.8}


def _network():
    return FittedRTD.from_parameters("four_compartment", RATES,
                                     free=("k_f", "k_r", "k_s")).unit()


@pytest.mark.parametrize("kind, method", [("exit_age", "exit_age"),
                                          ("cumulative", "cumulative"),
                                          ("ramp", "ramp_response")])
@pytest.mark.parametrize("first, count", [(-3.3, 700), (0.0, 3), (0.4, 1), (-50.0, 40)])
def test_network_curves_on_a_grid_equal_those_at_each_time(kind, method, first, count):
    unit = _network()
    step = 0.043
    times = first + step * np.arange(count)
    on_grid = np.asarray(grid_curve(unit, kind, first, step, count))
    each = np.asarray(getattr(unit, method)(times))
    scale = max(np.abs(each).max(), 1e-300)
    np.testing.assert_allclose(on_grid, each, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("unit", [_network(), Unit.closed_closed(7.0, 8.0)],
                         ids=["network", "closed-closed"])
def test_the_outlet_on_a_grid_equals_the_outlet_at_each_time(unit):
    disturbance = (Disturbance.square(20.0, 5.0, 10.0) + Disturbance.pulse(3.0, 4.0)
                   + Disturbance.ramp(5.0, 3.0, 2.0))
    step, count = 0.05, 900
    times = step * np.arange(count)
    on_grid = np.asarray(response_on_grid(unit, disturbance, 0.0, step, count))
    each = np.asarray(response_at(unit, disturbance, times))
    np.testing.assert_allclose(on_grid, each, rtol=0, atol=1e-10 * np.abs(each).max())


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 7])
@pytest.mark.parametrize("probability", [0.5, 0.9, 0.95, 0.99])
def test_chi_square_quantile_is_scipys(dof, probability):
    expected = 2.0 * gammaincinv(dof / 2.0, probability)
    assert chi_square_quantile(dof, probability) == pytest.approx(expected, rel=1e-13)


def _window_arguments(unit, magnitude=20.0):
    return (unit, Disturbance.square(magnitude, 5.0, 10.0), np.linspace(0.0, 60.0, 101),
            np.asarray(100.0), np.asarray(95.0), np.asarray(105.0), np.asarray(1.0), 101)


def test_a_program_identity_names_the_static_values_and_refuses_a_model_it_cannot_name():
    first = program_identity(_window_program, _window_arguments(_network()))
    # The same structure and static values in another call (other array values): the same.
    again = program_identity(_window_program, _window_arguments(_network(), 30.0))
    assert first is not None and first == again
    assert all(isinstance(part, str) and "0x" not in part for part in first)
    # Another model, another static count: another identity.
    other = program_identity(_window_program, _window_arguments(Unit.closed_closed(7.0, 8.0)))
    assert other not in (None, first)
    changed = (*_window_arguments(_network())[:-1], 51)
    assert program_identity(_window_program, changed) != first
    # A model of the user's own (the built-in functions under another name) has no identity.
    mine = UnitModel(name="mine", parameter_names=("tau", "peclet"),
                     exit_age=CLOSED_CLOSED.exit_age, cumulative=CLOSED_CLOSED.cumulative)
    unit = Unit.from_model(mine, {"tau": 7.0, "peclet": 8.0})
    assert program_identity(_window_program, _window_arguments(unit)) is None


def _fit_record(path):
    record = {
        "model": "four-compartment", "data": "horizontal", "time_unit": "s",
        "parameters": {
            **{name: {"value": value, "stderr": 0.1 * value, "vary": name != "k_out",
                      "expr": None} for name, value in RATES.items()},
        },
        "correlation": {"names": ["k_f", "k_r", "k_s"],
                        "matrix": [[1.0, 0.5, -0.3], [0.5, 1.0, -0.2], [-0.3, -0.2, 1.0]]},
    }
    path.write_text(json.dumps(record))
    return path


def _traced_line_programs(stderr: str) -> list[str]:
    names = ("_window_program", "_settle_program", "_drawn_settle", "_sample_windows",
             "_moments_program", "_funnel_program")
    return [line for line in stderr.splitlines()
            if "Finished tracing" in line and any(name in line for name in names)]


def test_a_second_process_loads_the_divert_and_funnel_programs_from_the_cache(tmp_path):
    record = _fit_record(tmp_path / "fit.json")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home"),
           "AXIALMIX_COMPILATION_CACHE": "on", "JAX_LOG_COMPILES": "1"}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    commands = {
        "divert": ["divert", "--model", str(record), "--disturbance",
                   "square:magnitude=20,start=10,duration=5", "--points", "401",
                   "--samples", "64"],
        "funnel": ["funnel", "--model", str(record), "--durations", "1,5,20",
                   "--magnitudes", "5,10"],
    }
    for name, argv in commands.items():
        runs = [subprocess.run([sys.executable, "-c", "import sys; from fitting.cli import "
                                "main; sys.exit(main(sys.argv[1:]))", *argv], env=env,
                               capture_output=True, text=True, timeout=600)
                for _ in range(2)]
        for run in runs:
            assert run.returncode == 0, run.stderr[-2000:]
        first, second = runs
        assert first.stdout == second.stdout
        assert _traced_line_programs(first.stderr), name  # the first run traced them
        assert _traced_line_programs(second.stderr) == [], name
        exported = list((tmp_path / "home" / "axialmix" / "solvers").glob("*.jaxexport"))
        assert any(f"-{name}-" in path.name for path in exported), name
