"""The README's shell examples, run on the shipped files: their printed outputs must match.

Every indented ``axialmix ...`` command of README.md that is followed by a fenced block of
output (before the next command or heading) is run in order, in a scratch folder holding
the repository's ``examples/`` (later commands read what earlier ones wrote, as a reader's
would), through the same entry point as the installed command. Its standard output is
compared with the block line by line, except the fields that measure the machine rather
than the result (see :func:`_masked`). The CSV excerpt of the study summary is compared with
the file the study command wrote, and the Python example's printed report with its block.
A README whose outputs drift from what the shipped files give fails here.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"

#: Rows of a report whose values are timings or round-off-level convergence measures: they
#: differ from machine to machine (and run to run), so they are not compared. The solver's
#: evaluation count is among them: the same fit takes 912 evaluations on one processor and
#: 984 on another (the compiled model's round-off follows the instruction set), while the
#: fitted values agree to every printed digit.
VOLATILE_ROWS = ("wall time", "time (s)", "gradient norm", "Gauss-Newton step", "evaluations")
#: Columns of a table (by header) that are timings or evaluation counts.
VOLATILE_COLUMNS = ("time (s)", "evaluations")


@dataclass(frozen=True)
class Example:
    command: str  # the command line as the README gives it (from "axialmix" on)
    output: str  # the fenced block that follows it
    line: int  # 1-based line of the command in the README


def readme_examples(text: str) -> list[Example]:
    """The README's ``axialmix`` commands that are followed by an output block."""
    lines = text.splitlines()
    examples, pending, fenced = [], None, False
    index = 0
    while index < len(lines):
        line = lines[index]
        if line.startswith("```"):
            if not fenced and pending is not None and line.strip() == "```":
                end = lines.index("```", index + 1)
                examples.append(Example(pending[0], "\n".join(lines[index + 1:end]), pending[1]))
                pending, index = None, end + 1
                continue
            fenced = not fenced
        elif not fenced and line.startswith("    ") and "axialmix " in line:
            command = line.strip().split("&& ")[-1]
            # Synopses ("[--json OUT]", "A|B", "FILE...") are not commands to run.
            runnable = command.startswith("axialmix ") and not re.search(r"[\[|]|\.\.\.", command)
            pending = (command, index + 1) if runnable else None
        elif not fenced and line.startswith("#"):
            pending = None
        index += 1
    return examples


def _masked(text: str) -> list[str]:
    """The lines of an output with its volatile fields replaced by ``*``: the value of a
    report row named in :data:`VOLATILE_ROWS`, and the cells of a table column named in
    :data:`VOLATILE_COLUMNS` (located by the dashes under the table's header)."""
    lines = [line.rstrip() for line in text.strip("\n").splitlines()]
    spans: list[tuple[int, int]] = []
    for i, line in enumerate(lines):
        if i > 0 and re.fullmatch(r"-+( +-+)*", line):
            header = lines[i - 1]
            spans = [(m.start(), m.end()) for m in re.finditer(r"-+", line)
                     if header[m.start():m.end()].strip() in VOLATILE_COLUMNS]
            continue
        if not line.strip():
            spans = []
        if spans and len(line) < spans[0][0]:
            spans = []  # the table has ended
        for start, end in spans:
            line = line[:start] + "*".center(end - start) + line[end:]
        for row in VOLATILE_ROWS:
            stripped = line.lstrip()
            if stripped.startswith(row + " ") or stripped.startswith(row + "="):
                line = line[: len(line) - len(stripped)] + row + " *"
        lines[i] = line.rstrip()
    return lines


