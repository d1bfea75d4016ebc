"""Physical results of a fit with units and uncertainty: tau, Pe, v and D_z in SI.

A model's ``equivalent_adm`` hook (computed by :mod:`axialmix`: for the ADM family
:func:`axialmix.analytic.inverse.transport_from_dimensionless` and the model's mean residence
time, for networks :func:`axialmix.network.moment_matched_adm`) turns fitted values into
physical quantities: ``tau`` and the mean residence time in the curve's time unit, ``Pe``,
and with a blender length ``L`` the velocity ``v`` (m/s) and the axial dispersion ``D_z``
(m²/s). Their standard errors come from the delta method: with ``g = d q / d p`` the
gradient of a quantity in the free parameters and ``C`` the fit's covariance, ``se(q) =
sqrt(g C gᵀ)``. The gradient is taken by central differences of the hook (in ``ln p`` for
positive parameters, step 1e-6), which are exact to round-off where a quantity is a power
law of the parameters (``v = L / tau``, ``D_z = L² / (tau Pe)``) and accurate to about 1e-9
elsewhere. 95 % intervals are symmetric in ``ln q`` for positive quantities (as for positive
parameters, :func:`fitting.uncertainty.interval`), with the fit's Student-t quantile. The
linearisation is the same as that of the parameters' own intervals; a profile of the
likelihood (:func:`fitting.diagnostics.profile_likelihood`) checks it where it matters.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fitting.parameters import Parameter, evaluate_expression, make_layout, parse_expression
from fitting.result import FitResult
from fitting.uncertainty import interval, t_quantile

__all__ = ["PhysicalQuantity", "hook_numbers", "physical_quantities", "propagated_quantities",
           "quantity_column", "quantity_unit"]

#: Relative step of the central differences (in ln p for positive parameters).
STEP = 1e-6
#: Units of the hook's keys that do not carry their unit in a time-unit suffix.
_FIXED_UNITS = {"peclet": "1", "variance_ratio": "1", "length_m": "m",
                "velocity_m_per_s": "m/s", "dispersion_m2_per_s": "m^2/s"}
#: Readable labels of the hook's keys (the time unit is added).
_LABELS = {"tau": "tau", "mean_residence_time": "mean residence time", "variance": "variance",
           "variance_ratio": "sigma^2/tau^2", "peclet": "peclet", "length_m": "L",
           "velocity_m_per_s": "v", "dispersion_m2_per_s": "D_z"}


@dataclass(frozen=True)
class PhysicalQuantity:
    """One physical quantity of a fit with its uncertainty.

    - `key`: its name with its unit (``"dispersion_m2_per_s"``, ``"tau_min"``), as in JSON.
    - `label`: a readable name (``"D_z"``).
    - `unit`: its unit (``"m^2/s"``, ``"min"``, ``"1"``).
    - `value`: its value; `stderr`: standard error by the delta method (``None`` when
      undefined, e.g. a singular covariance); `ci95`: 95 % interval, or ``None``.
    """

    key: str
    label: str
    unit: str
    value: float | None
    stderr: float | None
    ci95: tuple[float, float] | None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready record (``{value, stderr, ci95, unit}``)."""
        return {"value": self.value, "stderr": self.stderr,
                "ci95": None if self.ci95 is None else [_finite(x) for x in self.ci95],
                "unit": self.unit}


