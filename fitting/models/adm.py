"""The axial dispersion models (closed–closed exact and by finite volumes, open–open) and tanks
in series (MODELS.md section 2), with their method-of-moments starts and equivalent ADM.

The exact closed–closed model evaluates a curve of :data:`axialmix.analytic.panels.LONG_CURVE`
points or more from exact values at the nodes of Chebyshev panels
(:func:`axialmix.analytic.panels.exit_age_closed_panels`: about 1e-13 of the peak, checked
at every evaluation, exact on every point where the check fails); its ``long_curve_check``
hook measures that evaluation against the exact one on every point of a fitted curve."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from axialmix.adm import exit_age as _fv_exit_age
from axialmix.adm import outlet_response as _fv_outlet_response
from axialmix.adm import step_response as _fv_step_response
from axialmix.analytic import (
    exit_age_closed,
    exit_age_open,
    exit_age_tanks,
    mean_closed,
    mean_open,
    step_response_closed,
    step_response_open,
    step_response_tanks,
)
from axialmix.analytic.inverse import (
    approximate_peclet_from_variance_ratio,
    transport_from_dimensionless,
)
from axialmix.analytic.panels import (
    LONG_CURVE,
    closed_panel_deviation,
    exit_age_closed_panels,
)
from axialmix.line import Disturbance, Unit
from axialmix.line import outlet_response as _unit_outlet_response
from fitting.data import Curve, seconds_per
from fitting.models.base import Model
from fitting.models.inlet import quadrature_inlet_response
from fitting.models.moments import moment_estimates
from fitting.parameters import Parameter


def _start_peclet(mean: float, variance: float) -> float:
    """A start value of Pe: within 5 % of the closed–closed Pe with these moments, in NumPy
    (no JAX program traced for a start value); NaN (keep the default) for moments no
    closed–closed ADM has (a mean or variance that is not positive, or a ratio of 1 or more)."""
    if not (mean > 0 and variance > 0):
        return math.nan
    return float(approximate_peclet_from_variance_ratio(variance / mean**2))


def _adm_guess(curve: Curve) -> dict[str, float]:
    mean, variance = moment_estimates(curve)
    return {"tau": mean, "peclet": _start_peclet(mean, variance)}


def _tanks_guess(curve: Curve) -> dict[str, float]:
    mean, variance = moment_estimates(curve)
    return {"tau": mean, "n_tanks": mean**2 / variance if variance > 0 else math.nan}


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def adm_transport(values: Mapping[str, float], length: float | None, time_unit: str,
                  mean: Callable) -> dict[str, Any]:
    """tau, Pe, the mean residence time and, with a length, ``v`` and ``D_z`` in SI of an ADM
    fit (:func:`axialmix.analytic.inverse.transport_from_dimensionless`, tau in seconds)."""
    tau, peclet = float(values["tau"]), float(values["peclet"])
    velocity = dispersion = mean_time = None
    if tau > 0 and peclet > 0:
        mean_time = float(mean(tau, peclet))
        if length is not None:
            velocity, dispersion = (float(x) for x in transport_from_dimensionless(
                tau * seconds_per(time_unit), peclet, length))
    return {f"tau_{time_unit}": _finite(tau), "peclet": _finite(peclet),
            f"mean_residence_time_{time_unit}": _finite(mean_time), "length_m": length,
            "velocity_m_per_s": _finite(velocity), "dispersion_m2_per_s": _finite(dispersion)}


def _closed_adm_transport(values: Mapping[str, float], length: float | None,
                          time_unit: str) -> dict[str, Any]:
    """The closed–closed ADM's tau (= L/v = the mean), Pe, v and D_z (MODELS.md section 2)."""
    return adm_transport(values, length, time_unit, mean_closed)


def _open_adm_transport(values: Mapping[str, float], length: float | None,
                        time_unit: str) -> dict[str, Any]:
    """The open–open ADM's tau = L/v, its mean residence time (1 + 2/Pe) tau, Pe, v, D_z."""
    return adm_transport(values, length, time_unit, mean_open)


def _adm_closed_exact(t, p):
    return exit_age_closed(t, p["tau"], p["peclet"])


def _adm_closed_function(t, p):
    # A curve of LONG_CURVE points or more (a static shape): exact values at the nodes of
    # Chebyshev panels, interpolated, to about 1e-13 of the peak; every evaluation checks
    # itself between the nodes and is exact on every point where that check fails.
    if jnp.size(t) >= LONG_CURVE:
        return exit_age_closed_panels(t, p["tau"], p["peclet"])
    return exit_age_closed(t, p["tau"], p["peclet"])


