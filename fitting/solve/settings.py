"""The optimiser's settings: the local method and its tolerances
(:class:`~fitting.solve.Optimiser`), the starts (:class:`~fitting.solve.MultiStart`), and the
static plan one compiled solver is built for (:class:`~fitting.solve.SolverPlan`,
:func:`~fitting.solve.make_plan`)."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import equinox as eqx

from fitting.losses import LOSSES

#: The optimiser methods (see :class:`Optimiser`).
METHODS = ("auto", "lm", "lbfgs", "adam")
#: Method names in results and reports.
METHOD_NAMES = {"lm": "levenberg-marquardt", "lbfgs": "lbfgs", "adam": "adam"}


class Optimiser(eqx.Module):
    """Settings of the local optimiser, immutable.

    **Arguments:**

    - `method`: ``'auto'`` (default: Levenberg–Marquardt for least squares, L-BFGS for the
      mean absolute error), ``'lm'`` (Levenberg–Marquardt, least squares only), ``'lbfgs'``
      or ``'adam'``.
    - `max_steps`: iteration limit per start; ``None``: 500 for Levenberg–Marquardt and
      L-BFGS, 5000 for Adam.
    - `tol`: gradient-norm tolerance on the scaled loss in transformed coordinates.
    - `ftol`: relative loss change below which the iteration stops.
    - `xtol`: a least-squares fit counts as converged only if one Gauss–Newton step from the
      result would move no transformed coordinate by more than `xtol` (for positive
      parameters: a relative change).
    - `learning_rate`: Adam's step size in transformed coordinates.
    - `memory_size`: L-BFGS history length.
    """

    method: str = eqx.field(default="auto", static=True)
    max_steps: int | None = eqx.field(default=None, static=True)
    tol: float = eqx.field(default=1e-10, static=True)
    ftol: float = eqx.field(default=1e-10, static=True)
    xtol: float = eqx.field(default=1e-6, static=True)
    learning_rate: float = eqx.field(default=0.05, static=True)
    memory_size: int = eqx.field(default=10, static=True)

    def __check_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got "
                             f"{self.method!r}")
        if self.max_steps is not None and not self.max_steps >= 1:
            raise ValueError(f"max_steps must be at least 1, got {self.max_steps}")
        if not (self.tol > 0 and self.xtol > 0 and self.ftol >= 0):
            raise ValueError("tol and xtol must be positive and ftol non-negative")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be positive, got {self.learning_rate}")
        if not self.memory_size >= 1:
            raise ValueError(f"memory_size must be at least 1, got {self.memory_size}")

    @property
    def steps(self) -> int:
        """The iteration limit in force."""
        if self.max_steps is not None:
            return int(self.max_steps)
        return 5000 if self.method == "adam" else 500

    def resolved(self, loss: str) -> str:
        """The method used on `loss`: ``'auto'`` resolved, ``'lm'`` refused off least squares."""
        if self.method == "auto":
            return "lm" if loss == "sse" else "lbfgs"
        if self.method == "lm" and loss != "sse":
            raise ValueError(f"method 'lm' (Levenberg-Marquardt) fits least squares only; use "
                             f"'lbfgs' or 'adam' for loss {loss!r}")
        return self.method


class MultiStart(eqx.Module):
    """How many starts a fit makes and how random starts are drawn, immutable.

    **Arguments:**

    - `n_starts`: number of starts, run as one vmapped batch: the start value, then (for
      models with a moment estimate) the moment estimate, then random starts. ``None``
      (default): the model's default (the start value, plus the moment estimate when it
      differs, unless the model says otherwise).
    - `seed`: seed of the random starts.
    - `warmup_steps`: Adam steps applied to each random start before L-BFGS.
    """

    n_starts: int | None = eqx.field(default=None, static=True)
    seed: int = eqx.field(default=0, static=True)
    warmup_steps: int = eqx.field(default=100, static=True)

    def __check_init__(self):
        if self.n_starts is not None and not self.n_starts >= 1:
            raise ValueError(f"n_starts must be at least 1, got {self.n_starts}")
        if not self.warmup_steps >= 0:
            raise ValueError(f"warmup_steps must be non-negative, got {self.warmup_steps}")
        if (isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral)
                or self.seed < 0):
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")


@dataclass(frozen=True)
class SolverPlan:
    """The static settings one compiled solver is built for (hashable; see :func:`make_plan`)."""

    loss: str
    method: str
    max_steps: int
    tol: float
    ftol: float
    warmup_steps: int
    learning_rate: float
    memory_size: int
    xtol: float


def make_plan(loss: str, optimiser: Optimiser, multistart: MultiStart) -> SolverPlan:
    """The :class:`SolverPlan` of a loss and settings.

    A single start never warms up, so its solver has no Adam loop; ``method='auto'`` is
    resolved for the loss (:meth:`Optimiser.resolved`).

    **Arguments:** `loss`: a key of :data:`fitting.losses.LOSSES`; `optimiser`, `multistart`:
    the settings.

    **Returns:** the plan.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {sorted(LOSSES)}, got {loss!r}")
    n_starts = multistart.n_starts
    warmup = int(multistart.warmup_steps) if n_starts is None or n_starts > 1 else 0
    return SolverPlan(loss, optimiser.resolved(loss), optimiser.steps, float(optimiser.tol),
                      float(optimiser.ftol), warmup, float(optimiser.learning_rate),
                      int(optimiser.memory_size), float(optimiser.xtol))
