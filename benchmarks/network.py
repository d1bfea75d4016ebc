"""Accuracy and speed of the compartment-network model (axialmix.network).

Printed tables:

1. the ADM chain (Danckwerts boundaries, tau = 1) against the exact closed–closed exit age
   (axialmix.analytic.exit_age_closed) on theta in [0, 3] (121 points): max |E - E_exact|
   for 10 … 160 cells, central and upwind chains, and the ratio of successive errors
   (4 = second order, 2 = first order);
2. the discrete-step network (fractions k dt per step) against the continuous one, for the
   four-compartment model (2.125, 2.125, 0.625, k_out 1): max error and ratio as dt halves;
3. four_compartment_exit_age speed on 201 uniform times: jitted forward call, forward and
   gradient, and the source's 21³ = 9,261-point grid vmapped, against SciPy's solve_ivp
   (LSODA, rtol 1e-8) for one curve, measured in the same run (medians of repeats);
4. traced times, as inside a fit: compile seconds and run milliseconds of E and its Jacobian
   in the four rates and a dead time, by what the program is told of its times (``regular``:
   not said, which compiles both propagations, or said), on the 4,145 regular bins of the
   simulator's histogram (with and without a dead time that clips the first bins) and on
   the 17 irregular times of an example curve. Both are checked against ``expm(K t) e_1``
   at every time before they are timed.

Run: ``python benchmarks/network.py`` (about two minutes on 2 cores).
"""

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm as scipy_expm

import axialmix  # noqa: F401  (float64)
from axialmix.analytic import exit_age_closed
from axialmix.network import (
    adm_chain,
    exit_age,
    four_compartment,
    four_compartment_exit_age,
    four_compartment_generator,
    regular_grid,
)


def median_seconds(function, repeats=5):
    function()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def chain_table():
    theta = np.linspace(0.0, 3.0, 121)
    print("ADM chain vs exact closed-closed exit age (max abs error, tau = 1)")
    print(f"{'Pe':>6} {'cells':>6} {'central':>11} {'ratio':>6} {'upwind':>11} {'ratio':>6}")
    for peclet in (1.0, 7.5, 50.0):
        exact = np.asarray(exit_age_closed(theta, 1.0, peclet))
        previous = {}
        for cells in (10, 20, 40, 80, 160):
            row = [f"{peclet:6g}", f"{cells:6d}"]
            for scheme in ("central", "upwind"):
                try:
                    values = np.asarray(exit_age(adm_chain(1.0, peclet, cells, scheme=scheme),
                                                 theta))
                except ValueError:
                    row += [f"{'n/a':>11}", f"{'':>6}"]
                    continue
                error = np.abs(values - exact).max()
                ratio = previous.get(scheme, np.nan) / error
                previous[scheme] = error
                row += [f"{error:11.3e}", f"{ratio:6.2f}"]
            print(" ".join(row))
    print()


def discrete_table():
    network = four_compartment(2.125, 2.125, 0.625, 1.0)
    times = np.linspace(0.0, 24.0, 121)
    exact = np.asarray(exit_age(network, times))
    print("Discrete steps vs continuous time, four-compartment (max abs error)")
    print(f"{'dt':>8} {'error':>11} {'ratio':>6}")
    previous = np.nan
    for dt in (0.1, 0.05, 0.025, 0.0125, 0.00625):
        error = np.abs(np.asarray(exit_age(network.discretised(dt), times)) - exact).max()
        print(f"{dt:8g} {error:11.3e} {previous / error:6.2f}")
        previous = error
    print()


