"""Models to fit: named, immutable wrappers around the forward models of :mod:`axialmix`.

A :class:`Model` is a pure JAX function ``f(t, params) -> E(t)`` (``params`` a dict of scalars,
``E`` in 1/time) together with its parameter names, default :class:`~fitting.parameters.Parameter`
settings (start value and bounds) and, where one exists, a method-of-moments start value
computed from a measured curve.

Built-in models (also by name through :func:`get_model`):

* ``'adm'`` (:data:`adm_closed`): closed–closed ADM, exact
  (:func:`axialmix.analytic.exit_age_closed`); parameters ``tau``, ``peclet``.
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
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from axialmix.adm import exit_age as _fv_exit_age
from axialmix.adm import outlet_response as _fv_outlet_response
from axialmix.adm import step_response as _fv_step_response
from axialmix.analytic import (
    exit_age_closed,
    exit_age_open,
    exit_age_tanks,
    mean_closed,
    mean_open,
    peclet_from_moments,
    step_response_closed,
    step_response_open,
    step_response_tanks,
)
from axialmix.analytic.inverse import (
    approximate_peclet_from_variance_ratio,
    transport_from_dimensionless,
)
from axialmix.analytic.responses import exit_age as _unit_exit_age
from axialmix.analytic.responses import step_response as _unit_step_response
from axialmix.analytic.transfer import (
    ClosedClosedADM,
    ExchangeZone,
    Series,
    StirredTank,
    TanksInSeries,
)
from axialmix.line import Disturbance, Unit
from axialmix.line import outlet_response as _unit_outlet_response
from axialmix.network import (
    FOUR_COMPARTMENT_CONNECTIONS,
    CompartmentNetwork,
    cumulative_exit_age,
    four_compartment_exit_age,
    moment_matched_adm,
    moment_matched_adm_from_moments,
    residence_time_moments,
)
from axialmix.network import exit_age as _network_exit_age
from axialmix.network import four_compartment as _four_compartment_network
from fitting.data import Curve, seconds_per
from fitting.parameters import Parameter, Parameters, clip_into_bounds

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

ModelFunction = Callable[..., object]
#: ``(values, length_m or None, time_unit) -> {key: value}``: the equivalent closed–closed
#: ADM of fitted values, units in the keys (``tau_<unit>``, ``peclet``, ``velocity_m_per_s``,
#: ``dispersion_m2_per_s``, ...; ``None`` where undefined).
EquivalentADM = Callable[[Mapping[str, float], "float | None", str], dict[str, Any]]
#: ``(values, settings) -> [sentence, ...]``: facts about a fit of this model in words.
Statements = Callable[[Mapping[str, float], Mapping[str, Parameter]], list[str]]
#: ``(t, params, inlet_times, inlet_values) -> outlet``: the outlet signal at times ``t`` for
#: an inlet signal linear between its samples, zero before the first and after the last
#: (JAX; ``t`` need not be sorted against the inlet samples).
InletResponse = Callable[..., object]


def parameter_unit(template: str, time_unit: str, value_unit: str | None = None) -> str:
    """A parameter's unit from its template: ``{t}`` is the curve's time unit, ``{y}`` its
    value unit (``"{t}"`` -> ``"min"``, ``"1/{t}"`` -> ``"1/min"``, ``"1"`` dimensionless,
    ``"{y}*{t}"`` -> ``"g/L*min"``, and ``"particles"`` for counts per time unit).

    **Arguments:** `template`; `time_unit` (``"s"``, ``"min"``, ...); `value_unit` (the data
    column's unit, or ``None`` when the file names none: then ``"signal"``, the unit of the
    file's values).

    **Returns:** the unit as text.
    """
    value_unit = value_unit or "signal"
    per_time = f"/{time_unit}"
    if "{y}*{t}" in template and value_unit.endswith(per_time):
        # A rate times time: "particles/s*s" is "particles".
        template = template.replace("{y}*{t}", value_unit[: -len(per_time)])
    return template.replace("{t}", time_unit).replace("{y}", value_unit)


@dataclass(frozen=True, eq=False)
class Model:
    """A fittable residence-time model: a JAX function of time and a parameter dict.

    **Arguments:**

    - `name`: short name (used in reports and by :func:`get_model`).
    - `parameter_names`: the names ``f`` reads from its parameter dict, in report order.
    - `function`: ``f(t, params) -> E``: ``t`` an array of times (unit T), ``params`` a dict
      of scalar JAX values, returns the exit-age density at ``t`` (unit 1/T). Must be
      jit-, grad- and vmap-able.
    - `defaults`: one :class:`~fitting.parameters.Parameter` per name (start value, bounds).
    - `initial_guess`: optional ``curve -> {name: value}`` start values from the curve's
      moments; used when :func:`~fitting.fit.fit` is given no start values.
    - `description`: one line for reports.
    - `default_starts`: number of starts of a fit by default; ``None``: the start values
      and, when it differs, the moment estimate.
    - `equivalent_adm`: optional hook, see :data:`EquivalentADM`.
    - `statements`: optional hook, see :data:`Statements`.
    - `units`: each parameter's unit as a template for :func:`parameter_unit` (``"{t}"``,
      ``"1/{t}"``, ``"1"``); a parameter without one has an unknown unit.
    - `meanings`: what a parameter means, one sentence, by name (e.g. for ``tau``).
    - `step_response`: optional ``F(t, params)``, the outlet for a unit step inlet at t = 0.
    - `inlet_response`: optional hook, see :data:`InletResponse`.
    - `transfer_unit`: optional ``params -> TransferFunction``, the model as an exact unit of
      :mod:`axialmix.analytic`; with it, fits report fitted values outside the range where
      its inversion is verified (:func:`axialmix.analytic.unverified_parameters`).
    """

    name: str
    parameter_names: tuple[str, ...]
    function: ModelFunction
    defaults: Mapping[str, Parameter] = field(repr=False)
    initial_guess: Callable[[Curve], dict[str, float]] | None = field(default=None, repr=False)
    description: str = ""
    default_starts: int | None = None
    equivalent_adm: EquivalentADM | None = field(default=None, repr=False)
    statements: Statements | None = field(default=None, repr=False)
    units: Mapping[str, str] = field(default_factory=dict, repr=False)
    meanings: Mapping[str, str] = field(default_factory=dict, repr=False)
    step_response: ModelFunction | None = field(default=None, repr=False)
    inlet_response: InletResponse | None = field(default=None, repr=False)
    transfer_unit: Callable[[Mapping[str, float]], Any] | None = field(default=None,
                                                                        repr=False)

    def __post_init__(self) -> None:
        names = tuple(self.parameter_names)
        if not names:
            raise ValueError(f"model {self.name!r} has no parameters")
        if len(set(names)) != len(names):
            raise ValueError(f"model {self.name!r} has repeated parameter names: {names}")
        missing = [n for n in names if n not in self.defaults]
        if missing:
            raise ValueError(f"model {self.name!r}: no default for parameter(s) {missing}")
        if self.default_starts is not None and self.default_starts < 1:
            raise ValueError(f"model {self.name!r}: default_starts must be at least 1")
        object.__setattr__(self, "parameter_names", names)
        object.__setattr__(
            self, "defaults", {n: _as_parameter(self.defaults[n], n) for n in names}
        )

    def __call__(self, time, params: Mapping[str, object]):
        """Evaluate the model: exit-age density at `time` for the parameter values `params`."""
        return self.function(time, {n: params[n] for n in self.parameter_names})

    def evaluate(self, time, params: Mapping[str, float]) -> np.ndarray:
        """The model at concrete times and parameter values, as one compiled program.

        Same values as calling the model, but traced and compiled once per model and shape
        (a plot and the start-value check share it) instead of dispatching each operation
        of the model eagerly. Warnings that look at concrete parameter values (such as an
        unverified parameter range) are not raised on this path.

        **Arguments:**

        - `time`: times in the curve's unit, a 1-D array.
        - `params`: a value for every name in :attr:`parameter_names` (plain numbers).

        **Returns:** the model's values at `time` as a float64 NumPy array (1/T for an
        exit-age model).
        """
        values = {n: np.float64(params[n]) for n in self.parameter_names}
        return np.asarray(_compiled_model(self)(np.asarray(time, np.float64), values))

    def parameters(self, curve: Curve | None = None) -> Parameters:
        """A fresh :class:`~fitting.parameters.Parameters` with the defaults.

        With a `curve` and a method-of-moments guess available, the start values are the
        moment estimates (clipped into the bounds).
        """
        params = Parameters({n: self.defaults[n] for n in self.parameter_names})
        if curve is not None and self.initial_guess is not None:
            for name, value in self.initial_guess(curve).items():
                if name in params and np.isfinite(value):
                    params[name] = params[name].replace(
                        value=clip_into_bounds(value, params[name]))
        return params

    def facts(self, values: Mapping[str, float], settings: Mapping[str, Parameter]) -> list[str]:
        """The model's :data:`Statements` about fitted `values` (empty without the hook)."""
        return [] if self.statements is None else list(self.statements(values, settings))

    def unit(self, name: str, time_unit: str, value_unit: str | None = None) -> str:
        """The unit of parameter `name` for a curve in `time_unit` (``""`` when unknown)."""
        template = self.units.get(name)
        return "" if template is None else parameter_unit(template, time_unit, value_unit)


