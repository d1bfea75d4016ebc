"""The global fit itself (:func:`~fitting.study.global_fit.global_fit`): the joint problem
solved by the project's compiled Levenberg–Marquardt solver, one start, then its result with
its uncertainty.
"""

from __future__ import annotations

import time as _time
from collections.abc import Mapping, Sequence

import numpy as np

from fitting.data import Curve
from fitting.result import FitResult
from fitting.solve import MultiStart, Optimiser, Status, compiled_solver, make_plan, run_solver
from fitting.study.global_fit.model import GlobalModel
from fitting.study.global_fit.problem import global_problem
from fitting.study.global_fit.propagation import fit_result
from fitting.study.global_fit.result import GlobalFitResult


def global_fit(
    spec: GlobalModel,
    curves: Sequence[Curve | tuple],
    factors: Mapping[str, Sequence[float]] | None = None,
    *,
    first: Sequence[FitResult] | None = None,
    weights: str | Sequence[float] = "combined",
    optimiser: Optimiser | None = None,
) -> GlobalFitResult:
    """Fit the curves of a study jointly: shared parameters and factor laws with one covariance.

    See the module docstring for the model, the two stages and the uncertainty.

    **Arguments:**

    - `spec`: the :class:`GlobalModel` (which parameters are shared, given by laws, per
      curve).
    - `curves`: raw tracer curves (:class:`~fitting.data.Curve` s or ``(time, values)``
      pairs, time in seconds for pairs), each on its own time grid, all in one time unit.
    - `factors`: factor columns by name, one number per curve (every column a law reads).
    - `first`: first-stage fits (:func:`fitting.fit.fit_many` with ``spec.curve_model``),
      or ``None`` to fit them here.
    - `weights`: ``"combined"`` (default), ``"per-curve"``, ``"equal"``, or one known weight
      per curve (see :func:`global_problem`).
    - `optimiser`: settings of the solver (:class:`~fitting.solve.Optimiser`; default
      Levenberg–Marquardt).

    **Returns:** a :class:`GlobalFitResult`.
    """
    began = _time.perf_counter()
    problem = global_problem(spec, curves, factors, first, weights)
    optimiser = optimiser if optimiser is not None else Optimiser()
    plan = make_plan("sse", optimiser, MultiStart(n_starts=1))
    layout = problem.layout
    solver = compiled_solver(problem.model, layout, plan, "curves")
    start_u = layout.unconstrained_from_physical(problem.start)
    out, _, compile_time = run_solver(
        solver, start_u[None, None, :], np.zeros(1, dtype=bool), problem.start[None, :],
        problem.time[None, :], problem.observed[None, :], problem.weights[None, :])
    out = {k: np.asarray(v[0]) for k, v in out.items()}
    status = Status(int(out["status"]))
    return fit_result(problem, out, status, compile_time, _time.perf_counter() - began)
