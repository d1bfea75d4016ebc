"""Output paths of every sub-command: checked before any work, written all or nothing.

Each bad output case exits with status 2 and one line that names the option, writes nothing
(the scratch folder's listing is unchanged) and leaves every input byte for byte as it was.
Ctrl-C during the drawing of a result set leaves either the whole set or nothing, and says
which.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fitting.cli import main

ROOT = Path(__file__).resolve().parents[1]
CURVE = ROOT / "examples" / "data" / "horizontal.csv"
STUDY = ROOT / "examples" / "study" / "speed_flow.csv"
TABLE = ROOT / "examples" / "source_tables" / "mixer1_residence.csv"

_FUNNEL = ["funnel", "--model", "tanks", "--set", "tau=5", "--set", "n_tanks=2",
           "--durations", "1,5", "--magnitudes", "5"]
_DIVERT = ["divert", "--model", "tanks", "--set", "tau=5", "--set", "n_tanks=2",
           "--disturbance", "square:magnitude=20,duration=3,start=1"]


def _copy(source: Path, target: Path) -> Path:
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(source.read_bytes())
    return target


def _commands(tmp: Path) -> dict[str, tuple[list[str], Path | None, str]]:
    """Sub-command -> (argv without --out, its input file or None, a file of its result set)."""
    table = _copy(TABLE, tmp / "inputs" / "table.csv")
    study = _copy(STUDY, tmp / "inputs" / "study.csv")
    curve = _copy(CURVE, tmp / "inputs" / "curve.csv")
    return {
        "funnel": (_FUNNEL, None, "funnel.json"),
        "divert": (_DIVERT, None, "divert.png"),
        "anova": (["anova", str(table), "--response", "residence_time_s", "--factors",
                   "angle,rpm"], table, "anova.csv"),
        "global-fit": (["global-fit", str(study), "--curve-column", "run", "--law",
                        "log(peclet)=speed+flow"], study, "curves.csv"),
        "fit": (["fit", str(curve), "--model", "adm"], curve, "summary.json"),
    }


def _case_out_is_a_file(tmp, argv, source, result):
    target = tmp / "taken.txt"
    target.write_text("keep me\n")
    return [*argv, "--out", str(target)], "--out"


def _case_out_under_a_file(tmp, argv, source, result):
    target = tmp / "taken.txt"
    target.write_text("keep me\n")
    return [*argv, "--out", str(target / "sub")], "--out"


def _case_out_holds_another_command_s_results(tmp, argv, source, result):
    folder = tmp / "other"
    folder.mkdir()
    other = "divert" if argv[0] != "divert" else "funnel"
    (folder / f".axialmix-{other}").write_text(f"axialmix {other}\n")
    (folder / f"{other}.json").write_text("{}\n")
    return [*argv, "--out", str(folder)], "--out"


def _case_out_is_the_input(tmp, argv, source, result):
    if source is None:
        pytest.skip("no input file")
    return [*argv, "--out", str(source)], "--out"


def _case_out_would_overwrite_the_input(tmp, argv, source, result):
    if source is None:  # the model is a fit record named as a result file
        folder = tmp / "res"
        record = _copy(ROOT / "examples" / "data" / "horizontal.csv", folder / result)
        index = argv.index("--model") + 1
        argv = [*argv[:index], str(record), *argv[index + 1:]]
        return [*argv, "--out", str(folder)], "--out"
    if argv[0] == "fit":
        pytest.skip("fit writes <name>.json beside summaries: a curve file is never a result")
    folder = source.parent
    moved = folder / result
    source.rename(moved)
    argv = [str(moved) if a == str(source) else a for a in argv]
    return [*argv, "--out", str(folder)], "--out"


def _case_result_name_is_a_folder(tmp, argv, source, result):
    folder = tmp / "res"
    (folder / result).mkdir(parents=True)
    if argv[0] == "fit":
        pytest.skip("fit's folder check is its own")
    return [*argv, "--out", str(folder)], result


def _case_replaced_option(tmp, argv, source, result):
    if argv[0] == "fit":
        pytest.skip("fit never had --json")
    return [*argv, "--json", str(tmp / "x.json")], "--json"


CASES = {name[len("_case_"):]: case for name, case in globals().items()
         if name.startswith("_case_")}
COMMANDS = ("funnel", "divert", "anova", "global-fit", "fit")


def _listing(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in folder.rglob("*")}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("command", COMMANDS)
def test_a_bad_output_is_refused_before_any_work(command, case, tmp_path, capsys):
    argv, source, result = _commands(tmp_path)[command]
    argv, culprit = CASES[case](tmp_path, list(argv), source, result)
    before = _listing(tmp_path)
    status = main(argv)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"axialmix {command}: error:"), err
    assert culprit in lines[0], lines[0]
    assert _listing(tmp_path) == before  # nothing written, every input untouched


def test_without_out_nothing_is_written(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(_FUNNEL) == 0
    assert "largest outlet deviation" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []


def test_a_result_set_is_written_whole_and_a_second_run_replaces_it(tmp_path, capsys):
    folder = tmp_path / "res"
    for _ in range(2):
        assert main([*_FUNNEL, "--out", str(folder)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert sorted(p.name for p in folder.iterdir()) == [".axialmix-funnel", "funnel.json",
                                                         "funnel.png"]


@pytest.mark.parametrize("options", [
    ["--json", "a.csv", "--rtd-csv", "a.csv"],
    ["--rtd-csv", "a.csv", "--samples-csv", "./a.csv"],
])
def test_simulate_refuses_one_file_for_two_outputs(options, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    status = main(["simulate", "continuous", "--particles", "200", "--steps", "10",
                   "--quiet", *options])
    err = capsys.readouterr().err.strip()
    assert status == 2 and "\n" not in err and "the same file as" in err, err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ Ctrl-C while drawing
#: The installed command's entry point, as the ``axialmix`` script runs it.
_PROGRAM = [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())"]


def _start(argv: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([*_PROGRAM, *argv], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _interrupt_runs(tmp_path: Path, argv: list[str], files: tuple[str, ...], moments: int):
    """Run `argv` with ``--out`` once to time its drawing (from the first printed line to the
    end), then `moments` times with Ctrl-C at a random moment of that span; each run must
    leave the whole result set or nothing, and say which."""
    probe = _start([*argv, "--out", str(tmp_path / "probe")], tmp_path)
    probe.stdout.readline()
    began = time.perf_counter()
    probe.communicate(timeout=600)
    span = time.perf_counter() - began
    assert probe.returncode == 0
    rng = random.Random(20261202)
    outcomes = []
    for k in range(moments):
        folder = tmp_path / f"run{k}"
        process = _start([*argv, "--out", str(folder)], tmp_path)
        process.stdout.readline()  # the table is printed: drawing starts
        time.sleep(rng.uniform(0.0, 1.2 * span))
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=600)
        names = sorted(p.name for p in folder.iterdir()) if folder.exists() else []
        complete = sorted([*files, f".axialmix-{argv[0]}"])
        assert names in ([], complete), (names, err)
        if names:
            assert process.returncode == 0 or (
                process.returncode == 130 and "are complete" in err), (process.returncode, err)
        else:
            assert process.returncode == 130 and "nothing written" in err, (
                process.returncode, err)
        outcomes.append("complete" if names else "nothing")
    return outcomes


def test_ctrl_c_while_drawing_leaves_the_whole_set_or_nothing(tmp_path):
    outcomes = _interrupt_runs(tmp_path, _FUNNEL, ("funnel.json", "funnel.png"), 3)
    assert len(outcomes) == 3


@pytest.mark.study
@pytest.mark.parametrize("argv, files", [(_FUNNEL, ("funnel.json", "funnel.png")),
                                         (_DIVERT, ("divert.json", "divert.png"))])
def test_ctrl_c_at_twenty_moments_of_drawing(argv, files, tmp_path):
    outcomes = _interrupt_runs(tmp_path, argv, files, 20)
    print(f"{argv[0]}: {outcomes.count('complete')} complete, {outcomes.count('nothing')} "
          "nothing written, of 20")