def _adm_closed_long_check(t, p) -> tuple[float, float]:
    """The panel evaluation's largest deviation from the exact E over `t` and the peak
    (1/time)."""
    return closed_panel_deviation(np.asarray(t, float), float(p["tau"]), float(p["peclet"]))


def _adm_closed_fv_function(t, p):
    return _fv_exit_age(t, p["tau"], p["peclet"])


def _adm_open_function(t, p):
    return exit_age_open(t, p["tau"], p["peclet"])


def _tanks_function(t, p):
    return exit_age_tanks(t, p["tau"], p["n_tanks"])


def _adm_closed_step(t, p):
    return step_response_closed(t, p["tau"], p["peclet"])


def _adm_closed_fv_step(t, p):
    return _fv_step_response(t, p["tau"], p["peclet"])


def _adm_open_step(t, p):
    return step_response_open(t, p["tau"], p["peclet"])


def _tanks_step(t, p):
    return step_response_tanks(t, p["tau"], p["n_tanks"])


def _tanks_inlet_response(t, p, inlet_times, inlet_values):
    # Tanks in series have exact closed-form step and ramp responses (axialmix.line); E of
    # fewer than one tank is singular at t = 0, where quadrature would fail.
    signal = (Disturbance.trace(inlet_times, inlet_values)
              + Disturbance.step(-inlet_values[-1], inlet_times[-1]))
    unit = Unit.tanks(p["tau"], p["n_tanks"])
    return _unit_outlet_response(unit, signal, jnp.atleast_1d(t)).outlet.reshape(jnp.shape(t))


def _adm_closed_fv_inlet(t, p, inlet_times, inlet_values):
    # The solver holds the inlet at its last sample; a step of minus that value at the last
    # sample time ends it there (both curves from the same solver).
    held = _fv_outlet_response(t, p["tau"], p["peclet"], inlet_times, inlet_values)
    return held - inlet_values[-1] * _fv_step_response(t - inlet_times[-1], p["tau"],
                                                       p["peclet"])


#: Units of the ADM parameters ({t}: the curve's time unit).
ADM_UNITS = {"tau": "{t}", "peclet": "1"}
_CLOSED_TAU = ("tau = L/v, the space time; for the closed-closed model it equals the mean "
               "residence time")
_OPEN_TAU = ("tau = L/v, the space time; for the open-open model it is not the mean residence "
             "time, which is (1 + 2/Pe) tau")


def adm_defaults() -> dict[str, Parameter]:
    """Fresh default settings of ``tau`` (time unit of the curve) and ``peclet`` (1): start
    values 1 and 10, each with the lower bound 0."""
    return {"tau": Parameter(1.0, min=0.0), "peclet": Parameter(10.0, min=0.0)}


adm_closed = Model(
    name="adm",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_function,
    defaults=adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), exact",
    equivalent_adm=_closed_adm_transport,
    units=ADM_UNITS,
    meanings={"tau": _CLOSED_TAU},
    step_response=_adm_closed_step,
    inlet_response=quadrature_inlet_response(_adm_closed_exact),
    long_curve_check=_adm_closed_long_check,
)

adm_closed_fv = Model(
    name="adm-fv",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_fv_function,
    defaults=adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), finite volumes",
    equivalent_adm=_closed_adm_transport,
    units=ADM_UNITS,
    meanings={"tau": _CLOSED_TAU},
    step_response=_adm_closed_fv_step,
    inlet_response=_adm_closed_fv_inlet,
)

adm_open = Model(
    name="adm-open",
    parameter_names=("tau", "peclet"),
    function=_adm_open_function,
    defaults=adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, open-open, exact",
    equivalent_adm=_open_adm_transport,
    units=ADM_UNITS,
    meanings={"tau": _OPEN_TAU},
    step_response=_adm_open_step,
    inlet_response=quadrature_inlet_response(_adm_open_function),
)

tanks = Model(
    name="tanks",
    parameter_names=("tau", "n_tanks"),
    function=_tanks_function,
    defaults={"tau": Parameter(1.0, min=0.0), "n_tanks": Parameter(5.0, min=0.0)},
    initial_guess=_tanks_guess,
    description="tanks in series (gamma distribution, continuous number of tanks)",
    units={"tau": "{t}", "n_tanks": "1"},
    meanings={"tau": "tau is the mean residence time of the whole chain of tanks"},
    step_response=_tanks_step,
    inlet_response=_tanks_inlet_response,
)
