"""``axialmix dem`` through the command line: files written, networks readable, one-line errors."""

import csv
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from axialmix.dem import (
    DEMRun,
    block_count_matrices,
    cells_of_run,
    count_occupancy,
    dem_available,
)
from axialmix.network import CompartmentNetwork

_COMMAND = [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())"]


def _axialmix(*args, cwd=None):
    return subprocess.run([*_COMMAND, *args], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize(
    "args, words",
    [
        (["learn", "--duration", "0.5"], "two impeller revolutions"),
        (["learn", "--run", "missing.npz"], "missing.npz: not a DEM run file"),
        (["learn", "--cells", "0"], "positive whole number"),
        (["learn", "--bootstrap", "-1"], "whole number >= 0"),
        (["hybrid", "--dem-regions", "10"], "must be below --regions"),
        (["validate", "--particles", "1,x"], "counts per species"),
    ],
)
def test_bad_options_give_one_line_and_write_nothing(tmp_path, args, words):
    out = tmp_path / "out"
    result = _axialmix("dem", *args, "--out", str(out), cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in result.stderr
    assert not out.exists()


@pytest.mark.skipif(not dem_available(), reason="the dem extra is not installed")
def test_learn_writes_a_network_that_axialmix_reads(tmp_path):
    out = tmp_path / "learned"
    result = _axialmix("dem", "learn", "--particles", "300", "--rpm", "120", "--duration",
                       "1.2", "--record-interval", "0.02", "--settle", "0.25", "--lag",
                       "0.04", "--cells", "6", "--bootstrap", "50", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert {p.name for p in out.iterdir()} == {"network.json", "rates.csv", "learn.json",
                                               "run.npz"}
    network = CompartmentNetwork.from_json(out / "network.json")
    assert network.n_compartments == 6 and not network.is_discrete
    with open(out / "rates.csv") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["source", "target", "rate [1/s]", "lower [1/s]", "upper [1/s]"]
    for source, target, rate, lower, upper in rows[1:]:
        c = next(c for c in network.connections if (c.source, c.target) == (source, target))
        assert float(rate) == pytest.approx(c.rate)
        assert float(lower) <= float(rate) * (1 + 1e-9) + 1e-12
        assert float(upper) >= float(rate) * (1 - 1e-9) - 1e-12
    record = json.loads((out / "learn.json").read_text())
    assert record["particles"] == 300 and record["cells"] == 6
    assert np.isfinite(record["dem"]["D_z_m2_per_s"])
    assert record["network"]["bootstrap_replicates_without_rates"] == 0
    # Learning again from the saved run gives the same network.
    again = tmp_path / "again"
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--lag", "0.04",
                       "--cells", "6", "--bootstrap", "50", "--out", str(again))
    assert result.returncode == 0, result.stderr
    assert CompartmentNetwork.from_json(again / "network.json") == network
    # Too few replicates for an interval: the rates alone, and the output says why.
    for replicates in ("0", "3"):
        bare = tmp_path / f"bare{replicates}"
        result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--lag", "0.04",
                           "--cells", "6", "--bootstrap", replicates, "--out", str(bare))
        assert result.returncode == 0, result.stderr
        assert (f"no 95 % intervals: {replicates} usable bootstrap replicate(s), at least 20 "
                "needed") in result.stdout
        assert CompartmentNetwork.from_json(bare / "network.json") == network
        with open(bare / "rates.csv") as handle:
            rows = list(csv.reader(handle))[1:]
        assert rows and all(not np.isfinite(float(row[3] or "nan"))
                            and not np.isfinite(float(row[4] or "nan")) for row in rows)
        assert json.loads((bare / "learn.json").read_text())["network"]["v_95"] == [None, None]
    # The likelihood estimator: a network on the connections seen from frame to frame.
    likely = tmp_path / "likely"
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--lag", "0.04",
                       "--cells", "6", "--bootstrap", "20", "--estimator", "likelihood",
                       "--out", str(likely))
    assert result.returncode == 0, result.stderr
    record = json.loads((likely / "learn.json").read_text())
    assert record["estimator"] == "likelihood"
    assert record["network"]["clipped_rate_share"] == 0
    learned = CompartmentNetwork.from_json(likely / "network.json")
    assert learned.n_compartments == 6 and all(c.rate > 0 for c in learned.connections)
    # The stationary estimator: the network written holds the occupancy of the counted
    # frames (whole blocks of one revolution) as its steady state, recomputed here from the
    # saved run.
    held = tmp_path / "held"
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--lag", "0.04",
                       "--cells", "6", "--bootstrap", "20", "--estimator", "stationary",
                       "--out", str(held))
    assert result.returncode == 0, result.stderr
    assert json.loads((held / "learn.json").read_text())["estimator"] == "stationary"
    written = CompartmentNetwork.from_json(held / "network.json")
    index = {name: i for i, name in enumerate(written.compartments)}
    q = np.zeros((6, 6))
    for c in written.connections:
        q[index[c.source], index[c.target]] = c.rate
    q -= np.diag(q.sum(axis=1))
    run = DEMRun.load(out / "run.npz")
    cells = cells_of_run(run, 6).cells
    block = round(run.geometry.revolution_time / run.frame_interval)
    counted = block_count_matrices(cells, 6, round(0.04 / run.frame_interval), block)
    occupancy = count_occupancy(counted.sum(axis=0))
    assert np.abs(occupancy @ q).max() < 1e-6 * np.abs(np.diag(q)).max()
    # Angular sectors: 3 axial cells x 2 sectors of equal occupancy, named and recorded.
    sectors = tmp_path / "sectors"
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--lag", "0.04",
                       "--cells", "3", "--sectors", "2", "--bootstrap", "20", "--estimator",
                       "likelihood", "--out", str(sectors))
    assert result.returncode == 0, result.stderr
    record = json.loads((sectors / "learn.json").read_text())
    assert record["cells"] == 6 and record["angular_sectors"] == 2
    edges = record["sector_edges_rad"]
    assert len(edges) == 3 and edges[0] == pytest.approx(-np.pi)
    assert edges[2] == pytest.approx(np.pi)
    split = CompartmentNetwork.from_json(sectors / "network.json")
    assert split.compartments[:3] == ("z1s1", "z1s2", "z2s1")
    # Several runs learned as one network. The same run given twice doubles every count,
    # which leaves the likelihood's maximum where it was: the network of the run alone.
    twice = tmp_path / "twice"
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--run",
                       str(out / "run.npz"), "--lag", "0.04", "--cells", "6", "--bootstrap",
                       "20", "--estimator", "likelihood", "--out", str(twice))
    assert result.returncode == 0, result.stderr
    assert result.stdout.count(f"DEM {out / 'run.npz'} (300 spheres") == 2
    record = json.loads((twice / "learn.json").read_text())
    assert record["runs"] == [str(out / "run.npz")] * 2
    assert record["network"]["blocks"] == 2 * json.loads(
        (likely / "learn.json").read_text())["network"]["blocks"]
    again = CompartmentNetwork.from_json(twice / "network.json")
    for mine, alone in zip(again.connections, learned.connections, strict=True):
        assert (mine.source, mine.target) == (alone.source, alone.target)
        assert mine.rate == pytest.approx(alone.rate, rel=1e-6)
    # A run of another frame interval is refused in one line naming it.
    other = tmp_path / "other.npz"
    dataclasses.replace(run, times=run.times * 2).save(other)
    result = _axialmix("dem", "learn", "--run", str(out / "run.npz"), "--run", str(other),
                       "--out", str(tmp_path / "refused"), cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{other}: not a run of the geometry and frame interval" \
        in lines[0]


@pytest.mark.skipif(not dem_available(), reason="the dem extra is not installed")
def test_validate_writes_composition_errors_and_plot(tmp_path):
    out = tmp_path / "validation"
    result = _axialmix("dem", "validate", "--particles", "100,100", "--learn-duration", "1.2",
                       "--duration", "0.4", "--record-interval", "0.05", "--settle", "0.2",
                       "--dem-regions", "4", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert {p.name for p in out.iterdir()} == {"composition.csv", "errors.csv",
                                               "validation.json", "validation.png"}
    with open(out / "composition.csv") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["t [s]", "region", "species 0", "species 1"]
    table = np.array(rows[1:], float)
    for t in np.unique(table[:, 0]):
        at = table[table[:, 0] == t]
        assert at.shape[0] == 10 and at[:, 2:].sum(axis=0).tolist() == [100, 100]
    record = json.loads((out / "validation.json").read_text())
    assert record["dem_regions"] == 4 and 0 <= record["compartment_share"] < 1
    assert (out / "validation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
