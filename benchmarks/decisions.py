"""Time to a decision: ``axialmix divert`` and ``axialmix funnel`` against ``import jax`` and rtdpy.

Each row is a fresh Python process, timed end to end (wall clock, process start to exit),
repeated and reported as the median, in one run so that the ratios share the machine's load:

* ``python -c "import jax"``: the unit of the ratios;
* the README's diversion, ``axialmix divert --model results/horizontal.json --disturbance
  square:magnitude=20,start=10,duration=5 --flow 30 --out DIR`` on the four-compartment fit of
  the README's main job (made first, here, by ``axialmix fit examples/data --model
  four-compartment --fix k_out=0.8 --out results``; not timed);
* a funnel plot of 24 durations × 6 magnitudes of the closed–closed ADM (tau = 1 s, Pe = 20;
  the grid of ``benchmarks/line.py``: durations that are multiples of rtdpy's time step,
  magnitudes from -2 to 2), ``axialmix funnel --model adm --set tau=1 --set peclet=20
  --durations ... --magnitudes ...``, which prints its table (no files, as the peer);
* the floor of that route (warm only): a process that imports JAX alone, loads the funnel's
  exported program from the warm cache folder and runs it (on ones) — what any command that
  runs one exported JAX program costs before doing anything of its own;
* the peer: a Python script that computes and prints the same grid with rtdpy (its
  ``AD_cc`` RTD with ``dt = 1/1024 s``, ``nx = 400``, then ``funnelplot``), written to a
  temporary file. Before anything is timed its values are compared with ours (the JSON of
  the same funnel command); above :data:`PEER_TOLERANCE` of the largest deviation (rtdpy's
  own grid error is about 3.5e-5 of it) the benchmark stops.

Cold runs start with an empty cache folder (``XDG_CACHE_HOME`` a new temporary folder, each
run its own: every program is traced, compiled and exported); warm runs share one folder
that a first, untimed run filled (programs loaded from their exported files and JAX's
persistent compilation cache). ``import jax`` and the peer have no cache: the same numbers
stand in both columns. Every output lies in a temporary folder, removed at the end.

The targets: both commands within 3× ``import jax`` (warm), and the funnel no slower than
the peer.

    python benchmarks/decisions.py [--repeat N] [--cold-repeat N] [--fit horizontal.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: rtdpy's time step (s), as in benchmarks/line.py: the durations are multiples of it.
STEP = 2.0**-10
#: The closed–closed ADM of the funnel.
TAU, PECLET = 1.0, 20.0
#: Largest difference allowed between the peer's funnel and ours, relative to the largest
#: deviation (about three times rtdpy's own grid error at nx = 400).
PEER_TOLERANCE = 1e-4

DIVERT = ["divert", "--model", "results/horizontal.json", "--disturbance",
          "square:magnitude=20,start=10,duration=5", "--flow", "30"]

#: The peer: rtdpy's funnel of the same grid, printed (or written as JSON with --json FILE).
PEER = f'''
import json
import sys

import numpy as np
import rtdpy

durations = np.array([float(x) for x in sys.argv[1].split(",")])
magnitudes = np.array([float(x) for x in sys.argv[2].split(",")])
rtd = rtdpy.AD_cc(tau={TAU!r}, peclet={PECLET!r}, dt={STEP!r}, time_end=6.0, nx=400)
_, _, deviation = rtd.funnelplot(durations, magnitudes)
if len(sys.argv) > 4 and sys.argv[3] == "--json":
    with open(sys.argv[4], "w") as file:
        json.dump(np.asarray(deviation).tolist(), file)
else:
    np.set_printoptions(precision=4, linewidth=200)
    print(np.asarray(deviation))
'''


#: The floor: import JAX, load one exported program (and its compiled form from the persistent
#: cache, configured as the command line configures it), run it.
FLOOR = r'''
import sys

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", sys.argv[2])
jax.config.update("jax_compilation_cache_max_size", 2 * 1024**3)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
import numpy as np
from jax import export

exported = export.deserialize(bytearray(open(sys.argv[1], "rb").read()))
specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in exported.in_avals]
compiled = jax.jit(exported.call).lower(*specs).compile()
jax.block_until_ready(compiled(*[np.ones(a.shape, a.dtype) for a in exported.in_avals]))
'''


def grid() -> tuple[np.ndarray, np.ndarray]:
    """24 durations (multiples of rtdpy's step, 0.05 to 5 s) and 6 magnitudes (-2 to 2)."""
    durations = np.unique(np.round(np.geomspace(0.05, 5.0, 24) / STEP) * STEP)
    return durations, np.linspace(-2.0, 2.0, 6)


def _text(values: np.ndarray) -> str:
    return ",".join(repr(float(v)) for v in values)


def environment(cache: Path) -> dict[str, str]:
    """The environment of a timed process: its own cache folder, nothing else changed."""
    env = dict(os.environ)
    env["XDG_CACHE_HOME"] = str(cache)
    for name in ("JAX_COMPILATION_CACHE_DIR", "AXIALMIX_COMPILATION_CACHE"):
        env.pop(name, None)
    return env


def seconds(argv: list[str], folder: Path, cache: Path) -> float:
    """Wall-clock seconds of one process, start to exit; a failure stops the benchmark."""
    began = time.perf_counter()
    done = subprocess.run(argv, cwd=folder, env=environment(cache), capture_output=True,
                          text=True)
    elapsed = time.perf_counter() - began
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv[:4])} ... exited {done.returncode}:\n"
                         f"{done.stdout}\n{done.stderr}")
    return elapsed


