"""``axialmix funnel`` and ``axialmix divert``: numbers against closed forms, the fit adapter.

A stirred tank has closed forms for both commands: the funnel is ``M (1 - e^{-D/tau})`` and
the outlet after a square disturbance crosses a limit at times given by logarithms. A fit's
JSON record (the layout ``axialmix fit`` writes) becomes the same unit as the model with its
values, and its covariance is ``stderr_i r_ij stderr_j``. Bad input exits 2 on one line and
writes nothing.
"""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from axialmix.line import (
    UNIT_BUILDERS,
    Disturbance,
    FittedRTD,
    Unit,
    conservative_diversion_window,
    diversion_window,
)
from fitting.cli import main
from fitting.cli.funnel import LINE_MODELS, fitted_rtd
from fitting.models import MODELS

TAU = 10.0


def _run(argv, capsys):
    status = main(argv)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def _fit_record(tmp_path, model="adm", values=None, time_unit="min", data="run 7"):
    """A fit record in the layout of ``axialmix fit`` (measurement model parameters included,
    dead time fixed): standard errors 4 % and 12 % of the two model parameters."""
    values = values or {"tau": 2.0, "peclet": 25.0}
    (first, second), (a, b) = values.items(), (0.04, 0.12)
    record = {
        "model": model,
        "data": data,
        "time_unit": time_unit,
        "parameters": {
            first[0]: {"value": first[1], "stderr": a * first[1], "vary": True, "expr": None},
            second[0]: {"value": second[1], "stderr": b * second[1], "vary": True,
                        "expr": None},
            "amplitude": {"value": 1.4, "stderr": 0.04, "vary": True, "expr": None},
            "dead_time": {"value": 0.0, "stderr": None, "vary": False, "expr": None},
        },
        "correlation": {"names": [first[0], second[0], "amplitude"],
                        "matrix": [[1.0, -0.4, 0.8], [-0.4, 1.0, -0.6], [0.8, -0.6, 1.0]]},
    }
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(record))
    return path, record


def test_funnel_command_of_a_stirred_tank_is_its_closed_form(tmp_path, capsys):
    folder = tmp_path / "res"
    out, png = folder / "funnel.json", folder / "funnel.png"
    status, text, _ = _run(["funnel", "--model", "tanks", "--set", f"tau={TAU}", "--set",
                            "n_tanks=1", "--time-unit", "min", "--durations", "1,5,20",
                            "--magnitudes", "5,-10", "--out", str(folder)], capsys)
    assert status == 0
    assert "rows magnitudes" in text
    assert sorted(p.name for p in folder.iterdir()) == [".axialmix-funnel", "funnel.json",
                                                         "funnel.png"]
    record = json.loads(out.read_text())
    durations, magnitudes = np.array([1.0, 5.0, 20.0]), np.array([5.0, -10.0])
    expected = magnitudes[:, None] * -np.expm1(-durations / TAU)[None, :]
    np.testing.assert_allclose(record["max_deviation"], expected, rtol=1e-12)
    assert record["durations"] == durations.tolist()
    assert record["magnitudes"] == magnitudes.tolist()
    assert (record["time_unit"], record["magnitude_unit"]) == ("min", "%")
    assert (record["rows"], record["columns"]) == ("magnitudes", "durations")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_funnel_command_from_a_fit_uses_its_values_and_time_unit(tmp_path, capsys):
    # The same compiled funnel as above (tanks in minutes, labelled "tanks", three durations,
    # two magnitudes).
    path, _ = _fit_record(tmp_path, "tanks", {"tau": 4.0, "n_tanks": 1.0}, data="tanks")
    out = tmp_path / "res"
    status, _, _ = _run(["funnel", "--model", str(path), "--durations", "0.5,3,9",
                         "--magnitudes", "10,1", "--out", str(out)], capsys)
    assert status == 0
    record = json.loads((out / "funnel.json").read_text())
    durations = np.array([0.5, 3.0, 9.0])
    np.testing.assert_allclose(record["max_deviation"][0], 10 * -np.expm1(-durations / 4.0),
                               rtol=1e-12)
    assert record["time_unit"] == "min"
    assert record["parameters"]["tau"] == {"value": 4.0, "stderr": 0.16}
    assert "amplitude" not in record["parameters"]