@functools.lru_cache(maxsize=64)
def _compiled_model(model: Model) -> Callable:
    """``jax.jit`` of `model`'s function, kept while the model is among the 64 last used
    (models compare by identity)."""
    return jax.jit(model.function)


def _as_parameter(value: Parameter | float, name: str) -> Parameter:
    if isinstance(value, Parameter):
        return value
    try:
        return Parameter(float(value))
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name!r}: expected a Parameter or a number") from None


def moment_estimates(curve: Curve) -> tuple[float, float]:
    """Mean residence time and variance of a measured curve (trapezoid rule).

    Negative samples (noise around a subtracted baseline) are set to zero first, so the
    moments of a noisy curve stay those of a density.

    **Arguments:**

    - `curve`: a measured curve (need not be normalised).

    **Returns:**

    ``(mean, variance)`` in the curve's time unit and its square.
    """
    # The same trapezoid moments as axialmix.rtd.moments, in NumPy: start values are computed
    # per curve in Python, where eager JAX dispatch would dominate the cost of a fit.
    time = curve.time
    density = np.clip(curve.value, 0.0, None)
    area = np.trapezoid(density, time)
    mean = np.trapezoid(time * density, time) / area
    variance = np.trapezoid((time - mean) ** 2 * density, time) / area
    return float(mean), float(variance)


