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


def test_noise_that_grows_with_the_model_is_not_called_a_misfit(tmp_path):
    # Noise proportional to the signal: in the tails, where it is small, the residuals of the
    # unweighted fit are those of its fitted values' own error, so their signs run in long
    # stretches and that fit looks systematic. The weighted fit's residuals are noise: the
    # command must give it (no MISFIT), with intervals that hold the truth.
    from axialmix.analytic.closed import exit_age_closed

    tau, peclet = 60.0, 100.0
    time = np.linspace(0.0, 240.0, 301)[1:]  # s
    model = 350.0 * np.asarray(exit_age_closed(time, tau, peclet))  # mV
    folder = tmp_path / "curves"
    folder.mkdir()
    seeds = range(40)
    for seed in seeds:
        noisy = model * (1 + 0.02 * np.random.default_rng(seed).standard_normal(time.size))
        lines = ["time (s),signal (mV)"] + [f"{t:.10g},{c:.10g}" for t, c in
                                             zip(time, noisy, strict=True)]
        (folder / f"s{seed}.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert main(["fit", str(folder), "--model", "adm", "--out", str(out)]) == 0
    covered = {"tau": 0, "peclet": 0}
    for seed in seeds:
        record = json.loads((out / f"s{seed}.json").read_text())
        assert not record["lack_of_fit"]["systematic"], seed
        assert record["error_model"]["kind"] == "combined", seed
        sizes = record["error_model"]  # the noise said to grow with the model
        assert sizes["proportional_sd"] * model.max() > 100 * sizes["additive_sd"]
        for name, truth in (("tau", tau), ("peclet", peclet)):
            low, high = record["parameters"][name]["ci95"]
            covered[name] += low <= truth <= high
    # 95 % intervals: 34 of 40 or fewer happens with probability 1.4 % (binomial). Counting
    # every point as a degree of freedom (far below the peak they hold almost no residual)
    # gave about 80 %.
    assert covered["tau"] >= 35 and covered["peclet"] >= 35, covered