_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def _last_place(token: str) -> float:
    """One unit in the last printed place of a number token (``0.0002313`` -> 1e-7)."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 10.0 ** (int(exponent or 0) - decimals)


def _agree(printed: list[str], shown: list[str]) -> bool:
    """Equal lines, but for printed numbers that differ from the shown ones by at most one
    unit in their last printed place: the last digit of a rounded value can fall either way
    on another processor (the round-off of compiled code follows the instruction set)."""
    if len(printed) != len(shown):
        return False
    for mine, theirs in zip(printed, shown, strict=True):
        if mine == theirs:
            continue
        words, expected = mine.replace("±", " ± ").split(), theirs.replace("±", " ± ").split()
        if len(words) != len(expected):
            return False
        for word, want in zip(words, expected, strict=True):
            if word == want:
                continue
            # Numbers inside punctuation (``[0.0093175,``) are compared as numbers too.
            numbers, wanted = _NUMBER.findall(word), _NUMBER.findall(want)
            if (_NUMBER.sub("#", word) != _NUMBER.sub("#", want)
                    or len(numbers) != len(wanted) or not wanted):
                return False
            for number, target in zip(_NUMBER.finditer(word), _NUMBER.finditer(want),
                                      strict=True):
                if abs(float(number.group()) - float(target.group())) > (
                        1.000001 * _last_place(target.group())):
                    return False
    return True


def test_numbers_may_differ_in_their_last_printed_digit_only():
    assert _agree(["loss 8.286e-05 done"], ["loss 8.287e-05 done"])
    assert _agree(["7.029 +/- 0.39"], ["7.030 +/- 0.39"])
    assert _agree(["[0.0093175, 194.14]"], ["[0.0093176, 194.14]"])
    assert not _agree(["[0.0093174, 194.14]"], ["[0.0093176, 194.14]"])
    assert not _agree(["(0.0093176, 194.14]"], ["[0.0093176, 194.14]"])
    assert _agree(["7.029±0.39 ok"], ["7.030±0.38 ok"])
    assert not _agree(["7.029±0.39"], ["7.029±0.41"])
    assert not _agree(["loss 8.284e-05 done"], ["loss 8.287e-05 done"])
    assert not _agree(["7.029 +/- 0.39"], ["7.029 +/- 0.40 yes"])
    assert not _agree(["converged: no"], ["converged: yes"])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Run every README example in order in one scratch folder; their outputs by command."""
    from fitting.cli import main

    folder = tmp_path_factory.mktemp("readme")
    (folder / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
    outputs = {}
    here = Path.cwd()
    os.chdir(folder)
    try:
        for example in readme_examples(README.read_text(encoding="utf-8")):
            argv = shlex.split(example.command)[1:]
            stdout, stderr = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                status = main(argv)
            outputs[example.command] = (status, stdout.getvalue(), stderr.getvalue())
    finally:
        os.chdir(here)
    return folder, outputs


EXAMPLES = readme_examples(README.read_text(encoding="utf-8"))


def test_the_readme_has_the_examples_it_should():
    commands = [example.command.split()[:2] for example in EXAMPLES]
    for expected in (["axialmix", "fit"], ["axialmix", "anova"], ["axialmix", "funnel"],
                     ["axialmix", "divert"], ["axialmix", "global-fit"]):
        assert expected in commands, f"README has no checked example of {' '.join(expected)}"
    # The minutes example runs on a file the repository ships.
    minutes = [e for e in EXAMPLES if "minutes" in e.command]
    assert minutes and all((ROOT / word).is_file() for e in minutes
                           for word in shlex.split(e.command) if word.endswith(".csv"))


@pytest.mark.parametrize("example", EXAMPLES, ids=[f"line{e.line}" for e in EXAMPLES])
def test_a_readme_example_prints_what_the_readme_shows(runs, example):
    _, outputs = runs
    status, out, err = outputs[example.command]
    assert status == 0, f"README line {example.line}: {example.command} exited {status}: {err}"
    shown, printed = _masked(example.output), _masked(out)
    assert _agree(printed, shown), (f"README line {example.line}: `{example.command}` prints\n"
                              + "\n".join(printed))


def _significant(text: str) -> int:
    digits = re.sub(r"[^0-9]", "", text.split("e")[0].lower()).lstrip("0")
    return max(len(digits), 1)


def test_the_study_summary_excerpt_matches_the_file(runs):
    import csv

    folder, _ = runs
    text = README.read_text(encoding="utf-8")
    block = text.split("`study/summary.csv` has one row per curve", 1)[1]
    block = block.split("```\n", 1)[1].split("\n```", 1)[0].splitlines()
    header, rows = block[0].split(","), [line.split(",") for line in block[1:]]
    with open(folder / "study" / "summary.csv", newline="", encoding="utf-8") as stream:
        table = {row["curve"]: row for row in csv.DictReader(stream)}
    for row in rows:
        written = table[row[0]]
        for name, shown in zip(header, row, strict=True):
            assert name in written, f"study/summary.csv has no column {name!r}"
            try:
                value = float(shown)
            except ValueError:
                assert written[name] == shown, (row[0], name)
                continue
            digits = _significant(shown)
            assert float(f"{float(written[name]):.{digits}g}") == value, (row[0], name)


def test_the_python_example_prints_what_the_readme_shows(tmp_path, monkeypatch):
    text = README.read_text(encoding="utf-8")
    code = text.split("```python\n", 1)[1].split("\n```", 1)[0]
    shown = text.split("```python\n", 1)[1].split("prints\n\n```\n", 1)[1].split("\n```", 1)[0]
    monkeypatch.chdir(tmp_path)
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})  # noqa: S102
    assert _agree(_masked(stdout.getvalue()), _masked(shown))
