"""Models to fit: named, immutable wrappers around the forward models of :mod:`axialmix`.

A :class:`Model` is a pure JAX function ``f(t, params) -> E(t)`` (``params`` a dict of scalars,
``E`` in 1/time) together with its parameter names, default :class:`~fitting.optimize.Parameter`
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

Method-of-moments start values: ``tau`` = mean, ``Pe`` from
:func:`axialmix.analytic.peclet_from_moments` (closed–closed relation, also used as a start
for the open–open model), ``n_tanks = mean² / variance``; for the four-compartment model all
rates equal, matched to the mean residence time.

The :mod:`axialmix` functions are looked up when a model is first evaluated, so this module
imports even where an optional forward model is missing.
"""

from __future__ import annotations

import functools
import importlib
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fitting.io import Curve
from fitting.optimize import Parameter, Parameters

__all__ = [
    "MODELS",
    "Model",
    "adm_closed",
    "adm_closed_fv",
    "adm_open",
    "custom_model",
    "four_compartment",
    "get_model",
    "moment_estimates",
    "network_model",
    "tanks",
]

ModelFunction = Callable[..., object]


@dataclass(frozen=True, eq=False)
class Model:
    """A fittable residence-time model: a JAX function of time and a parameter dict.

    **Arguments:**

    - `name`: short name (used in reports and by :func:`get_model`).
    - `parameter_names`: the names ``f`` reads from its parameter dict, in report order.
    - `function`: ``f(t, params) -> E``: ``t`` an array of times (unit T), ``params`` a dict
      of scalar JAX values, returns the exit-age density at ``t`` (unit 1/T). Must be
      jit-, grad- and vmap-able.
    - `defaults`: one :class:`~fitting.optimize.Parameter` per name (start value, bounds).
    - `initial_guess`: optional ``curve -> {name: value}`` start values from the curve's
      moments; used when :func:`~fitting.optimize.fit` is given no start values.
    - `description`: one line for reports.
    """

    name: str
    parameter_names: tuple[str, ...]
    function: ModelFunction
    defaults: Mapping[str, Parameter] = field(repr=False)
    initial_guess: Callable[[Curve], dict[str, float]] | None = field(default=None, repr=False)
    description: str = ""

    def __post_init__(self) -> None:
        names = tuple(self.parameter_names)
        if not names:
            raise ValueError(f"model {self.name!r} has no parameters")
        if len(set(names)) != len(names):
            raise ValueError(f"model {self.name!r} has repeated parameter names: {names}")
        missing = [n for n in names if n not in self.defaults]
        if missing:
            raise ValueError(f"model {self.name!r}: no default for parameter(s) {missing}")
        object.__setattr__(self, "parameter_names", names)
        object.__setattr__(
            self, "defaults", {n: _as_parameter(self.defaults[n], n) for n in names}
        )

    def __call__(self, time, params: Mapping[str, object]):
        """Evaluate the model: exit-age density at `time` for the parameter values `params`."""
        return self.function(time, {n: params[n] for n in self.parameter_names})

    def parameters(self, curve: Curve | None = None) -> Parameters:
        """A fresh :class:`~fitting.optimize.Parameters` with the defaults.

        With a `curve` and a method-of-moments guess available, the start values are the
        moment estimates (clipped into the bounds).
        """
        params = Parameters({n: self.defaults[n] for n in self.parameter_names})
        if curve is not None and self.initial_guess is not None:
            for name, value in self.initial_guess(curve).items():
                if name in params and np.isfinite(value):
                    params[name] = params[name].replace(value=_clip(value, params[name]))
        return params


def _as_parameter(value: Parameter | float, name: str) -> Parameter:
    if isinstance(value, Parameter):
        return value
    try:
        return Parameter(float(value))
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name!r}: expected a Parameter or a number") from None


def _clip(value: float, parameter: Parameter) -> float:
    """Move a start value strictly inside the parameter's bounds."""
    low = parameter.min if parameter.min is not None else -np.inf
    high = parameter.max if parameter.max is not None else np.inf
    if np.isfinite(low) and np.isfinite(high):
        margin = 1e-3 * (high - low)
        return float(np.clip(value, low + margin, high - margin))
    if np.isfinite(low) and value <= low:
        return float(low + max(abs(low), 1.0) * 1e-3)
    if np.isfinite(high) and value >= high:
        return float(high - max(abs(high), 1.0) * 1e-3)
    return float(value)


def _lookup(module: str, name: str) -> Callable:
    """The function `name` of `module`, with a one-line error if it is not available."""
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        raise ImportError(f"this model needs {module}.{name}, which is not available") from None


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


@functools.cache
def _compiled_peclet_from_moments() -> Callable:
    """:func:`axialmix.analytic.peclet_from_moments`, jitted (NaN outside its range)."""
    import jax

    return jax.jit(_lookup("axialmix.analytic", "peclet_from_moments"))


def _adm_guess(curve: Curve) -> dict[str, float]:
    mean, variance = moment_estimates(curve)
    # NaN (keep the default) for a variance no closed-closed ADM has (ratio >= 1).
    peclet = float(_compiled_peclet_from_moments()(mean, variance))
    return {"tau": mean, "peclet": peclet}


def _tanks_guess(curve: Curve) -> dict[str, float]:
    mean, variance = moment_estimates(curve)
    return {"tau": mean, "n_tanks": mean**2 / variance if variance > 0 else math.nan}


def _adm_closed_function(t, p):
    return _lookup("axialmix.analytic", "exit_age_closed")(t, p["tau"], p["peclet"])


def _adm_closed_fv_function(t, p):
    return _lookup("axialmix.adm", "exit_age")(t, p["tau"], p["peclet"])


