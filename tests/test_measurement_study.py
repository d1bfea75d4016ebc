"""Studies of the measurement model through ``axialmix fit`` (opt-in: ``pytest --studies``).

* A measured inlet: an outlet made from the exact closed-closed ADM (tau 40 s, Pe 8) and a
  sin² inlet pulse lasting 0.3 tau, convolved by the exact transfer-function inversion of
  :mod:`axialmix.analytic` (an independent route: the fit uses Gauss-Legendre quadrature of
  the exact E); the inlet file holds the pulse with 2 % noise. With ``--inlet`` the fit's
  95 % intervals hold tau and Pe; treating the pulse as ideal is biased.
* A constant background of 10 % of the peak: with ``--free baseline`` tau and Pe lie within
  the intervals of the fit of the same curve without the background; left at 0, the
  lack-of-fit verdict fires.

The exact outlet takes minutes to compile, hence opt-in.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from axialmix.analytic import ClosedClosedADM, exit_age_closed, inlet_response
from fitting.cli import main

pytestmark = pytest.mark.study

TAU, PECLET, AMPLITUDE = 40.0, 8.0, 3.7


def _write(path, time, values, header="time_s,concentration"):
    path.write_text(header + "\n" + "".join(
        f"{t:.17g},{v:.17g}\n" for t, v in zip(time, values, strict=True)))
    return path


def _record(tmp_path, path, *options):
    out = tmp_path / f"out{len(list(tmp_path.iterdir()))}"
    assert main(["fit", str(path), *options, "--out", str(out)]) == 0
    return json.loads((out / f"{path.stem}.json").read_text())


def _fit(tmp_path, path, *options):
    return _record(tmp_path, path, *options)["parameters"]


def _inside(parameters, name, value):
    low, high = parameters[name]["ci95"]
    return low <= value <= high


def test_measured_inlet_recovers_tau_and_peclet_and_an_ideal_pulse_is_biased(tmp_path,
                                                                             capsys):
    rng = np.random.default_rng(3)
    width = 0.3 * TAU
    inlet_times = np.arange(0.0, width + 1e-9, 1.0)
    pulse = np.sin(np.pi * inlet_times / width) ** 2
    time = np.linspace(2.0, 3 * TAU, 30)
    clean = AMPLITUDE * np.asarray(inlet_response(
        ClosedClosedADM(TAU, PECLET), time, inlet_times, pulse / np.trapezoid(pulse, inlet_times),
        after="zero"))
    noisy = clean + np.hypot(0.005 * clean.max(), 0.02 * clean) * rng.standard_normal(time.size)
    outlet = _write(tmp_path / "outlet.csv", time, noisy)
    inlet = _write(tmp_path / "inlet.csv", inlet_times,
                   pulse + 0.02 * rng.standard_normal(pulse.size), "time_s,signal")
    with_inlet = _fit(tmp_path, outlet, "--inlet", str(inlet))
    ideal = _fit(tmp_path, outlet)
    capsys.readouterr()
    print(f"with --inlet: tau {with_inlet['tau']['value']:.3f} {with_inlet['tau']['ci95']}, "
          f"Pe {with_inlet['peclet']['value']:.3f} {with_inlet['peclet']['ci95']}; ideal pulse: "
          f"tau {ideal['tau']['value']:.3f}, Pe {ideal['peclet']['value']:.3f}")
    assert _inside(with_inlet, "tau", TAU) and _inside(with_inlet, "peclet", PECLET)
    assert not _inside(ideal, "tau", TAU) and not _inside(ideal, "peclet", PECLET)


def test_freed_baseline_under_a_background_agrees_with_the_background_free_fit(tmp_path,
                                                                               capsys):
    rng = np.random.default_rng(3)
    time = np.linspace(0.0, 3 * TAU, 30)
    clean = AMPLITUDE * np.asarray(exit_age_closed(time, TAU, PECLET))
    noise = np.hypot(0.005 * clean.max(), 0.02 * clean) * rng.standard_normal(time.size)
    plain = _fit(tmp_path, _write(tmp_path / "plain.csv", time, clean + noise))
    background = _write(tmp_path / "background.csv", time, clean + noise + 0.1 * clean.max())
    freed_record = _record(tmp_path, background, "--free", "baseline")
    ignored_record = _record(tmp_path, background)
    freed, ignored = freed_record["parameters"], ignored_record["parameters"]
    capsys.readouterr()
    print(f"background-free: tau {plain['tau']['value']:.3f} {plain['tau']['ci95']}, Pe "
          f"{plain['peclet']['value']:.3f} {plain['peclet']['ci95']}; baseline freed: tau "
          f"{freed['tau']['value']:.3f}, Pe {freed['peclet']['value']:.3f}, b "
          f"{freed['baseline']['value']:.4g} (true {0.1 * clean.max():.4g}); baseline 0: tau "
          f"{ignored['tau']['value']:.3f}, Pe {ignored['peclet']['value']:.3f}")
    print(f"lack of fit, baseline freed: {freed_record['lack_of_fit']['statement']}")
    print(f"lack of fit, baseline 0: {ignored_record['lack_of_fit']['statement']}")
    assert ignored_record["lack_of_fit"]["systematic"]
    assert not freed_record["lack_of_fit"]["systematic"]
    for name in ("tau", "peclet"):
        assert _inside(plain, name, freed[name]["value"]), name
        assert not _inside(plain, name, ignored[name]["value"]), name
    assert _inside(freed, "baseline", 0.1 * clean.max())
