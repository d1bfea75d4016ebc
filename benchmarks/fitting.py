"""Gradient fits against the source's exhaustive grid search, on the example curves.

For every curve in examples/data the four-compartment model (k_out held at its design value
0.8 /s, as the source's grid held everything but k_f, k_r, k_s) is fitted two ways, on the
same loss:

* grid: every point of ``[0 : 0.125 : 2.5]³`` (9,261 model evaluations), chunked and vmapped;
* gradient: L-BFGS from ``STARTS`` starts (the moment estimate plus random ones) on the least
  squares loss; for the source's mean absolute error the least-squares optimum is then
  polished by at most ``POLISH_STEPS`` L-BFGS iterations on that loss (its evaluations are
  added).

Both timings exclude compilation (a warm-up call compiles first). Printed: losses,
evaluations, the evaluation ratio, wall times, best parameters, and what the curve
determines (from the gradient fit's uncertainty).

    python benchmarks/fitting.py [--data examples/data] [--starts 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# This script's own name would shadow the `fitting` package when run as a file.
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]

import axialmix  # noqa: E402, F401  (float64)
from fitting.data import read_many  # noqa: E402
from fitting.fit import fit  # noqa: E402
from fitting.gridsearch import grid_search, source_flux_grid  # noqa: E402
from fitting.models import four_compartment  # noqa: E402
from fitting.parameters import Parameter  # noqa: E402
from fitting.report import identifiability_statements, text_table  # noqa: E402
from fitting.solve import MultiStart, Optimiser  # noqa: E402

K_OUT = 0.8  # 1/s, the examples' design value (examples/make_data.py)
STARTS = 3
#: L-BFGS iterations of the MAE polish: the mean absolute error is not smooth, so L-BFGS
#: creeps along its kinks with many short line searches; the first few steps give most of
#: the gain (on incline_plus14: 5 steps reach 0.0027151, 25 steps 0.0027127).
POLISH_STEPS = 5
RATES = ("k_f", "k_r", "k_s")


def gradient_fits(curve, starts: int):
    """Least-squares multi-start fit, then the MAE polish from its optimum."""
    held = {"k_out": Parameter(K_OUT, vary=False)}
    sse = fit(four_compartment, curve, held, loss="sse",
              multistart=MultiStart(n_starts=starts, warmup_steps=0))
    polish_start = {**held, **{n: Parameter(sse.values[n], min=0.0) for n in RATES}}
    mae = fit(four_compartment, curve, polish_start, loss="mae",
              multistart=MultiStart(n_starts=1, warmup_steps=0),
              optimiser=Optimiser(max_steps=POLISH_STEPS))
    return sse, mae


def _rates(values) -> str:
    return "(" + ", ".join(f"{values[n]:.3f}" for n in RATES) + ")"


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and print its tables; returns the exit status."""
    parser = argparse.ArgumentParser(description="gradient fits vs grid search")
    parser.add_argument("--data", type=Path, default=Path(__file__).parents[1] / "examples/data")
    parser.add_argument("--starts", type=int, default=STARTS)
    args = parser.parse_args(argv)
    curves = read_many(args.data)
    grid = source_flux_grid()
    grids = dict.fromkeys(RATES, grid)
    # Warm-up: compile the solvers and the grid kernel once, outside the timings.
    gradient_fits(curves[0], args.starts)
    for loss in ("sse", "mae"):
        grid_search(four_compartment, curves[0], {"k_f": grid[:2], "k_r": grid[:2],
                                                  "k_s": grid[:2]},
                    loss=loss, fixed={"k_out": K_OUT}, progress=False)

    header = ["curve", "loss", "gradient", "grid", "grad evals", "grid evals", "ratio",
              "grad s", "grid s", "gradient (k_f, k_r, k_s)", "grid (k_f, k_r, k_s)", "ok"]
    rows, statements, all_ok = [], [], True
    for curve in curves:
        sse, mae = gradient_fits(curve, args.starts)
        for loss, result, evaluations, seconds in (
            ("sse", sse, sse.n_evaluations, sse.wall_time),
            ("mae", mae, sse.n_evaluations + mae.n_evaluations, sse.wall_time + mae.wall_time),
        ):
            best = grid_search(four_compartment, curve, grids, loss=loss,
                               fixed={"k_out": K_OUT}, progress=False)
            ratio = best.n_evaluations / evaluations
            ok = result.loss <= best.loss and ratio >= 50
            all_ok &= ok
            rows.append([curve.name, loss, f"{result.loss:.5g}", f"{best.loss:.5g}",
                         f"{evaluations:,}", f"{best.n_evaluations:,}", f"{ratio:.0f}x",
                         f"{seconds:.3f}", f"{best.wall_time:.3f}", _rates(result.values),
                         _rates(best.values), "yes" if ok else "NO"])
        statements.append((curve.name, identifiability_statements(sse)))
    print(f"Four-compartment fits, k_out = {K_OUT} 1/s held; gradient = L-BFGS from "
          f"{args.starts} starts (sse), polished on mae from the sse optimum; grid = "
          f"[0:0.125:2.5]^3.\n")
    print(text_table(header, rows))
    print("\nok: gradient loss <= grid loss with at least 50x fewer model evaluations.")
    print("\nWhat each curve determines (least-squares fit, linearised uncertainty):")
    for name, sentences in statements:
        print(f"  {name}:")
        for sentence in sentences:
            print(f"    - {sentence}")
    return 0 if all_ok else 1


if __name__ == "__main__":
    sys.exit(main())