#: :func:`axialmix.analytic.peclet_from_moments`, jitted (NaN outside its range): the exact
#: moment match the dead-zone and series models' starts are built on.
_peclet_from_moments = jax.jit(peclet_from_moments)


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


def _adm_transport(values: Mapping[str, float], length: float | None, time_unit: str,
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


#: The means of the closed and open ADM compiled (a record's quantities evaluate them seven
#: times per fit; operation by operation that was 14 ms).
_MEAN_CLOSED = jax.jit(mean_closed)
_MEAN_OPEN = jax.jit(mean_open)


def _closed_adm_transport(values: Mapping[str, float], length: float | None,
                          time_unit: str) -> dict[str, Any]:
    """The closed–closed ADM's tau (= L/v = the mean), Pe, v and D_z (MODELS.md section 2)."""
    return _adm_transport(values, length, time_unit, _MEAN_CLOSED)


def _open_adm_transport(values: Mapping[str, float], length: float | None,
                        time_unit: str) -> dict[str, Any]:
    """The open–open ADM's tau = L/v, its mean residence time (1 + 2/Pe) tau, Pe, v, D_z."""
    return _adm_transport(values, length, time_unit, _MEAN_OPEN)


def _adm_closed_function(t, p):
    return exit_age_closed(t, p["tau"], p["peclet"])


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


#: Gauss–Legendre nodes per inlet interval of :func:`_quadrature_inlet_response`.
INLET_NODES = 16
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(INLET_NODES)


def _quadrature_inlet_response(exit_age: ModelFunction) -> InletResponse:
    """The response to a piecewise-linear inlet, ``∫ u(s) E(t - s) ds``, of a model whose exact
    E is smooth: on each inlet interval, cut at ``t`` (E is zero at negative ages), the linear
    signal times the exact E is integrated by 16-point Gauss–Legendre quadrature.

    Measured against the exact transfer-function inversion
    (:func:`axialmix.analytic.responses.inlet_response`) for the closed–closed and open–open
    ADM at Pe 0.5 to 5000 with 4 to 13 inlet samples over 0.3 tau: at most 4e-10 of the
    peak (Pe 0.5 with 4 samples, where E rises steeply from t = 0), 1e-12 typically. That
    inversion is exact too but takes minutes to compile inside a fit's solver; this costs
    ``16 × intervals`` evaluations of E per output time and compiles like E itself.
    """

    @jax.jit
    def response(t, p, inlet_times, inlet_values):
        t = jnp.asarray(t, float)
        start, end = inlet_times[:-1], inlet_times[1:]
        top = jnp.clip(t[..., None], start, end)
        width = top - start
        nodes = start[:, None] + width[..., None] * ((1.0 + _NODES) / 2.0)
        slopes = jnp.diff(inlet_values) / jnp.diff(inlet_times)
        signal = inlet_values[:-1, None] + slopes[:, None] * (nodes - start[:, None])
        ages = t[..., None, None] - nodes
        density = exit_age(ages.reshape(-1), p).reshape(ages.shape)
        return jnp.sum(density * signal * _WEIGHTS * (width[..., None] / 2.0), axis=(-2, -1))

    return response


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


def _network_inlet_response(unit_of: Callable) -> InletResponse:
    """The exact response of a continuous network to a piecewise-linear inlet, through
    :func:`axialmix.line.outlet_response` (exact step and ramp responses, matrix exponentials)."""

    def response(t, p, inlet_times, inlet_values):
        signal = (Disturbance.trace(inlet_times, inlet_values)
                  + Disturbance.step(-inlet_values[-1], inlet_times[-1]))
        return _unit_outlet_response(unit_of(p), signal, jnp.atleast_1d(t)).outlet.reshape(
            jnp.shape(t))

    return response


#: Units of the ADM parameters ({t}: the curve's time unit).
_ADM_UNITS = {"tau": "{t}", "peclet": "1"}
_CLOSED_TAU = ("tau = L/v, the space time; for the closed-closed model it equals the mean "
               "residence time")
_OPEN_TAU = ("tau = L/v, the space time; for the open-open model it is not the mean residence "
             "time, which is (1 + 2/Pe) tau")


def _adm_defaults() -> dict[str, Parameter]:
    return {"tau": Parameter(1.0, min=0.0), "peclet": Parameter(10.0, min=0.0)}


adm_closed = Model(
    name="adm",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), exact",
    equivalent_adm=_closed_adm_transport,
    units=_ADM_UNITS,
    meanings={"tau": _CLOSED_TAU},
    step_response=_adm_closed_step,
    inlet_response=_quadrature_inlet_response(_adm_closed_function),
)