def test_fit_models_map_to_units_with_the_same_parameters():
    for name, line_model in LINE_MODELS.items():
        assert MODELS[name].parameter_names == UNIT_BUILDERS[line_model][0], name


@pytest.mark.study
def test_every_fit_model_becomes_a_unit_with_the_fit_models_exit_age():
    # Minutes of compilation (the dead-zone inversions): a study.
    values = {"tau": 4.0, "peclet": 12.0, "n_tanks": 3.0, "beta": 0.3, "k_d": 0.2,
              "tau_tank": 1.0, "k_f": 2.1, "k_r": 1.9, "k_s": 0.6, "k_out": 0.8}
    t = jnp.linspace(0.05, 30.0, 40)
    for name, line_model in LINE_MODELS.items():
        model = MODELS[name]
        parameters = {n: values[n] for n in model.parameter_names}
        record = {"model": name, "time_unit": "s", "correlation": {"names": [], "matrix": []},
                  "parameters": {n: {"value": v, "vary": False} for n, v in parameters.items()}}
        fitted, _ = fitted_rtd(record)
        assert fitted.model == line_model
        reference = np.asarray(model.function(t, {n: jnp.asarray(v)
                                                  for n, v in parameters.items()}))
        # adm-fv fits the same closed-closed ADM by finite volumes; the unit is exact.
        tolerance = 2e-3 if name == "adm-fv" else 1e-9
        np.testing.assert_allclose(fitted.unit().exit_age(t), reference,
                                   atol=tolerance * reference.max(), err_msg=name)


def test_fit_record_covariance_is_the_standard_errors_times_the_correlation(tmp_path):
    _, record = _fit_record(tmp_path)
    fitted, model = fitted_rtd(record, {"peclet": 30.0})
    assert (model, fitted.model, fitted.time_unit) == ("adm", "closed_closed", "min")
    assert fitted.free == ("tau",)
    np.testing.assert_allclose(fitted.covariance, [[0.08**2]])
    assert float(fitted.unit().mean()) == 2.0
    assert float(fitted.values[1]) == 30.0
    both, _ = fitted_rtd(record)
    np.testing.assert_allclose(both.covariance, [[0.08**2, -0.4 * 0.08 * 3.0],
                                                 [-0.4 * 0.08 * 3.0, 3.0**2]])


def _open_open_window(tau, peclet, magnitude, duration, start, delta):
    """Exit and return times of the open-open ADM's outlet after a square disturbance, from
    its E (MODELS.md §2) integrated by adaptive quadrature and bracketed roots (scipy)."""

    def exit_age(t):
        theta = t / tau
        return np.sqrt(peclet / (4 * np.pi * theta)) * np.exp(
            -peclet * (1 - theta) ** 2 / (4 * theta)) / tau

    def cumulative(t):
        return quad(exit_age, 0.0, t, epsabs=1e-14, epsrel=1e-13, limit=200)[0] if t > 0 else 0.0

    def excess(t):
        return magnitude * (cumulative(t - start) - cumulative(t - start - duration)) - delta

    peak = start + duration + 0.5 * tau
    return brentq(excess, start, peak, xtol=1e-13), brentq(excess, peak, start + 20 * tau,
                                                            xtol=1e-13)


