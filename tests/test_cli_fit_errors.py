"""``axialmix fit`` with bad input: status 2, one line naming the culprit, nothing written.

Every case below must be refused before the first output file is written (the exit-status
policy of :mod:`axialmix._exits`): exactly one line on standard error, ``axialmix fit:
error: ...``, naming the file and row, the option, or the network file at fault; no
traceback; nothing on standard output; the ``--out`` folder absent (or, where it existed,
unchanged). Most cases run the command in-process (``fitting.cli.main``); a few run it as a
real process, as a user would.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fitting.cli import main

EXAMPLES = Path(__file__).parents[1] / "examples" / "data"
GOOD = "time_s,concentration\n0,0\n1,0.2\n2,0.5\n3,0.3\n4,0.1\n5,0.02\n"
# A two-compartment network a -> b (rates in 1/s), written as JSON or TOML.
NETWORK = {
    "compartments": ["a", "b"],
    "connections": [{"source": "a", "target": "b", "rate": 1.0}],
    "inlets": [{"compartment": "a", "fraction": 1.0}],
    "outlets": [{"compartment": "b", "rate": 1.0}],
}


def _curve(values, times=None) -> str:
    times = range(len(values)) if times is None else times
    return "time_s,concentration\n" + "".join(f"{t},{v}\n" for t, v in zip(times, values,
                                                                          strict=True))


def _network(**changes) -> str:
    return json.dumps({**NETWORK, **changes})


# (id, {file name: contents}, arguments before --out ({name} = that file's path),
#  the text the one line must contain ({name} = that file's path))
CASES = [
    ("empty file", {"e.csv": ""}, ["{e.csv}"], "{e.csv}: no data"),
    ("header only", {"h.csv": "time_s,concentration\n"}, ["{h.csv}"], "{h.csv}: "),
    ("comments only", {"c.csv": "# nothing here\n\n# still nothing\n"}, ["{c.csv}"],
     "{c.csv}: no data"),
    ("NaN cell", {"n.csv": GOOD.replace("0.5", "nan")}, ["{n.csv}"], "{n.csv}:4: NaN"),
    ("inf cell", {"i.csv": GOOD.replace("0.3", "inf")}, ["{i.csv}"], "{i.csv}:5: infinite"),
    ("-inf time", {"i.csv": GOOD.replace("4,0.1", "-inf,0.1")}, ["{i.csv}"],
     "{i.csv}:6: infinite"),
    ("overflowing cell 1e309", {"o.csv": GOOD.replace("0.5", "1e309")}, ["{o.csv}"],
     "{o.csv}:4: infinite"),
    ("ragged row, extra cell", {"r.csv": GOOD.replace("3,0.3", "3,0.3,7")}, ["{r.csv}"],
     "{r.csv}:5: extra columns"),
    ("ragged row, missing cell", {"r.csv": GOOD.replace("3,0.3", "3")}, ["{r.csv}"],
     "{r.csv}:5: missing columns"),
    ("empty cell", {"r.csv": GOOD.replace("3,0.3", "3,")}, ["{r.csv}"], "{r.csv}:5: empty cell"),
    ("binary", {"b.csv": bytes(range(256)) * 8}, ["{b.csv}"], "{b.csv}:1: not a text file"),
    ("not UTF-8", {"b.csv": GOOD.encode() + b"6,\xff\xfe\n"}, ["{b.csv}"], "{b.csv}:8: not UTF-8"),
    ("UTF-16", {"u.csv": GOOD.encode("utf-16")}, ["{u.csv}"], "{u.csv}: UTF-16"),
    ("duplicate time", {"d.csv": GOOD.replace("3,0.3", "2,0.3")}, ["{d.csv}"],
     "{d.csv}:5: times not increasing (2 after 2; repeated)"),
    ("descending times", {"d.csv": _curve([0, 0.2, 0.5, 0.3, 0.1, 0], [5, 4, 3, 2, 1, 0])},
     ["{d.csv}"], "{d.csv}:3: times not increasing"),
    ("negative time", {"d.csv": _curve([0, 0.2, 0.5, 0.3, 0.1, 0], [-1, 0, 1, 2, 3, 4])},
     ["{d.csv}"], "{d.csv}:2: negative time"),
    ("unknown time unit", {"t.csv": GOOD.replace("time_s", "t [fortnight]")}, ["{t.csv}"],
     "{t.csv}:1: unknown time unit 'fortnight'"),
    ("non-numeric cell", {"x.csv": GOOD.replace("0.5", "abc")}, ["{x.csv}"],
     "{x.csv}:4: non-numeric cell 'abc'"),
    ("non-numeric cell of 200 kB", {"x.csv": GOOD.replace("0.5", "7" * 100 + "x" * 200_000)},
     ["{x.csv}"], "{x.csv}:4: non-numeric cell"),
    ("quoted cell of 200 kB", {"x.csv": GOOD.replace("0.5", '"' + "y" * 200_000 + '"')},
     ["{x.csv}"], "{x.csv}:4: non-numeric cell"),
    ("denormal values 1e-320", {"s.csv": _curve([0, 1e-320, 3e-320, 2e-320, 1e-320, 0])},
     ["{s.csv}"], "{s.csv}: values too small"),
    ("values near 1e308", {"v.csv": _curve([0, 1e307, 8e307, 5e307, 1e307, 0])}, ["{v.csv}"],
     "{v.csv}:3: value 1e+307 is too large"),
    ("time near 1e308", {"v.csv": _curve([0, 0.2, 0.5, 0.3, 0.1, 0],
                                         [0, 1, 2, 3, 4, 1.7e308])}, ["{v.csv}"],
     "{v.csv}:7: value 1.7e+308 is too large"),
    ("time span of 1e-190 s", {"v.csv": _curve([0, 0.2, 0.5, 0.3, 0.1, 0],
                                               [f"{i}e-190" for i in range(6)])},
     ["{v.csv}"], "{v.csv}: "),
    ("time span of 1e150 s", {"v.csv": _curve([0, 0.2, 0.5, 0.3, 0.1, 0],
                                              [f"{i}e150" for i in range(6)])},
     ["{v.csv}"], "{v.csv}: "),
    ("all-zero curve", {"z.csv": _curve([0] * 6)}, ["{z.csv}"], "{z.csv}: all-zero curve"),
    ("too short a curve", {"s.csv": _curve([0, 0.2, 0.1])}, ["{s.csv}"],
     "{s.csv}: too few points: 3"),
    ("one column", {"s.csv": "t\n0\n1\n2\n3\n4\n5\n"}, ["{s.csv}"], "{s.csv}:1: missing column"),
    ("missing file", {}, ["{nowhere.csv}"], "{nowhere.csv}: file not found"),
    ("folder without CSV files", {"empty/readme.txt": "no data"}, ["{empty}"],
     "{empty}: no files matching"),
    # Network files.
    ("network JSON malformed", {"good.csv": GOOD, "n.json": '{"compartments": ["a",}'},
     ["{good.csv}", "--model", "{n.json}"], "{n.json}: "),
    ("network TOML malformed", {"good.csv": GOOD, "n.toml": 'compartments = ["a"\n[[x]\n'},
     ["{good.csv}", "--model", "{n.toml}"], "{n.toml}: "),
    ("network negative rate",
     {"good.csv": GOOD, "n.json": _network(connections=[{"source": "a", "target": "b",
                                                         "rate": -1.0}])},
     ["{good.csv}", "--model", "{n.json}"], "{n.json}: Negative rate"),
    ("network unknown compartment",
     {"good.csv": GOOD, "n.json": _network(connections=[{"source": "a", "target": "zz",
                                                         "rate": 1.0}])},
     ["{good.csv}", "--model", "{n.json}"], "{n.json}: "),
    ("network rate names collide (b-c, b_c)",
     {"good.csv": GOOD, "n.json": _network(
         compartments=["a", "b-c", "b_c"],
         connections=[{"source": "a", "target": "b-c", "rate": 1.0},
                      {"source": "a", "target": "b_c", "rate": 1.0}],
         outlets=[{"compartment": "b-c", "rate": 1.0}, {"compartment": "b_c", "rate": 1.0}])},
     ["{good.csv}", "--model", "{n.json}"], "{n.json}: rates 'k_a_b-c' and 'k_a_b_c'"),
    ("network not an object", {"good.csv": GOOD, "n.json": "[1, 2]"},
     ["{good.csv}", "--model", "{n.json}"], "{n.json}: "),
    ("network file missing", {"good.csv": GOOD}, ["{good.csv}", "--model", "{nowhere.json}"],
     "{nowhere.json}: network file not found"),
    # Options.
    ("--fix tau=0", {"good.csv": GOOD}, ["{good.csv}", "--model", "adm", "--fix", "tau=0"],
     "--fix tau"),
    ("--fix k_out=0 (four-compartment)", {"good.csv": GOOD},
     ["{good.csv}", "--model", "four-compartment", "--fix", "k_out=0"], "--fix k_out"),
    ("--fix nope=1", {"good.csv": GOOD}, ["{good.csv}", "--fix", "nope=1"], "'nope'"),
    ("--fix tau=abc", {"good.csv": GOOD}, ["{good.csv}", "--fix", "tau=abc"], "--fix tau"),
    ("--fix tau=nan", {"good.csv": GOOD}, ["{good.csv}", "--fix", "tau=nan"], "--fix tau"),
    ("--fix tau=-1", {"good.csv": GOOD}, ["{good.csv}", "--fix", "tau=-1"], "--fix tau"),
    ("--fix without a value", {"good.csv": GOOD}, ["{good.csv}", "--fix", "tau"], "--fix"),
    ("--tie to an unknown parameter", {"good.csv": GOOD},
     ["{good.csv}", "--model", "four-compartment", "--tie", "k_r=k_q"], "'k_q'"),
    ("--loss xyz", {"good.csv": GOOD}, ["{good.csv}", "--loss", "xyz"], "--loss"),
    ("--starts 0", {"good.csv": GOOD}, ["{good.csv}", "--starts", "0"], "--starts"),
    ("--starts -1", {"good.csv": GOOD}, ["{good.csv}", "--starts", "-1"], "--starts"),
    ("--starts abc", {"good.csv": GOOD}, ["{good.csv}", "--starts", "abc"], "--starts"),
    ("--starts 1e12", {"good.csv": GOOD}, ["{good.csv}", "--starts", "1000000000000"],
     "--starts"),
    ("unknown model", {"good.csv": GOOD}, ["{good.csv}", "--model", "nonsense"], "--model"),
    ("--length 0", {"good.csv": GOOD}, ["{good.csv}", "--length", "0"], "--length"),
    ("--errors lognormal", {"good.csv": GOOD}, ["{good.csv}", "--errors", "lognormal"], "--errors"),
    # --out.
    ("--out under a file", {"good.csv": GOOD, "a_file": "x"},
     ["{good.csv}", "--out", "{a_file}/results"], "{a_file}/results: --out"),
    ("--out is a file", {"good.csv": GOOD, "a_file": "x"}, ["{good.csv}", "--out", "{a_file}"],
     "{a_file}: --out"),
    # Its summary.csv would be read as a curve by the next run on the folder.
    ("--out is the input folder", {"f/a.csv": GOOD}, ["{f}", "--out", "{f}"],
     "{f}: --out is the input folder"),
    ("--out would overwrite the input summary.csv", {"f/summary.csv": GOOD},
     ["{f/summary.csv}", "--out", "{f}"], "{f}: --out would overwrite the input"),
    ("--out locked by a running fit", {"good.csv": GOOD, "busy/.axialmix-fit.lock": "{pid}\n"},
     ["{good.csv}", "--out", "{busy}"], "{busy}: --out is being written"),
    # A folder with a good file and a bad one: nothing is written for the good one either.
    ("folder: good + denormal",
     {"f/a.csv": GOOD, "f/b.csv": _curve([0, 1e-320, 3e-320, 2e-320, 1e-320, 0])},
     ["{f}"], "{f/b.csv}: values too small"),
    ("folder: good + near 1e308",
     {"f/a.csv": GOOD, "f/b.csv": _curve([0, 1e307, 8e307, 5e307, 1e307, 0])},
     ["{f}"], "{f/b.csv}:3: "),
    ("folder: good + NaN", {"f/a.csv": GOOD, "f/b.CSV": GOOD.replace("0.3", "nan")},
     ["{f}"], "{f/b.CSV}:5: NaN"),
    ("folder: good + all-zero", {"f/a.csv": GOOD, "f/b.csv": _curve([0] * 6)}, ["{f}"],
     "{f/b.csv}: all-zero"),
    ("folder: two good, --fix tau=0", {"f/a.csv": GOOD, "f/b.csv": GOOD},
     ["{f}", "--fix", "tau=0"], "--fix tau"),
    ("same name twice", {"f/a.csv": GOOD, "g/a.csv": GOOD}, ["{f}", "{g}"],
     "{g/a.csv}: has the name 'a' of {f/a.csv} too"),
    ("same file twice", {"a.csv": GOOD}, ["{a.csv}", "{a.csv}"], "{a.csv}: given twice"),
]


def _fill(text: str, names: dict[str, str]) -> str:
    """`text` with each ``{name}`` replaced by ``names[name]``."""
    return re.sub(r"\{([^{}]+)\}", lambda match: names[match.group(1)], text)


def _make(tmp_path: Path, files: dict, arguments: list[str], culprit: str):
    """Write the case's files; returns (argv, culprit, out folder) with paths filled in."""
    names = {"pid": str(os.getpid()), "nowhere.csv": str(tmp_path / "nowhere.csv"),
             "nowhere.json": str(tmp_path / "nowhere.json")}
    for name in files:
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        names[name] = str(path)
        names[name.split("/")[0]] = str(tmp_path / name.split("/")[0])
    for name, contents in files.items():
        path = tmp_path / name
        if isinstance(contents, bytes):
            path.write_bytes(contents)
        else:
            path.write_text(_fill(contents, names) if "{pid}" in contents else contents,
                            encoding="utf-8")
    argv = [_fill(a, names) for a in arguments]
    out = tmp_path / "results"
    if "--out" not in argv:
        argv += ["--out", str(out)]
    else:
        out = Path(argv[argv.index("--out") + 1])
    if "--model" not in argv:
        argv += ["--model", "adm"]
    return argv, _fill(culprit, names), out


