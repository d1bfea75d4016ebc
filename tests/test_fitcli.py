"""The ``axialmix fit`` command (fitting.cli.fit through fitting.cli.main)."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from fitting.cli import main

EXAMPLES = Path(__file__).parents[1] / "examples" / "data"
EXAMPLE_FILES = sorted(EXAMPLES.glob("*.csv"))
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# The four-compartment fits compile a vmapped multi-start solver (tens of seconds of CPU the
# first time in a process), so the tests that run them are marked slow (CI runs them).
FOUR_COMPARTMENT = ["--model", "four-compartment", "--fix", "k_out=0.8", "--starts", "2"]


def _check_record(path: Path, model: str) -> dict:
    record = json.loads(path.read_text())
    assert record["model"] == model
    for key in ("parameters", "loss", "converged", "n_evaluations", "identifiability"):
        assert key in record
    for entry in record["parameters"].values():
        assert set(entry) >= {"value", "stderr", "ci95"}
    assert record["n_evaluations"] > 0 and record["loss"] >= 0
    assert record["identifiability"] and all(isinstance(s, str) for s in record["identifiability"])
    return record


def _check_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR" and len(data) > 5_000


def test_examples_exist():
    assert len(EXAMPLE_FILES) == 5


@pytest.mark.slow
def test_fit_folder_gives_summary_table_json_csv_and_plots(tmp_path, capsys):
    out = tmp_path / "results"
    status = main(["fit", str(EXAMPLES), *FOUR_COMPARTMENT, "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 0
    for path in EXAMPLE_FILES:
        assert path.stem in captured.out
        record = _check_record(out / f"{path.stem}.json", "four-compartment")
        assert record["parameters"]["k_out"]["value"] == 0.8
        assert record["parameters"]["k_out"]["stderr"] is None  # fixed, not fitted
        equivalent = record["equivalent_adm"]
        assert equivalent["tau_s"] > 0 and equivalent["peclet"] > 0
        _check_png(out / f"{path.stem}.png")
    for column in ("k_f (1/s)", "k_r (1/s)", "k_s (1/s)", "tau (s)", "peclet", "fit"):
        assert column in captured.out
    table = captured.out.split("results written")[0]
    assert max(len(line) for line in table.splitlines()) <= 100  # a 100-column terminal
    assert f"[{len(EXAMPLE_FILES)}/{len(EXAMPLE_FILES)}]" in captured.err  # progress
    summary = json.loads((out / "summary.json").read_text())
    assert [f["data"] for f in summary["fits"]] == [p.stem for p in EXAMPLE_FILES]
    with open(out / "summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["curve"] for r in rows] == [p.stem for p in EXAMPLE_FILES]
    assert {"model", "n_points", "k_f [1/s]", "k_f_stderr [1/s]", "k_f_ci95_low [1/s]",
            "loss", "n_evaluations"} <= set(rows[0])


@pytest.mark.slow
@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=lambda p: p.stem)
def test_fit_each_example_file_prints_table_and_writes_json_and_png(path, tmp_path, capsys):
    out = tmp_path / "results"
    status = main(["fit", str(path), *FOUR_COMPARTMENT, "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 0
    for word in ("value", "std. error", "95 % interval", "loss (sse)", "evaluations", "time (s)",
                 "equivalent closed-closed ADM"):
        assert word in captured.out
    record = _check_record(out / f"{path.stem}.json", "four-compartment")
    # The table shows the same value as the record.
    assert f"{record['parameters']['k_f']['value']:.6g}" in captured.out
    _check_png(out / f"{path.stem}.png")
    assert sorted(p.name for p in out.iterdir()) == [f"{path.stem}.json", f"{path.stem}.png",
                                                     "summary.csv", "summary.json"]


def test_fit_with_grid_shows_both_side_by_side(tmp_path, capsys):
    out = tmp_path / "results"
    status = main(["fit", str(EXAMPLE_FILES[0]), "--model", "tanks", "--loss", "mae", "--grid",
                   "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 0
    assert "grid search" in captured.out and "grid search:" in captured.err
    record = _check_record(out / f"{EXAMPLE_FILES[0].stem}.json", "tanks")
    grid = record["grid_search"]
    assert grid["n_evaluations"] == 21 * 21 and grid["loss_name"] == "mae"
    # The grid is centred on the gradient optimum, so the gradient fit is at least as good.
    assert record["loss"] <= grid["loss"] * (1 + 1e-9)
    _check_png(out / f"{EXAMPLE_FILES[0].stem}.png")


@pytest.mark.slow
def test_fix_and_tie_are_honoured(tmp_path, capsys):
    out = tmp_path / "results"
    status = main(["fit", str(EXAMPLE_FILES[0]), "--model", "four-compartment", "--fix",
                   "k_out=0.8", "--tie", "k_r=k_f", "--starts", "1", "--out", str(out)])
    assert status == 0
    record = json.loads((out / f"{EXAMPLE_FILES[0].stem}.json").read_text())
    parameters = record["parameters"]
    assert parameters["k_r"]["value"] == pytest.approx(parameters["k_f"]["value"], rel=1e-12)
    assert parameters["k_r"]["expr"] == "k_f"
    assert "= k_f" in capsys.readouterr().out


def test_relative_errors_option_runs_the_weighted_fit_of_the_library(tmp_path, capsys):
    # Multiplicative noise on an exact ADM curve; the command must give exactly what the
    # library's relative-error fit gives, and differ from the unweighted fit.
    import numpy as np

    from axialmix.analytic import exit_age_closed
    from fitting.data import read_rtd_csv
    from fitting.fit import fit
    from fitting.measurement import measured

    rng = np.random.default_rng(5)
    t = np.linspace(3.0, 90.0, 15)
    y = np.asarray(exit_age_closed(t, 30.0, 20.0)) * (1 + 0.02 * rng.standard_normal(t.size))
    path = tmp_path / "noisy.csv"
    rows = "".join(f"{a:.17g},{b:.17g}\n" for a, b in zip(t, y, strict=True))
    path.write_text("time_s,E_per_s\n" + rows)
    records = {}
    for errors in ("absolute", "relative"):
        out = tmp_path / errors
        assert main(["fit", str(path), "--model", "adm", "--errors", errors,
                     "--out", str(out)]) == 0
        records[errors] = json.loads((out / "noisy.json").read_text())
    capsys.readouterr()
    # The command fits the raw values with the measurement model (amplitude fitted).
    library = fit(measured("adm"), read_rtd_csv(path, normalise=False), relative_errors=True)
    weighted = records["relative"]["parameters"]
    for name in ("tau", "peclet"):
        assert weighted[name]["value"] == pytest.approx(library.values[name], rel=1e-10)
        assert weighted[name]["stderr"] == pytest.approx(library.stderr[name], rel=1e-8)
        unweighted = records["absolute"]["parameters"][name]
        assert abs(unweighted["stderr"] / weighted[name]["stderr"] - 1) > 0.2
    assert records["relative"]["converged"]


GOOD = "time_s,concentration\n0,0\n1,0.2\n2,0.5\n3,0.3\n4,0.1\n5,0.02\n"
BAD_FILES = {
    "bad_columns": ("a,b,c\n1,2,3\n2,3,4\n3,4,5\n4,5,6\n5,6,7\n", None),
    "non_numeric": ("time_s,concentration\n0,0\n1,0.2\n2,abc\n3,0.3\n4,0.1\n5,0\n", 4),
    "nan": ("time_s,concentration\n0,0\n1,0.2\n2,nan\n3,0.3\n4,0.1\n5,0\n", 4),
    "negative": ("time_s,concentration\n0,0\n1,0.2\n2,-0.5\n3,0.3\n4,0.1\n5,0\n", 4),
    "not_increasing": ("time_s,concentration\n0,0\n1,0.2\n3,0.5\n2,0.3\n4,0.1\n5,0\n", 5),
    "too_few": ("time_s,concentration\n0,0\n1,0.2\n2,0.1\n", None),
    "all_zero": ("time_s,concentration\n0,0\n1,0\n2,0\n3,0\n4,0\n5,0\n", None),
    "missing_cell": ("time_s,concentration\n0,0\n1,0.2\n2\n3,0.3\n4,0.1\n5,0\n", 4),
}


def _assert_one_line_error(captured, path: Path, row: int | None) -> None:
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("axialmix fit: error: ")
    assert str(path) in lines[0]
    if row is not None:
        assert f"{path}:{row}: " in lines[0]
    assert "Traceback" not in captured.err
    assert captured.out == ""


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_input_prints_one_line_exits_2_and_writes_nothing(case, tmp_path, capsys):
    text, row = BAD_FILES[case]
    good = tmp_path / "good.csv"
    good.write_text(GOOD)
    bad = tmp_path / f"{case}.csv"
    bad.write_text(text)
    out = tmp_path / "results"
    # The good file comes first: nothing may be written for it either.
    status = main(["fit", str(good), str(bad), "--model", "tanks", "--out", str(out)])
    assert status == 2
    _assert_one_line_error(capsys.readouterr(), bad, row)
    assert not out.exists()


def test_missing_file_is_one_line_error(tmp_path, capsys):
    missing = tmp_path / "nowhere.csv"
    out = tmp_path / "results"
    status = main(["fit", str(missing), "--out", str(out)])
    assert status == 2
    _assert_one_line_error(capsys.readouterr(), missing, None)
    assert not out.exists()


def test_bad_folder_file_and_options_are_one_line_errors(tmp_path, capsys):
    folder = tmp_path / "data"
    folder.mkdir()
    shutil.copy(EXAMPLE_FILES[0], folder / "a.csv")
    (folder / "b.csv").write_text(BAD_FILES["negative"][0])
    out = tmp_path / "results"
    assert main(["fit", str(folder), "--out", str(out)]) == 2
    _assert_one_line_error(capsys.readouterr(), folder / "b.csv", 4)
    for options in (["--model", "nonsense"], ["--fix", "k_f"], ["--fix", "zeta=1"],
                    ["--model", "four-compartment", "--tie", "k_r=k_q"], ["--starts", "0"],
                    ["--grid", "--errors", "relative"], ["--errors", "lognormal"]):
        assert main(["fit", str(EXAMPLE_FILES[0]), *options, "--out", str(out)]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("axialmix fit: error: ")
    assert not out.exists()


def _additive_noise_curve(path: Path, seed: int) -> None:
    """A closed-closed ADM curve (tau 80 s, Pe 60) sampled over 0-240 s with additive noise
    of 2 % of its peak: its tails hold noise and no signal."""
    import numpy as np

    from axialmix.analytic import exit_age_closed

    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 240.0, 59)
    e = np.asarray(exit_age_closed(t, 80.0, 60.0))
    y = e + 0.02 * e.max() * rng.standard_normal(t.size)
    path.write_text("time_s,E_per_s\n" + "".join(f"{a:.17g},{b:.17g}\n"
                                                 for a, b in zip(t, y, strict=True)))


def test_relative_errors_that_do_not_settle_say_so(tmp_path, capsys):
    # Relative errors on additive noise: the weights 1/model^2 put the zero-signal tails
    # first, and the reweighted fits wander pass after pass (tau 189 s where it is 80 s).
    # Such a fit must not be reported as converged; the default error model fits the curve.
    path = tmp_path / "tails.csv"
    _additive_noise_curve(path, seed=0)
    assert main(["fit", str(path), "--model", "adm", "--errors", "relative",
                 "--out", str(tmp_path / "relative")]) == 0
    printed = capsys.readouterr().out
    record = json.loads((tmp_path / "relative" / "tails.json").read_text())
    assert record["converged"] is False
    assert record["message"].startswith("not converged: the relative error model's reweighted "
                                        "fits did not settle in 10 passes")
    assert "try combined errors" in record["message"]
    assert "did not settle" in printed
    assert abs(record["parameters"]["tau"]["value"] / 80.0 - 1) > 0.5  # why it must say so
    assert main(["fit", str(path), "--model", "adm", "--out", str(tmp_path / "combined")]) == 0
    capsys.readouterr()
    default = json.loads((tmp_path / "combined" / "tails.json").read_text())
    assert default["converged"] is True
    assert default["parameters"]["tau"]["value"] == pytest.approx(80.0, rel=0.01)


def test_relative_errors_that_collapse_are_a_one_line_error(tmp_path, capsys):
    # A curve of the study benchmark's kind (tau 83.7 s, Pe 58.5, 59 samples over 0-3 tau,
    # additive noise of 2 % of the peak) whose relative-error passes drift until the model
    # curve is zero everywhere: the weights cannot be formed, and the command says why.
    import numpy as np

    from axialmix.analytic import exit_age_closed

    rng = np.random.default_rng(1)
    count = 640
    tau = np.exp(rng.uniform(np.log(7.0), np.log(225.0), count))
    peclet = np.exp(rng.uniform(np.log(8.0), np.log(137.0), count))
    sizes = rng.integers(15, 61, count)
    for i in range(543):
        t = np.linspace(0.0, 3.0 * tau[i], sizes[i])
        exact = np.asarray(exit_age_closed(t, tau[i], peclet[i]))
        noisy = exact + 0.02 * exact.max() * rng.standard_normal(t.size)
    path = tmp_path / "drift.csv"
    path.write_text("t [s],c\n" + "".join(f"{float(a)!r},{float(b)!r}\n"
                                         for a, b in zip(t, noisy, strict=True)))
    assert main(["fit", str(path), "--model", "adm", "--errors", "relative",
                 "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0
    assert "relative errors collapsed on curve 'drift'" in error
    assert "weights 1/model^2 cannot be formed" in error
