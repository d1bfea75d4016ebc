"""Dead zones and units in series (MODELS.md section 6): the ADM and tanks in series exchanging
with a dead zone, and the ADM followed by a stirred tank, exact through the transfer functions
of :mod:`axialmix.analytic` (``axialmix.analytic.transfer``)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import jax

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from axialmix.analytic import peclet_from_moments
from axialmix.analytic.responses import exit_age as _unit_exit_age
from axialmix.analytic.responses import step_response as _unit_step_response
from axialmix.analytic.transfer import (
    ClosedClosedADM,
    ExchangeZone,
    Series,
    StirredTank,
    TanksInSeries,
)
from fitting.data import Curve
from fitting.models.adm import ADM_UNITS, adm_defaults, adm_transport
from fitting.models.base import Model, ModelFunction
from fitting.models.inlet import quadrature_inlet_response
from fitting.models.moments import moment_estimates
from fitting.parameters import Parameter

#: :func:`axialmix.analytic.peclet_from_moments`, jitted (NaN outside its range): the exact
#: moment match the dead-zone and series models' starts are built on.
_peclet_from_moments = jax.jit(peclet_from_moments)


#: Start values of a dead zone: its capacity ratio beta, and the share of the curve's variance
#: its exchange makes (which sets k_d); the mobile-phase tau and Pe (or number of tanks) take
#: the rest, so the start matches the curve's mean and variance.
EXCHANGE_START_CAPACITY = 0.25
EXCHANGE_START_VARIANCE_SHARE = 0.5
#: Share of the curve's variance the stirred tank after an ADM makes at the start.
SERIES_START_VARIANCE_SHARE = 0.1


def _adm_exchange_unit(p):
    return ExchangeZone(ClosedClosedADM(p["tau"], p["peclet"]), p["beta"], p["k_d"])


def _tanks_exchange_unit(p):
    return ExchangeZone(TanksInSeries(p["tau"], p["n_tanks"]), p["beta"], p["k_d"])


def _adm_tank_unit(p):
    return Series(ClosedClosedADM(p["tau"], p["peclet"]), StirredTank(p["tau_tank"]))


def _unit_exit_age_function(unit_of: Callable) -> ModelFunction:
    """``f(t, params) -> E`` of a transfer-function unit, inverted exactly
    (:func:`axialmix.analytic.responses.exit_age`)."""

    def function(t, p):
        return _unit_exit_age(unit_of(p), t)

    return function


def _unit_step_function(unit_of: Callable) -> ModelFunction:
    """``F(t, params)`` of a transfer-function unit, inverted exactly
    (:func:`axialmix.analytic.responses.step_response`)."""

    def function(t, p):
        return _unit_step_response(unit_of(p), t)

    return function


_adm_exchange_function = _unit_exit_age_function(_adm_exchange_unit)
_tanks_exchange_function = _unit_exit_age_function(_tanks_exchange_unit)
_adm_tank_function = _unit_exit_age_function(_adm_tank_unit)


def _exchange_start(curve: Curve) -> tuple[float, float, float, float]:
    """``(tau, mobile variance, beta, k_d)`` with the curve's mean and variance: mean
    ``(1 + beta) tau``, variance ``(1 + beta)² v + 2 beta tau / k_d`` (MODELS.md section 6),
    the exchange term taking :data:`EXCHANGE_START_VARIANCE_SHARE` of it."""
    mean, variance = moment_estimates(curve)
    beta = EXCHANGE_START_CAPACITY
    tau = mean / (1.0 + beta)
    share = EXCHANGE_START_VARIANCE_SHARE
    rate = 2.0 * beta * tau / (share * variance) if variance > 0 else math.nan
    mobile_variance = (1.0 - share) * variance / (1.0 + beta) ** 2
    return tau, mobile_variance, beta, rate


def _adm_exchange_guess(curve: Curve) -> dict[str, float]:
    tau, mobile_variance, beta, rate = _exchange_start(curve)
    # NaN (keep the default Pe) where no closed-closed ADM has this variance.
    return {"tau": tau, "peclet": float(_peclet_from_moments(tau, mobile_variance)),
            "beta": beta, "k_d": rate}


def _tanks_exchange_guess(curve: Curve) -> dict[str, float]:
    tau, mobile_variance, beta, rate = _exchange_start(curve)
    n_tanks = tau**2 / mobile_variance if mobile_variance > 0 else math.nan
    return {"tau": tau, "n_tanks": n_tanks, "beta": beta, "k_d": rate}


def _adm_tank_guess(curve: Curve) -> dict[str, float]:
    """The tank with :data:`SERIES_START_VARIANCE_SHARE` of the curve's variance (a tank's
    variance is its tau²); the ADM takes the rest of the mean and variance."""
    mean, variance = moment_estimates(curve)
    tank = math.sqrt(SERIES_START_VARIANCE_SHARE * max(variance, 0.0))
    tau = mean - tank
    return {"tau": tau, "peclet": float(_peclet_from_moments(tau, variance - tank**2)),
            "tau_tank": tank}


def _adm_exchange_transport(values: Mapping[str, float], length: float | None,
                            time_unit: str) -> dict[str, Any]:
    """The flowing material's tau = L/v, Pe, v and D_z; mean residence time (1 + beta) tau."""
    beta = float(values["beta"])
    return adm_transport(values, length, time_unit, lambda tau, peclet: (1.0 + beta) * tau)


