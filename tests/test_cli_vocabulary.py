"""One vocabulary: the five shipped curves fitted as a folder, as a long-format study and one
by one give the same summary columns (value, standard error and 95 % interval, units in the
header), and every parameter name the table prints is a name the options take."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from fitting.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "data"
FILES = sorted(EXAMPLES.glob("*.csv"))
MODEL = ["--model", "four-compartment", "--fix", "k_out=0.8"]


def _summary(folder: Path) -> list[dict[str, str]]:
    with open(folder / "summary.csv", newline="") as stream:
        return list(csv.DictReader(stream))


def _long_table(path: Path) -> Path:
    rows = ["curve,time_s,concentration"]
    for file in FILES:
        lines = [line for line in file.read_text().splitlines()
                 if line.strip() and not line.startswith("#")]
        rows += [f"{file.stem},{line}" for line in lines[1:]]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def summaries(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vocabulary")
    assert main(["fit", str(EXAMPLES), *MODEL, "--out", str(tmp / "folder")]) == 0
    assert main(["fit", str(_long_table(tmp / "long.csv")), "--curve-column", "curve", *MODEL,
                 "--out", str(tmp / "study")]) == 0
    alone = []
    for file in FILES:
        assert main(["fit", str(file), *MODEL, "--out", str(tmp / file.stem)]) == 0
        alone += _summary(tmp / file.stem)
    return _summary(tmp / "folder"), _summary(tmp / "study"), alone, tmp / "folder"


def test_every_mode_writes_the_same_summary_columns(summaries, capsys):
    capsys.readouterr()
    folder, study, alone, _ = summaries
    assert [r["curve"] for r in folder] == [r["curve"] for r in study] == [f.stem for f in FILES]
    assert list(folder[0]) == list(study[0]) == list(alone[0])
    header = list(folder[0])
    for name, unit in (("k_f", "1/s"), ("amplitude", "signal*s"), ("tau", "s")):
        for part in ("", "_stderr", "_ci95_low", "_ci95_high"):
            assert f"{name}{part} [{unit}]" in header
    assert {"peclet", "peclet_ci95_low", "variance_ratio"} <= set(header)


def test_files_and_folders_give_the_same_values_and_the_study_the_same_optimum(summaries):
    folder, study, alone, _ = summaries
    skip = {"wall_time_s", "message"}
    for mine, theirs in zip(folder, alone, strict=True):  # the same solver, curve by curve
        for key in set(mine) - skip - {"n_evaluations"}:
            if _number(mine[key]) is None:
                assert mine[key] == theirs[key], key
            else:
                assert _number(theirs[key]) == pytest.approx(_number(mine[key]), rel=1e-9), key
    # A study runs the batched engine, files the multi-start solver. Where the curve fixes
    # the rates both find one optimum; on a curve whose rates are not identified (k_f
    # ± 230 1/s) they may stop at different points of its flat valley, with losses equal to
    # 0.2 %, tau within a tenth of its standard error and each rate inside the other's
    # 95 % interval.
    for mine, theirs in zip(folder, study, strict=True):
        loss, other = _number(mine["loss"]), _number(theirs["loss"])
        assert other == pytest.approx(loss, rel=2e-3), mine["curve"]
        assert abs(_number(theirs["tau [s]"]) - _number(mine["tau [s]"])) <= 0.1 * _number(
            mine["tau_stderr [s]"]), mine["curve"]
        for rate in ("k_f", "k_r", "k_s"):
            value = _number(theirs[f"{rate} [1/s]"])
            low = _number(mine[f"{rate}_ci95_low [1/s]"])
            high = _number(mine[f"{rate}_ci95_high [1/s]"])
            if low is not None and high is not None:  # (an undefined interval bounds nothing)
                assert low <= value <= high, (mine["curve"], rate)


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


@pytest.mark.parametrize("model, fixed", [("four-compartment", ["k_out=0.8"]),
                                          ("adm", [])])
def test_every_parameter_name_the_table_prints_is_taken_by_fix(model, fixed, tmp_path, capsys):
    from fitting.cli.fit import _parameter_settings
    from fitting.measurement import Inlet, measured
    from fitting.models import get_model

    out = tmp_path / "one"
    assert main(["fit", str(FILES[0]), "--model", model,
                 *[a for f in fixed for a in ("--fix", f)], "--out", str(out)]) == 0
    table = capsys.readouterr().out.split("\n-")[1].splitlines()[1:]
    printed = [line.split()[0] for line in table if line and not line[0].isspace()]
    measured_model = measured(get_model(model), Inlet.pulse(), ("dead_time", "baseline"))
    parameters = [name for name in printed if name in measured_model.parameter_names]
    assert {"amplitude", "dead_time", "baseline"} <= set(parameters)
    for name in parameters:
        settings = _parameter_settings(measured_model, [f"{name}=0.5"], [])
        assert settings[name].value == 0.5 and not settings[name].vary
    if model == "adm":  # the table's name, and its symbol
        assert "peclet" in parameters
        assert _parameter_settings(measured_model, ["Pe=3"], [])["peclet"].value == 3.0


def test_the_summary_table_fits_100_columns_and_wide_shows_every_column(summaries):
    import json

    from fitting.report import summary_table

    records = json.loads((summaries[3] / "summary.json").read_text())["fits"]
    compact = summary_table(records)
    assert max(len(line) for line in compact.splitlines()) <= 100
    assert all(r["data"] in compact for r in records) and "k_out" not in compact
    wide = summary_table(records, wide=True)
    for column in ("k_out (1/s)", "amplitude", "loss", "evaluations", "lack of fit"):
        assert column in wide


def test_a_study_writes_each_curves_record_which_funnel_reads(summaries, tmp_path, capsys):
    import json

    study = summaries[3].parent / "study"
    records = json.loads((study / "summary.json").read_text())["curves"]
    files = sorted((study / "curves").glob("*.json"))
    assert [f.stem for f in files] == [f.stem for f in FILES]
    for record in records:
        assert json.loads((study / "curves" / f"{record['curve']}.json").read_text()) == record
    capsys.readouterr()
    status = main(["funnel", "--model", str(study / "curves" / "horizontal.json"),
                   "--durations", "1,5", "--magnitudes", "10,30", "--out", str(tmp_path / "f")])
    assert status == 0, capsys.readouterr().err
    assert (tmp_path / "f" / "funnel.json").exists()


def test_curve_file_names_are_safe_and_distinct():
    from fitting.study.batch import curve_file_stem

    assert curve_file_stem("run 1/2") == "run_1_2"
    assert curve_file_stem("A-3.b_c") == "A-3.b_c"
    assert curve_file_stem("..") == "curve" and curve_file_stem("é") == "_"


def test_a_study_with_plots_draws_each_curve_as_a_single_file_fit_is(tmp_path, capsys):
    from matplotlib.image import imread

    long = _long_table(tmp_path / "long.csv")
    out = tmp_path / "study"
    assert main(["fit", str(long), "--curve-column", "curve", "--model", "adm", "--plots",
                 "--out", str(out)]) == 0
    single = tmp_path / "single"
    assert main(["fit", str(FILES[0]), "--model", "adm", "--out", str(single)]) == 0
    capsys.readouterr()
    images = sorted((out / "curves").glob("*.png"))
    assert [f.stem for f in images] == [f.stem for f in FILES]
    reference = imread(single / f"{FILES[0].stem}.png")
    for image in images:
        assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert imread(image).shape == reference.shape
    # The same folder continued without --plots would leave curves without PNGs: refused.
    status = main(["fit", str(long), "--curve-column", "curve", "--model", "adm",
                   "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2 and "--plots" in err and len(err.strip().splitlines()) == 1, err


def test_a_study_without_curve_files_holds_the_same_records_in_its_summary(tmp_path, capsys):
    import json

    long = _long_table(tmp_path / "long.csv")
    common = ["fit", str(long), "--curve-column", "curve", "--model", "adm"]
    assert main([*common, "--out", str(tmp_path / "files")]) == 0
    assert main([*common, "--no-curve-files", "--out", str(tmp_path / "none")]) == 0
    capsys.readouterr()
    assert not (tmp_path / "none" / "curves").exists()
    assert len(list((tmp_path / "files" / "curves").glob("*.json"))) == len(FILES)

    def fitted(folder):
        records = json.loads((tmp_path / folder / "summary.json").read_text())["curves"]
        return [{k: v for k, v in r.items() if k != "wall_time"} for r in records]

    assert fitted("none") == fitted("files")
    # funnel takes a curve of the summary by --curve.
    assert main(["funnel", "--model", str(tmp_path / "none" / "summary.json"), "--curve",
                 FILES[0].stem, "--durations", "1,5", "--magnitudes", "10,30"]) == 0
    # Continued with curve files, the folder would hold some curves' files only: refused.
    status = main([*common, "--out", str(tmp_path / "none")])
    err = capsys.readouterr().err
    assert status == 2 and "--no-curve-files" in err and len(err.strip().splitlines()) == 1
    # A single file writes its record as its result: the option is refused there.
    status = main(["fit", str(FILES[0]), "--no-curve-files", "--out", str(tmp_path / "one")])
    err = capsys.readouterr().err
    assert status == 2 and "study's option" in err and not (tmp_path / "one").exists()


def test_profile_intervals_through_the_command_line(tmp_path, capsys):
    import json

    curve = EXAMPLES / "horizontal.csv"
    common = ["fit", str(curve), "--model", "adm", "--fix", "tau=7.19", "--fix", "Pe=0.64",
              "--errors", "absolute"]
    assert main([*common, "--out", str(tmp_path / "plain")]) == 0
    assert main([*common, "--profile", "amplitude", "--out", str(tmp_path / "prof")]) == 0
    out = capsys.readouterr().out
    assert "from the profile likelihood" in out
    plain = json.loads((tmp_path / "plain" / "horizontal.json").read_text())["parameters"]
    prof = json.loads((tmp_path / "prof" / "horizontal.json").read_text())["parameters"]
    assert plain["amplitude"]["interval"] == "linearised"
    assert prof["amplitude"]["interval"] == "profile"
    # The model is linear in the amplitude alone: its profile interval is the exact one,
    # value ± t s.e. (the linearised interval of a positive parameter is drawn on its log
    # scale, so it is not).
    from scipy import stats

    record = json.loads((tmp_path / "prof" / "horizontal.json").read_text())
    value, error = plain["amplitude"]["value"], plain["amplitude"]["stderr"]
    half = stats.t.ppf(0.975, record["n_points"] - 1) * error
    p_low, p_high = prof["amplitude"]["ci95"]
    assert p_low == pytest.approx(value - half, abs=1e-4 * half)
    assert p_high == pytest.approx(value + half, abs=1e-4 * half)
    for bad, culprit in ((["--profile", "nosuch"], "'nosuch'"), (["--profile", "tau"], "fixed"),
                         (["--profile", "--curve-column", "run"], "--profile")):
        status = main([*common, *bad, "--out", str(tmp_path / "bad")])
        err = capsys.readouterr().err
        assert status == 2 and culprit in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "bad").exists()