def _snapshot(tmp_path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(tmp_path)): (p.read_bytes() if p.is_file() else b"")
            for p in sorted(tmp_path.rglob("*"))}


def _assert_refused(status: int, err: str, out_text: str, culprit: str) -> str:
    lines = err.splitlines()
    assert status == 2, err
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith("axialmix fit: error: "), line
    assert culprit in line, f"{culprit!r} not in {line!r}"
    assert "Traceback" not in err and out_text == ""
    return line


@pytest.mark.parametrize(("files", "arguments", "culprit"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_bad_input_exits_2_with_one_line_naming_the_culprit_and_writes_nothing(
    files, arguments, culprit, tmp_path, capsys
):
    argv, culprit, out = _make(tmp_path, files, arguments, culprit)
    before = _snapshot(tmp_path)
    status = main(["fit", *argv])
    captured = capsys.readouterr()
    line = _assert_refused(status, captured.err, captured.out, culprit)
    print(line)
    assert _snapshot(tmp_path) == before, "bad input wrote or changed a file"


# ------------------------------------------------------------- the same, as a real process
_COMMAND = [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())"]
SUBPROCESS_CASES = ["NaN cell", "folder: good + near 1e308", "--fix k_out=0 (four-compartment)",
                    "network rate names collide (b-c, b_c)", "--out under a file"]


@pytest.mark.parametrize("case", SUBPROCESS_CASES)
def test_bad_input_as_a_real_process(case, tmp_path):
    _, files, arguments, culprit = next(c for c in CASES if c[0] == case)
    argv, culprit, out = _make(tmp_path, files, arguments, culprit)
    before = _snapshot(tmp_path)
    done = subprocess.run([*_COMMAND, "fit", *argv], capture_output=True, text=True,
                          timeout=120)
    _assert_refused(done.returncode, done.stderr, done.stdout, culprit)
    assert _snapshot(tmp_path) == before


def _without_write_permission_bypass() -> list[str] | None:
    """A command prefix under which folder permissions apply (root bypasses them), or None."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return None
    # Root keeps reading everything (CAP_DAC_READ_SEARCH) but may not write where the mode
    # forbids it (CAP_DAC_OVERRIDE dropped), as an ordinary user.
    return [setpriv, "--bounding-set", "-dac_override", "--inh-caps", "-dac_override"]


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permissions")
@pytest.mark.parametrize("where", ["inside", "itself"])
def test_out_in_or_as_a_read_only_folder_is_refused_before_fitting(where, tmp_path):
    prefix = _without_write_permission_bypass()
    if prefix is None:
        pytest.skip("running as root without setpriv: folder permissions cannot apply")
    good = tmp_path / "good.csv"
    good.write_text(GOOD)
    locked = tmp_path / "read-only"
    locked.mkdir()
    locked.chmod(0o555)
    out = locked / "results" if where == "inside" else locked
    try:
        done = subprocess.run([*prefix, *_COMMAND, "fit", str(good), "--model", "adm", "--out",
                               str(out)], capture_output=True, text=True, timeout=120)
        line = _assert_refused(done.returncode, done.stderr, done.stdout, f"{out}: --out")
        assert "writable" in line or "cannot be created" in line, line
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)