def _adm_tank_transport(values: Mapping[str, float], length: float | None,
                        time_unit: str) -> dict[str, Any]:
    """The blender's tau = L/v, Pe, v and D_z; mean residence time tau + tau_tank."""
    tank = float(values["tau_tank"])
    return adm_transport(values, length, time_unit, lambda tau, peclet: tau + tank)


def _dead_zone_statements(values: Mapping[str, float],
                          settings: Mapping[str, Parameter]) -> list[str]:
    """A fitted dead zone in words: its share of the hold-up, its stays, the mean."""
    tau, beta, rate = (float(values[n]) for n in ("tau", "beta", "k_d"))
    if not (tau > 0 and beta >= 0 and rate > 0):
        return []
    return [
        f"Dead zone: it holds beta = {beta:.3g} times the flowing material "
        f"({100 * beta / (1 + beta):.3g} % of the hold-up is stagnant), and a stay in it lasts "
        f"1/k_d = {1 / rate:.4g} on average; tau = {tau:.4g} is the flowing material's space "
        f"time and the mean residence time is (1 + beta) tau = {(1 + beta) * tau:.4g} (times "
        "in the curve's unit)."
    ]


def _adm_tank_statements(values: Mapping[str, float],
                         settings: Mapping[str, Parameter]) -> list[str]:
    tau, tank = float(values["tau"]), float(values["tau_tank"])
    return [f"Mean residence time tau + tau_tank = {tau + tank:.4g}: the dispersed section "
            f"takes tau = {tau:.4g}, the stirred tank tau_tank = {tank:.4g} (times in the "
            "curve's unit)."]


_DEAD_ZONE_MEANINGS = {
    "beta": "beta is the dead-zone (stagnant) hold-up over the flowing hold-up",
    "k_d": "k_d is the exchange rate between flowing material and dead zone; a stay in the "
           "dead zone lasts 1/k_d on average",
}
_EXCHANGE_DEFAULTS = {"beta": Parameter(EXCHANGE_START_CAPACITY, min=0.0),
                      "k_d": Parameter(1.0, min=0.0)}

adm_exchange = Model(
    name="adm-exchange",
    parameter_names=("tau", "peclet", "beta", "k_d"),
    function=_adm_exchange_function,
    defaults={**adm_defaults(), **_EXCHANGE_DEFAULTS},
    initial_guess=_adm_exchange_guess,
    description="closed-closed ADM exchanging with a dead zone (mobile-immobile), exact",
    equivalent_adm=_adm_exchange_transport,
    statements=_dead_zone_statements,
    units={**ADM_UNITS, "beta": "1", "k_d": "1/{t}"},
    meanings={"tau": "tau = L/v, the space time of the flowing material; the mean residence "
                     "time is (1 + beta) tau", **_DEAD_ZONE_MEANINGS},
    step_response=_unit_step_function(_adm_exchange_unit),
    inlet_response=quadrature_inlet_response(_adm_exchange_function),
    transfer_unit=_adm_exchange_unit,
)

tanks_exchange = Model(
    name="tanks-exchange",
    parameter_names=("tau", "n_tanks", "beta", "k_d"),
    function=_tanks_exchange_function,
    defaults={"tau": Parameter(1.0, min=0.0), "n_tanks": Parameter(5.0, min=0.0),
              **_EXCHANGE_DEFAULTS},
    initial_guess=_tanks_exchange_guess,
    description="tanks in series exchanging with a dead zone (mobile-immobile), exact",
    statements=_dead_zone_statements,
    units={"tau": "{t}", "n_tanks": "1", "beta": "1", "k_d": "1/{t}"},
    meanings={"tau": "tau is the flowing material's mean residence time in the chain of tanks; "
                     "the mean residence time is (1 + beta) tau", **_DEAD_ZONE_MEANINGS},
    step_response=_unit_step_function(_tanks_exchange_unit),
    inlet_response=quadrature_inlet_response(_tanks_exchange_function),
    transfer_unit=_tanks_exchange_unit,
)

adm_tank = Model(
    name="adm-tank",
    parameter_names=("tau", "peclet", "tau_tank"),
    function=_adm_tank_function,
    defaults={**adm_defaults(), "tau_tank": Parameter(0.1, min=0.0)},
    initial_guess=_adm_tank_guess,
    description="closed-closed ADM followed by a stirred tank (detector cell, feed frame, "
                "hopper), exact",
    equivalent_adm=_adm_tank_transport,
    statements=_adm_tank_statements,
    units={**ADM_UNITS, "tau_tank": "{t}"},
    meanings={"tau": "tau = L/v, the space time of the dispersed section; the mean residence "
                     "time is tau + tau_tank",
              "tau_tank": "tau_tank is the mean residence time of the stirred tank after it"},
    step_response=_unit_step_function(_adm_tank_unit),
    inlet_response=quadrature_inlet_response(_adm_tank_function),
    transfer_unit=_adm_tank_unit,
)
