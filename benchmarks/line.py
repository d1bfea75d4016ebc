"""Funnel plots: axialmix.line.funnel (exact, vectorised) against rtdpy's funnelplot.

For each RTD both compute the largest outlet deviation of square disturbances on the same
grid of durations (multiples of rtdpy's time step, so its rectangle-rule convolution sees the
same squares) and magnitudes. rtdpy samples the RTD every ``dt = tau / 1024`` and convolves
once per grid cell (a Python double loop); ours scans the exact F once per duration (vmap)
and refines by golden-section search, whatever the number of magnitudes.

Printed per RTD and grid (seconds): our time (first call, with compilation, and warm median),
rtdpy's time to build its RTD (not counted in the ratio) and to compute the funnel, their
ratio (rtdpy funnel / ours warm), and the largest difference relative to the largest
deviation. For the closed–closed ADM rtdpy's own grid error is shown too: the difference
between its 200- and 400-node solutions divided by 3 (it is second order), which the
difference between the two codes should match.

Run: ``python benchmarks/line.py`` (a few minutes on 2 cores; rtdpy is in the ``bench``
extra).
"""

import statistics
import time

import jax
import numpy as np
import rtdpy

import axialmix  # noqa: F401  (float64)
from axialmix.line import Unit, funnel

STEP = 2.0**-10


def seconds(function, repeats=5):
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def grid(count):
    durations = np.unique(np.round(np.geomspace(0.05, 5.0, count) / STEP) * STEP)
    magnitudes = np.linspace(-2.0, 2.0, count)
    return durations, magnitudes


def row(label, unit, model_factory, count, nx_pair=None):
    durations, magnitudes = grid(count)
    start = time.perf_counter()
    ours = np.asarray(funnel(unit, durations, magnitudes).max_deviation)
    first = time.perf_counter() - start
    warm = seconds(lambda: funnel(unit, durations, magnitudes).max_deviation)
    start = time.perf_counter()
    model = model_factory()
    build = time.perf_counter() - start
    start = time.perf_counter()
    _, _, theirs = model.funnelplot(durations, magnitudes)
    theirs_seconds = time.perf_counter() - start
    scale = np.abs(ours).max()
    difference = np.abs(ours - theirs).max() / scale
    own_error = ""
    if nx_pair is not None:
        coarse = nx_pair().funnelplot(durations, magnitudes)[2]
        own_error = f"{np.abs(theirs - coarse).max() / 3 / scale:10.2e}"
    cells = f"{magnitudes.size}x{durations.size}"
    print(
        f"{label:<22} {cells:>7} {first:9.3f} {warm:9.4f} {build:9.3f} {theirs_seconds:9.3f} "
        f"{theirs_seconds / warm:8.0f} {difference:10.2e} {own_error:>10}"
    )


def main():
    print("Funnel plot: axialmix.line.funnel vs rtdpy funnelplot (tau = 1, rtdpy dt = 1/1024)")
    print(
        f"{'RTD':<22} {'grid':>7} {'ours 1st':>9} {'ours':>9} {'rtdpy RTD':>9} {'rtdpy':>9} "
        f"{'ratio':>8} "
        f"{'max diff':>10} {'rtdpy err':>10}"
    )
    for count in (10, 30, 60):
        for n in (2.0, 5.0, 20.0):
            row(f"tanks n={n:g}", Unit.tanks(1.0, n),
                lambda n=n: rtdpy.Ncstr(tau=1.0, n=n, dt=STEP, time_end=14.0), count)
        for peclet in (7.5, 20.0, 100.0):
            row(
                f"closed-closed Pe={peclet:g}",
                Unit.closed_closed(1.0, peclet),
                lambda peclet=peclet: rtdpy.AD_cc(tau=1.0, peclet=peclet, dt=STEP, time_end=6.0,
                                                  nx=400),
                count,
                nx_pair=lambda peclet=peclet: rtdpy.AD_cc(
                    tau=1.0, peclet=peclet, dt=STEP, time_end=6.0, nx=200),
            )
    print(
        "\nrtdpy err: its 400-node result minus its 200-node result, over 3 (second order); "
        "max diff: |ours - rtdpy 400 nodes|, both relative to the largest deviation."
    )


if __name__ == "__main__":
    main()
