"""Models to fit: named, immutable wrappers around the forward models of :mod:`axialmix`.

A :class:`Model` is a pure JAX function ``f(t, params) -> E(t)`` (``params`` a dict of scalars,
``E`` in 1/time) together with its parameter names, default :class:`~fitting.parameters.Parameter`
settings (start value and bounds) and, where one exists, a method-of-moments start value
computed from a measured curve.

Built-in models (also by name through :func:`get_model`):

* ``'adm'`` (:data:`adm_closed`): closed–closed ADM, exact
  (:func:`axialmix.analytic.exit_age_closed`; a curve of 16,384 points or more, in a fit
  one of more than 8,192 samples padded to a power of two, from exact values at the nodes
  of Chebyshev panels, interpolated to about 1e-13 of the peak and checked at every
  evaluation, :func:`axialmix.analytic.panels.exit_age_closed_panels`);
  parameters ``tau``, ``peclet``.
* ``'adm-fv'`` (:data:`adm_closed_fv`): closed–closed ADM by finite volumes
  (:func:`axialmix.adm.exit_age`); ``tau``, ``peclet``.
* ``'adm-open'`` (:data:`adm_open`): open–open ADM (:func:`axialmix.analytic.exit_age_open`);
  ``tau``, ``peclet``.
* ``'tanks'`` (:data:`tanks`): tanks in series, gamma form with a real number of tanks
  (:func:`axialmix.analytic.exit_age_tanks`); ``tau``, ``n_tanks``.
* ``'four-compartment'`` (:data:`four_compartment`): the source's 2 × 2 network
  (:func:`axialmix.network.four_compartment_exit_age`); ``k_f``, ``k_r``, ``k_s``, ``k_out``.
* ``'adm-exchange'`` (:data:`adm_exchange`): closed–closed ADM whose flowing material
  exchanges with a dead zone (MODELS.md section 6), exact (transfer function
  :class:`~axialmix.analytic.transfer.ExchangeZone` inverted by
  :func:`axialmix.analytic.responses.exit_age`); ``tau`` (the flowing material's space time
  L/v; the mean residence time is ``(1 + beta) tau``), ``peclet``, ``beta`` (dead-zone to
  flowing hold-up, >= 0), ``k_d`` (exchange rate, 1/time, > 0).
* ``'tanks-exchange'`` (:data:`tanks_exchange`): tanks in series with a dead zone, exact;
  ``tau`` (the flowing material's mean residence time), ``n_tanks``, ``beta``, ``k_d``.
* ``'adm-tank'`` (:data:`adm_tank`): closed–closed ADM followed by a stirred tank (a detector
  cell, feed frame or hopper; the product of the transfer functions), exact; ``tau`` (L/v of
  the dispersed section), ``peclet``, ``tau_tank``; the mean residence time is
  ``tau + tau_tank``.

Method-of-moments start values: ``tau`` = mean, ``Pe`` from
:func:`axialmix.analytic.approximate_peclet_from_variance_ratio` (the closed–closed relation to 5 %,
also used as a start for the open–open model; the dead-zone and series models match the moments
exactly with :func:`axialmix.analytic.peclet_from_moments`), ``n_tanks = mean² / variance``; for the
four-compartment model all rates equal, matched to the mean residence time. Dead-zone models start
from beta = 0.25 with the exchange making half of the curve's variance (which sets ``k_d``) and the
flowing part the rest of the mean and variance; the ADM with a tank starts with the tank making a
tenth of the variance.

Model-specific facts are optional hooks of a :class:`Model`, so no other module needs to know
a model by name: ``default_starts`` (how many starts a fit makes by default),
``equivalent_adm`` (the closed–closed ADM equivalent to fitted values, with units, computed
by :mod:`axialmix`), ``statements`` (facts about a fit in words, e.g. the
four-compartment model's twin solutions), ``units`` and ``meanings`` (each parameter's unit
and what it means, e.g. that the open–open ``tau`` is ``L/v``, not the mean residence time),
and ``step_response`` and ``inlet_response`` (the model's exact outlet signal for a step and
for a sampled inlet signal, used by the measurement model of :mod:`fitting.measurement`).

The package's modules, each importing only those before it: :mod:`~fitting.models.base` (the
:class:`Model` type, :func:`custom_model`), :mod:`~fitting.models.moments` (a curve's
moments for start values), :mod:`~fitting.models.inlet` (responses to a sampled inlet
signal), :mod:`~fitting.models.adm` (the ADM and tanks in series),
:mod:`~fitting.models.exchange` (dead zones and units in series),
:mod:`~fitting.models.network` (compartment networks) and :mod:`~fitting.models.registry`
(the built-in models by name). This face re-exports their public names.
"""

# Public names outside the documented API (``__all__``) are re-exported by a redundant alias.
from fitting.models.adm import adm_closed, adm_closed_fv, adm_open, tanks
from fitting.models.base import EquivalentADM as EquivalentADM
from fitting.models.base import InletResponse as InletResponse
from fitting.models.base import Model, custom_model, parameter_unit
from fitting.models.base import ModelFunction as ModelFunction
from fitting.models.base import Statements as Statements
from fitting.models.exchange import EXCHANGE_START_CAPACITY as EXCHANGE_START_CAPACITY
from fitting.models.exchange import EXCHANGE_START_VARIANCE_SHARE as EXCHANGE_START_VARIANCE_SHARE
from fitting.models.exchange import SERIES_START_VARIANCE_SHARE as SERIES_START_VARIANCE_SHARE
from fitting.models.exchange import adm_exchange, adm_tank, tanks_exchange
from fitting.models.inlet import INLET_NODES as INLET_NODES
from fitting.models.moments import moment_estimates
from fitting.models.network import FOUR_COMPARTMENT_NAMES as FOUR_COMPARTMENT_NAMES
from fitting.models.network import MIRROR_CLOSENESS as MIRROR_CLOSENESS
from fitting.models.network import NETWORK_STARTS as NETWORK_STARTS
from fitting.models.network import four_compartment, network_model
from fitting.models.registry import MODELS, get_model

__all__ = [
    "MODELS",
    "Model",
    "adm_closed",
    "adm_closed_fv",
    "adm_exchange",
    "adm_open",
    "adm_tank",
    "custom_model",
    "four_compartment",
    "get_model",
    "moment_estimates",
    "network_model",
    "parameter_unit",
    "tanks",
    "tanks_exchange",
]