adm_closed_fv = Model(
    name="adm-fv",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_fv_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), finite volumes",
    equivalent_adm=_closed_adm_transport,
    units=_ADM_UNITS,
    meanings={"tau": _CLOSED_TAU},
    step_response=_adm_closed_fv_step,
    inlet_response=_adm_closed_fv_inlet,
)

adm_open = Model(
    name="adm-open",
    parameter_names=("tau", "peclet"),
    function=_adm_open_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, open-open, exact",
    equivalent_adm=_open_adm_transport,
    units=_ADM_UNITS,
    meanings={"tau": _OPEN_TAU},
    step_response=_adm_open_step,
    inlet_response=_quadrature_inlet_response(_adm_open_function),
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


# --- dead zones and units in series (MODELS.md section 6; axialmix.analytic.transfer) ---------

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
    return _adm_transport(values, length, time_unit, lambda tau, peclet: (1.0 + beta) * tau)


def _adm_tank_transport(values: Mapping[str, float], length: float | None,
                        time_unit: str) -> dict[str, Any]:
    """The blender's tau = L/v, Pe, v and D_z; mean residence time tau + tau_tank."""
    tank = float(values["tau_tank"])
    return _adm_transport(values, length, time_unit, lambda tau, peclet: tau + tank)


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
    defaults={**_adm_defaults(), **_EXCHANGE_DEFAULTS},
    initial_guess=_adm_exchange_guess,
    description="closed-closed ADM exchanging with a dead zone (mobile-immobile), exact",
    equivalent_adm=_adm_exchange_transport,
    statements=_dead_zone_statements,
    units={**_ADM_UNITS, "beta": "1", "k_d": "1/{t}"},
    meanings={"tau": "tau = L/v, the space time of the flowing material; the mean residence "
                     "time is (1 + beta) tau", **_DEAD_ZONE_MEANINGS},
    step_response=_unit_step_function(_adm_exchange_unit),
    inlet_response=_quadrature_inlet_response(_adm_exchange_function),
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
    inlet_response=_quadrature_inlet_response(_tanks_exchange_function),
    transfer_unit=_tanks_exchange_unit,
)