def _finite(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def quantity_unit(key: str, time_unit: str) -> tuple[str, str]:
    """The label and unit of a key of an ``equivalent_adm`` record.

    **Arguments:** `key` (e.g. ``"tau_min"``, ``"variance_s2"``, ``"velocity_m_per_s"``);
    `time_unit` of the fit.

    **Returns:** ``(label, unit)``.
    """
    if key in _FIXED_UNITS:
        return _LABELS.get(key, key), _FIXED_UNITS[key]
    for stem in ("mean_residence_time", "tau", "variance"):
        if key == f"{stem}_{time_unit}":
            return _LABELS[stem], time_unit
        if key == f"{stem}_{time_unit}2":
            return _LABELS[stem], f"{time_unit}^2"
    return key, ""


#: Column names (in files) of the keys whose name holds a fixed unit.
_COLUMNS = {"length_m": "length", "velocity_m_per_s": "velocity",
            "dispersion_m2_per_s": "dispersion"}


def quantity_column(key: str, time_unit: str) -> tuple[str, str]:
    """The column name and unit of a key of an ``equivalent_adm`` or ``physical`` record in
    the summary files: the name without its unit (``"tau_min"`` -> ``("tau", "min")``,
    ``"dispersion_m2_per_s"`` -> ``("dispersion", "m^2/s")``), the names of the ADM's
    parameters where it is one (``tau``, ``peclet``)."""
    if key in _FIXED_UNITS:
        return _COLUMNS.get(key, key), _FIXED_UNITS[key]
    for stem in ("mean_residence_time", "tau", "variance"):
        if key == f"{stem}_{time_unit}":
            return stem, time_unit
        if key == f"{stem}_{time_unit}2":
            return stem, f"{time_unit}^2"
    return key, ""


def _values_with(result: FitResult, changes: Mapping[str, float],
                 tied: Sequence[tuple[str, Any]]) -> dict[str, float]:
    """The fitted values with some free ones changed and the tied ones (``(name, parsed
    expression)`` pairs, in order) recomputed."""
    values = dict(result.values)
    values.update(changes)
    for name, expression in tied:
        values[name] = float(evaluate_expression(expression, values))
    return values


def hook_numbers(record: Mapping[str, Any] | None) -> dict[str, float]:
    """The numbers of an ``equivalent_adm`` record (``None`` as NaN; ``length_m`` and text
    left out)."""
    if record is None:
        return {}
    return {k: float(v) if v is not None else math.nan for k, v in record.items()
            if k != "length_m" and (v is None or isinstance(v, int | float))}


def physical_quantities(result: FitResult, length: float | None = None
                        ) -> dict[str, PhysicalQuantity]:
    """The physical quantities of a fit (the model's equivalent-ADM hook) with uncertainty.

    **Arguments:**

    - `result`: a fit whose model has an ``equivalent_adm`` hook.
    - `length`: blender length ``L`` (m); without it there are no ``v`` and ``D_z`` (there
      is no default length).

    **Returns:** ``{key: PhysicalQuantity}`` in the hook's order (``tau_<unit>``, ``peclet``,
    ``mean_residence_time_<unit>``, ``velocity_m_per_s``, ``dispersion_m2_per_s``, ...);
    empty when the model has no hook. ``length_m`` is not a fitted quantity and is left out.
    """
    if result.model.equivalent_adm is None:
        return {}
    unit = result.time_unit
    tied = []
    if any(setting.expr is not None for setting in result.init_params.values()):
        layout = make_layout(result.model.name, result.model.parameter_names,
                             result.init_params)
        tied = [(name, parse_expression(expr)) for name, expr in layout.tied]

    def evaluate(changes: Mapping[str, float]) -> dict[str, float]:
        return hook_numbers(result.model.equivalent_adm(_values_with(result, changes, tied),
                                                    length, unit))

    free = list(result.free_names)
    return propagated_quantities(evaluate, {n: float(result.values[n]) for n in free},
                                 {n: result.init_params[n] for n in free},
                                 np.asarray(result.covariance, float), result.dof, unit)


def propagated_quantities(evaluate: Callable[[Mapping[str, float]], Mapping[str, float]],
                          values: Mapping[str, float], settings: Mapping[str, Parameter],
                          covariance: np.ndarray, dof: int, time_unit: str
                          ) -> dict[str, PhysicalQuantity]:
    """Quantities computed from fitted values, with delta-method standard errors.

    **Arguments:**

    - `evaluate`: ``evaluate(changes)`` gives the quantities (key -> number) with the free
      values changed as `changes` says (``{}``: at the fitted values).
    - `values`: the free values, in the order of `covariance`; `settings`: their
      :class:`~fitting.parameters.Parameter` (a value bounded below by 0 is differenced in
      its logarithm).
    - `covariance`: of the free values; `dof`: the fit's degrees of freedom (t quantile of
      the 95 % intervals); `time_unit`: of the fit (labels and units).

    **Returns:** ``{key: PhysicalQuantity}`` in the order `evaluate` gives them.
    """
    centre = dict(evaluate({}))
    free = list(values)
    gradients = {key: np.zeros(len(free)) for key in centre}
    for j, name in enumerate(free):
        value = float(values[name])
        setting = settings[name]
        if setting.min is not None and setting.min >= 0 and value > 0:
            up, down = value * math.exp(STEP), value * math.exp(-STEP)
        else:
            delta = STEP * max(abs(value), 1e-12)
            up, down = value + delta, value - delta
        upper, lower = evaluate({name: up}), evaluate({name: down})
        for key in centre:
            gradients[key][j] = (upper[key] - lower[key]) / (up - down)
    quantile = t_quantile(dof)
    quantities = {}
    for key, value in centre.items():
        label, quantity_unit_ = quantity_unit(key, time_unit)
        gradient = gradients[key]
        stderr = ci95 = None
        if math.isfinite(value) and covariance.shape == (len(free),) * 2:
            variance = float(gradient @ covariance @ gradient)
            if math.isfinite(variance) and variance >= 0:
                stderr = math.sqrt(variance)
                ci95 = interval(value, quantile * stderr,
                                Parameter(value, min=0.0 if value > 0 else None))
        quantities[key] = PhysicalQuantity(key, label, quantity_unit_, _finite(value),
                                           _finite(stderr), ci95)
    return quantities
