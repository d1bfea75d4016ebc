"""Real tracer files through ``axialmix fit``: noise below zero, decimal commas, column choice,
sparse and cut curves, measured inlet files, freed measurement parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed
from fitting.cli import main
from fitting.data import NEGATIVE_FRACTION, DataError, read_inlet_csv, read_rtd_csv

TAU, PECLET, AMPLITUDE = 40.0, 8.0, 3.7
TIME = np.linspace(0.0, 3 * TAU, 25)
CLEAN = AMPLITUDE * np.asarray(exit_age_closed(TIME, TAU, PECLET))
PEAK = float(CLEAN.max())


def _text(time, values, header="time_s,concentration", delimiter=",", decimal="."):
    rows = []
    for t, v in zip(time, values, strict=True):
        cells = [f"{t:.12g}", f"{v:.12g}"]
        rows.append(delimiter.join(c.replace(".", decimal) for c in cells))
    return header + "\n" + "\n".join(rows) + "\n"


def _run(tmp_path, name, text, *options):
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    out = tmp_path / f"out_{name}"
    status = main(["fit", str(path), *options, "--out", str(out)])
    record = json.loads((out / f"{name}.json").read_text()) if status == 0 else None
    return status, record, out, path


def test_noise_dipping_to_two_percent_below_zero_is_fitted(tmp_path, capsys):
    rng = np.random.default_rng(4)
    noisy = CLEAN + 0.005 * PEAK * rng.standard_normal(TIME.size)
    noisy[-2] = -0.02 * PEAK
    status, record, _, _ = _run(tmp_path, "dip", _text(TIME, noisy))
    capsys.readouterr()
    assert status == 0 and record["converged"]
    low, high = record["parameters"]["tau"]["ci95"]
    assert low <= TAU <= high


def test_a_value_thirty_percent_below_zero_is_refused_with_one_line(tmp_path, capsys):
    values = CLEAN.copy()
    values[12] = -0.30 * PEAK
    status, _, out, path = _run(tmp_path, "gross", _text(TIME, values))
    captured = capsys.readouterr()
    assert status == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    # Row 14 of the file: header on row 1, the 13th sample (index 12) on row 14.
    assert lines[0].startswith(f"axialmix fit: error: {path}:14: negative value -")
    assert "% of the peak" in lines[0]
    assert not out.exists()


def test_the_negative_threshold_is_at_least_five_percent_of_the_peak(tmp_path):
    # The limit follows the curve's noise (fitting.data.negative_limit) but never falls
    # below 5 % of the peak, nor reaches 25 %.
    assert NEGATIVE_FRACTION == 0.05
    for fraction, accepted in ((0.049, True), (0.26, False)):
        values = CLEAN.copy()
        values[-1] = -fraction * PEAK
        path = tmp_path / f"edge{fraction}.csv"
        path.write_text(_text(TIME, values))
        if accepted:
            assert read_rtd_csv(path, normalise=False).value[-1] == pytest.approx(-fraction * PEAK)
        else:
            with pytest.raises(DataError, match="negative value"):
                read_rtd_csv(path, normalise=False)


def test_decimal_commas_are_detected_and_forced(tmp_path, capsys):
    text = _text(TIME, CLEAN, header="tiempo_s;c", delimiter=";", decimal=",")
    detected, record, _, _ = _run(tmp_path, "european", text, "--time-column", "0")
    assert detected == 0
    assert record["parameters"]["tau"]["value"] == pytest.approx(TAU, rel=1e-6)
    forced, again, _, _ = _run(tmp_path, "european2", text, "--decimal", ",",
                               "--time-column", "tiempo_s")
    capsys.readouterr()
    assert forced == 0
    assert again["parameters"]["peclet"]["value"] == pytest.approx(PECLET, rel=1e-6)


def test_value_column_picks_one_of_several(tmp_path, capsys):
    lines = ["time_s,ch1,ch2"] + [f"{t:.12g},{9.0:.12g},{v:.12g}" for t, v in
                                   zip(TIME, CLEAN, strict=True)]
    text = "\n".join(lines) + "\n"
    refused, _, _, _ = _run(tmp_path, "many", text)
    assert refused == 2 and "--value-column" in capsys.readouterr().err
    status, record, _, _ = _run(tmp_path, "many2", text, "--value-column", "ch2")
    capsys.readouterr()
    assert status == 0
    assert record["parameters"]["tau"]["value"] == pytest.approx(TAU, rel=1e-6)


def test_sparse_uneven_cut_curve_fits_without_bias_and_warns_as_information(tmp_path, capsys):
    time = np.array([0.0, 6.0, 11.0, 19.0, 24.0, 33.0, 41.0, 52.0, 60.0, 71.0, 80.0])
    values = AMPLITUDE * np.asarray(exit_age_closed(time, TAU, PECLET))
    status, record, _, _ = _run(tmp_path, "sparse", _text(time, values))
    captured = capsys.readouterr()
    assert status == 0
    assert "warning" in captured.err and "never returns to baseline" in captured.err
    assert record["parameters"]["tau"]["value"] == pytest.approx(TAU, rel=1e-6)
    assert record["parameters"]["peclet"]["value"] == pytest.approx(PECLET, rel=1e-6)


def test_inlet_file_in_other_time_unit_is_converted(tmp_path):
    path = tmp_path / "inlet.csv"
    path.write_text("t [min],signal\n0,0\n0.05,1\n0.1,0\n")
    inlet = read_inlet_csv(path, time_unit="s")
    np.testing.assert_allclose(inlet.time, [0.0, 3.0, 6.0])
    assert inlet.time_unit == "s"


def test_measured_inlet_and_freed_measurement_parameters_on_the_command_line(tmp_path,
                                                                             capsys):
    from fitting.models import adm_closed

    inlet_times = np.linspace(0.0, 12.0, 13)
    signal = np.sin(np.pi * inlet_times / 12.0) ** 2
    (tmp_path / "pulse.csv").write_text(_text(inlet_times, signal, header="time_s,signal"))
    area = np.trapezoid(signal, inlet_times)
    outlet = AMPLITUDE * np.asarray(adm_closed.inlet_response(
        TIME, {"tau": TAU, "peclet": PECLET}, inlet_times, signal / area)) + 0.05
    status, record, _, _ = _run(tmp_path, "outlet", _text(TIME, outlet), "--inlet",
                                str(tmp_path / "pulse.csv"), "--free", "b")
    capsys.readouterr()
    assert status == 0
    assert record["measurement"]["inlet"] == "sampled"
    for name, value in (("tau", TAU), ("peclet", PECLET), ("baseline", 0.05)):
        assert record["parameters"][name]["value"] == pytest.approx(value, rel=1e-6), name
    assert record["parameters"]["baseline"]["vary"] is True


@pytest.mark.parametrize(
    ("options", "words"),
    [
        (["--free", "amplitude"], "--free: unknown measurement parameter 'amplitude'"),
        (["--inlet", "nowhere.csv"], "--inlet: nowhere.csv: file not found"),
        (["--grid", "--errors", "combined"], "--grid scores the unweighted loss"),
        (["--value-column", "zz"], "no column named 'zz'"),
    ],
)
def test_bad_new_options_are_one_line_errors_and_write_nothing(tmp_path, capsys, options,
                                                               words):
    status, _, out, _ = _run(tmp_path, "curve", _text(TIME, CLEAN), *options)
    captured = capsys.readouterr()
    assert status == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], captured.err
    assert not out.exists()
