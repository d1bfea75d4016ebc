"""ANOVA of study tables: exact balanced-design sums of squares, statsmodels' own tables,
estimability in designs whose factors were never crossed, and one-line errors."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from fitting.study import anova, is_balanced

TABLES = Path(__file__).resolve().parents[1] / "examples" / "source_tables"


def _synthetic_two_way(replicates: int, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for a, b in itertools.product(["a1", "a2", "a3"], ["b1", "b2"]):
        for _ in range(replicates):
            effect = {"a1": 0.0, "a2": 1.0, "a3": 3.0}[a] + {"b1": 0.0, "b2": -2.0}[b]
            rows.append({"A": a, "B": b, "y": effect + rng.normal(0, 0.5)})
    return pd.DataFrame(rows)


def test_balanced_main_effect_sums_of_squares_match_the_textbook_formula():
    frame = _synthetic_two_way(replicates=4)
    table = anova(frame, "y", ["A", "B"], interactions=2)
    grand = frame["y"].mean()
    for factor in ("A", "B"):
        groups = frame.groupby(factor)["y"]
        exact = float((groups.count() * (groups.mean() - grand) ** 2).sum())
        assert table.source(factor).ss == pytest.approx(exact, rel=1e-10)
    cells = frame.groupby(["A", "B"])["y"]
    within = float(((frame["y"] - cells.transform("mean")) ** 2).sum())
    error = table.source("error")
    assert error.ss == pytest.approx(within, rel=1e-10)
    assert error.df == len(frame) - 6
    total = float(((frame["y"] - grand) ** 2).sum())
    assert sum(r.ss for r in table.sources) == pytest.approx(total, rel=1e-10)
    row = table.source("A:B")
    assert row.df == 2
    assert row.p == pytest.approx(stats.f.sf(row.F, 2, error.df), rel=1e-12)
    assert table.balanced


@pytest.mark.parametrize("ss_type", [1, 2])
def test_agrees_with_statsmodels_anova_lm_on_the_source_table(ss_type):
    import statsmodels.formula.api as smf
    from statsmodels.stats.anova import anova_lm

    frame = pd.read_csv(TABLES / "mixer2_variance.csv", comment="#")
    # Unbalanced but fully crossed: the angles run with both lactose grades.
    frame = frame[frame["angle"].isin(["downward", "horizontal", "upward"])]
    ours = anova(frame, "variance", ["angle", "cohesion"], interactions=2, ss_type=ss_type)
    fitted = smf.ols("variance ~ C(angle) + C(cohesion) + C(angle):C(cohesion)", frame).fit()
    theirs = anova_lm(fitted, typ=ss_type)
    for source, label in [("angle", "C(angle)"), ("cohesion", "C(cohesion)"),
                          ("angle:cohesion", "C(angle):C(cohesion)")]:
        assert ours.source(source).ss == pytest.approx(theirs.loc[label, "sum_sq"], rel=1e-9)
        assert ours.source(source).p == pytest.approx(theirs.loc[label, "PR(>F)"], rel=1e-7)
    assert not ours.balanced


def test_partly_crossed_interaction_gets_the_degrees_of_freedom_the_design_can_estimate():
    # Two of five angles were run with one lactose grade only, so the angle x cohesion
    # interaction has (3 - 1) x (2 - 1) = 2 estimable degrees of freedom, not the nominal 4
    # that a column count (statsmodels' anova_lm) would give.
    frame = pd.read_csv(TABLES / "mixer2_variance.csv", comment="#")
    table = anova(frame, "variance", ["angle", "cohesion"], interactions=2)
    assert table.source("angle:cohesion").df == 2
    cells = frame.groupby(["angle", "cohesion"])["variance"]
    within = float(((frame["variance"] - cells.transform("mean")) ** 2).sum())
    assert table.source("error").ss == pytest.approx(within, rel=1e-10)
    assert table.source("error").df == len(frame) - cells.ngroups


def test_interaction_of_factors_never_crossed_is_named_not_estimable():
    frame = pd.read_csv(TABLES / "mixer2_residence.csv", comment="#")
    table = anova(frame, "residence_time_s", ["angle", "rpm"], interactions=2)
    assert table.not_estimable == ("angle:rpm",)
    assert [r.source for r in table.sources] == ["angle", "rpm", "error"]
    assert "never crossed" in table.statement


def test_unreplicated_full_model_is_refused():
    frame = pd.read_csv(TABLES / "mixer1_variance.csv", comment="#")
    assert is_balanced(frame, ["angle", "rpm", "cohesion"])
    with pytest.raises(ValueError, match="leaving none for error"):
        anova(frame, "variance", ["angle", "rpm", "cohesion"], interactions=3)
    table = anova(frame, "variance", ["angle", "rpm", "cohesion"], interactions=2)
    assert table.source("error").df == 2  # the three-way interaction is the error term


def test_numeric_factor_is_one_degree_of_freedom_of_linear_trend():
    frame = _synthetic_two_way(replicates=3)
    frame["speed"] = frame["B"].map({"b1": 50.0, "b2": 100.0})
    table = anova(frame, "y", ["A", "speed"], numeric=["speed"])
    assert table.source("speed").df == 1
    slope = stats.linregress(frame["speed"], frame["y"] - frame.groupby("A")["y"]
                             .transform("mean"))
    assert slope.slope < 0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"response": "nope", "factors": ["A"]}, "no column 'nope'"),
        ({"response": "y", "factors": ["A"], "interactions": 2}, "interactions must be"),
        ({"response": "y", "factors": ["A"], "ss_type": 4}, "ss_type must be"),
        ({"response": "y", "factors": ["A", "A"]}, "listed twice"),
        ({"response": "y", "factors": ["C"]}, "single level"),
    ],
)
def test_bad_requests_are_refused_in_one_line(kwargs, message):
    frame = _synthetic_two_way(replicates=2)
    frame["C"] = "same"
    with pytest.raises(ValueError, match=message) as info:
        anova(frame, **kwargs)
    assert "\n" not in str(info.value)
