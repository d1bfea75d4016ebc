"""The combined error model on a curve its model does not describe, through ``axialmix fit``.

The combined error model reads the size of the noise from the residuals; when the model does
not describe the curve, the residuals are misfit, large where the model is large, and the
iterated weights would read them as proportional noise and pull the fit off the peak, further
each pass. A symmetric Gaussian pulse (no noise) is such a curve for the closed-closed ADM,
whose curves are skewed: the fit command must keep the unweighted fit, say why, and still
flag the lack of fit.
"""

from __future__ import annotations

import json

import numpy as np

from fitting.cli import main


def _write_gaussian_pulse(path):
    time = np.linspace(0.0, 1.5, 25)  # min (25 points, a shape other tests compile too)
    value = 1000.0 * np.exp(-((time - 0.5) ** 2) / 0.02)  # mg/L
    lines = ["t [min],c [mg/L]"] + [f"{t:.6g},{c:.9g}" for t, c in zip(time, value, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def test_a_curve_the_model_does_not_describe_keeps_its_unweighted_fit(tmp_path):
    curve = tmp_path / "pulse.csv"
    _write_gaussian_pulse(curve)
    records = {}
    for errors in ("absolute", "combined"):
        out = tmp_path / errors
        assert main(["fit", str(curve), "--model", "adm", "--errors", errors,
                     "--out", str(out)]) == 0
        records[errors] = json.loads((out / "pulse.json").read_text())
    absolute, combined = records["absolute"], records["combined"]
    assert combined["lack_of_fit"]["systematic"] and absolute["lack_of_fit"]["systematic"]
    assert combined["error_model"]["kind"] == "absolute"
    assert "not estimated" in combined["error_model"]["note"]
    for name in ("tau", "peclet", "amplitude"):
        a, c = absolute["parameters"][name]["value"], combined["parameters"][name]["value"]
        assert abs(c / a - 1) < 1e-12, (name, a, c)
    # The area of the samples (the amplitude's meaning) is what the unweighted fit finds,
    # within the misfit: the weighted collapse gave a third of it (0.3 % with 121 points).
    area = 1000.0 * np.sqrt(0.02 * np.pi)
    assert abs(combined["parameters"]["amplitude"]["value"] / area - 1) < 0.05
