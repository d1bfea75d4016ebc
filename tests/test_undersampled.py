"""A curve whose samples do not trace its shape (a sharp peak caught by one sample) must not
be called determined, through ``axialmix fit`` on a CSV file in raw units.

The truth: the closed-closed ADM at tau = 60 s, Pe = 1000 (a peak about 2.7 s wide) and an
amplitude of 350 mV·s, with noise of 0.2 mV. Sampled every 20 s, one sample lies on the
peak; the fit then finds a wider curve through it (Pe 185 ± 27, amplitude 919 ± 106: linearised
intervals that exclude the truth), which must not be called determined. Sampled every 0.5 s,
the same curve is traced and its parameters are determined (intervals that hold the truth).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from axialmix.analytic.closed import exit_age_closed
from fitting.cli import main
from fitting.diagnostics import points_on_curve

TAU, PECLET, AMPLITUDE = 60.0, 1000.0, 350.0


#: The peak sampled every 20 s, with noise of 0.2 mV (one draw, kept as a lab's file would
#: be): one sample, at 60 s, lies on the peak.
SPARSE = """time (s),signal (mV)
20,0.097505117
40,0.20837473
60,53.331756
80,0.23482817
100,-0.11893333
120,0.10432961
140,0.014676456
160,-0.074849019
180,-0.46690765
200,-0.27272981
220,0.30037909
240,-0.28743708
"""


def _fit(tmp_path, text: str) -> dict:
    path = tmp_path / "peak.csv"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["fit", str(path), "--model", "adm", "--out", str(out)]) == 0
    return json.loads((out / "peak.json").read_text())


def test_a_peak_caught_by_one_sample_leaves_every_parameter_undetermined(tmp_path):
    record = _fit(tmp_path, SPARSE)
    assert record["converged"]
    statements = record["identifiability"]
    assert any(s.startswith("Only 1 of the 12 points lies on the fitted curve")
               for s in statements), statements
    assert "Not determined by this curve: tau, peclet, amplitude;" in " ".join(statements)
    assert not any("are determined by this curve" in s for s in statements)
    # What the statement guards against: linearised intervals that miss the truth.
    assert record["parameters"]["peclet"]["ci95"][1] < PECLET
    assert record["parameters"]["amplitude"]["ci95"][0] > 2 * AMPLITUDE


def test_the_same_peak_sampled_densely_is_determined(tmp_path):
    time = np.arange(0.5, 240.25, 0.5)
    signal = AMPLITUDE * np.asarray(exit_age_closed(time, TAU, PECLET))
    signal = signal + 0.2 * np.random.default_rng(1).standard_normal(time.size)
    record = _fit(tmp_path, "time (s),signal (mV)\n" + "".join(
        f"{t:.6g},{c:.9g}\n" for t, c in zip(time, signal, strict=True)))
    statements = record["identifiability"]
    assert not any(s.startswith("Only ") for s in statements), statements
    assert any(s.startswith("All fitted parameters are determined") for s in statements)
    for name, truth in (("tau", TAU), ("peclet", PECLET), ("amplitude", AMPLITUDE)):
        low, high = record["parameters"][name]["ci95"]
        assert low <= truth <= high, (name, low, high)


@pytest.mark.parametrize(("values", "expected"), [
    ([0.0, 0.0, 10.0, 0.0], 1),           # one sample on the peak
    ([5.0, 5.0, 15.0, 5.2], 1),           # the same on a baseline of 5
    ([0.0, 0.4, 10.0, 0.6, 0.0], 2),      # 4 % and 6 % of the height: the second counts
    ([3.0, 3.0, 3.0], 0),                 # a flat model traces nothing
])
def test_points_on_the_curve_are_counted_above_its_baseline(values, expected):
    class Fitted:  # the two arrays points_on_curve reads from a fit result
        predicted = np.asarray(values)
        weights = np.ones(len(values))

    assert points_on_curve(Fitted()) == expected
