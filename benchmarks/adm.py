"""Accuracy and speed of the closed–closed ADM exit age: exact, JAX FV, rtdpy and FiPy.

For each Peclet number the exit age E(theta) (tau = 1, so t = theta) is computed on
theta in [0, 3] at 301 points by

* ``exact``     axialmix.analytic.exit_age_closed (Bromwich inversion, JAX, jitted);
* ``FV``        axialmix.adm.exit_age (JAX finite volumes, jitted, default settings): forward;
                forward and the gradient of a least-squares loss with respect to (tau, Pe)
                by ``jax.value_and_grad``; and a vmapped batch of 100 (tau, Pe) sets
                (tau and Pe within 20 % of the row's, one ``SolverConfig.for_peclet`` level
                for the batch), reported per curve;
* ``rtdpy``     rtdpy.AD_cc (method of lines, scipy BDF) with nx = 200 and 400 nodes;
* ``FiPy``      axialmix.reference.exit_age_fipy (backward Euler, central differences) with
                its default max(200, Pe) cells and a step of 0.002 tau (0.01 with --quick).

Errors are ``max |E - E_ref| / max E_ref`` against the extended-precision eigenfunction
series (axialmix.analytic.highprecision, mpmath) computed here. rtdpy's grid is its own
``arange(0, 3, 0.01)`` (300 points, the first 300 of ours), and its error is measured on that
grid. Timings: one warm-up call (for JAX the jit compilation, reported separately), then the
median wall time of several repeats with ``block_until_ready``; the exact and FV timings
run interleaved, round by round, so that their ratios see the same machine load; FiPy is
run once (seconds per curve).

Run: ``python benchmarks/adm.py`` (a few minutes on 2 cores), ``--quick`` for a smoke run,
``--pe 10 100`` to select Peclet numbers, ``--fipy-step 0.005`` for a coarser (faster) FiPy run.
"""

import argparse
import math
import statistics
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64)
from axialmix.adm import SolverConfig, exit_age
from axialmix.analytic import exit_age_closed
from axialmix.analytic.highprecision import exit_age_closed_series
from axialmix.reference import exit_age_fipy

PECLET_NUMBERS = (0.1, 1.0, 10.0, 100.0, 1000.0)
THETA = np.linspace(0.0, 3.0, 301)
BATCH_SIZE = 100
FIPY_STEP = 0.002  # theta: 1500 backward-Euler steps per curve (about 10 s each)


def timed(
    functions: dict[str, Callable[[], object]], repeats: int
) -> dict[str, tuple[float, float]]:
    """Time several functions in interleaved rounds, so that they share the machine's load.

    Each function is called once first (for a jitted function: compilation), then
    `repeats` rounds call every function once in turn.

    **Returns:**

    For each name: (extra seconds of the first call over the median, median seconds).
    """
    first: dict[str, float] = {}
    for name, function in functions.items():
        start = time.perf_counter()
        jax.block_until_ready(function())
        first[name] = time.perf_counter() - start
    samples: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            jax.block_until_ready(function())
            samples[name].append(time.perf_counter() - start)
    result = {}
    for name in functions:
        median = statistics.median(samples[name]) if samples[name] else first[name]
        result[name] = (max(first[name] - median, 0.0), median)
    return result


def peak_error(curve: np.ndarray, reference: np.ndarray) -> float:
    """Max absolute deviation relative to the reference peak."""
    return float(np.max(np.abs(np.asarray(curve) - reference)) / np.max(reference))


THETA_JAX = jnp.asarray(THETA)


def _squared_error(params: jax.Array, target: jax.Array, config: SolverConfig | None) -> jax.Array:
    """Least-squares loss of the FV exit age at params = (tau, Pe) against a target curve."""
    curve = exit_age(THETA_JAX, params[0], params[1], config=config)
    return jnp.mean((curve - target) ** 2)


# Jitted once for all Peclet numbers (traced Pe), so compilation is paid in the first row only.
exact_curve = jax.jit(lambda tau, pe: exit_age_closed(THETA_JAX, tau, pe))
fv_curve = jax.jit(lambda tau, pe: exit_age(THETA_JAX, tau, pe))
fv_value_and_grad = jax.jit(jax.value_and_grad(_squared_error), static_argnums=2)