def _adm_open_function(t, p):
    return _lookup("axialmix.analytic", "exit_age_open")(t, p["tau"], p["peclet"])


def _tanks_function(t, p):
    return _lookup("axialmix.analytic", "exit_age_tanks")(t, p["tau"], p["n_tanks"])


def _adm_defaults() -> dict[str, Parameter]:
    return {"tau": Parameter(1.0, min=0.0), "peclet": Parameter(10.0, min=0.0)}


adm_closed = Model(
    name="adm",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), exact",
)

adm_closed_fv = Model(
    name="adm-fv",
    parameter_names=("tau", "peclet"),
    function=_adm_closed_fv_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, closed-closed (Danckwerts), finite volumes",
)

adm_open = Model(
    name="adm-open",
    parameter_names=("tau", "peclet"),
    function=_adm_open_function,
    defaults=_adm_defaults(),
    initial_guess=_adm_guess,
    description="axial dispersion model, open-open, exact",
)

tanks = Model(
    name="tanks",
    parameter_names=("tau", "n_tanks"),
    function=_tanks_function,
    defaults={"tau": Parameter(1.0, min=0.0), "n_tanks": Parameter(5.0, min=0.0)},
    initial_guess=_tanks_guess,
    description="tanks in series (gamma distribution, continuous number of tanks)",
)


# --- the four-compartment network (MODELS.md section 3) -------------------------------------

FOUR_COMPARTMENT_NAMES = ("k_f", "k_r", "k_s", "k_out")


def _four_compartment_rate_matrix(k_f: float, k_r: float, k_s: float, k_out: float) -> np.ndarray:
    """Rate matrix K of dm/dt = K m for the 2 × 2 layout (1 inlet, 4 outlet), MODELS.md §3."""
    return np.array(
        [
            [-(k_f + k_s), k_r, k_s, 0.0],
            [k_f, -(k_r + k_s), 0.0, k_s],
            [k_s, 0.0, -(k_f + k_s), k_r],
            [0.0, k_s, k_f, -(k_s + k_r) - k_out],
        ]
    )


def _four_compartment_guess(curve: Curve) -> dict[str, float]:
    """All rates equal to k, with k matched to the measured mean residence time.

    The mean residence time of a linear compartment network fed a unit pulse into
    compartment 1 is ``1ᵀ (-K)⁻¹ e_1``; with all rates equal to k it is ``m_1 / k``, where
    ``m_1`` is its value for k = 1.
    """
    mean, _ = moment_estimates(curve)
    unit_mean = float(np.sum(np.linalg.solve(-_four_compartment_rate_matrix(1, 1, 1, 1),
                                             np.eye(4)[0])))
    rate = unit_mean / mean
    return dict.fromkeys(FOUR_COMPARTMENT_NAMES, rate)


def _four_compartment_function(t, p):
    exit_age = _lookup("axialmix.network", "four_compartment_exit_age")
    return exit_age(t, p["k_f"], p["k_r"], p["k_s"], p["k_out"])


four_compartment = Model(
    name="four-compartment",
    parameter_names=FOUR_COMPARTMENT_NAMES,
    function=_four_compartment_function,
    defaults={n: Parameter(1.0, min=0.0) for n in FOUR_COMPARTMENT_NAMES},
    initial_guess=_four_compartment_guess,
    description="four-compartment network (2 x 2; k_f forward, k_r backward, k_s side, k_out)",
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
    ``_``). `groups` lets one parameter drive several rates (``{"k_f": ["k_C1_C2",
    "k_C3_C4"]}``). Rates that are not fitted keep the file's values.

    **Arguments:**

    - `network_file`: a network JSON file (:meth:`axialmix.network.CompartmentNetwork.to_json`).
    - `parameter_names`: the parameters to fit (rate names, or keys of `groups`); by default
      every key of `groups`, or every rate of the file.
    - `groups`: parameter name -> rate names it sets.
    - `name`: the model's name (the file name without extension by default).

    **Returns:**

    A :class:`Model` with positive rate parameters (1/time; per step for discrete networks),
    started at the file's values.
    """
    import jax.numpy as jnp

    from axialmix.network import CompartmentNetwork, exit_age

    network = CompartmentNetwork.from_json(network_file)
    rate_index = {
        _identifier(f"k_{c.source}_{c.target}"): ("connection", i)
        for i, c in enumerate(network.connections)
    }
    rate_index.update({
        _identifier(f"k_out_{o.compartment}"): ("outflow", j) for j, o in enumerate(network.outlets)
    })
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

    def function(t, p):
        rates = jnp.asarray(base_rates)
        outflow = jnp.asarray(base_outflow)
        for parameter, rate_names in members.items():
            for rate in rate_names:
                kind, index = rate_index[rate]
                if kind == "connection":
                    rates = rates.at[index].set(p[parameter])
                else:
                    outflow = outflow.at[index].set(p[parameter])
        return exit_age(network, t, rates, outflow)

    return Model(
        name=name or Path(network_file).stem,
        parameter_names=names,
        function=function,
        defaults={n: Parameter(start(n), min=0.0) for n in names},
        description=f"compartment network from {Path(network_file).name}",
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
    - `parameters`: name -> :class:`~fitting.optimize.Parameter` or start value, in order.
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
}


def get_model(model: str | Model) -> Model:
    """The built-in model called `model` (see :data:`MODELS`), or `model` itself.

    **Arguments:**

    - `model`: a name (``'adm'``, ``'adm-fv'``, ``'adm-open'``, ``'tanks'``,
      ``'four-compartment'``) or a :class:`Model`.

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
