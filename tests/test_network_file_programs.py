"""Programs of a network-file model are identified by the file's content and the parameter
mapping, so a later process loads them from the cache; any change of either, or a model
derived with dataclasses.replace, gets programs of its own."""

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from axialmix.network import CompartmentNetwork, four_compartment, four_compartment_exit_age
from fitting.models import network_model
from fitting.solve.programs import export_key, model_identity

GROUPS = {"k_f": ["k_C1_C2", "k_C3_C4"], "k_r": ["k_C2_C1", "k_C4_C3"],
          "k_s": ["k_C1_C3", "k_C3_C1", "k_C2_C4", "k_C4_C2"], "k_out": ["k_out_C4"]}


#: Rates held at their true values (k_s, and k_f and k_r of the second pair): three fitted.
FIXED = [*(f"--fix={name}=0.625" for name in ("k_C1_C3", "k_C3_C1", "k_C2_C4", "k_C4_C2")),
         "--fix=k_C3_C4=2.125", "--fix=k_C4_C3=2.125"]


def _file(folder, name="four.json", rates=(2.0, 1.0, 0.5, 1.5)):
    path = folder / name
    four_compartment(*rates).to_json(path)
    return path


def test_the_identity_follows_the_file_content_and_the_mapping(tmp_path):
    first = network_model(_file(tmp_path), groups=GROUPS)
    identity = model_identity(first)
    assert identity is not None
    # The same content under another file name, read again: the same programs.
    assert model_identity(network_model(_file(tmp_path, "copy.json"), groups=GROUPS)) == identity
    # One rate that is not fitted, one ulp away: other programs (its value is in them).
    data = json.loads(_file(tmp_path).read_text())
    data["connections"][0]["rate"] = float(np.nextafter(data["connections"][0]["rate"], 3.0))
    nudged = tmp_path / "nudged.json"
    CompartmentNetwork.from_dict(data).to_json(nudged)
    assert model_identity(network_model(nudged, "k_out_C4")) != model_identity(
        network_model(_file(tmp_path), "k_out_C4"))
    # Another mapping of parameters to rates, or other parameters fitted: other programs.
    regrouped = dict(GROUPS, k_f=["k_C1_C2"])
    assert model_identity(network_model(_file(tmp_path), groups=regrouped)) != identity
    assert model_identity(network_model(_file(tmp_path))) != identity
    # A model made from it with another function has no identity: traced in each process.
    derived = dataclasses.replace(first, function=lambda t, p: 2.0 * first.function(t, p))
    assert derived.export_identity is None and model_identity(derived) is None
    assert export_key(derived, "layout") is None


@pytest.mark.parametrize("grid", ["regular", "irregular"])
def test_a_second_process_loads_the_programs_of_a_network_file_fit(tmp_path, grid):
    """The user's path: ``axialmix fit curve.csv --model four.json`` twice, sharing a cache
    folder. The first run exports its programs; the second loads every one of them (none is
    written again) and prints and records the same fit."""
    network = _file(tmp_path, rates=(2.125, 2.125, 0.625, 0.8))
    t = (np.arange(0.0, 30.5, 0.5) if grid == "regular"
         else np.concatenate([np.arange(0.0, 10.0, 0.5), np.arange(10.0, 31.0, 2.0)]))
    exact = np.asarray(four_compartment_exit_age(t, 2.125, 2.125, 0.625, 0.8))
    noise = 0.01 * exact.max() * np.random.default_rng(7).standard_normal(t.size)
    csv = tmp_path / "curve.csv"
    csv.write_text("time_s,concentration\n"
                   + "".join(f"{float(a)!r},{float(b)!r}\n"
                           for a, b in zip(t, exact + noise, strict=True)))
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home")}
    env.pop("AXIALMIX_TEST_CACHE", None)
    solvers = tmp_path / "home" / "axialmix" / "solvers"

    def run(out: str) -> tuple[str, dict]:
        done = subprocess.run(
            [sys.executable, "-c", "import sys; from fitting.cli import main; sys.exit(main())",
             "fit", str(csv), "--model", str(network),
             *FIXED, "--out", str(tmp_path / out)],
            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        record = json.loads((tmp_path / out / "curve.json").read_text())
        printed = [line for line in done.stdout.splitlines()
                   if not line.startswith(("time (s)", "results written to"))]
        return "\n".join(printed), record

    first_out, first = run("first")
    exported = {p.name: p.stat().st_mtime_ns for p in solvers.glob("*.jaxexport")}
    assert exported, "the first run kept no program"
    second_out, second = run("second")
    assert {p.name: p.stat().st_mtime_ns for p in solvers.glob("*.jaxexport")} == exported
    assert second_out == first_out
    for record in (first, second):
        record.pop("wall_time")  # the only entry that may differ
    assert json.dumps(second, sort_keys=True) == json.dumps(first, sort_keys=True)
