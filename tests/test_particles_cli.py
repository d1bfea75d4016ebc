"""``axialmix simulate``: output files, their contents, and one-line errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import axialmix.network as mean_field
import axialmix.particles as particles
from fitting.cli import main


def test_simulate_vblender_writes_counts_and_chi_square_for_each_report(tmp_path, capsys):
    path = tmp_path / "vblender.json"
    argv = [
        "simulate",
        "vblender",
        "--loading",
        "E",
        "--steps",
        "3000",
        "--report-every",
        "1000",
        "--seed",
        "1",
        "--json",
        str(path),
    ]
    assert main(argv) == 0
    data = json.loads(path.read_text())
    assert [r["step"] for r in data["reports"]] == [0, 1000, 2000, 3000]
    assert data["steps_completed"] == 3000 and not data["interrupted"]
    table = capsys.readouterr().out.splitlines()  # the reports, one line each
    assert [line.split()[0] for line in table[1:]] == ["0", "1000", "2000", "3000"]
    counts = np.array([r["species1_counts"] for r in data["reports"]])
    assert counts[0].tolist() == [200_000, 200_000, 100_000, 0, 0]  # loading E
    assert np.all(counts.sum(axis=1) == 500_000)
    # chi-square recomputed from the counts: expected 100,000 species-1 particles each
    expected = 100_000.0
    for row, counts_row in zip(data["reports"], counts, strict=True):
        assert row["chi_square"] == pytest.approx(np.sum((counts_row - expected) ** 2 / expected))
    # the same run through the library gives the same numbers (seeded)
    network = particles.particle_v_blender()
    again = particles.simulate(
        network, particles.v_blender_loading(network, "E"), 3000, seed=1, report_every=1000
    )
    assert np.array_equal(again.counts[:, :, 0], counts)
    # and the file is the same with the identity engine's layout
    assert main(argv[:-2] + ["--engine", "identity", "--json", str(path), "--quiet"]) == 0
    assert json.loads(path.read_text())["engine"] == "identity"


def test_simulate_continuous_writes_rtd_close_to_network_mean(tmp_path):
    path = tmp_path / "rtd.json"
    assert (
        main(
            [
                "simulate",
                "continuous",
                "--steps",
                "8000",
                "--seed",
                "2",
                "--json",
                str(path),
                "--quiet",
            ]
        )
        == 0
    )
    data = json.loads(path.read_text())
    rtd = data["rtd"]
    assert rtd["fraction_left"] == pytest.approx(1.0, abs=1e-3)
    reference = particles.particle_four_compartment().to_network()
    exact = float(mean_field.residence_time_moments(reference).mean)
    # 1,676 tracers, RTD standard deviation ~ mean: 3 standard errors is about 7 %.
    assert rtd["mean_residence_time_s"] == pytest.approx(exact, rel=0.08)
    samples = data["outflow_samples"]
    assert len(samples["fractions"]) == 30 and samples["species"] == "tracer"  # the default


def test_simulate_continuous_grid_with_feeder_reports_vrr(tmp_path):
    path = tmp_path / "grid.json"
    assert (
        main(
            [
                "simulate",
                "continuous",
                "--preset",
                "grid",
                "--n-axial",
                "10",
                "--n-radial",
                "2",
                "--feeder",
                "--steps",
                "4000",
                "--json",
                str(path),
                "--quiet",
            ]
        )
        == 0
    )
    samples = json.loads(path.read_text())["outflow_samples"]
    assert samples["vrr"] == pytest.approx(samples["variance_in"] / samples["variance_out"])
    assert len(samples["inflow_fractions"]) == len(samples["fractions"]) == 30


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["vblender", "--loading", "Z"], "Unknown V-blender loading"),
        (["vblender", "--particles", "12"], "multiple of 5"),
        (["vblender", "--exchanges", "1,2,3"], "4 numbers"),
        (["continuous", "--preset", "grid", "--particles", "1001"], "multiple"),
        (["continuous", "--pulse-step", "50", "--steps", "10"], "before"),
        (["continuous", "--tracer", "100000"], "does not fit"),
    ],
)
def test_simulate_bad_input_gives_one_line_error_and_status_2(argv, message, capsys):
    assert main(["simulate", *argv, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("axialmix simulate: error:") and message in err
    assert "\n" not in err


def test_simulate_rejects_negative_steps_with_status_2(capsys):
    # An argument the parser rejects: one line on stderr, status 2, no usage dump.
    assert main(["simulate", "vblender", "--steps", "-3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "positive whole number" in err and "\n" not in err


def test_interrupted_simulation_still_writes_results_so_far(tmp_path, monkeypatch):
    import axialmix._progress

    class InterruptingBar:
        # Stands for the progress bar; Ctrl-C arrives while the run reports step 1000.
        n = 0

        def __init__(self, *args, **kwargs):
            pass

        def update(self, steps):
            self.n += steps
            raise KeyboardInterrupt

        def close(self):
            pass

    monkeypatch.setattr(axialmix._progress, "progress_bar", InterruptingBar)
    path = tmp_path / "partial.json"
    argv = [
        "simulate",
        "vblender",
        "--steps",
        "5000",
        "--report-every",
        "1000",
        "--json",
        str(path),
    ]
    assert main(argv) == 130  # interrupted: 128 + SIGINT
    data = json.loads(path.read_text())
    assert data["interrupted"] and data["steps_completed"] == 1000
    assert [r["step"] for r in data["reports"]] == [0, 1000]
    assert [p.name for p in tmp_path.iterdir()] == ["partial.json"]  # no temporary file left
