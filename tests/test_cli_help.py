"""The command line's help reads as plain text, and an unusual blender length is questioned."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from fitting.cli import main

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "data" / "horizontal.csv"


def _help(command: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main([command, "--help"])
    return out.getvalue()


@pytest.mark.parametrize("command", ["fit", "anova", "global-fit", "funnel", "divert",
                                     "simulate"])
def test_help_has_no_doubled_percent_signs_or_markup(command):
    text = _help(command)
    assert "%%" not in text and "``" not in text, text


def test_fit_help_says_how_the_time_unit_is_found():
    text = " ".join(_help("fit").split())
    assert "95 % intervals" in text
    assert "unit is read from its header name" in text and "t [min]" in text


def test_an_unusual_length_is_questioned_and_the_fit_goes_on(tmp_path, capsys):
    status = main(["fit", str(EXAMPLE), "--model", "adm", "--length", "50",
                   "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 0
    assert "warning: --length 50 m is outside 0.02 to 10 m" in err
    assert (tmp_path / "out" / "horizontal.json").is_file()


def test_a_usual_length_passes_without_a_word(tmp_path, capsys):
    status = main(["fit", str(EXAMPLE), "--model", "adm", "--length", "0.31",
                   "--out", str(tmp_path / "out")])
    assert status == 0 and "--length" not in capsys.readouterr().err