adm_tank = Model(
    name="adm-tank",
    parameter_names=("tau", "peclet", "tau_tank"),
    function=_adm_tank_function,
    defaults={**_adm_defaults(), "tau_tank": Parameter(0.1, min=0.0)},
    initial_guess=_adm_tank_guess,
    description="closed-closed ADM followed by a stirred tank (detector cell, feed frame, "
                "hopper), exact",
    equivalent_adm=_adm_tank_transport,
    statements=_adm_tank_statements,
    units={**_ADM_UNITS, "tau_tank": "{t}"},
    meanings={"tau": "tau = L/v, the space time of the dispersed section; the mean residence "
                     "time is tau + tau_tank",
              "tau_tank": "tau_tank is the mean residence time of the stirred tank after it"},
    step_response=_unit_step_function(_adm_tank_unit),
    inlet_response=_quadrature_inlet_response(_adm_tank_function),
    transfer_unit=_adm_tank_unit,
)


# --- the four-compartment network (MODELS.md section 3; defined in axialmix.network) ----------

FOUR_COMPARTMENT_NAMES = ("k_f", "k_r", "k_s", "k_out")
#: Starts of a compartment-network fit by default: their losses have several local minima
#: (the four-compartment model's twin solutions among them).
NETWORK_STARTS = 8
#: |ln(k_r / k_f)| and |ln(k_s / k_f)| below this count as equal for the mirror statements.
MIRROR_CLOSENESS = 0.05


def _four_compartment_guess(curve: Curve) -> dict[str, float]:
    """All rates equal to k, with k matched to the measured mean residence time.

    The mean residence time of a linear compartment network scales as 1/k when all its rates
    are multiplied by k; with all rates equal to k it is ``m_1 / k``, where ``m_1`` is its
    value for k = 1 (:func:`axialmix.network.residence_time_moments`).
    """
    mean, _ = moment_estimates(curve)
    return dict.fromkeys(FOUR_COMPARTMENT_NAMES, _four_compartment_unit_mean() / mean)


@functools.cache
def _four_compartment_unit_mean() -> float:
    """The four-compartment network's mean residence time with every rate 1 (1/rate unit),
    computed once a process (start values ask for it many times a fit)."""
    return _four_compartment_moments(dict.fromkeys(FOUR_COMPARTMENT_NAMES, 1.0))[0]


