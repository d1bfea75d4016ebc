"""Other optima of a multi-start fit: starts that ended elsewhere with a loss as low as the
best one's, where a parameter lies outside the best optimum's linearised interval, are said,
and the reported interval is widened to hold them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from axialmix.analytic import exit_age_closed
from fitting.data import read_rtd_csv
from fitting.diagnostics import other_optima
from fitting.fit import fit
from fitting.measurement import measured
from fitting.parameters import Parameter
from fitting.report import identifiability_statements
from fitting.solve import MultiStart

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "incline_plus7p5.csv"


def test_the_four_compartment_twin_is_said_and_its_parameter_not_called_determined():
    # With k_r tied to k_f the RTD is unchanged when k_f and k_s are exchanged: the starts
    # end at both twins, and the interval of one twin's k_s excludes the other's.
    curve = read_rtd_csv(EXAMPLE, normalise=False)
    result = fit(measured("four-compartment"), curve,
                 {"k_out": Parameter(0.8, vary=False, min=0.0),
                  "k_r": Parameter(1.0, expr="k_f", min=0.0)},
                 errors="combined", multistart=MultiStart(n_starts=8))
    optima = other_optima(result)
    assert optima, result.start_losses
    best = float(np.min(result.start_losses))
    for optimum in optima:
        assert optimum.loss <= best * (1 + 2.6**2 / (result.n_points - 3))
        for name in optimum.outside:
            # Outside the best optimum's linearised interval, inside the reported one, which
            # says how it was found.
            low, high = result.linearised_intervals[name]
            assert not low <= optimum.values[name] <= high
            low, high = result.ci95[name]
            assert low <= optimum.values[name] <= high
            assert name in result.joined
            assert result.to_dict()["parameters"][name]["interval"] == \
                "linearised and other optima"
    # Exchanging k_f and k_s of the best fit gives the other twin's values.
    twin = optimum_near(optima, result.values["k_s"], result.values["k_f"])
    assert twin is not None
    text = " ".join(identifiability_statements(result))
    assert "Another optimum fits the curve as well" in text
    undetermined = next(s for s in identifiability_statements(result)
                        if s.startswith("Not determined by this curve"))
    for name in optima[0].outside:
        assert name in undetermined


def _same_rate(a, b):
    # Rates past 1e3 1/s are all "instantaneous" for a curve sampled every 0.1 s or so:
    # the loss is flat there, and a twin's huge rate lands anywhere on that plateau.
    return abs(np.log(a / b)) < 0.05 or min(a, b) > 1e3


def optimum_near(optima, k_f, k_s):
    for optimum in optima:
        values = optimum.values
        if _same_rate(values["k_f"], k_f) and _same_rate(values["k_s"], k_s):
            return optimum
    return None


def test_a_fit_with_one_optimum_has_no_other():
    t = np.linspace(0.0, 60.0, 40)
    y = np.asarray(exit_age_closed(t, 10.0, 8.0))
    y = y + 0.01 * y.max() * np.random.default_rng(0).standard_normal(t.size)
    assert other_optima(fit("adm", (t, y))) == []
