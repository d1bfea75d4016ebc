"""Exact results of the axial dispersion model (MODELS.md section 2) and its relatives.

Everything here is JAX, float64, and differentiable in the parameters (``tau``, ``peclet``,
``n_tanks``); times are 1-D arrays in any unit with ``tau`` in the same unit, and densities
are returned in 1/(time unit).

* closed–closed (Danckwerts): :func:`exit_age_closed`, :func:`step_response_closed`,
  :func:`transfer_function_closed`, :func:`mean_closed`, :func:`variance_closed`,
  :func:`variance_ratio_closed`;
* open–open: :func:`exit_age_open`, :func:`step_response_open`, :func:`mean_open`,
  :func:`variance_open`;
* tanks in series (real-valued number of tanks): :func:`exit_age_tanks`,
  :func:`step_response_tanks`, :func:`mean_tanks`, :func:`variance_tanks`;
* inverse relations: :func:`peclet_from_moments`, :func:`sherritt_dispersion`,
  :func:`sherritt_peclet`, :func:`peclet_from_physical`, :func:`tau_from_physical`.
* any unit given by its transfer function (MODELS.md §6): :class:`ClosedClosedADM`,
  :class:`OpenOpenADM`, :class:`TanksInSeries`, :class:`StirredTank`, a dead zone on any of
  them (:class:`ExchangeZone`) and units in series (:class:`Series`), inverted exactly by
  :func:`exit_age`, :func:`step_response`, :func:`ramp_response` and, for a sampled inlet
  signal, :func:`inlet_response`;
* the ADM and tanks with a dead zone: :func:`exit_age_exchange`, :func:`step_response_exchange`,
  :func:`transfer_function_exchange`, :func:`mean_exchange`, :func:`variance_exchange`,
  :func:`exit_age_tanks_exchange`, :func:`step_response_tanks_exchange`,
  :func:`mean_tanks_exchange`, :func:`variance_tanks_exchange`.

:func:`peclet_from_variance_ratio` is the unchecked, traceable core of
:func:`peclet_from_moments`. :mod:`axialmix.analytic.highprecision` holds the slow mpmath
series used as the reference in tests and benchmarks. :mod:`axialmix.analytic.panels`
evaluates the closed–closed E on curves of many points from exact values at the nodes of
Chebyshev panels (about 1e-13 of the peak, checked at every evaluation).
"""

from axialmix.analytic.closed import (
    exit_age_closed,
    mean_closed,
    step_response_closed,
    transfer_function_closed,
    variance_closed,
    variance_ratio_closed,
)
from axialmix.analytic.exchange import (
    exit_age_exchange,
    exit_age_tanks_exchange,
    mean_exchange,
    mean_tanks_exchange,
    step_response_exchange,
    step_response_tanks_exchange,
    transfer_function_exchange,
    variance_exchange,
    variance_tanks_exchange,
)
from axialmix.analytic.inverse import (
    approximate_peclet_from_variance_ratio,
    peclet_from_moments,
    peclet_from_physical,
    peclet_from_variance_ratio,
    sherritt_dispersion,
    sherritt_peclet,
    tau_from_physical,
    transport_from_dimensionless,
)
from axialmix.analytic.open import exit_age_open, mean_open, step_response_open, variance_open
from axialmix.analytic.responses import (
    AccuracyWarning,
    exit_age,
    inlet_response,
    ramp_response,
    step_response,
    unverified_parameters,
)
from axialmix.analytic.tanks import exit_age_tanks, mean_tanks, step_response_tanks, variance_tanks
from axialmix.analytic.transfer import (
    ClosedClosedADM,
    ExchangeZone,
    OpenOpenADM,
    Series,
    StirredTank,
    TanksInSeries,
    TransferFunction,
)

__all__ = [
    "AccuracyWarning",
    "ClosedClosedADM",
    "ExchangeZone",
    "OpenOpenADM",
    "Series",
    "StirredTank",
    "TanksInSeries",
    "TransferFunction",
    "exit_age",
    "exit_age_exchange",
    "exit_age_tanks_exchange",
    "inlet_response",
    "mean_exchange",
    "mean_tanks_exchange",
    "ramp_response",
    "step_response",
    "step_response_exchange",
    "step_response_tanks_exchange",
    "transfer_function_exchange",
    "variance_exchange",
    "variance_tanks_exchange",
    "exit_age_closed",
    "exit_age_open",
    "exit_age_tanks",
    "mean_closed",
    "mean_open",
    "mean_tanks",
    "approximate_peclet_from_variance_ratio",
    "peclet_from_moments",
    "peclet_from_physical",
    "peclet_from_variance_ratio",
    "sherritt_dispersion",
    "sherritt_peclet",
    "step_response_closed",
    "step_response_open",
    "step_response_tanks",
    "unverified_parameters",
    "tau_from_physical",
    "transport_from_dimensionless",
    "transfer_function_closed",
    "variance_closed",
    "variance_open",
    "variance_ratio_closed",
    "variance_tanks",
]
