"""The uncertainty of a global fit: the one joint covariance (with the degrees of freedom its
estimated weights take), intervals, the laws' coefficients and each curve's parameters by the
delta method (``fit_result``), and each curve's physical quantities propagated from that
covariance (:func:`~fitting.study.global_fit.curve_physical_quantities`).
"""

from __future__ import annotations

import math

import numpy as np

from fitting.parameters import Parameter
from fitting.physical import PhysicalQuantity, hook_numbers, propagated_quantities
from fitting.solve import CONVERGED, STATUS_MESSAGES, Status
from fitting.study.global_fit.estimate import law_estimate
from fitting.study.global_fit.joint import joint_units
from fitting.study.global_fit.model import curve_name
from fitting.study.global_fit.problem import GlobalProblem
from fitting.study.global_fit.result import GlobalFitResult
from fitting.uncertainty import gauss_newton_uncertainty, interval, t_quantile


def fit_result(problem: GlobalProblem, out: dict, status: Status, compile_time: float,
               wall_time: float) -> GlobalFitResult:
    """The :class:`GlobalFitResult` of the solver's output for `problem`."""
    spec, count, length = problem.spec, len(problem.curves), problem.length
    names = problem.names
    residual = out["predicted"] - problem.observed
    weights = problem.weights
    uncertainty = gauss_newton_uncertainty(out["jacobian"], residual, weights)
    covariance, dof = uncertainty.covariance, uncertainty.dof
    all_stderr, sigma = uncertainty.all_stderr, uncertainty.sigma
    # Weights estimated from residuals of the same data take one degree of freedom each,
    # less one for their common scale (as for the estimated weight shape of the combined
    # error model, fitting.fit): the n_curves - 1 ratios of per-curve weights; the additive
    # and proportional sizes of each curve under combined weights.
    estimated = 0
    if problem.weighting == "per-curve":
        estimated = count - 1
    elif problem.weighting == "combined":
        estimated = sum(2 if r.error_model.kind == "combined" else 1
                        for r in problem.first) - 1
    if estimated and dof > estimated + 1:
        factor = dof / (dof - estimated)
        dof -= estimated
        covariance, all_stderr, sigma = (covariance * factor, all_stderr * math.sqrt(factor),
                                         sigma * math.sqrt(factor))
    quantile = t_quantile(dof)
    free = np.asarray(out["free_values"], dtype=float)
    values = dict(zip(names, free.tolist(), strict=True))
    index = {n: j for j, n in enumerate(names)}
    settings = problem.model.defaults
    joint_settings = {n: settings[n] for n in names}
    curve_defaults = spec.curve_model.defaults
    for name in spec.fitted:  # bounds of the curve parameters, for their intervals
        keys = [name] if name in spec.shared else [curve_name(name, i) for i in range(count)] \
            if name in spec.per_curve else []
        for key in keys:
            joint_settings[key] = curve_defaults[name].replace(vary=True)
    stderr = dict(zip(names, all_stderr.tolist(), strict=True))
    ci95 = {n: interval(values[n], quantile * stderr[n], joint_settings[n]) for n in names}
    laws = []
    per_curve, per_curve_stderr, per_curve_ci95 = {}, {}, {}
    for law in spec.laws:
        picked = [index[c] for c in law.coefficient_names]
        block = covariance[np.ix_(picked, picked)]
        coefficients = free[picked]
        laws.append(law_estimate(law, "global fit", law.coefficient_names, coefficients,
                                 block, dof, quantile))
        design = law.design(problem.factors)
        linear = design @ coefficients
        linear_error = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", design, block, design), 0,
                                       None))
        value = np.asarray(law.apply(linear))
        low = np.asarray(law.apply(linear - quantile * linear_error))
        high = np.asarray(law.apply(linear + quantile * linear_error))
        scale = value if law.transform == "log" else 1.0
        per_curve[law.parameter] = value
        per_curve_stderr[law.parameter] = scale * linear_error
        per_curve_ci95[law.parameter] = np.column_stack([low, high])
    for name in spec.fitted:
        if name in per_curve:
            continue
        keys = [name] * count if name in spec.shared else \
            [curve_name(name, i) for i in range(count)]
        per_curve[name] = np.array([values[k] for k in keys])
        per_curve_stderr[name] = np.array([stderr[k] for k in keys])
        per_curve_ci95[name] = np.array([ci95[k] for k in keys], dtype=float)
    predicted = out["predicted"].reshape(count, length)
    residuals = residual.reshape(count, length)
    jacobian = out["jacobian"].reshape(count, length, len(names))
    sizes = [len(c) for c in problem.curves]
    curve_weights = weights.reshape(count, length)[:, 0]
    converged = status in CONVERGED
    n_points = int(np.count_nonzero(weights))
    correlation = uncertainty.correlation
    return GlobalFitResult(
        spec=spec, curve_names=tuple(c.name or f"curve {i}" for i, c in
                                     enumerate(problem.curves)),
        factors=dict(problem.factors), names=names, values=values, stderr=stderr, ci95=ci95,
        covariance=covariance, correlation=correlation, laws=tuple(laws),
        per_curve=per_curve, per_curve_stderr=per_curve_stderr,
        per_curve_ci95=per_curve_ci95,
        units=joint_units(spec, problem.curves, names, count),
        sse=float(np.sum(weights * residual**2)), n_points=n_points, dof=dof, sigma=sigma,
        weighting=problem.weighting,
        curve_weights=curve_weights, status=status, converged=converged,
        message=STATUS_MESSAGES[status], n_steps=int(out["steps"]),
        n_evaluations=int(out["evaluations"]), wall_time=wall_time, compile_time=compile_time,
        predicted=tuple(p[:n] for p, n in zip(predicted, sizes, strict=True)),
        residuals=tuple(r[:n] for r, n in zip(residuals, sizes, strict=True)),
        jacobian=tuple(j[:n] for j, n in zip(jacobian, sizes, strict=True)),
        first=problem.first,
    )