def benchmark_peclet(
    peclet: float, repeats: int, quick: bool, fipy_step: float
) -> tuple[list[dict], dict]:
    """Rows of the accuracy/speed table and the promised ratios for one Peclet number."""
    from rtdpy import AD_cc

    rows = []
    reference = exit_age_closed_series(THETA, peclet)

    def add(method, seconds, compile_s=None, curve=None, own_reference=reference):
        error = None if curve is None else peak_error(curve, own_reference)
        rows.append(dict(method=method, error=error, seconds=seconds, compile=compile_s))

    # Gradient of a fit's loss with respect to (tau, Pe) by reverse mode: with the default
    # settings (resolution level chosen from the traced Pe at run time, as in a fit) and with
    # the level fixed in advance by SolverConfig.for_peclet.
    target = jnp.asarray(reference) * 1.01
    params = jnp.array([1.0, peclet])
    fixed = SolverConfig.for_peclet(peclet)
    timings = timed(
        {
            "exact": lambda: exact_curve(1.0, peclet),
            "forward": lambda: fv_curve(1.0, peclet),
            "grad": lambda: fv_value_and_grad(params, target, None),
            "grad_fixed": lambda: fv_value_and_grad(params, target, fixed),
        },
        repeats,
    )
    add("exact (Bromwich)", timings["exact"][1], timings["exact"][0], exact_curve(1.0, peclet))
    add("FV forward", timings["forward"][1], timings["forward"][0], fv_curve(1.0, peclet))
    add("FV fwd+grad (default)", timings["grad"][1], timings["grad"][0])
    add("FV fwd+grad (fixed level)", timings["grad_fixed"][1], timings["grad_fixed"][0])
    exact_s, fv_forward_s = timings["exact"][1], timings["forward"][1]
    fv_grad_s, fv_grad_fixed_s = timings["grad"][1], timings["grad_fixed"][1]

    rng = np.random.default_rng(0)
    taus = jnp.asarray(rng.uniform(0.8, 1.2, BATCH_SIZE))
    pes = jnp.asarray(peclet * rng.uniform(0.8, 1.2, BATCH_SIZE))
    # One resolution level for the whole batch (the FV solver's advice for vmap).
    batch_config = SolverConfig.for_peclet(float(pes.max()))
    batch = jax.jit(jax.vmap(lambda tau, pe: exit_age(THETA_JAX, tau, pe, config=batch_config)))
    ((compile_s, batch_s),) = timed(
        {"batch": lambda: batch(taus, pes)}, max(1, repeats // 4)
    ).values()
    add(f"FV vmap {BATCH_SIZE}, per curve", batch_s / BATCH_SIZE, compile_s)

    rtdpy_seconds = {}
    for nx in (200, 400):

        def rtdpy_curve(nx=nx):
            return AD_cc(tau=1.0, peclet=peclet, dt=0.01, time_end=3.0, nx=nx)

        ((_, run_s),) = timed({"rtdpy": rtdpy_curve}, 1 if quick else 3).values()
        model = rtdpy_curve()
        own_grid = np.asarray(model.time)
        assert np.allclose(own_grid, THETA[: own_grid.size], rtol=0, atol=1e-12)
        add(f"rtdpy AD_cc nx={nx}", run_s, None, model.exitage, reference[: own_grid.size])
        rtdpy_seconds[nx] = run_s

    fipy_cells = max(200, math.ceil(peclet))  # exit_age_fipy's default: cell Pe <= 1
    start = time.perf_counter()
    fipy_curve = exit_age_fipy(THETA, 1.0, peclet, n_cells=fipy_cells, dt=fipy_step)
    fipy_s = time.perf_counter() - start
    add(f"FiPy n={fipy_cells} dθ={fipy_step:g}", fipy_s, None, fipy_curve)

    ratios = {
        "FV/rtdpy200": rtdpy_seconds[200] / fv_forward_s,
        "grad/FV": fv_grad_s / fv_forward_s,
        "grad(fixed)/FV": fv_grad_fixed_s / fv_forward_s,
        "FV/FiPy": fipy_s / fv_forward_s,
        "exact/rtdpy200": rtdpy_seconds[200] / exact_s,
    }
    return rows, ratios


def format_seconds(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    if seconds < 1e-3:
        return f"{seconds * 1e6:8.1f} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:8.2f} ms"
    return f"{seconds:8.2f} s "


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="fewer repeats, coarse FiPy step, Pe 10 and 100 only"
    )
    parser.add_argument("--pe", type=float, nargs="+", help="Peclet numbers to run")
    parser.add_argument(
        "--fipy-step", type=float, help=f"FiPy time step in units of tau (default {FIPY_STEP})"
    )
    args = parser.parse_args()
    fipy_step = args.fipy_step or (0.01 if args.quick else FIPY_STEP)
    peclets = args.pe or ((10.0, 100.0) if args.quick else PECLET_NUMBERS)
    repeats = 3 if args.quick else 15

    print(
        f"closed-closed ADM exit age, theta in [0, 3] at {THETA.size} points, tau = 1; "
        f"jax {jax.__version__} on {jax.devices()[0].platform}"
    )
    print(
        "error = max|E - E_ref| / max E_ref, E_ref = mpmath eigenfunction series; "
        "time = median per curve; compile = first call (jit) extra"
    )
    header = f"{'Pe':>7}  {'method':<28}{'error':>11}  {'time/curve':>11}  {'compile':>11}"
    ratio_lines = []
    print(header)
    print("-" * len(header))
    for peclet in peclets:
        rows, ratios = benchmark_peclet(peclet, repeats, args.quick, fipy_step)
        for row in rows:
            error = "-" if row["error"] is None else f"{row['error']:.2e}"
            compile_text = format_seconds(row["compile"]) if row["compile"] else "-"
            print(
                f"{peclet:>7g}  {row['method']:<28}{error:>11}  "
                f"{format_seconds(row['seconds']):>11}  {compile_text:>11}",
                flush=True,
            )
        print()
        ratio_lines.append((peclet, ratios))

    names = list(ratio_lines[0][1])
    print("ratios measured in this run:")
    print("  FV/rtdpy200    speed-up of the FV forward solve over rtdpy AD_cc nx=200")
    print("  grad/FV        cost of FV forward + gradient w.r.t. (tau, Pe) over forward alone")
    print("  grad(fixed)/FV the same with the resolution level fixed (SolverConfig.for_peclet)")
    print("  FV/FiPy        speed-up of the FV forward solve over the FiPy reference")
    print("  exact/rtdpy200 speed-up of the exact solution over rtdpy AD_cc nx=200")
    ratio_header = f"{'Pe':>7}" + "".join(f"  {name:>15}" for name in names)
    print(ratio_header)
    print("-" * len(ratio_header))
    for peclet, ratios in ratio_lines:
        print(f"{peclet:>7g}" + "".join(f"  {ratios[name]:>15.3g}" for name in names))


if __name__ == "__main__":
    main()
