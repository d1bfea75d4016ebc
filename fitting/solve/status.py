"""Why a fit stopped: the status codes of the optimisation loop, their messages, and which
of them count as converged."""

from __future__ import annotations

import enum


class Status(enum.IntEnum):
    """Why a fit stopped; the values are the status codes of earlier releases."""

    GRADIENT = 0
    LOSS_CHANGE = 1
    MAX_STEPS = 2
    NO_DECREASE = 3
    NOT_FINITE = 4
    PRECISION_LIMIT = 5
    FLAT = 6
    MISSES_DATA = 7
    SECOND_ORDER = 8
    ON_BOUND = 9
    SLOW = 10

    @property
    def converged(self) -> bool:
        """Whether this stopping rule counts as convergence."""
        return self in CONVERGED

    @property
    def message(self) -> str:
        """The stopping rule in words."""
        return STATUS_MESSAGES[self]


#: Stopping codes of the optimisation loop and their messages.
STATUS_MESSAGES = {
    Status.GRADIENT: "converged: gradient norm below tol",
    Status.LOSS_CHANGE: "converged: relative loss change below ftol",
    Status.MAX_STEPS: "not converged: maximum number of steps reached",
    Status.NO_DECREASE: "not converged: no step found a decrease (line search, or damping "
    "past 1e16)",
    Status.NOT_FINITE: "not converged: the loss is not finite",
    Status.PRECISION_LIMIT: "converged: at the precision limit (no further decrease possible; "
    "Gauss-Newton step below xtol)",
    Status.FLAT: "not converged: a Gauss-Newton step from here is still large (flat loss: the "
    "model curve may miss the data; try other start values or n_starts > 1)",
    Status.MISSES_DATA: "not converged: the model curve misses the data (loss at least 99 % of "
    "that of a zero curve); try other start values or n_starts > 1",
    Status.SECOND_ORDER: "converged: a local minimum where the Gauss-Newton curvature is "
    "singular (the full Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors); a parameter combination is determined only at second "
    "order, see the identifiability report",
    Status.ON_BOUND: "converged: a minimum on the bound of {names} (the loss falls towards it; "
    "the other parameters' Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors)",
    Status.SLOW: "not converged: the loss fell by less than 0.1 % over 20 Levenberg-Marquardt "
    "steps (a slow crawl, e.g. along a valley towards a bound); try other start values, "
    "n_starts > 1 or method='lbfgs'",
}
#: Status codes that count as converged.
CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT, Status.SECOND_ORDER,
             Status.ON_BOUND)
#: Status codes that count as converged without the second-order check (profile re-fits).
FIRST_ORDER_CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT)
#: Newton distance to a local minimum, in standard errors, below which a fit that stopped on
#: a singular Gauss-Newton curvature counts as converged (status 8).
SECOND_ORDER_DISTANCE = 1e-3
#: Status of a loop that has not stopped yet.
RUNNING = -1
#: Scaled loss (1 = a zero model curve) at or above which a fit is reported as missing the data.
PLATEAU = 0.99