def curve_physical_quantities(result: GlobalFitResult, length_m: float | None
                              ) -> list[dict[str, PhysicalQuantity]]:
    """Each curve's physical quantities (the model's equivalent ADM: ``tau``, ``peclet``,
    and with a length the velocity and axial dispersion in SI units) from the global fit,
    with standard errors and 95 % intervals by the delta method over the one joint
    covariance (a law's parameters carry the laws' uncertainty, shared ones theirs).

    **Arguments:** `result`, a :class:`GlobalFitResult`; `length_m`, the blender length (m)
    or ``None`` (then no velocity and dispersion; there is no default length).

    **Returns:** per curve, in order, ``{key: PhysicalQuantity}`` (keys as in
    :func:`fitting.physical.physical_quantities`); empty dicts for a model without an
    equivalent ADM.
    """
    spec = result.spec
    model = spec.curve_model
    count = len(result.curve_names)
    if model.equivalent_adm is None:
        return [{} for _ in range(count)]
    time_unit = result.first[0].time_unit if result.first else "s"
    defaults = model.defaults
    designs = {law.parameter: law.design(result.factors) for law in spec.laws}
    settings = {}
    for name in result.names:
        stem = name.split("[", 1)[0] if "[" in name else name
        base = defaults[stem] if stem in defaults else None
        settings[name] = Parameter(result.values[name],
                                   min=None if base is None else base.min)
    covariance = np.asarray(result.covariance, float)

    def curve_values(joint: dict, i: int) -> dict[str, float]:
        values = {}
        for name in model.parameter_names:
            law = spec.law_of(name)
            if law is not None:
                coefficients = np.array([joint[c] for c in law.coefficient_names])
                values[name] = float(law.apply(designs[name][i] @ coefficients))
            elif name in spec.shared:
                values[name] = joint[name]
            elif name in spec.per_curve:
                values[name] = joint[curve_name(name, i)]
            else:
                values[name] = defaults[name].value
        return values

    quantities = []
    for i in range(count):
        def evaluate(changes, i=i):
            joint = {**result.values, **changes}
            return hook_numbers(model.equivalent_adm(curve_values(joint, i), length_m,
                                                     time_unit))

        quantities.append(propagated_quantities(evaluate, dict(result.values), settings,
                                                covariance, result.dof, time_unit))
    return quantities
