"""Studies of many curves: study input, chunked resumable fits, the study summary."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from axialmix.analytic.closed import exit_age_closed
from fitting.cli import main
from fitting.data import Curve, DataError, read_rtd_csv
from fitting.fit import fit
from fitting.measurement import Inlet, measured
from fitting.models import MODELS
from fitting.solve import MultiStart, padded_length
from fitting.study.batch import JOURNAL_NAME, StudyPlan, StudyRun, fit_chunk
from fitting.study.input import read_design, read_long_csv, study_from_files

#: (curve id, rpm, angle, tau in min, Pe, samples): every curve pads to 32 samples, so the
#: whole module shares one compiled program.
RUNS = [("r1", 20, "up", 1.2, 15.0, 18), ("r2", 40, "up", 0.9, 30.0, 20),
        ("r3", 20, "down", 1.5, 10.0, 22), ("r4", 40, "down", 1.0, 45.0, 25)]
LENGTH_M = 0.31


def _samples(tau: float, peclet: float, count: int):
    t = np.linspace(0.0, 3.0 * tau, count)
    # Evaluated on one grid length (padded), so the exact series compiles once.
    theta = np.r_[t / tau, 3.0 + np.arange(1, 33 - count)]
    return t, 2.5 / tau * np.asarray(exit_age_closed(theta, 1.0, peclet))[:count]


def _write_long(path: Path, runs=RUNS) -> Path:
    lines = ["run,rpm,angle,t [min],c [g/L]"]
    for name, rpm, angle, tau, peclet, count in runs:
        for t, c in zip(*_samples(tau, peclet, count), strict=True):
            lines.append(f"{name},{rpm},{angle},{float(t)!r},{float(c)!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def long_csv(tmp_path_factory) -> Path:
    return _write_long(tmp_path_factory.mktemp("study") / "study.csv")


@pytest.fixture(scope="module")
def cli_summary(long_csv, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "fits"
    status = main(["fit", str(long_csv), "--curve-column", "run", "--length", str(LENGTH_M),
                   "--chunk", "3", "--out", str(out)])
    assert status == 0
    with open(out / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    return out, rows, json.loads((out / "summary.json").read_text())


def test_long_table_is_split_into_curves_with_their_factors(long_csv):
    study = read_long_csv(long_csv, "run")
    assert study.ids == tuple(r[0] for r in RUNS)
    assert study.factors == ("rpm", "angle")
    assert study.levels == tuple((str(r[1]), r[2]) for r in RUNS)
    for curve, (_, _, _, tau, peclet, count) in zip(study.curves, RUNS, strict=True):
        t, c = _samples(tau, peclet, count)
        assert curve.time_unit == "min" and curve.value_unit == "g/L"
        np.testing.assert_array_equal(curve.time, t)
        np.testing.assert_array_equal(curve.value, c)


def test_cli_study_recovers_exact_curves_with_units_factors_and_transport(cli_summary):
    out, rows, summary = cli_summary
    assert [row["curve"] for row in rows] == [r[0] for r in RUNS]
    for row, (_, rpm, angle, tau, peclet, _) in zip(rows, RUNS, strict=True):
        assert (row["rpm"], row["angle"]) == (str(rpm), angle)
        # Exact model curves: the fit recovers them to the solver's tolerance.
        assert float(row["tau [min]"]) == pytest.approx(tau, rel=1e-6)
        assert float(row["peclet"]) == pytest.approx(peclet, rel=1e-6)
        assert float(row["amplitude [g/L*min]"]) == pytest.approx(2.5, rel=1e-6)
        low, high = float(row["tau_ci95_low [min]"]), float(row["tau_ci95_high [min]"])
        assert low <= float(row["tau [min]"]) <= high
        # v = L / tau and D_z = v L / Pe (MODELS.md section 2), tau in seconds.
        velocity = LENGTH_M / (float(row["tau [min]"]) * 60.0)
        assert float(row["velocity [m/s]"]) == pytest.approx(velocity, rel=1e-9)
        assert float(row["dispersion [m^2/s]"]) == pytest.approx(
            velocity * LENGTH_M / float(row["peclet"]), rel=1e-9)
        assert row["converged"] == "True" and row["errors"] == "combined"
    assert summary["complete"] and summary["n_fitted"] == len(RUNS)
    assert summary["curves"][0]["factors"] == {"rpm": 20.0, "angle": "up"}
    assert summary["curves"][0]["parameters"]["tau"]["unit"] == "min"


def test_study_rows_are_the_fits_of_single_curves(long_csv, cli_summary):
    _, rows, summary = cli_summary
    study = read_long_csv(long_csv, "run")
    model = measured(MODELS["adm"], Inlet.pulse(), ())
    alone = fit(model, study.curves[2], errors="combined",
                multistart=MultiStart(n_starts=None))
    record = summary["curves"][2]
    for name in ("tau", "peclet", "amplitude"):
        assert record["parameters"][name]["value"] == alone.values[name]
        assert record["parameters"][name]["stderr"] == alone.stderr[name]


def test_design_table_gives_curve_files_their_factors(tmp_path):
    folder = tmp_path / "curves"
    folder.mkdir()
    for name, _, _, tau, peclet, count in RUNS[:2]:
        t, c = _samples(tau, peclet, count)
        rows = "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(t, c, strict=True))
        (folder / f"{name}.csv").write_text("t [min],c\n" + rows)
    design = tmp_path / "design.csv"
    design.write_text("file,rpm,angle\nr2.csv,40,up\nr1,20,down\n")
    curves = [read_rtd_csv(folder / f"{r[0]}.csv", normalise=False) for r in RUNS[:2]]
    study = study_from_files(curves, design)
    assert study.factors == ("rpm", "angle")
    assert study.levels == (("20", "down"), ("40", "up"))
    out = tmp_path / "out"
    assert main(["fit", str(folder), "--design", str(design), "--out", str(out)]) == 0
    with open(out / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert [(r["curve"], r["rpm"], r["angle"]) for r in rows] == [
        ("r1", "20", "down"), ("r2", "40", "up")]
    assert float(rows[1]["tau [min]"]) == pytest.approx(RUNS[1][3], rel=1e-6)


@pytest.mark.parametrize("design, words", [
    ("file,rpm\nr1,20\n", "no row for curve file 'r2'"),
    ("file,rpm\nr1,20\nr2,40\nr9,60\n", "row for 'r9', which is not among the curve files"),
    ("file,rpm\nr1,20\nr1.csv,40\n", ":3: 'r1.csv' in column 'file' is named on row 2 too"),
    ("file\nr1\nr2\n", "needs at least one factor column"),
])
def test_design_table_errors_are_one_line(tmp_path, design, words):
    curves = [Curve(name, *_samples(1.0, 20.0, 20), source=f"{name}.csv")
              for name in ("r1", "r2")]
    path = tmp_path / "design.csv"
    path.write_text(design)
    with pytest.raises(DataError) as caught:
        study_from_files(curves, path)
    assert words in caught.value.compact() and "\n" not in str(caught.value)


@pytest.mark.parametrize("edit, options, words", [
    (lambda lines: lines[:3] + [lines[3].replace(",20,up,", ",25,up,")] + lines[4:], [],
     "study.csv:4: factor 'rpm' changes within curve 'r1': '25' here, '20' on row 2"),
    (lambda lines: lines[:5] + [lines[5].replace("r1,", ",", 1)] + lines[6:], [],
     "study.csv:6: empty curve id in column 'run'"),
    (lambda lines: lines, ["--curve-column", "batch"],
     "study.csv:1: --curve-column: no column named 'batch'"),
    (lambda lines: lines, ["--factors", "speed"],
     "study.csv:1: --factors: no column named 'speed'"),
])
def test_study_table_errors_name_file_row_and_column(tmp_path, capsys, edit, options,
                                                     words):
    lines = _write_long(tmp_path / "study.csv").read_text().splitlines()
    path = tmp_path / "study.csv"
    path.write_text("\n".join(edit(lines)) + "\n")
    options = options if "--curve-column" in options else ["--curve-column", "run", *options]
    out = tmp_path / "out"
    assert main(["fit", str(path), *options, "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("axialmix fit: error: ") and "\n" not in error
    assert words in error
    assert not out.exists()


def test_a_curve_with_times_out_of_order_is_refused_and_the_others_fitted(tmp_path, capsys):
    lines = _write_long(tmp_path / "study.csv").read_text().splitlines()
    path = tmp_path / "study.csv"
    path.write_text("\n".join(lines[:4] + [lines[2]] + lines[4:]) + "\n")
    out = tmp_path / "out"
    assert main(["fit", str(path), "--curve-column", "run", "--out", str(out)]) == 3
    captured = capsys.readouterr()
    (line,) = [x for x in captured.err.splitlines() if "refused" in x]
    assert "curve 'r1'" in line and "study.csv, row 5: times not increasing" in line
    summary = json.loads((out / "summary.json").read_text())
    assert [r["curve"] for r in summary["refused"]] == ["r1"]
    assert summary["n_fitted"] == summary["n_curves"] - 1 > 0


def test_zero_weights_are_an_exact_mask():
    """Points with weight zero (as the solver pads ragged curves) change no bit of a fit."""
    model = measured(MODELS["adm"], Inlet.pulse(), ())
    t, c = _samples(1.0, 20.0, 20)
    extra = t[-1] + (t[1] - t[0]) * np.arange(1, 6)
    padded = Curve("padded", np.concatenate([t, extra]), np.concatenate([c, np.full(5, 7e3)]))
    assert padded_length(len(t)) == padded_length(len(padded.time))  # the same program
    start = {"tau": 0.8, "peclet": 12.0, "amplitude": 2.0}
    once = fit(model, Curve("plain", t, c), start, weights=np.ones(20),
               multistart=MultiStart(n_starts=1))
    masked = fit(model, padded, start, weights=np.r_[np.ones(20), np.zeros(5)],
                 multistart=MultiStart(n_starts=1))
    assert masked.values == once.values
    assert masked.n_evaluations == once.n_evaluations
    np.testing.assert_array_equal(masked.covariance, once.covariance)


def test_interrupted_study_resumes_without_losing_or_repeating_curves(long_csv, tmp_path):
    study = read_long_csv(long_csv, "run")
    plan = StudyPlan("adm", length_m=LENGTH_M)
    calls = []

    def stop_after_first_chunk() -> bool:
        calls.append(None)
        return len(calls) > 1

    first = StudyRun(plan, study, tmp_path, chunk=2)
    assert first.run(stop=stop_after_first_chunk, progress=False) == 2
    journal = tmp_path / JOURNAL_NAME
    # A kill during the next append leaves a torn line: it is dropped, its curve refitted.
    with open(journal, "a") as stream:
        stream.write('{"curve": "r3", "levels": ["20", "do')
    again = StudyRun(plan, study, tmp_path, chunk=3)
    assert again.resumed == 2 and again.pending == [2, 3]
    assert again.run(progress=False) == 2
    lines = journal.read_text().splitlines()
    assert [json.loads(line)["curve"] for line in lines[1:]] == ["r1", "r2", "r3", "r4"]
    fresh = fit_chunk(plan, study.curves)
    summary = json.loads((tmp_path / "summary.json").read_text())
    for record, alone in zip(summary["curves"], fresh, strict=True):
        assert record["parameters"] == alone["parameters"]
        assert record["physical"] == alone["physical"]


def test_summary_json_holds_each_record_as_written_anew_would(long_csv, tmp_path):
    # summary.json copies each curve's record from its journal line (not read and written
    # anew): the text must be what writing the record read back gives, factors included.
    study = read_long_csv(long_csv, "run")
    run = StudyRun(StudyPlan("adm", length_m=LENGTH_M), study, tmp_path, chunk=3)
    assert run.run(progress=False) == len(study)
    text = (tmp_path / "summary.json").read_text()
    records = list(run.records())
    assert [r["factors"] for r in records] == [{"rpm": 20, "angle": "up"},
                                               {"rpm": 40, "angle": "up"},
                                               {"rpm": 20, "angle": "down"},
                                               {"rpm": 40, "angle": "down"}]
    for count, record in enumerate(records):
        after = ",\n" if count < len(records) - 1 else "\n  ]"
        assert "\n" + json.dumps(record, allow_nan=False) + after in text
    assert json.loads(text)["curves"] == records


def test_a_run_freezes_the_heap_it_found_and_hands_it_back(long_csv, tmp_path):
    # The objects alive at the start are left out of the collector's scans during the run
    # (seen from `stop`, called between chunks) and handed back at the end; a caller's own
    # freeze is left as it is.
    import gc

    study = read_long_csv(long_csv, "run")
    seen = []

    def stop() -> bool:
        seen.append(gc.get_freeze_count())
        return False

    assert gc.get_freeze_count() == 0
    StudyRun(StudyPlan("adm"), study, tmp_path / "a", chunk=2).run(progress=False, stop=stop)
    assert len(seen) >= 3 and min(seen[:-1]) > 0 and seen[-1] == 0  # the last: the summary
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        StudyRun(StudyPlan("adm"), study, tmp_path / "b", chunk=2).run(progress=False)
        assert gc.get_freeze_count() > 0  # still the caller's: not handed back by the run
    finally:
        gc.unfreeze()
    assert gc.get_freeze_count() == 0


def test_a_folder_of_another_study_is_not_continued(long_csv, tmp_path):
    study = read_long_csv(long_csv, "run")
    StudyRun(StudyPlan("adm"), study, tmp_path, chunk=2)
    with pytest.raises(ValueError, match="holds a study with other settings"):
        StudyRun(StudyPlan("adm", errors="absolute"), study, tmp_path)
    smaller = read_long_csv(_write_long(tmp_path / "other.csv", RUNS[:2]), "run")
    with pytest.raises(ValueError, match="holds a study with other data"):
        StudyRun(StudyPlan("adm"), smaller, tmp_path)


def test_design_reader_takes_the_named_column(tmp_path):
    path = tmp_path / "design.csv"
    path.write_text("rpm,run,angle\n20,a.csv,up\n40,b,down\n")
    factors, rows = read_design(path)
    assert factors == ("rpm", "angle")
    assert rows == {"a": ("20", "up"), "b": ("40", "down")}


@pytest.mark.study
def test_killed_study_restarted_loses_and_repeats_no_curve(tmp_path):
    """SIGKILL the command after its first chunk is written, run it again: every curve once,
    with the numbers of an uninterrupted run."""
    rng = np.random.default_rng(7)
    runs = [(f"k{i:02d}", int(rng.integers(16, 60)), "x", float(rng.uniform(0.5, 2.0)),
             float(rng.uniform(8, 100)), int(rng.integers(15, 31))) for i in range(24)]
    path = _write_long(tmp_path / "study.csv", runs)
    out = tmp_path / "out"
    command = [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())",
               "fit", str(path), "--curve-column", "run",
               "--chunk", "4", "--out", str(out)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = out / JOURNAL_NAME
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if journal.exists() and len(journal.read_bytes().splitlines()) >= 2:
            break
        time.sleep(0.05)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    before = len(journal.read_bytes().splitlines()) - 1
    assert 0 < before < len(runs), "killed after the first chunk, before the last"
    assert subprocess.run(command, capture_output=True).returncode == 0
    lines = journal.read_text().splitlines()[1:]
    ids = [json.loads(line)["curve"] for line in lines]
    assert sorted(ids) == sorted(r[0] for r in runs) and len(ids) == len(set(ids))
    reference = tmp_path / "reference"
    assert subprocess.run([*command[:-1], str(reference)], capture_output=True).returncode == 0
    resumed = json.loads((out / "summary.json").read_text())["curves"]
    whole = json.loads((reference / "summary.json").read_text())["curves"]
    assert [r["parameters"] for r in resumed] == [r["parameters"] for r in whole]
    # Every curve has its record file, the one summary.json holds: those fitted before the
    # kill (rewritten at the end of the resumed run) and those fitted after it.
    files = {p.stem: json.loads(p.read_text()) for p in (out / "curves").glob("*.json")}
    assert sorted(files) == sorted(r[0] for r in runs)
    assert all(files[record["curve"]] == record for record in resumed)
    print(f"killed with {before} of {len(runs)} curves written; restarted: {len(ids)} curves, "
          "each once, equal to an uninterrupted run")


def test_chunks_on_two_threads_give_the_records_of_one_thread(tmp_path):
    # Curves of three padded lengths (three programs), in chunks of 3 so that several chunks
    # are in flight on two threads; the records must not depend on the threads (only the
    # wall times may), and the journal keeps the study's order.
    rng = np.random.default_rng(11)
    curves = []
    for i in range(10):
        tau, peclet, size = rng.uniform(20, 90), rng.uniform(8, 80), int(rng.integers(14, 60))
        t = np.linspace(0.0, 3.0 * tau, size)
        exact = np.asarray(exit_age_closed(t, tau, peclet))
        curves.append(Curve(f"t{i}", t, exact + 0.02 * exact.max() * rng.standard_normal(size),
                            time_unit="s", source="synthetic"))
    from fitting.study.input import Study

    study = Study(tuple(curves), (), tuple(() for _ in curves), tuple(None for _ in curves),
                  "synthetic")
    plan = StudyPlan("adm")
    summaries = []
    for threads in (1, 2):
        run = StudyRun(plan, study, tmp_path / f"threads{threads}", chunk=3)
        assert run.run(progress=False, threads=threads) == len(study)
        records = [json.loads(line) for line in
                   (tmp_path / f"threads{threads}" / JOURNAL_NAME).read_text().splitlines()[1:]]
        for line in records:
            line["record"].pop("wall_time")
        summaries.append(records)
    assert [r["curve"] for r in summaries[1]] == list(study.ids)
    assert summaries[1] == summaries[0]


def test_finished_curves_hold_no_memory_of_their_own(long_csv, tmp_path):
    """A study's memory is that of its chunks: a finished curve keeps only where its record
    and summary line lie on disk, so the run's retained memory does not grow with the curves
    it has finished (the old run kept about 1.5 KB a curve: its table line, offsets, names)."""
    import gc
    import tracemalloc

    template = read_long_csv(long_csv, "run")
    count = 3000
    curve = template.curves[0]
    curves = tuple(Curve(f"curve {i:05d}", curve.time, curve.value, time_unit=curve.time_unit,
                         value_unit=curve.value_unit) for i in range(count))
    study = type(template)(curves, template.factors, (template.levels[0],) * count,
                           (None,) * count, "synthetic")
    plan = StudyPlan("adm", length_m=LENGTH_M)
    record = fit_chunk(plan, [curve])[0]
    run = StudyRun(plan, study, tmp_path, chunk=250)
    run._append(range(250), [record] * 250)  # the one-off allocations (columns, files)

    def append(first: int, last: int) -> None:
        for start in range(first, last, 250):
            run._append(range(start, start + 250), [record] * 250)
        for write in run._file_writes:
            write.result()

    # Retained means reachable: garbage in reference cycles that the collector has not yet
    # reached (a chunk's finished write closures, by its timing) is collected first.
    # Memory kept per finished curve grows in every window of curves; a table of the
    # interpreter that doubles once (the interned strings, which pathlib adds each file's
    # name to: 3.7 MB at once in a worker that had run other files first) grows in one.
    # So the growth is measured over two equal windows and the smaller one counts.
    tracemalloc.start()
    try:
        snapshots = []
        for first, last in ((250, 1000), (1000, 2000), (2000, count)):
            append(first, last)
            gc.collect()
            snapshots.append(tracemalloc.take_snapshot())
    finally:
        tracemalloc.stop()
    grown = [sum(stat.size_diff for stat in after.compare_to(before, "filename")) / 1000
             for before, after in zip(snapshots, snapshots[1:], strict=False)]
    per_curve = min(grown)
    assert per_curve < 64, f"{per_curve:.0f} bytes retained per finished curve ({grown})"
    run.write_summary()
    with open(tmp_path / "summary.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert [row["curve"] for row in rows] == list(study.ids)
    assert rows[0] == {**rows[-1], "curve": rows[0]["curve"]}
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["n_fitted"] == count and len(summary["curves"]) == count


def test_one_thread_starts_each_chunk_before_handing_on_the_last():
    # The in-process runner starts chunk k+1 (its compiled fits run without Python's lock)
    # before it finishes chunk k; every begun chunk is handed on, in order, also when asked
    # to stop or when starting the next one fails.
    from fitting.study.batch import map_chunks

    events = []

    def launch(value):
        if value == "bad":
            raise RuntimeError("cannot start")
        events.append(f"start {value}")

        def finish():
            events.append(f"finish {value}")
            return value * 2

        return finish

    def task(value):
        return launch(value)()

    handed = []
    map_chunks(task, iter([(i, (i,)) for i in range(3)]), None, None, lambda: False,
               lambda key, result: handed.append((key, result)), launch=launch)
    assert events == ["start 0", "start 1", "finish 0", "start 2", "finish 1", "finish 2"]
    assert handed == [(0, 0), (1, 2), (2, 4)]

    events.clear(), handed.clear()
    asked = []

    def stop_before_third() -> bool:
        asked.append(None)
        return len(asked) > 2

    map_chunks(task, iter([(i, (i,)) for i in range(5)]), None, None, stop_before_third,
               lambda key, result: handed.append((key, result)), launch=launch)
    assert handed == [(0, 0), (1, 2)] and events[-1] == "finish 1"

    events.clear(), handed.clear()
    with pytest.raises(RuntimeError, match="cannot start"):
        map_chunks(task, iter([(0, (0,)), (1, ("bad",))]), None, None, lambda: False,
                   lambda key, result: handed.append((key, result)), launch=launch)
    assert handed == [(0, 0)]
    # Without `launch`, the task runs chunk by chunk: the same results.
    handed.clear()
    map_chunks(task, iter([(i, (i,)) for i in range(3)]), None, None, lambda: False,
               lambda key, result: handed.append((key, result)))
    assert handed == [(0, 0), (1, 2), (2, 4)]