@functools.cache
def _four_compartment_moments_program() -> Callable:
    """:func:`axialmix.network.residence_time_moments` of the 2 × 2 network as one compiled
    program of its rates (one trace a process, instead of dozens of eager operations each
    time start values or an equivalent ADM are asked for)."""
    network = _four_compartment_network(1.0, 1.0, 1.0, 1.0)

    def moments(rates, outflow):
        result = residence_time_moments(network, rates, outflow)
        return result.mean, result.variance

    return jax.jit(moments)


def _four_compartment_moments(values: Mapping[str, float]) -> tuple[float, float]:
    """Mean residence time and variance of the four-compartment network with rates `values`."""
    rates = np.array([values[rate] for _, _, rate in FOUR_COMPARTMENT_CONNECTIONS], float)
    outflow = np.array([values["k_out"]], float)
    mean, variance = _four_compartment_moments_program()(rates, outflow)
    return float(mean), float(variance)


def _four_compartment_function(t, p):
    return four_compartment_exit_age(t, p["k_f"], p["k_r"], p["k_s"], p["k_out"])


def _four_compartment_rates(p):
    """The 2 × 2 network and the rates of `p` as arrays in its connection order (the order of
    :data:`axialmix.network.FOUR_COMPARTMENT_CONNECTIONS`, which the network preset keeps)."""
    network = _four_compartment_network(1.0, 1.0, 1.0, 1.0)
    rates = jnp.stack([jnp.asarray(p[rate], float)
                       for _, _, rate in FOUR_COMPARTMENT_CONNECTIONS])
    return network, rates, jnp.stack([jnp.asarray(p["k_out"], float)])


def _four_compartment_step(t, p):
    network, rates, outflow = _four_compartment_rates(p)
    return cumulative_exit_age(network, t, rates, outflow)


def _four_compartment_unit(p):
    network, rates, outflow = _four_compartment_rates(p)
    return Unit.network(network, rates, outflow)


def _four_compartment_equivalent(values: Mapping[str, float], length: float | None,
                                 time_unit: str) -> dict[str, Any]:
    mean, variance = _four_compartment_moments(values)
    return moment_matched_adm_from_moments(mean, variance, length,
                                           time_unit=time_unit).as_dict()


def _mirror_statements(values: Mapping[str, float],
                       settings: Mapping[str, Parameter]) -> list[str]:
    """The four-compartment model's exact twin solutions, in words with numbers.

    With ``k_r = k_f`` every connection of the 2 × 2 network is two-way with a single rate,
    and relabelling compartments 2 and 3 maps the network onto itself with ``k_f`` and
    ``k_s`` exchanged: ``(k_f, k_f, k_s)`` and ``(k_s, k_s, k_f)`` give the same RTD.
    """
    k_f, k_r, k_s = (values[n] for n in ("k_f", "k_r", "k_s"))
    if not (k_f > 0 and k_r > 0 and k_s > 0):
        return []
    tied = (settings["k_r"].expr or "").strip() == "k_f"
    near_tie = abs(math.log(k_r / k_f)) < MIRROR_CLOSENESS
    if not (tied or near_tie):
        return []
    if abs(math.log(k_s / k_f)) < MIRROR_CLOSENESS:
        return [
            f"This optimum lies on the mirror line k_f = k_r = k_s (k_f = {k_f:.4g}, "
            f"k_r = {k_r:.4g}, k_s = {k_s:.4g}): with k_r = k_f the RTD is unchanged when "
            "k_f and k_s are exchanged, so here the curve does not change to first order "
            "along (k_f, k_r, k_s) ∝ (+1, +1, -1) and cannot tell forward from side "
            "exchange; only the second-order curvature holds the fit at this point."
        ]
    twin = "exactly" if tied else "almost exactly (k_r is close to k_f)"
    return [
        f"Twin solution: with k_r = k_f the RTD is unchanged when k_f and k_s are exchanged, "
        f"so k_f = {k_s:.4g}, k_s = {k_f:.4g} fits {twin} as well as k_f = {k_f:.4g}, "
        f"k_s = {k_s:.4g}; the curve alone cannot say which of the two is forward flow."
    ]


