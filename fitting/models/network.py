"""Compartment-network models (MODELS.md section 3): the four-compartment 2 × 2 network with
its twin solutions, and a model from any network file of :mod:`axialmix.network`
(:func:`~fitting.models.network_model`)."""

from __future__ import annotations

import functools
import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from axialmix.line import Unit
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
from fitting.data import Curve
from fitting.models.base import Model, traced_time_grid
from fitting.models.inlet import network_inlet_response
from fitting.models.moments import moment_estimates
from fitting.parameters import Parameter

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
    return four_compartment_exit_age(t, p["k_f"], p["k_r"], p["k_s"], p["k_out"],
                                     regular=traced_time_grid())


def _four_compartment_rates(p):
    """The 2 × 2 network and the rates of `p` as arrays in its connection order (the order of
    :data:`axialmix.network.FOUR_COMPARTMENT_CONNECTIONS`, which the network preset keeps)."""
    network = _four_compartment_network(1.0, 1.0, 1.0, 1.0)
    rates = jnp.stack([jnp.asarray(p[rate], float)
                       for _, _, rate in FOUR_COMPARTMENT_CONNECTIONS])
    return network, rates, jnp.stack([jnp.asarray(p["k_out"], float)])


def _four_compartment_step(t, p):
    network, rates, outflow = _four_compartment_rates(p)
    return cumulative_exit_age(network, t, rates, outflow, regular=traced_time_grid())


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
    inlet_response=network_inlet_response(_four_compartment_unit),
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
        return _network_exit_age(network, t, rates, outflow, regular=traced_time_grid())

    def step(t, p):
        rates, outflow = rates_of(p)
        return cumulative_exit_age(network, t, rates, outflow, regular=traced_time_grid())

    def unit_of(p):
        rates, outflow = rates_of(p)
        return Unit.network(network, rates, outflow)

    def equivalent(values, length, time_unit):
        rates, outflow = rates_of({n: float(values[n]) for n in names}, np)
        return moment_matched_adm(network, length, time_unit=time_unit, rates=rates,
                                  outflow_rates=outflow).as_dict()

    model = Model(
        name=name or Path(network_file).stem,
        parameter_names=names,
        function=function,
        defaults={n: Parameter(start(n), min=0.0) for n in names},
        description=f"compartment network from {Path(network_file).name}",
        default_starts=NETWORK_STARTS,
        equivalent_adm=equivalent,
        units=dict.fromkeys(names, "1/{t}" if not network.is_discrete else "1"),
        step_response=None if network.is_discrete else step,
        inlet_response=None if network.is_discrete else network_inlet_response(unit_of),
    )
    # What the programs compute: the network (structure and every rate, written exactly:
    # JSON floats round-trip) and which rates each parameter sets. Programs of the same file
    # content and mapping are then loaded from the cache in a later process.
    mapping = json.dumps([[n, list(members[n])] for n in names])
    object.__setattr__(model, "export_identity", ("network file", network.to_json(), mapping))
    return model