def axialmix(*words: str) -> list[str]:
    """The command line as a process: the installed entry point through this Python."""
    return [sys.executable, "-c", "import sys; from fitting.cli import main; "
            "sys.argv[0] = 'axialmix'; sys.exit(main())", *words]


def check_peer(folder: Path, cache: Path, funnel: list[str], peer: list[str]) -> float:
    """The largest difference between the peer's funnel and ours, relative to the largest
    deviation; stops the benchmark above :data:`PEER_TOLERANCE`."""
    out = folder / "funnel-check"
    seconds(axialmix(*funnel, "--out", str(out)), folder, cache)
    ours = np.asarray(json.loads((out / "funnel.json").read_text())["max_deviation"])
    seconds([*peer, "--json", str(folder / "peer.json")], folder, cache)
    theirs = np.asarray(json.loads((folder / "peer.json").read_text()))
    if theirs.shape != ours.shape:
        raise SystemExit(f"the peer's funnel has shape {theirs.shape}, ours {ours.shape}")
    difference = float(np.abs(ours - theirs).max() / np.abs(ours).max())
    if not difference <= PEER_TOLERANCE:
        raise SystemExit(f"the peer's funnel differs from ours by {difference:.2e} of the "
                         f"largest deviation (more than {PEER_TOLERANCE:g}): not timed")
    return difference


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="warm runs of each (median)")
    parser.add_argument("--cold-repeat", type=int, default=3,
                        help="cold runs of each command (median)")
    parser.add_argument("--fit", metavar="JSON", default=None,
                        help="a horizontal.json the README's main job wrote, used instead of "
                        "fitting it again")
    args = parser.parse_args()
    durations, magnitudes = grid()
    funnel = ["funnel", "--model", "adm", "--set", f"tau={TAU:g}", "--set",
              f"peclet={PECLET:g}", f"--durations={_text(durations)}",
              f"--magnitudes={_text(magnitudes)}"]
    with tempfile.TemporaryDirectory(prefix="axialmix-decisions-") as scratch:
        folder = Path(scratch)
        (folder / "examples").symlink_to(ROOT / "examples", target_is_directory=True)
        (folder / "peer.py").write_text(PEER)
        (folder / "floor.py").write_text(FLOOR)
        peer = [sys.executable, str(folder / "peer.py"), _text(durations), _text(magnitudes)]
        setup = folder / "cache-setup"
        if args.fit is not None:
            (folder / "results").mkdir()
            shutil.copy(args.fit, folder / "results" / "horizontal.json")
        else:
            print("making results/horizontal.json (the README's main job, not timed) ...",
                  flush=True)
            seconds(axialmix("fit", "examples/data", "--model", "four-compartment", "--fix",
                             "k_out=0.8", "--out", "results"), folder, setup)
        difference = check_peer(folder, setup, funnel, peer)
        print(f"peer check: rtdpy's funnel and ours differ by {difference:.2e} of the largest "
              f"deviation (at most {PEER_TOLERANCE:g} allowed)", flush=True)
        shutil.rmtree(setup)

        jax_times, peer_times, floor_times = [], [], []
        runs = {"divert": {"cold": [], "warm": []}, "funnel": {"cold": [], "warm": []}}
        count = 0

        def out() -> str:
            nonlocal count
            count += 1
            return str(folder / "out" / f"run{count}")

        commands = {"divert": lambda: [*DIVERT, "--out", out()], "funnel": lambda: funnel}
        # Cold: each run of each command with an empty cache folder of its own.
        for repeat in range(args.cold_repeat):
            jax_times.append(seconds([sys.executable, "-c", "import jax"], folder, setup))
            for name, words in commands.items():
                cache = folder / f"cache-cold-{name}-{repeat}"
                runs[name]["cold"].append(seconds(axialmix(*words()), folder, cache))
                shutil.rmtree(cache)
            peer_times.append(seconds(peer, folder, setup))
            print(f"cold run {repeat + 1} of {args.cold_repeat} done", flush=True)
        # Warm: one untimed run fills the shared cache folder, then the timed runs.
        warm = folder / "cache-warm"
        for words in commands.values():
            seconds(axialmix(*words()), folder, warm)
        exported = sorted((warm / "axialmix" / "solvers").glob("*-funnel-*.jaxexport"))
        floor = [sys.executable, str(folder / "floor.py"), str(exported[0]),
                 str(warm / "axialmix" / "jax")] if exported else None
        for repeat in range(args.repeat):
            jax_times.append(seconds([sys.executable, "-c", "import jax"], folder, setup))
            for name, words in commands.items():
                runs[name]["warm"].append(seconds(axialmix(*words()), folder, warm))
            peer_times.append(seconds(peer, folder, setup))
            if floor is not None:
                floor_times.append(seconds(floor, folder, setup))
            print(f"warm run {repeat + 1} of {args.repeat} done", flush=True)

    unit = statistics.median(jax_times)
    rows = [("python -c 'import jax'", unit, unit),
            ("axialmix divert (README)", statistics.median(runs["divert"]["cold"]),
             statistics.median(runs["divert"]["warm"])),
            ("axialmix funnel 24x6", statistics.median(runs["funnel"]["cold"]),
             statistics.median(runs["funnel"]["warm"])),
            ("rtdpy script 24x6 (peer)", statistics.median(peer_times),
             statistics.median(peer_times))]
    if floor_times:
        rows.insert(3, ("floor: jax + 1 exported prog", float("nan"),
                        statistics.median(floor_times)))
    print(f"\nmedians of {args.cold_repeat} cold and {args.repeat} warm runs "
          f"(import jax and the peer: all {len(jax_times)} runs); ratios to import jax")
    print(f"{'process':<28} {'cold (s)':>9} {'ratio':>6} {'warm (s)':>9} {'ratio':>6}")
    for label, cold, hot in rows:
        first = f"{cold:9.2f} {cold / unit:6.2f}" if cold == cold else f"{'-':>9} {'-':>6}"
        print(f"{label:<28} {first} {hot:9.2f} {hot / unit:6.2f}")
    funnel_warm = statistics.median(runs["funnel"]["warm"])
    divert_warm = statistics.median(runs["divert"]["warm"])
    print(f"\ntargets (warm): divert <= 3x import jax: {divert_warm / unit:.2f}x "
          f"({'met' if divert_warm <= 3 * unit else 'missed'}); funnel <= 3x: "
          f"{funnel_warm / unit:.2f}x ({'met' if funnel_warm <= 3 * unit else 'missed'}); "
          f"funnel <= peer: {funnel_warm:.2f} s against {statistics.median(peer_times):.2f} s "
          f"({'met' if funnel_warm <= statistics.median(peer_times) else 'missed'})")


if __name__ == "__main__":
    main()
