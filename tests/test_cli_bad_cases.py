"""Bad input and fault cases of every sub-command, through the command line.

Each case either gives a correct result, or exits 2 with ONE line on standard error that
names the culprit (option, file, curve or row), writes nothing and shows no traceback.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed
from fitting.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "data"


def _adm_csv(path: Path, tau=7.0, peclet=20.0, noise=0.0, seed=0, header="time_s,conc"):
    t = np.linspace(0.0, 6 * tau, 121)
    y = 1.3 * np.asarray(exit_age_closed(t, tau, peclet))
    y = y + noise * y.max() * np.random.default_rng(seed).standard_normal(t.size)
    lines = [header] + [f"{a:.6g},{b:.6g}" for a, b in zip(t, y, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _fit_record(path: Path, model="adm", values=None, errors=None, matrix=None):
    """A fit record in the layout ``axialmix fit`` writes."""
    values = values or {"tau": 7.0, "peclet": 20.0}
    errors = errors or {name: 0.05 * value for name, value in values.items()}
    names = list(values)
    if matrix is None:
        matrix = np.eye(len(names)).tolist()
    record = {
        "model": model, "data": "run", "time_unit": "s",
        "parameters": {name: {"value": values[name], "stderr": errors[name], "vary": True,
                              "expr": None} for name in names},
        "correlation": {"names": names, "matrix": matrix},
    }
    path.write_text(json.dumps(record))
    return path


def _long_study(path: Path, curves=8, noise=0.02, dip=None, seed=1):
    """A long-format study: `curves` ADM curves, additive noise of `noise` of the peak, and
    optionally one sample of curve 3 set to `dip` times the peak."""
    rng = np.random.default_rng(seed)
    rows = ["run,time_s,conc,speed"]
    for k in range(curves):
        tau = 6.0 + 0.1 * k
        t = np.linspace(0.0, 40.0, 81)
        y = np.asarray(exit_age_closed(t, tau, 20.0))
        peak = y.max()
        y = y + noise * peak * rng.standard_normal(t.size)
        if dip is not None and k == 3:
            y[2] = dip * peak
        rows += [f"c{k},{a:.6g},{b:.8g},{100 + 10 * k}" for a, b in zip(t, y, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def _listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _expect_refusal(status, err, before, after, culprit, command):
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"axialmix {command}: error:"), err
    assert culprit in lines[0], lines[0]
    assert after == before, sorted(after - before)


# ------------------------------------------------------------------ in-process cases
def _case_divert_unidentified_fit(tmp):
    # Relative standard errors of 1.4e4: nearly every covariance sample overflows.
    fit = _fit_record(tmp / "wide.json", "four-compartment",
                      {"k_f": 0.91, "k_r": 1.08, "k_s": 1.01, "k_out": 0.8},
                      {"k_f": 12767.0, "k_r": 15625.0, "k_s": 14166.0, "k_out": 0.01})
    return (["divert", "--model", str(fit), "--disturbance",
             "square:magnitude=20,duration=3,start=1", "--flow", "30", "--out",
             str(tmp / "dout")], "of 1000 samples")


def _case_divert_huge_stderr(tmp):
    fit = _fit_record(tmp / "wide.json", errors={"tau": 1e10, "peclet": 1.0})
    return (["divert", "--model", str(fit), "--disturbance",
             "square:magnitude=20,duration=3,start=1", "--out", str(tmp / "dout")],
            "of 1000 samples")


def _case_divert_huge_samples(tmp):
    fit = _fit_record(tmp / "fit.json")
    return (["divert", "--model", str(fit), "--disturbance",
             "square:magnitude=20,duration=3,start=1", "--samples", "10000000"], "--samples")


def _case_divert_huge_points(tmp):
    return (["divert", "--model", "adm", "--set", "tau=7", "--set", "peclet=20",
             "--disturbance", "square:magnitude=20,duration=3,start=1", "--points",
             "100000000"], "--points")


def _case_divert_tau_1e308(tmp):
    fit = _fit_record(tmp / "huge.json", values={"tau": 1e308, "peclet": 20.0})
    return (["divert", "--model", str(fit), "--disturbance",
             "square:magnitude=20,duration=3,start=1", "--out", str(tmp / "dout")], "tau")


def _case_divert_bad_correlation_shape(tmp):
    fit = _fit_record(tmp / "fit.json", matrix=[[1.0]])
    return (["divert", "--model", str(fit), "--disturbance",
             "square:magnitude=20,duration=3,start=1"], "correlation")


def _case_divert_trace_three_cells(tmp):
    trace = tmp / "trace.csv"
    trace.write_text("time_s,content\n0,100\n1,101,7\n2,100\n3,100\n")
    return (["divert", "--model", "adm", "--set", "tau=7", "--set", "peclet=20",
             "--trace", str(trace)], "trace.csv:3")


def _case_divert_target_zero(tmp):
    return (["divert", "--model", "adm", "--set", "tau=7", "--set", "peclet=20",
             "--disturbance", "step:magnitude=1", "--target", "0"], "--target")


def _case_divert_bad_time_unit_with_flow(tmp):
    return (["divert", "--model", "adm", "--set", "tau=7", "--set", "peclet=20",
             "--time-unit", "fortnight", "--disturbance", "step:magnitude=1", "--flow", "30"],
            "--time-unit")


def _case_funnel_bad_time_unit(tmp):
    return (["funnel", "--model", "adm", "--set", "tau=7", "--set", "peclet=20",
             "--time-unit", "parsec", "--durations", "1", "--magnitudes", "5"], "--time-unit")


def _case_funnel_peclet_1e308(tmp):
    return (["funnel", "--model", "adm", "--set", "tau=7", "--set", "peclet=1e308",
             "--durations", "1,5", "--magnitudes", "5", "--out", str(tmp / "fout")],
            "peclet")


def _case_fit_time_days(tmp):
    return (["fit", str(_adm_csv(tmp / "c.csv", header="time_days,conc")), "--out",
             str(tmp / "out")], "time_days")


def _case_fit_time_us(tmp):
    return (["fit", str(_adm_csv(tmp / "c.csv", header="time_us,conc")), "--out",
             str(tmp / "out")], "time_us")


def _case_fit_time_fortnight(tmp):
    return (["fit", str(_adm_csv(tmp / "c.csv", header="time_fortnight,conc")), "--out",
             str(tmp / "out")], "time_fortnight")


def _case_fit_underscore_cell(tmp):
    path = _adm_csv(tmp / "c.csv")
    lines = path.read_text().splitlines()
    lines[5] = "1_0," + lines[5].split(",")[1]
    path.write_text("\n".join(lines) + "\n")
    return (["fit", str(path), "--out", str(tmp / "out")], "c.csv:6")


def _case_fit_all_fixed(tmp):
    return (["fit", str(_adm_csv(tmp / "c.csv")), "--fix", "tau=7", "--fix", "peclet=20",
             "--fix", "amplitude=1.3", "--out", str(tmp / "out")], "fixed")


def _case_fit_tie_cycle(tmp):
    return (["fit", str(_adm_csv(tmp / "c.csv")), "--model", "four-compartment", "--tie",
             "k_f=k_r", "--tie", "k_r=k_f", "--out", str(tmp / "out")], "tie")


def _case_fit_too_few_points(tmp):
    path = tmp / "c.csv"
    path.write_text("time_s,conc\n1,0.5\n")
    return (["fit", str(path), "--out", str(tmp / "out")], "row 2")


def _case_study_workers_1000(tmp):
    return (["fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run", "--workers",
             "1000", "--out", str(tmp / "out")], "--workers")


def _case_study_scheduler_port(tmp):
    return (["fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run", "--scheduler",
             "tcp://127.0.0.1:99999", "--out", str(tmp / "out")], "--scheduler")


def _case_study_scheduler_not_url(tmp):
    return (["fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run", "--scheduler",
             "not a url", "--out", str(tmp / "out")], "--scheduler")


def _case_study_scheduler_closed(tmp):
    return (["fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run", "--scheduler",
             "tcp://127.0.0.1:59999", "--out", str(tmp / "out")], "--scheduler")


def _case_anova_huge_response(tmp):
    path = tmp / "t.csv"
    rows = ["a,b,y"] + [f"{i % 2},{i % 3},{1e308 if i == 0 else 1.0 + i}" for i in range(12)]
    path.write_text("\n".join(rows) + "\n")
    return (["anova", str(path), "--response", "y", "--factors", "a,b", "--out",
             str(tmp / "aout")], "t.csv")


def _case_anova_denormal_response(tmp):
    path = tmp / "t.csv"
    rows = ["a,b,y"] + [f"{i % 2},{i % 3},{(1 + i) * 1e-320:.3e}" for i in range(12)]
    path.write_text("\n".join(rows) + "\n")
    return (["anova", str(path), "--response", "y", "--factors", "a,b", "--out",
             str(tmp / "aout")], "t.csv")


def _case_global_fit_value_is_factor(tmp):
    return (["global-fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run",
             "--value-column", "speed", "--law", "log(peclet)=speed", "--out",
             str(tmp / "gout")], "--value-column")


def _case_global_fit_law_unknown_column(tmp):
    return (["global-fit", str(_long_study(tmp / "s.csv")), "--curve-column", "run",
             "--law", "log(peclet)=nosuch", "--out", str(tmp / "gout")], "--law")


def _case_simulate_sample_size(tmp):
    return (["simulate", "continuous", "--particles", "2000", "--steps", "100",
             "--sample-size", "100000", "--quiet", "--rtd-csv", str(tmp / "r.csv")],
            "--sample-size")


CASES = {name[len("_case_"):]: case for name, case in globals().items()
         if name.startswith("_case_")}


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_case_is_refused_in_one_line_naming_the_culprit(name, tmp_path, capsys):
    argv, culprit = CASES[name](tmp_path)
    before = _listing(tmp_path)
    status = main(argv)
    err = capsys.readouterr().err
    _expect_refusal(status, err, before, _listing(tmp_path), culprit, argv[0])


# ------------------------------------------------------------------ correct results
def test_negative_limits_in_the_documented_form_are_accepted(capsys):
    status = main(["divert", "--model", "tanks", "--set", "tau=10", "--set", "n_tanks=1",
                   "--disturbance", "step:magnitude=2", "--limits", "-5,5"])
    out = capsys.readouterr().out
    assert status == 0
    assert "no diversion" in out


def test_divert_scan_is_not_cut_by_until(tmp_path, capsys):
    out = tmp_path / "d"
    status = main(["divert", "--model", "adm", "--set", "tau=60", "--set", "peclet=20",
                   "--disturbance", "square:magnitude=20,duration=30,start=10", "--until",
                   "50", "--out", str(out)])
    capsys.readouterr()
    assert status == 0
    record = json.loads((out / "divert.json").read_text())
    assert record["nominal"]["diverts"]
    assert record["nominal"]["start"] == pytest.approx(56.7, abs=0.05)
    assert record["scan"]["end"] > 50


def test_simulate_continuous_without_samples_csv_runs(tmp_path, capsys):
    rtd = tmp_path / "r.csv"
    status = main(["simulate", "continuous", "--particles", "2000", "--steps", "100",
                   "--quiet", "--rtd-csv", str(rtd)])
    err = capsys.readouterr().err
    assert status in (0, 2), err
    assert "Traceback" not in err
    if status == 2:
        assert len(err.strip().splitlines()) == 1


def test_study_with_one_noise_dip_fits_every_curve(tmp_path, capsys):
    study = _long_study(tmp_path / "s.csv", curves=6, dip=-0.052)
    status = main(["fit", str(study), "--curve-column", "run", "--out", str(tmp_path / "o")])
    capsys.readouterr()
    assert status == 0
    lines = (tmp_path / "o" / "summary.jsonl").read_text().splitlines()
    header, *rows = [json.loads(line) for line in lines if line.strip()]
    assert header["n_curves"] == 6
    assert len(rows) == 6


def test_study_lists_a_curve_with_a_gross_negative_sample_and_fits_the_others(tmp_path,
                                                                                capsys):
    study = _long_study(tmp_path / "s.csv", curves=6, dip=-0.30)
    out = tmp_path / "o"
    status = main(["fit", str(study), "--curve-column", "run", "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 3, captured.err
    assert "Traceback" not in captured.err
    # One line names file, curve, row and value; the run says how many were refused.
    (line,) = [x for x in captured.err.splitlines() if "refused" in x]
    assert "s.csv, row 247" in line and "'c3'" in line \
        and "negative value" in line, line
    assert "1 refused" in captured.out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_curves"] == 6 and summary["n_fitted"] == 5
    assert summary["n_refused"] == 1 and summary["complete"]
    assert [r["curve"] for r in summary["refused"]] == ["c3"]
    assert [r["curve"] for r in summary["curves"]] == ["c0", "c1", "c2", "c4", "c5"]
    refused = (out / "refused.csv").read_text().splitlines()
    assert refused[0] == "curve,reason" and refused[1].startswith("c3,")
    assert len((out / "summary.csv").read_text().splitlines()) == 1 + 5
    # Run again on the same folder: nothing is left to fit, the same refusal is reported.
    status = main(["fit", str(study), "--curve-column", "run", "--out", str(out)])
    captured = capsys.readouterr()
    assert status == 3 and "1 refused" in captured.out


def test_summary_that_is_a_directory_is_refused(tmp_path, capsys):
    study = _long_study(tmp_path / "s.csv", curves=3)
    (tmp_path / "o" / "summary.jsonl").mkdir(parents=True)
    status = main(["fit", str(study), "--curve-column", "run", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err
    assert "summary.jsonl" in err.strip().splitlines()[-1]


def test_api_refuses_an_unknown_parameter_name():
    from fitting.fit import fit

    t = np.linspace(0.0, 40.0, 81)
    y = np.asarray(exit_age_closed(t, 7.0, 20.0))
    with pytest.raises(ValueError, match="nosuch"):
        fit("adm", (t, y), {"nosuch": 1.0})


# ------------------------------------------------------------------ through a process
def _axialmix(args, cwd):
    env = {**os.environ, "PYTHONWARNINGS": "default"}
    program = "import sys; from fitting.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", program, *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("args,culprit", [
    (["funnel", "--model", "adm", "--set", "tau=7", "--set", "peclet=1e308", "--durations",
      "1", "--magnitudes", "5"], "peclet"),
    (["divert", "--model", "adm", "--set", "tau=7", "--set", "peclet=20", "--time-unit", "d",
      "--disturbance", "step:magnitude=1", "--flow", "30"], "--time-unit"),
])
def test_no_warning_is_printed_before_a_one_line_error(args, culprit, tmp_path):
    done = _axialmix(args, tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1, done.stderr
    assert culprit in lines[0]
