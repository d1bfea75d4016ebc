"""Deprecated: the contents of this module moved to the layers of :mod:`fitting` (kept one
release): :mod:`fitting.parameters`, :mod:`fitting.solve`, :mod:`fitting.uncertainty`,
:mod:`fitting.result` and :mod:`fitting.fit`."""

from fitting.fit import fit, fit_many
from fitting.parameters import Parameter, Parameters
from fitting.result import FitResult, RelativeErrors
from fitting.solve import CONVERGED, SECOND_ORDER_DISTANCE, STATUS_MESSAGES, Status
from fitting.uncertainty import LOG_INTERVAL_LIMIT

#: Defaults of :class:`~fitting.result.RelativeErrors`, under their earlier names.
RELATIVE_FLOOR = RelativeErrors().floor
RELATIVE_MAX_PASSES, RELATIVE_CHANGE = RelativeErrors().max_passes, RelativeErrors().change

__all__ = [
    "CONVERGED",
    "LOG_INTERVAL_LIMIT",
    "RELATIVE_CHANGE",
    "RELATIVE_FLOOR",
    "RELATIVE_MAX_PASSES",
    "SECOND_ORDER_DISTANCE",
    "STATUS_MESSAGES",
    "FitResult",
    "Parameter",
    "Parameters",
    "Status",
    "fit",
    "fit_many",
]
