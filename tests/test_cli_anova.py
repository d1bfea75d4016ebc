"""``axialmix anova`` through the command line: the source's tables, --log, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from fitting.cli import main
from fitting.study import anova

TABLES = Path(__file__).resolve().parents[1] / "examples" / "source_tables"


def test_source_table_through_the_command_line_is_the_library_s_anova(tmp_path, capsys):
    out = tmp_path / "res"
    table = TABLES / "mixer1_residence.csv"
    status = main(["anova", str(table), "--response", "residence_time_s", "--factors",
                   "angle,rpm", "--interactions", "2", "--out", str(out)])
    assert status == 0
    printed = capsys.readouterr().out
    assert printed.startswith("ANOVA of residence_time_s") and "balanced design" in printed
    written = json.loads((out / "anova.json").read_text())
    frame = pd.read_csv(table, comment="#")
    expected = anova(frame, "residence_time_s", ["angle", "rpm"], interactions=2)
    assert [s["source"] for s in written["sources"]] == ["angle", "rpm", "angle:rpm", "error"]
    for entry in written["sources"]:
        row = expected.source(entry["source"])
        assert entry["df"] == row.df and entry["ss"] == pytest.approx(row.ss, rel=1e-12)
        if entry["source"] != "error":
            assert entry["p"] == pytest.approx(row.p, rel=1e-12)


def test_log_analyses_the_logarithm_of_the_response(tmp_path, capsys):
    table = TABLES / "mixer1_residence.csv"
    out = tmp_path / "res"
    assert main(["anova", str(table), "--response", "residence_time_s", "--factors",
                 "angle,rpm", "--log", "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith("ANOVA of ln(residence_time_s)")
    frame = pd.read_csv(table, comment="#")
    frame["logged"] = frame["residence_time_s"].map(math.log)
    expected = anova(frame, "logged", ["angle", "rpm"])
    written = {s["source"]: s for s in json.loads((out / "anova.json").read_text())["sources"]}
    for source in ("angle", "rpm", "error"):
        assert written[source]["ss"] == pytest.approx(expected.source(source).ss, rel=1e-12)


@pytest.mark.parametrize("rows, options, words", [
    (["a,b,y", "1,1,0.5", "1,2,-1", "2,1,2", "2,2,3"], ["--log"],
     "--log: the response 'y' of run 2 is '-1', not a positive number"),
    (["a,b,y", "1,1,0.5", "1,2,1", "2,1,2", "2,2,3"], ["--factors", "a,c"], "'c'"),
    (["a,b,y", "1,1,0.5", "1,2,x", "2,1,2", "2,2,3"], [], "y"),
])
def test_bad_tables_are_refused_in_one_line_and_nothing_is_written(tmp_path, capsys, rows,
                                                                    options, words):
    table = tmp_path / "bad.csv"
    table.write_text("\n".join(rows) + "\n")
    out = tmp_path / "res"
    factors = [] if "--factors" in options else ["--factors", "a,b"]
    status = main(["anova", str(table), "--response", "y", *factors, *options,
                   "--out", str(out)])
    error = capsys.readouterr().err.strip()
    assert status == 2 and not out.exists(), error
    assert words in error and "\n" not in error
