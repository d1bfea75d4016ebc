"""The multi-start solver: start points, the compiled single-start program run over starts
and curves, the best start checked by a Gauss–Newton step and polished where
Levenberg–Marquardt stopped short (:class:`~fitting.solve.MultiStartSolver`)."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.parameters import Layout
from fitting.solve.padding import pad_curve, padded_length
from fitting.solve.programs import Program, run_program
from fitting.solve.second_order import newton_polish
from fitting.solve.settings import SolverPlan
from fitting.solve.single_start import solver_program
from fitting.solve.status import PLATEAU, Status


class MultiStartSolver:
    """A multi-start solver: the compiled single-start program run over starts and curves.

    Each start on each curve is one call of one compiled program (no ``vmap``); the start
    with the lowest finite loss wins, and its Gauss–Newton step (least squares) is checked
    in NumPy. Where Levenberg–Marquardt stops at a point that check does not accept (a flat
    loss, or a minimum held only by the second-order term ``Σ r ∇²r`` that Gauss–Newton
    ignores, as on the four-compartment mirror line), Newton's method with the full Hessian
    (the program of :func:`compiled_curvature`, which the second-order check needs there
    anyway) continues from it while the Hessian is positive definite, and
    Levenberg–Marquardt runs once more from its end. Where Levenberg–Marquardt crawls (status
    SLOW, or out of steps) along a curved valley, L-BFGS, which learns the curvature along
    it, redoes that start (a second program, compiled only then) and the better of the two
    is kept. Their evaluations are counted too.
    Build it with :func:`compiled_solver`, run it with :func:`run_solver`.

    **Arguments:** `model`, `layout`, `options` (a :class:`SolverPlan`), and `batch`:
    ``'curves'`` (each row of the arguments is a curve with its own data) or ``'bases'`` (each
    row is a set of fixed-parameter values on one curve, for profiles).
    """

    def __init__(self, model, layout: Layout, options: SolverPlan, batch: str):
        if batch not in ("curves", "bases"):
            raise ValueError(f"batch must be 'curves' or 'bases', got {batch!r}")
        self.model, self.layout, self.options, self.batch = model, layout, options, batch
        self.program = solver_program(model, layout, options)
        self._lbfgs: Program | None = None

    def __call__(self, starts, warm, base, time, observed, weights) -> tuple[dict, float, float]:
        """Run every start on every row; returns the outputs (a leading axis per row), the run
        time and the compile (or load) time in seconds."""
        starts = np.asarray(starts, dtype=float)
        warm = np.asarray(warm, dtype=bool)
        base = np.asarray(base, dtype=float)
        shared = self.batch == "bases"
        times = [0.0, 0.0]
        outputs = []
        for i in range(starts.shape[0]):
            data = [np.asarray(a if shared else a[i], dtype=float)
                    for a in (time, observed, weights)]
            size = data[0].shape[0]
            padded = pad_curve(*data, padded_length(size))
            per_start = [run_program(self.program, (starts[i, s], np.asarray(warm[s]), base[i],
                                              *padded), times)
                         for s in range(starts.shape[1])]
            values = np.array([float(o["scaled_loss"]) for o in per_start])
            best = int(np.argmin(np.where(np.isfinite(values), values, np.inf)))
            out = per_start[best]
            status, newton_step = self._check(out, *padded)
            evaluations = int(np.sum([o["evaluations"] for o in per_start]))
            steps = int(out["steps"])
            polished = None
            if self.options.method == "lm" and status == Status.FLAT:
                polished = newton_polish(self.model, self.layout, self.program, out,
                                         base[i], padded, times)
            elif self.options.method == "lm" and status in (Status.SLOW, Status.MAX_STEPS):
                polished = run_program(self.lbfgs_program(),
                                       (starts[i, best], np.asarray(warm[best]), base[i],
                                        *padded), times)
            if polished is not None:
                evaluations += int(polished["evaluations"])
                steps += int(polished["steps"])
                if float(polished["scaled_loss"]) <= values[best]:
                    out, values[best] = polished, float(polished["scaled_loss"])
                    status, newton_step = self._check(out, *padded)
            # A model curve that explains (almost) nothing of the data sits on a plateau of
            # the loss where every stopping rule can fire; never call that converged.
            if values[best] >= PLATEAU:
                status = Status.MISSES_DATA
            outputs.append({
                "free_values": out["free_values"],
                "all_values": out["all_values"],
                "predicted": out["predicted"][:size],
                "jacobian": out["jacobian"][:size],
                "all_from_free": out["all_from_free"],
                "scaled_loss": np.asarray(values[best]),
                "start_losses": values * float(out["scale"]),
                # Where each start ended (free values; the polished best start's end for it).
                "start_values": np.stack([out["free_values"] if s == best else
                                          o["free_values"] for s, o in enumerate(per_start)]),
                "grad_norm": out["grad_norm"],
                "steps": np.asarray(steps),
                "evaluations": np.asarray(evaluations),
                "status": np.asarray(int(status)),
                "newton_step": np.asarray(newton_step),
            })
        run_time, compile_time = times
        return ({k: np.stack([o[k] for o in outputs]) for k in outputs[0]}, run_time,
                compile_time)

    def lbfgs_program(self) -> Program:
        """The L-BFGS program that redoes a start where Levenberg–Marquardt crawled (built once)."""
        if self._lbfgs is None:
            # Through the process's shared programs: a plan without warm-up (the one-start
            # refits of the error models' passes) runs on the L-BFGS program of the same plan
            # with a warm-up, its warm-up skipped at run time (one program compiled, not two).
            self._lbfgs = solver_program(self.model, self.layout,
                                         dataclasses.replace(self.options, method="lbfgs"))
        return self._lbfgs

    def _check(self, out: dict, time, observed, weights) -> tuple[Status, float]:
        """The status after the Gauss–Newton check (least squares), and that step's length."""
        status = Status(int(out["status"]))
        if self.options.loss != "sse":
            return status, math.nan
        # Distance to the optimum, estimated by one Gauss-Newton step in the transformed
        # coordinates (minimum-norm step: unidentifiable directions do not count).
        used = weights > 0
        root = np.sqrt(weights)
        design = np.where(used[:, None], root[:, None] * out["jacobian"] * out["derivative"], 0.0)
        residual = np.where(used, root * (out["predicted"] - observed), 0.0)
        newton_step = math.nan
        if np.all(np.isfinite(design)) and np.all(np.isfinite(residual)):
            step = np.linalg.lstsq(design, -residual, rcond=1e-10)[0]
            newton_step = float(np.max(np.abs(step)))
        if status in (Status.GRADIENT, Status.LOSS_CHANGE, Status.NO_DECREASE):
            if newton_step <= self.options.xtol:
                if status == Status.NO_DECREASE:
                    status = Status.PRECISION_LIMIT
            else:
                status = Status.FLAT
        return status, newton_step