four_compartment = Model(
    name="four-compartment",
    parameter_names=FOUR_COMPARTMENT_NAMES,
    function=_four_compartment_function,
    defaults={n: Parameter(1.0, min=0.0) for n in FOUR_COMPARTMENT_NAMES},
    initial_guess=_four_compartment_guess,
    description="four-compartment network (2 x 2; k_f forward, k_r backward, k_s side, k_out)",
    default_starts=NETWORK_STARTS,
    equivalent_adm=_four_compartment_equivalent,
    statements=_mirror_statements,
    units=dict.fromkeys(FOUR_COMPARTMENT_NAMES, "1/{t}"),
    step_response=_four_compartment_step,
    inlet_response=_network_inlet_response(_four_compartment_unit),
)


def _identifier(text: str) -> str:
    return re.sub(r"\W", "_", text)


def network_model(
    network_file: str | Path,
    *parameter_names: str,
    groups: Mapping[str, Sequence[str]] | None = None,
    name: str | None = None,
) -> Model:
    """A fittable model from any compartment-network JSON file of :mod:`axialmix.network`.

    Every rate of the file has a name: ``k_<source>_<target>`` for a connection and
    ``k_out_<outlet>`` for an outflow (non-word characters of compartment names become
    ``_``; two rates whose names would coincide are an error). `groups` lets one parameter
    drive several rates (``{"k_f": ["k_C1_C2", "k_C3_C4"]}``). Rates that are not fitted keep
    the file's values.

    **Arguments:**

    - `network_file`: a network JSON file (:meth:`axialmix.network.CompartmentNetwork.to_json`),
      or a TOML file of the same layout (``.toml``).
    - `parameter_names`: the parameters to fit (rate names, or keys of `groups`); by default
      every key of `groups`, or every rate of the file.
    - `groups`: parameter name -> rate names it sets.
    - `name`: the model's name (the file name without extension by default).

    **Returns:**

    A :class:`Model` with positive rate parameters (1/time; per step for discrete networks),
    started at the file's values, with :data:`NETWORK_STARTS` starts by default.
    """
    network = (CompartmentNetwork.from_toml(network_file)
               if Path(network_file).suffix.lower() == ".toml"
               else CompartmentNetwork.from_json(network_file))
    labels = [(f"k_{c.source}_{c.target}", ("connection", i))
              for i, c in enumerate(network.connections)]
    labels += [(f"k_out_{o.compartment}", ("outflow", j)) for j, o in enumerate(network.outlets)]
    rate_index: dict[str, tuple[str, int]] = {}
    spelled: dict[str, str] = {}
    for label, where in labels:
        key = _identifier(label)
        if key in rate_index:
            raise ValueError(f"rates {spelled[key]!r} and {label!r} both get the parameter name "
                             f"{key!r}; rename a compartment")
        rate_index[key], spelled[key] = where, label
    groups = dict(groups) if groups is not None else {}
    for group, members in groups.items():
        unknown = [m for m in members if m not in rate_index]
        if unknown:
            raise ValueError(f"group {group!r}: unknown rate(s) {unknown}; the file has "
                             f"{', '.join(rate_index)}")
    names = tuple(parameter_names) or tuple(groups) or tuple(rate_index)
    members = {n: tuple(groups.get(n, (n,))) for n in names}
    for parameter, rates in members.items():
        if any(r not in rate_index for r in rates):
            raise ValueError(f"unknown rate {parameter!r}; the file has {', '.join(rate_index)}")
    base_rates = np.asarray(network.rates, dtype=float)
    base_outflow = np.asarray(network.outflow_rates, dtype=float)

    def start(parameter: str) -> float:
        kind, index = rate_index[members[parameter][0]]
        value = (base_rates if kind == "connection" else base_outflow)[index]
        return float(value) if value > 0 else 1.0

    def rates_of(p, module=jnp):
        rates = module.array(base_rates)
        outflow = module.array(base_outflow)
        for parameter, rate_names in members.items():
            for rate in rate_names:
                kind, index = rate_index[rate]
                if module is jnp:
                    if kind == "connection":
                        rates = rates.at[index].set(p[parameter])
                    else:
                        outflow = outflow.at[index].set(p[parameter])
                elif kind == "connection":
                    rates[index] = p[parameter]
                else:
                    outflow[index] = p[parameter]
        return rates, outflow

    def function(t, p):
        rates, outflow = rates_of(p)
        return _network_exit_age(network, t, rates, outflow)

    def step(t, p):
        rates, outflow = rates_of(p)
        return cumulative_exit_age(network, t, rates, outflow)

    def unit_of(p):
        rates, outflow = rates_of(p)
        return Unit.network(network, rates, outflow)

    def equivalent(values, length, time_unit):
        rates, outflow = rates_of({n: float(values[n]) for n in names}, np)
        return moment_matched_adm(network, length, time_unit=time_unit, rates=rates,
                                  outflow_rates=outflow).as_dict()

    return Model(
        name=name or Path(network_file).stem,
        parameter_names=names,
        function=function,
        defaults={n: Parameter(start(n), min=0.0) for n in names},
        description=f"compartment network from {Path(network_file).name}",
        default_starts=NETWORK_STARTS,
        equivalent_adm=equivalent,
        units=dict.fromkeys(names, "1/{t}" if not network.is_discrete else "1"),
        step_response=None if network.is_discrete else step,
        inlet_response=None if network.is_discrete else _network_inlet_response(unit_of),
    )