def test_divert_command_from_a_fit_is_exact_and_samples_its_covariance(tmp_path, capsys):
    path, _ = _fit_record(tmp_path, "adm-open", {"tau": TAU, "peclet": 20.0}, time_unit="s")
    out = tmp_path / "res"
    status, text, _ = _run(["divert", "--model", str(path), "--disturbance",
                            "square:magnitude=20,duration=15,start=5", "--flow", "36",
                            "--points", "301", "--samples", "16", "--coverage", "0.9",
                            "--seed", "3", "--out", str(out)], capsys)
    assert status == 0
    assert "conservative (90%" in text
    assert (out / "divert.png").read_bytes()[:4] == b"\x89PNG"
    record = json.loads((out / "divert.json").read_text())
    start, stop = _open_open_window(TAU, 20.0, 20.0, 15.0, 5.0, 5.0)
    nominal = record["nominal"]
    assert nominal["start"] == pytest.approx(start, rel=1e-10)
    assert nominal["stop"] == pytest.approx(stop, rel=1e-10)
    # 36 kg/h is 0.01 kg/s.
    assert nominal["diverted_amount"] == pytest.approx(0.01 * (stop - start), rel=1e-10)
    assert (record["lower"], record["upper"], nominal["amount_unit"]) == (95.0, 105.0, "kg")
    # The same conservative window from the library, with the covariance of log tau and
    # log Pe written out from the standard errors (4 %, 12 %) and their correlation -0.4.
    log_covariance = np.array([[0.04**2, -0.4 * 0.04 * 0.12], [-0.4 * 0.04 * 0.12, 0.12**2]])
    values = np.array([TAU, 20.0])
    fitted = FittedRTD.from_parameters("open_open", {"tau": TAU, "peclet": 20.0},
                                       free=("tau", "peclet"), name="run 7",
                                       covariance=log_covariance * np.outer(values, values))
    window = conservative_diversion_window(
        fitted, values, log_covariance, Disturbance.square(20.0, 15.0, 5.0, value_unit="%"),
        np.linspace(0.0, record["scan"]["end"], 301), target=100.0, lower=95.0, upper=105.0,
        flow=0.01, coverage=0.9, samples=16, seed=3, scale="log", content_unit="%",
        amount_unit="kg")
    conservative = record["conservative"]
    assert conservative["start"] == pytest.approx(float(window.start), rel=1e-12)
    assert conservative["stop"] == pytest.approx(float(window.stop), rel=1e-12)
    assert conservative["start"] < nominal["start"] and conservative["stop"] > nominal["stop"]
    assert (conservative["scale"], conservative["samples"]) == ("log", 16)


@pytest.mark.study
def test_divert_command_reads_a_feeder_trace(tmp_path, capsys):
    # A feeder trace rising linearly from 100 to 120 % between 10 and 20 s, then held: the
    # ramp disturbance of 20 % over 10 s from 10 s, exactly. (Ten seconds of compilation of
    # the tanks' ramp response, whose incomplete gamma function is costly: a study.)
    trace = tmp_path / "feeder.csv"
    trace.write_text("time (s),content (%)\n0,100\n10,100\n20,120\n60,120\n")
    out = tmp_path / "res"
    status, _, _ = _run(["divert", "--model", "tanks", "--set", "tau=5", "--set", "n_tanks=3",
                         "--trace", str(trace), "--until", "60", "--points", "241",
                         "--out", str(out)], capsys)
    assert status == 0
    window = diversion_window(Unit.tanks(5.0, 3.0), Disturbance.ramp(20.0, 10.0, 10.0),
                              np.linspace(0.0, 60.0, 241), target=100.0, lower=95.0,
                              upper=105.0)
    record = json.loads((out / "divert.json").read_text())
    assert record["nominal"]["start"] == pytest.approx(float(window.start), rel=1e-12)
    assert record["nominal"]["stop"] == "inf"
    assert record["disturbance"] == {"kind": "trace", "file": str(trace), "samples": 4}