@functools.lru_cache(maxsize=64)
def compiled_solver(model, layout: Layout, options: SolverPlan, batch: str) -> MultiStartSolver:
    """The multi-start solver of one model, layout and option set (see :class:`MultiStartSolver`).

    **Arguments:** the model, its :class:`~fitting.parameters.Layout`, the
    :class:`SolverPlan`, and `batch` (``'curves'`` or ``'bases'``).

    **Returns:** the solver, kept for later fits of the same kind.
    """
    return MultiStartSolver(model, layout, options, batch)


def run_solver(solver: Callable, *arguments) -> tuple[dict, float, float]:
    """Run a solver from :func:`compiled_solver`.

    **Arguments:** the solver, then starts ``(rows, starts, free)``, warm-up flags
    ``(starts,)``, base values ``(rows, parameters)``, and times, observed values and weights
    (``(rows, samples)`` for ``'curves'``, ``(samples,)`` for ``'bases'``).

    **Returns:** ``(outputs, run time, compile time)``, times in seconds.
    """
    return solver(*arguments)


def start_points(
    layout: Layout, start: np.ndarray, anchor: np.ndarray | None, n_starts: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Start points in unconstrained coordinates, and which of them get the Adam warm-up.

    Row 0 is `start`; with `anchor` (the method-of-moments estimate) and ``n_starts >= 2``,
    row 1 is the anchor; the remaining rows are random: log-uniform within a factor of 10 of
    the anchor (or start) for one-sided bounds, uniform inside two-sided bounds (log-uniform
    when positive and wider than a factor 100), normal around it without bounds.
    """
    u_start = layout.unconstrained_from_physical(start)
    starts = np.tile(u_start, (n_starts, 1))
    first_random = 1
    centre = u_start
    if anchor is not None and n_starts >= 2:
        centre = layout.unconstrained_from_physical(anchor)
        starts[1] = centre
        first_random = 2
    count = n_starts - first_random
    rng = np.random.default_rng(seed) if count > 0 else None  # made only when drawn from
    spread = math.log(10.0)
    for j, kind in enumerate(layout.kinds):
        if count <= 0:
            break
        if kind in ("lower", "upper"):
            starts[first_random:, j] = centre[j] + rng.uniform(-spread, spread, count)
        elif kind == "both":
            low, high = layout.lower[j], layout.upper[j]
            fraction = rng.uniform(0.02, 0.98, count)
            if low > 0 and high / low > 100:
                values = np.exp(np.log(low) + fraction * (np.log(high) - np.log(low)))
            else:
                values = low + fraction * (high - low)
            starts[first_random:, j] = np.log((values - low) / (high - values))
        else:
            starts[first_random:, j] = centre[j] + rng.normal(0.0, 1.0, count)
    warm = np.arange(n_starts) >= first_random
    return starts, warm