def custom_model(
    name: str,
    fn: ModelFunction,
    parameters: Mapping[str, Parameter | float],
    *,
    initial_guess: Callable[[Curve], dict[str, float]] | None = None,
    description: str = "",
) -> Model:
    """Wrap a user's own JAX function as a fittable model.

    **Arguments:**

    - `name`: the model's name.
    - `fn`: ``fn(t, params) -> E``; ``params`` is a dict of scalar JAX values keyed by the
      names of `parameters`. It must be written in ``jax.numpy`` (jit/grad/vmap-able).
    - `parameters`: name -> :class:`~fitting.parameters.Parameter` or start value, in order.
    - `initial_guess`: optional ``curve -> {name: value}`` start values.
    - `description`: one line for reports.

    **Returns:**

    A :class:`Model`.
    """
    if not callable(fn):
        raise ValueError(f"custom model {name!r}: fn must be callable")
    return Model(
        name=name,
        parameter_names=tuple(parameters),
        function=fn,
        defaults={n: _as_parameter(v, n) for n, v in parameters.items()},
        initial_guess=initial_guess,
        description=description or f"user model {name}",
    )


MODELS: dict[str, Model] = {
    "adm": adm_closed,
    "adm-fv": adm_closed_fv,
    "adm-open": adm_open,
    "tanks": tanks,
    "four-compartment": four_compartment,
    "adm-exchange": adm_exchange,
    "tanks-exchange": tanks_exchange,
    "adm-tank": adm_tank,
}


def get_model(model: str | Model) -> Model:
    """The built-in model called `model` (see :data:`MODELS`), or `model` itself.

    **Arguments:**

    - `model`: a name (``'adm'``, ``'adm-fv'``, ``'adm-open'``, ``'tanks'``,
      ``'four-compartment'``, ``'adm-exchange'``, ``'tanks-exchange'``, ``'adm-tank'``) or a
      :class:`Model`.

    **Returns:**

    The :class:`Model`.
    """
    if isinstance(model, Model):
        return model
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown model {model!r}; choose one of {', '.join(MODELS)}"
        ) from None