def speed_table():
    times = np.linspace(0.0, 20.0, 201)
    k = jnp.array([2.125, 2.125, 0.625, 1.0])
    forward = jax.jit(lambda p: four_compartment_exit_age(times, *p))
    gradient = jax.jit(jax.value_and_grad(lambda p: jnp.sum(four_compartment_exit_age(times, *p)
                                                            ** 2)))
    axis = np.arange(0.0, 2.5 + 1e-9, 0.125)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    grid = jnp.asarray(np.concatenate([grid, np.ones((grid.shape[0], 1))], axis=1))
    batched = jax.jit(jax.vmap(lambda p: four_compartment_exit_age(times, *p)))

    generator = np.asarray(four_compartment_generator(*k))

    def scipy_curve():
        solution = solve_ivp(lambda t, m: generator @ m, (0.0, 20.0), [1.0, 0, 0, 0],
                             t_eval=times, rtol=1e-8, atol=1e-12, method="LSODA")
        return solution.y[3]

    error = np.abs(scipy_curve() - np.asarray(forward(k))).max()
    t_forward = median_seconds(lambda: forward(k).block_until_ready(), 20)
    t_gradient = median_seconds(lambda: gradient(k)[1].block_until_ready(), 20)
    t_grid = median_seconds(lambda: batched(grid).block_until_ready(), 3)
    t_scipy = median_seconds(scipy_curve, 5)
    print("four_compartment_exit_age, 201 times (median wall seconds, same run)")
    print(f"{'task':<38} {'seconds':>11} {'vs SciPy curve':>15}")
    for name, seconds in (
        ("forward, jitted", t_forward),
        ("forward + gradient, jitted", t_gradient),
        ("9,261-point grid, vmapped (total)", t_grid),
        ("9,261-point grid, per curve", t_grid / grid.shape[0]),
        ("SciPy solve_ivp LSODA, one curve", t_scipy),
    ):
        print(f"{name:<38} {seconds:11.3e} {seconds / t_scipy:15.3g}")
    print(f"max |E_jax - E_scipy| = {error:.2e} (SciPy rtol 1e-8)")


def _told(regular):
    """E and its Jacobian in (rates, dead time) at traced times, freshly jitted."""

    def both(rates, dead, times):
        def curve(r, d):
            return four_compartment_exit_age(times - d, *r, regular=regular)

        return curve(rates, dead), jax.jacfwd(curve, argnums=(0, 1))(rates, dead)

    return jax.jit(both)


def traced_times_table():
    jax.config.update("jax_enable_compilation_cache", False)  # every compile is a cold one
    rates = jnp.array([1.34, 1.01, 0.204, 4.77])
    generator = np.asarray(four_compartment_generator(*rates))
    example = np.r_[np.arange(16.0), 18.0, 22.0, 27.0, 33.0]
    cases = (("4,145 regular bins", np.arange(4145) * 0.01 + 0.005, 0.0),
             ("4,145 bins, dead time 0.123", np.arange(4145) * 0.01 + 0.005, 0.123),
             ("17 irregular times", example[:17], 0.4))
    print("Traced times (inside a fit): E and its Jacobian in the rates and the dead time")
    print(f"{'times':>28} {'said':>9} {'compile s':>10} {'run ms':>8} {'not said':>9} "
          f"{'compile s':>10} {'run ms':>8} {'compile ratio':>14} {'run ratio':>10}")
    for label, times, dead in cases:
        regular = regular_grid(times)
        shifted = np.maximum(times - dead, 0.0)
        exact = np.where(times - dead >= 0,
                         [float(rates[3]) * scipy_expm(generator * x)[3, 0] for x in shifted], 0.0)
        row = {}
        for told in (regular, None):
            program = _told(told)
            arguments = (rates, jnp.asarray(dead), jnp.asarray(times))
            start = time.perf_counter()
            compiled = program.lower(*arguments).compile()
            compile_seconds = time.perf_counter() - start
            values = np.asarray(compiled(*arguments)[0])
            error = float(np.max(np.abs(values - exact)) / np.max(np.abs(exact)))
            if not error < 1e-9:
                raise SystemExit(f"{label}, regular={told}: E differs from expm at each time by "
                                 f"{error:.2e} of the peak; not timed")
            run = median_seconds(lambda c=compiled, a=arguments: jax.block_until_ready(c(*a)))
            row[told] = (compile_seconds, run)
        (c_said, r_said), (c_none, r_none) = row[regular], row[None]
        print(f"{label:>28} {str(regular):>9} {c_said:10.2f} {r_said * 1e3:8.2f} {'None':>9} "
              f"{c_none:10.2f} {r_none * 1e3:8.2f} {c_none / c_said:13.2f}x "
              f"{r_none / r_said:9.2f}x")
    print()


if __name__ == "__main__":
    chain_table()
    discrete_table()
    speed_table()
    traced_times_table()
