"""The joint model of a global fit and its parameter layout: every curve's model in one
``vmap`` over the padded curves (one compiled program per study structure), the joint
parameters' names, start settings and bounds, and their units.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from fitting.data import Curve
from fitting.models import Model
from fitting.parameters import Parameter, Parameters
from fitting.study.global_fit.model import GlobalModel, curve_name

#: Joint models kept per process (same structure: the same compiled solver).
_CACHE_SIZE = 16


@functools.lru_cache(maxsize=_CACHE_SIZE)
def joint_model(spec: GlobalModel, count: int, length: int, designs: tuple[bytes, ...]) -> Model:
    """The joint model of a study structure; the same structure gives the same object, so
    its compiled solver is reused (the designs are constants of the program)."""
    curve_model = spec.curve_model
    matrices = {law.parameter: jnp.asarray(np.frombuffer(blob).reshape(count, -1))
                for law, blob in zip(spec.laws, designs, strict=True)}
    names = _joint_names(spec, count)
    per_curve = spec.per_curve
    fixed = {n: curve_model.defaults[n].value for n in curve_model.parameter_names
             if n not in spec.fitted}

    def function(t, p):
        size = count * length
        columns = {}
        for name in spec.fitted:
            law = spec.law_of(name)
            if law is not None:
                coefficients = jnp.stack([p[c] for c in law.coefficient_names])
                columns[name] = law.apply(matrices[name] @ coefficients)
            elif name in spec.shared:
                columns[name] = jnp.broadcast_to(p[name], (count,))
            else:
                # Gathers the per-curve entries of the parameter vector (bookkeeping; the
                # model itself runs once, vmapped over the curves).
                columns[name] = jnp.stack([p[curve_name(name, i)] for i in range(count)])
        for name, value in fixed.items():
            columns[name] = jnp.full((count,), value)
        times = t[:size].reshape(count, length)
        curves = jax.vmap(curve_model)(times, columns)
        return jnp.concatenate([curves.reshape(size), jnp.zeros(t.shape[0] - size)])

    defaults = {n: Parameter(0.0) for n in names}
    label = ", ".join([law.describe() for law in spec.laws]
                      + [f"shared {', '.join(spec.shared)}"] * bool(spec.shared))
    return Model(name=f"global-{spec.model}", parameter_names=names, function=function,
                 defaults=defaults,
                 description=f"{count} curves of {curve_model.description}; {label}; "
                 f"{', '.join(per_curve)} per curve")


def _joint_names(spec: GlobalModel, count: int) -> tuple[str, ...]:
    names = [c for law in spec.laws for c in law.coefficient_names]
    names += [n for n in spec.fitted if n in spec.shared]
    names += [curve_name(n, i) for n in spec.per_curve for i in range(count)]
    return tuple(names)


def joint_parameters(spec: GlobalModel, start: Mapping[str, float], count: int) -> Parameters:
    defaults = spec.curve_model.defaults
    params = Parameters()
    for law in spec.laws:
        for name in law.coefficient_names:
            params[name] = Parameter(start[name])
    for name in spec.fitted:
        setting = defaults[name].replace(vary=True)
        keys = [name] if name in spec.shared else \
            [curve_name(name, i) for i in range(count)] if name in spec.per_curve else []
        for key in keys:
            value = start[key]
            low = setting.min if setting.min is not None else -math.inf
            high = setting.max if setting.max is not None else math.inf
            if not low < value < high:  # a first-stage value on its bound: start inside
                value = min(max(value, low + 1e-9 * max(abs(low), 1.0)),
                            high - 1e-9 * max(abs(high), 1.0))
            params[key] = setting.replace(value=value)
    return params


def joint_units(spec: GlobalModel, curves: Sequence[Curve], names: Sequence[str],
                count: int) -> dict[str, str]:
    """The unit of each joint parameter and of each fitted curve parameter."""
    curve_model = spec.curve_model
    time_unit, value_unit = curves[0].time_unit, curves[0].value_unit
    units = {n: curve_model.unit(n, time_unit, value_unit) for n in spec.fitted}
    for law in spec.laws:
        unit = units.get(law.parameter) or "1"
        left = ("1" if unit == "1" else f"ln({unit})") if law.transform == "log" else unit
        units[law.coefficient_names[0]] = left
        for name, term in zip(law.coefficient_names[1:], law.terms, strict=True):
            units[name] = f"{left} per unit of {term}"
    for name in spec.per_curve:
        for i in range(count):
            units[curve_name(name, i)] = units[name]
    return {n: units[n] for n in (*names, *spec.fitted)}