BAD = [
    (["funnel", "--model", "nope", "--durations", "1", "--magnitudes", "1"], "no such model"),
    (["funnel", "--model", "tanks", "--set", "tau=1", "--durations", "1", "--magnitudes", "1"],
     "needs --set for n_tanks"),
    (["funnel", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2", "--set", "pe=3",
      "--durations", "1", "--magnitudes", "1"], "--set pe"),
    (["funnel", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2", "--durations",
      "1,-2", "--magnitudes", "1"], "--durations"),
    (["funnel", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2", "--durations",
      "1", "--magnitudes", "1,x"], "--magnitudes"),
    (["funnel", "--model", "tanks", "--set", "tau=0", "--set", "n_tanks=2", "--durations",
      "1", "--magnitudes", "1"], "tau must be positive"),
    (["funnel", "--model", "{fit}", "--set", "tau=1", "--durations", "1", "--magnitudes", "1",
      "--time-unit", "h"], "--time-unit h"),
    (["funnel", "--model", "{fit}", "--set", "k_d=1", "--durations", "1", "--magnitudes", "1"],
     "--set k_d"),
    (["funnel", "--model", "{network}", "--durations", "1", "--magnitudes", "1"],
     "not the JSON record of a fit"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--disturbance", "wave:magnitude=1"], "unknown kind"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--disturbance", "square:magnitude=1"], "needs duration"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--disturbance", "step:magnitude=1", "--limits", "2,5"], "do not contain the target"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--disturbance", "step:magnitude=1", "--coverage", "1.5"], "--coverage"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--trace", "{trace}"], "does not increase"),
    (["divert", "--model", "tanks", "--set", "tau=1", "--set", "n_tanks=2",
      "--trace", "{minutes}"], "times are in min, the RTD in s"),
    # A pulse through the ADM at Pe 1000 comes out about 4 s wide (a spread of 1.79 s): a
    # scan of two hours at 2001 points (3.6 s apart) stepped over its excursion and said
    # "no diversion"; the same scan to its default end finds start 43.54 s, stop 46.27 s.
    (["divert", "--model", "adm", "--set", "tau=40", "--set", "peclet=1000",
      "--disturbance", "pulse:amount=30,at=5", "--flow", "30", "--until", "7200"],
     "more than a quarter of the RTD's spread"),
]


@pytest.mark.parametrize("argv, words", BAD, ids=[f"{a[0]}-{w}" for a, w in BAD])
def test_bad_input_exits_2_on_one_line_and_writes_nothing(argv, words, tmp_path, capsys):
    fit, _ = _fit_record(tmp_path)
    network = tmp_path / "network.json"
    network.write_text(json.dumps({"compartments": ["A", "B"]}))
    trace = tmp_path / "trace.csv"
    trace.write_text("time,content\n0,100\n5,101\n5,102\n")
    minutes = tmp_path / "minutes.csv"
    minutes.write_text("time (min),content (%)\n0,100\n5,101\n")
    out = tmp_path / "out"
    argv = [a.format(fit=fit, network=network, trace=trace, minutes=minutes) for a in argv] + [
        "--out", str(out)]
    status, _, err = _run(argv, capsys)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"axialmix {argv[0]}: error:")
    assert words in lines[0]
    assert not out.exists()


@pytest.mark.parametrize("kind", ["curves", "fits"])  # a study's summary, a folder's
def test_funnel_takes_one_curve_of_a_summary_by_curve(kind, tmp_path, capsys):
    import copy

    _, first = _fit_record(tmp_path, "tanks", {"tau": 4.0, "n_tanks": 1.0}, data="a")
    path, second = _fit_record(tmp_path, "tanks", {"tau": 6.0, "n_tanks": 1.0}, data="b")
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({kind: [first, copy.deepcopy(second)]}))
    argv = ["funnel", "--durations", "0.5,3", "--magnitudes", "10"]
    assert main([*argv, "--model", str(summary), "--curve", "b", "--out",
                 str(tmp_path / "picked")]) == 0
    assert main([*argv, "--model", str(path), "--out", str(tmp_path / "alone")]) == 0
    capsys.readouterr()
    picked = json.loads((tmp_path / "picked" / "funnel.json").read_text())
    alone = json.loads((tmp_path / "alone" / "funnel.json").read_text())
    assert picked["max_deviation"] == alone["max_deviation"]
    assert picked["parameters"]["tau"]["value"] == 6.0
    for extra, words in ((["--curve", "zz"], "--curve zz: no such curve"),
                         ([], "a summary of 2 fits; choose one with --curve ID (a, b)")):
        status, _, err = _run([*argv, "--model", str(summary), *extra], capsys)
        assert status == 2 and words in err and len(err.strip().splitlines()) == 1, err
