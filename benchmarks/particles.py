"""Speed and memory of the two particle engines, and their agreement.

    python benchmarks/particles.py [--quick]

Cases (MODELS.md section 4 quotes the source's FORTRAN: about 8,000 CPU s for the
1,000,000-particle batch V-blender, 51 CPU s for 10,000 particles in 250 compartments):

* V-blender, 5 compartments, exchanges 1000/100/100/1000 per step, loading E, 30,000 steps,
  with 1e6 and 1e7 particles (both engines) and 1e9 particles (count engine);
* continuous 50 x 5 axial x radial grid (250 compartments), constant feed and a tracer pulse,
  10,000 steps (5 mean residence times), with 10,000 and 1,000,000 particles.

Each case runs in a fresh Python process with an empty numba cache, so the warm-up (numba
compilation, timed on a small network) is reported apart from the timed run, and memory
figures belong to that case alone:

* "traced MB": peak of Python/NumPy allocations during the run, by ``tracemalloc`` (every
  array the simulator holds is allocated through NumPy, so this is the simulator's state);
* "max RSS MB": the process's peak resident memory by ``resource.getrusage`` (includes the
  interpreter, NumPy, numba and JAX, about the "base RSS" column before the run).

"CPU s" is the process's CPU time over the same run (``time.process_time``): on a shared
machine it shows what the wall time would be with a core to itself. "moves/s" counts
particles moved over connections and the weir (for the count engine, the
particles its draws stand for). Finally the two engines' V-blender species-1 counts are
compared: the identity run's counts against the mean and spread of 20 count-engine runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc

import numpy as np

STEPS_VBLENDER = 30_000
STEPS_GRID = 10_000


def _case_inputs(case: str, steps: int):
    import axialmix.particles as particles

    if case.startswith("vblender"):
        total = int(float(case.split("_")[1]))
        network = particles.particle_v_blender(total)
        return network, particles.v_blender_loading(network, "E"), {}
    per_compartment = int(float(case.split("_")[1])) // 250
    network = particles.particle_axial_radial_grid(50, 5,
                                                  particles_per_compartment=per_compartment)
    initial = np.column_stack([network.holdups, np.zeros_like(network.holdups)])
    options = {
        "feed": particles.constant_feed(network, [1.0, 0.0], steps),
        "tracer": particles.TracerPulse(0, per_compartment * 5 // 2, 1),
        # No per-particle histories: their events cost memory in proportion to tracer moves
        # (about 400 MB for the 1e6 case), which is not the engine's cost per move.
        "tracked_species": (),
    }
    return network, initial, options


def run_case(case: str, engine: str, steps: int) -> dict:
    """Run one case in this process; returns its timings and memory."""
    import axialmix.particles as particles

    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    # Warm-up on a small network of the same kind: compiles every kernel used below.
    small = "vblender_1e4" if case.startswith("vblender") else "grid_1e4"
    network, initial, options = _case_inputs(small, 50)
    clock = time.perf_counter()
    particles.simulate(network, initial, 50, engine=engine, **options)
    warm_up = time.perf_counter() - clock

    network, initial, options = _case_inputs(case, steps)
    tracemalloc.start()
    cpu = time.process_time()
    clock = time.perf_counter()
    result = particles.simulate(
        network, initial, steps, engine=engine, seed=1, report_every=max(steps // 6, 1), **options
    )
    wall = time.perf_counter() - clock
    cpu = time.process_time() - cpu
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "case": case,
        "engine": engine,
        "particles": network.n_particles,
        "compartments": network.n_compartments,
        "steps": result.steps_completed,
        "moves": result.particles_moved(),
        "wall_s": wall,
        "cpu_s": cpu,
        "moves_per_s": result.particles_moved() / wall,
        "warm_up_s": warm_up,
        "traced_mb": traced_peak / 2**20,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "base_rss_mb": base_rss,
        "species1": result.counts[:, :, 0].tolist() if case.startswith("vblender") else None,
        "report_steps": result.report_steps.tolist(),
    }


def _in_subprocess(case: str, engine: str, steps: int) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = subprocess.run(
            [sys.executable, __file__, "--case", case, "--engine", engine, "--steps", str(steps)],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
    return json.loads(out.stdout.strip().splitlines()[-1])


def _agreement(identity_row: dict, seeds: int = 20) -> tuple[float, int]:
    """Largest |z| of the identity run's counts against `seeds` count-engine runs."""
    import axialmix.particles as particles

    network, initial, _ = _case_inputs("vblender_1e6", STEPS_VBLENDER)
    steps = identity_row["report_steps"]
    runs = np.array(
        [
            particles.simulate(
                network, initial, steps[-1], seed=100 + s, report_steps=steps
            ).counts[:, :, 0]
            for s in range(seeds)
        ]
    )
    identity = np.array(identity_row["species1"])
    spread = runs.std(axis=0, ddof=1)
    # Both runs fluctuate: the difference of one identity run from the count mean has
    # standard deviation spread * sqrt(1 + 1/seeds).
    keep = spread > 0
    z = (identity - runs.mean(axis=0))[keep] / (spread[keep] * np.sqrt(1 + 1 / seeds))
    return float(np.abs(z).max()), int(keep.sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case")
    parser.add_argument("--engine")
    parser.add_argument("--steps", type=int)
    parser.add_argument("--quick", action="store_true", help="a tenth of the steps")
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case, args.engine, args.steps)))
        return
    scale = 10 if args.quick else 1
    plan = [
        ("vblender_1e6", "count", STEPS_VBLENDER),
        ("vblender_1e6", "identity", STEPS_VBLENDER),
        ("vblender_1e7", "count", STEPS_VBLENDER),
        ("vblender_1e7", "identity", STEPS_VBLENDER),
        ("vblender_1e9", "count", STEPS_VBLENDER),
        ("grid_1e4", "count", STEPS_GRID),
        ("grid_1e4", "identity", STEPS_GRID),
        ("grid_1e6", "count", STEPS_GRID),
        ("grid_1e6", "identity", STEPS_GRID),
    ]
    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start", flush=True)
    header = (
        f"{'case':<14}{'engine':<10}{'particles':>10}{'steps':>7}{'moves':>10}{'wall s':>9}"
        f"{'CPU s':>8}{'moves/s':>10}{'warm-up s':>10}{'traced MB':>10}{'max RSS MB':>11}"
        f"{'base RSS':>9}"
    )
    print(header)
    rows = {}
    for case, engine, steps in plan:
        row = _in_subprocess(case, engine, steps // scale)
        rows[case, engine] = row
        print(
            f"{case:<14}{engine:<10}{row['particles']:>10.3g}{row['steps']:>7}"
            f"{row['moves']:>10.3g}{row['wall_s']:>9.3f}{row['cpu_s']:>8.3f}"
            f"{row['moves_per_s']:>10.3g}{row['warm_up_s']:>10.2f}{row['traced_mb']:>10.1f}"
            f"{row['max_rss_mb']:>11.0f}{row['base_rss_mb']:>9.0f}",
            flush=True,
        )
    print(f"load average {os.getloadavg()[0]:.2f} at end")

    def ratio(numerator: tuple[str, str], denominator: tuple[str, str]) -> str:
        top, bottom = rows[numerator], rows[denominator]
        return (
            f"{top['wall_s'] / bottom['wall_s']:.2f} wall, {top['cpu_s'] / bottom['cpu_s']:.2f} CPU"
        )

    count_1e6, identity_1e6 = rows["vblender_1e6", "count"], rows["vblender_1e6", "identity"]
    moves_ratio = rows["grid_1e6", "identity"]["moves"] / rows["grid_1e4", "identity"]["moves"]
    print("\nmeasured in this run [targets]:")
    print(
        f"  count V-blender 1e6: {count_1e6['wall_s']:.3f} s wall, "
        f"{count_1e6['cpu_s']:.3f} s CPU  [<= 0.1 s]"
    )
    print(
        f"  identity V-blender 1e6: {identity_1e6['wall_s']:.2f} s wall, "
        f"{identity_1e6['cpu_s']:.2f} s CPU  [<= 2 s]"
    )
    print(
        "  count 1e7 / 1e6: "
        + ratio(("vblender_1e7", "count"), ("vblender_1e6", "count"))
        + ";  count 1e9 / 1e6: "
        + ratio(("vblender_1e9", "count"), ("vblender_1e6", "count"))
        + "  [about 1]"
    )
    print(
        "  identity 1e7 / 1e6: "
        + ratio(("vblender_1e7", "identity"), ("vblender_1e6", "identity"))
        + "  [<= 2]"
    )
    print(
        "  count grid 1e6 / 1e4: "
        + ratio(("grid_1e6", "count"), ("grid_1e4", "count"))
        + ";  identity grid 1e6 / 1e4: "
        + ratio(("grid_1e6", "identity"), ("grid_1e4", "identity"))
        + f"  [identity: moves ratio {moves_ratio:.0f}]"
    )
    if not args.quick:
        z, n = _agreement(rows["vblender_1e6", "identity"])
        print(
            f"  engines agree on V-blender 1e6 counts: max |z| = {z:.2f} over {n} "
            "(report step, compartment) pairs, identity run vs 20 count runs [< ~3]"
        )


if __name__ == "__main__":
    main()
