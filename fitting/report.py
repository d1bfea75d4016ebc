"""Reports of fits: readable tables, JSON records, plots, written atomically.

Everything a user sees after ``axialmix fit`` comes from here: the per-curve parameter table
(value, standard error, 95 % interval, and the grid search beside it when one was run), the
summary table of several curves, the JSON record of a fit with plain statements about which
parameters the curve determines, the equivalent axial dispersion of a compartment-network fit,
and a two-panel PNG (data and fitted curve; residuals). Files are written by
:mod:`axialmix._files` (a temporary file moved into place), so an interrupted run never
leaves a half-written file. Nothing here computes physics: the equivalent ADM comes from the
model's hook (:meth:`fitting.result.FitResult.equivalent_adm`), its uncertainty from
:func:`fitting.physical.physical_quantities`.

Every number carries its unit: parameters in tables as ``tau (min)``, in JSON with a
``unit`` field; physical quantities with the unit in their key (``dispersion_m2_per_s``,
``mean_residence_time_min``). The plot shows data, model and residuals in the units of the
data, with the headline parameters and their 95 % intervals written on it.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from axialmix._files import write_atomic, write_csv, write_json
from axialmix.adm import error_estimate as _fv_error_estimate
from fitting.diagnostics import (
    ON_CURVE_SHARE,
    ModelComparison,
    has_poorly_determined_combinations,
    identifiability,
    other_optima,
    points_on_curve,
)
from fitting.drawing import FigureSpec, draw
from fitting.gridsearch import GridResult
from fitting.measurement import MEASUREMENT_PARAMETERS, MeasuredModel
from fitting.physical import physical_quantities, quantity_column, quantity_unit
from fitting.residuals import COUNTS_PER_MERGED_BIN, merged_counts
from fitting.result import FitResult

__all__ = [
    "comparison_record",
    "comparison_table",
    "fit_record",
    "fit_table",
    "identifiability_statements",
    "PLOT_POINTS",
    "plot_fit",
    "plot_times",
    "fit_figure",
    "headline_parameters",
    "render_fit_png",
    "solver_accuracy",
    "summary_columns",
    "summary_row",
    "summary_rows",
    "summary_table",
    "text_table",
    "write_atomic",
    "write_csv",
    "write_json",
    "write_png",
]

#: Most data points drawn in a plot; longer curves are drawn with every k-th point (a plot of
#: a million markers takes seconds and shows nothing more).
MAX_DRAWN_POINTS = 5000
#: A 95 % interval wider than this multiple of the value (or reaching a bound) means the
#: curve does not determine the parameter.
UNDETERMINED_RELATIVE_ERROR = 0.5
#: Correlations beyond this magnitude mean only a combination of two parameters is determined.
STRONG_CORRELATION = 0.95


# --- numbers ------------------------------------------------------------------------------------


def _finite(x: Any) -> float | None:
    """A plain float, or None for missing, NaN and infinite numbers (JSON has no NaN)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _number(x: Any, digits: int = 5) -> str:
    if x is not None and math.isinf(float(x)):
        return "inf" if float(x) > 0 else "-inf"
    value = _finite(x)
    return "-" if value is None else f"{value:.{digits}g}"


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain-text table with columns padded to their widest cell.

    **Arguments:**

    - `header`: column titles.
    - `rows`: rows of already formatted cells.

    **Returns:** the table as lines joined by newlines (no trailing newline).
    """
    widths = [max(len(str(c)) for c in column) for column in zip(header, *rows, strict=True)]
    line = "  ".join("-" * w for w in widths)

    def render(cells: Sequence[str]) -> str:
        first, *rest = cells
        return "  ".join([f"{first:<{widths[0]}}", *(f"{c:>{w}}" for c, w in
                                                       zip(rest, widths[1:], strict=True))])

    return "\n".join([render(header), line, *(render(r) for r in rows)])


# --- what a fit determines ----------------------------------------------------------------------


def identifiability_statements(result: FitResult) -> list[str]:
    """Plain sentences on which parameters the curve determines, from the fit's uncertainty.

    A free parameter is called undetermined when its 95 % interval is undefined (singular
    curvature), reaches zero for a positive parameter, or is wider than
    ``±UNDETERMINED_RELATIVE_ERROR`` of the value; a pair is called confounded when its
    correlation exceeds ``STRONG_CORRELATION`` in magnitude. These are statements about the
    linearised (Gauss–Newton) uncertainty; a profile likelihood checks them more strictly.
    They hold only for a model that describes the curve: the fit's lack-of-fit verdict
    (:attr:`~fitting.result.FitResult.lack_of_fit`) comes with them, and when it finds
    systematic residuals the summary says that the model does not describe the curve and
    that its intervals understate the uncertainty, instead of calling parameters determined.

    **Arguments:**

    - `result`: a :class:`~fitting.result.FitResult`.

    **Returns:** a list of sentences; the last one summarises.
    """
    statements = []
    undetermined = []
    for name in result.free_names:
        value = result.values[name]
        error = _finite(result.stderr.get(name))
        interval = result.ci95.get(name)
        if error is None or interval is None:
            statements.append(f"{name} is not identifiable: its standard error is undefined "
                              "(the curve does not constrain it).")
            undetermined.append(name)
            continue
        low, high = interval
        relative = error / abs(value) if value else math.inf
        if relative > UNDETERMINED_RELATIVE_ERROR or (low <= 0 < value):
            statements.append(
                f"{name} is poorly identifiable: {name} = {value:.4g} +/- {error:.3g} "
                f"({100 * relative:.0f} %), 95 % interval [{low:.4g}, {high:.4g}]."
            )
            undetermined.append(name)
    on_curve = points_on_curve(result) if result.free_names else math.inf
    if on_curve <= len(result.free_names):
        statements.append(
            f"Only {on_curve} of the {int(np.count_nonzero(result.weights > 0))} points "
            f"{'lies' if on_curve == 1 else 'lie'} on the fitted curve (above "
            f"{100 * ON_CURVE_SHARE:.0f} % of its height), for "
            f"{len(result.free_names)} free parameters: the samples do not trace its shape, "
            "so the intervals from the linearised model do not hold (--profile shows how far "
            "each parameter is free).")
        undetermined.extend(n for n in result.free_names if n not in undetermined)
    names = list(result.free_names)
    correlation = np.asarray(result.correlation, dtype=float)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            r = correlation[i, j] if correlation.shape == (len(names),) * 2 else math.nan
            if math.isfinite(r) and abs(r) > STRONG_CORRELATION:
                statements.append(
                    f"{names[i]} and {names[j]} are strongly correlated (r = {r:+.3f}): the "
                    "curve determines a combination of them, not each one."
                )
    if (len(names) > 1 and result.loss_name == "sse"
            and has_poorly_determined_combinations(result)):
        statements.append(f"Combinations (curvature eigen-analysis, log scale): "
                          f"{identifiability(result).summary}.")
    if result.profiled:
        names = ", ".join(result.profiled)
        statements.append(
            f"95 % intervals of {names} from the profile likelihood: each held on a grid "
            "over a factor 1000 either way (or ±4 of its scale), the others refitted; the "
            "interval holds every value whose refitted loss stays below the F-test level "
            "(0 or inf: the curve does not bound it on that side within the grid).")
    statements.extend(result.model.facts(result.values, result.init_params))
    for optimum in other_optima(result)[:1]:
        where = ", ".join(f"{n} = {v:.4g}" for n, v in optimum.values.items())
        outside = ", ".join(optimum.outside)
        local = "; ".join(f"{n} {_bracket(result.linearised_intervals[n])}"
                          for n in optimum.outside)
        statements.append(
            f"Another optimum fits the curve as well: start {optimum.start + 1} ended at "
            f"{where} (first-fit loss {optimum.loss:.4g}, within the 95 % threshold of the "
            f"best); there {outside} {'lies' if len(optimum.outside) == 1 else 'lie'} outside "
            f"the linearised interval of the best optimum alone ({local}), so the 95 % "
            "interval above is widened to hold them: the curve does not choose between them.")
        if result.free_names:
            for name in optimum.outside:
                if name not in undetermined:
                    undetermined.append(name)
    if result.evaluation_check is not None:
        largest, peak = result.evaluation_check
        statements.append(
            f"The model was evaluated on Chebyshev panels of exact values ({len(result.curve):,} "
            f"points); at the fitted values it is at most {largest / peak:.1g} of the peak from "
            "the exact model on every point." if peak > 0 else
            "The model was evaluated on Chebyshev panels of exact values.")
    verdict = result.lack_of_fit
    if verdict.tested:
        statements.append(verdict.statement)
    if undetermined:
        statements.append(
            f"Not determined by this curve: {', '.join(undetermined)}; fix or tie them "
            "(--fix, --tie) or add information to report them."
        )
    if verdict.systematic:
        statements.append(
            f"The {result.model.name} model does not describe this curve, so its parameters "
            "are not determined by it: the standard errors and intervals above understate "
            "the uncertainty."
        )
    elif not undetermined:
        limit = 100 * UNDETERMINED_RELATIVE_ERROR
        statements.append("All fitted parameters are determined by this curve "
                          f"(relative standard errors below {limit:.0f} %).")
    return statements


def _bracket(interval) -> str:
    """``[low, high]`` of an interval, 4 significant digits (an open side as -inf/inf)."""
    low, high = interval
    return (f"[{-math.inf if low is None else low:.4g}, "
            f"{math.inf if high is None else high:.4g}]")


# --- tables and records -------------------------------------------------------------------------


def _verdict(record: Mapping[str, Any] | None) -> str:
    """A lack-of-fit record in a table cell: ``systematic (runs p 2e-06, r1 +0.71)``."""
    if not record:
        return "-"
    if not record.get("tested", True):
        return "not tested"
    word = "SYSTEMATIC" if record["systematic"] else "none"
    runs = (f"runs p {_number(record['runs_test_p'], 2)}" if record.get("runs", 2) > 1
            else "one sign")
    return f"{word} ({runs}, r1 {record['lag1_autocorrelation']:+.2f})"



def _labelled(name: str, unit: str) -> str:
    """``"tau (min)"``; a dimensionless or unknown unit is left out."""
    return name if unit in ("", "1") else f"{name} ({unit})"


def parameter_units(result: FitResult) -> dict[str, str]:
    """The unit of each parameter of a fit, from its model (``""`` where unknown)."""
    value_unit = result.curve.value_unit
    if result.curve.normalised:
        value_unit = f"1/{result.time_unit}"
    return {name: result.model.unit(name, result.time_unit, value_unit)
            for name in result.values}


def _derived(result: FitResult, length_m: float | None) -> dict[str, Any]:
    """The physical quantities that are not parameters themselves (v, D_z, mean time, ...)."""
    quantities = physical_quantities(result, length_m)
    own = {"peclet", f"tau_{result.time_unit}"} if "tau" in result.values else set()
    tau = result.values.get("tau")
    return {key: q for key, q in quantities.items()
            if key not in own and q.value is not None
            and not (key.startswith("mean_residence_time") and q.value == tau)}


#: Models solved by finite volumes: their fits state the solver's accuracy.
FINITE_VOLUME_MODELS = ("adm-fv",)


def solver_accuracy(result: FitResult) -> dict[str, Any] | None:
    """The finite-volume solver's accuracy at a fit's values, or None for another model.

    Renders :func:`axialmix.adm.error_estimate` (the difference to a solve on a refined
    grid) for the fitted ``tau`` and ``peclet`` at the curve's sample times, for the inlet
    the fit used; with the measurement model the error is also given in the signal's unit
    (times the fitted amplitude).

    **Arguments:** `result`: a fit.

    **Returns:** :meth:`axialmix.adm.FVErrorEstimate.to_dict` with ``unit`` and, for a
    measured model, ``max_error_signal`` and ``signal_unit``; None when the model is not
    solved by finite volumes or the estimate cannot be made.
    """
    model = result.model
    base = model.base if isinstance(model, MeasuredModel) else model
    if base is None or base.name not in FINITE_VOLUME_MODELS:
        return None
    values = result.values
    time = np.asarray(result.time, float)
    kind, extra = "exit_age", {}
    unit = f"1/{result.time_unit}"
    if isinstance(model, MeasuredModel):
        time = time - float(values.get("dead_time", 0.0))
        if model.inlet.kind == "step":
            kind, unit = "step", "1"
        elif model.inlet.kind != "pulse":
            kind, unit = "inlet", "1"
            extra = {"inlet_times": np.asarray(model.inlet.times, float),
                     "inlet_values": np.asarray(model.inlet.values, float)}
    try:
        estimate = _fv_error_estimate(time, float(values["tau"]), float(values["peclet"]),
                                      response=kind, **extra)
    except ValueError:
        return None  # outside the verified range: the fit already says so
    record = {**estimate.to_dict(), "unit": unit}
    if isinstance(model, MeasuredModel):
        signal = result.curve.value_unit or "signal"
        record["max_error_signal"] = float(estimate.max_error) * abs(float(values["amplitude"]))
        record["signal_unit"] = signal
    return record


def fit_table(result: FitResult, grid: GridResult | None = None,
              length_m: float | None = None) -> str:
    """The parameter table of one fit, with the grid search beside it when given.

    **Arguments:**

    - `result`: the gradient fit.
    - `grid`: the grid search on the same curve and loss, or ``None``.
    - `length_m`: blender length ``L`` (m): physical quantities (``v``, ``D_z``) are added
      with their standard errors and 95 % intervals (delta method).

    **Returns:** the table text (parameters with units, physical quantities, then the error
    model, loss, evaluations and time).
    """
    header = ["parameter", "value", "std. error", "95 % interval"]
    if grid is not None:
        header.append("grid search")
    units = parameter_units(result)
    rows = []
    for name, value in result.values.items():
        setting = result.init_params[name]
        interval = result.ci95.get(name)
        if setting.expr is not None:
            kind = f"= {setting.expr}"
        elif not setting.vary:
            kind = "fixed"
        else:
            kind = (f"[{_number(interval[0])}, {_number(interval[1])}]"
                    if interval is not None else "-")
        row = [_labelled(name, units[name]), _number(value, 6),
               _number(result.stderr.get(name), 3), kind]
        if grid is not None:
            row.append(_number(grid.values.get(name), 6))
        rows.append(row)
    for quantity in _derived(result, length_m).values():
        interval = quantity.ci95
        rows.append([_labelled(quantity.label, quantity.unit), _number(quantity.value, 6),
                     _number(quantity.stderr, 3),
                     f"[{_number(interval[0])}, {_number(interval[1])}]" if interval else "-"]
                    + ([""] if grid is not None else []))
    if result.error_model is not None:
        rows.append(["errors", result.error_model.kind, "", ""]
                    + ([""] if grid is not None else []))
    accuracy = solver_accuracy(result)
    if accuracy is not None:
        rows.append(["FV solver error", f"{_number(accuracy['relative_error'], 2)} of peak",
                     "", "refined grid"] + ([""] if grid is not None else []))
    rows.append(["loss (" + result.loss_name + ")", _number(result.loss, 5), "", ""]
                + ([_number(grid.loss, 5)] if grid is not None else []))
    rows.append(["evaluations", f"{result.n_evaluations:,}", "", ""]
                + ([f"{grid.n_evaluations:,}"] if grid is not None else []))
    rows.append(["time (s)", f"{result.wall_time:.3f}", "", ""]
                + ([f"{grid.wall_time:.3f}"] if grid is not None else []))
    rows.append(["converged", "yes" if result.converged else "no", "", ""]
                + (["interrupted" if grid.interrupted else "complete"] if grid is not None
                   else []))
    rows.append(["lack of fit", _verdict(result.lack_of_fit.to_dict()), "", ""]
                + ([""] if grid is not None else []))
    signal = result.curve.value_unit or ("E" if result.curve.normalised else "")
    title = (f"{result.name or 'curve'}: model {result.model.name}, {result.n_points} points, "
             f"times in {result.time_unit}" + (f", signal in {signal}" if signal else ""))
    return title + "\n" + text_table(header, rows)


def fit_record(
    result: FitResult,
    grid: GridResult | None = None,
    source: str | None = None,
    length_m: float | None = None,
) -> dict[str, Any]:
    """The JSON record of one fit.

    **Arguments:**

    - `result`: the gradient fit.
    - `grid`: the grid search on the same curve, or ``None``.
    - `source`: the data file.
    - `length_m`: blender length ``L`` (m) for the equivalent ``v`` and ``D_z``; without it
      only ``tau`` and ``Pe`` are given (there is no default length).

    **Returns:** a JSON-ready dict with ``model``, ``data``, ``source``, ``parameters``
    (``{name: {value, stderr, ci95, vary, expr, unit}}``), ``meanings`` (what a parameter
    means, e.g. the open–open tau), ``loss``, ``loss_name``, ``converged``,
    ``message``, ``n_evaluations``, ``wall_time``, ``correlation``, ``aic``, ``bic``,
    ``time_unit``, ``value_unit``, ``error_model`` (kind and estimated sizes),
    ``identifiability`` (sentences), ``lack_of_fit``
    (:meth:`fitting.residuals.LackOfFit.to_dict`), ``equivalent_adm`` (models with that hook;
    units in its keys), ``physical`` (the same quantities with ``value``, ``stderr``,
    ``ci95`` and ``unit``: delta method), ``measurement`` (the inlet signal, for a measured
    model), ``solver_accuracy`` for a finite-volume model (:func:`solver_accuracy`) and
    ``grid_search`` when one was run.
    """
    base = result.to_dict()
    units = parameter_units(result)
    parameters = {
        name: {**{key: entry[key] for key in ("value", "stderr", "ci95", "interval", "vary",
                                              "expr")},
               "unit": units[name]}
        for name, entry in base["parameters"].items()
    }
    record: dict[str, Any] = {
        "model": result.model.name,
        "data": result.name,
        "source": source,
        "time_unit": result.time_unit,
        "parameters": parameters,
        "loss": base["loss"],
        "loss_name": result.loss_name,
        "converged": bool(result.converged),
        "message": result.message,
        "n_evaluations": int(result.n_evaluations),
        "n_starts": int(result.n_starts),
        "wall_time": float(result.wall_time),
        "n_points": int(result.n_points),
        "sse": base["sse"],
        "aic": base["aic"],
        "bic": base["bic"],
        "correlation": base["correlation"],
        "identifiability": identifiability_statements(result),
        "lack_of_fit": result.lack_of_fit.to_dict(),
        "value_unit": result.curve.value_unit,
        "meanings": dict(result.model.meanings),
        "error_model": base.get("error_model"),
    }
    if isinstance(result.model, MeasuredModel):
        record["measurement"] = {"inlet": result.model.inlet.kind,
                                 "inlet_description": result.model.inlet.describe()}
    equivalent = result.equivalent_adm(length_m)
    if equivalent is not None:
        record["equivalent_adm"] = equivalent
        record["physical"] = {key: quantity.to_dict() for key, quantity in
                              physical_quantities(result, length_m).items()}
    accuracy = solver_accuracy(result)
    if accuracy is not None:
        record["solver_accuracy"] = accuracy
    if "evaluation_check" in base:
        record["evaluation_check"] = base["evaluation_check"]
    if grid is not None:
        record["grid_search"] = grid.to_dict()
    return record


def _label(name: str, unit: str | None) -> str:
    """A column name with its unit in brackets (``tau [min]``; none for dimensionless)."""
    return name if unit in (None, "", "1") else f"{name} [{unit}]"


def _extra_quantities(record: Mapping[str, Any]) -> list[str]:
    """Physical quantities of a record that do not repeat one of its parameters (v, D_z for
    the ADM; a network's equivalent tau, Pe, D_z)."""
    values = [entry.get("value") for entry in record["parameters"].values()]
    keys = []
    for key, entry in (record.get("physical") or {}).items():
        stem = key.removesuffix(f"_{record.get('time_unit', 's')}")
        if entry.get("value") is None or stem in record["parameters"] or (
                entry["value"] in values and stem == "mean_residence_time"):
            continue
        keys.append(key)
    return keys


def summary_columns(record: Mapping[str, Any], factors: Sequence[str]
                    ) -> tuple[list[str], list[str], list[str]]:
    """The header of ``summary.csv`` for records like `record` with these `factors`, the
    parameters it shows and the extra physical quantities (see :func:`summary_rows`)."""
    names = [name for name, entry in record["parameters"].items()
             if entry.get("vary", True) or entry.get("expr") is not None]
    extra = _extra_quantities(record)
    header = ["curve", *factors, "model", "n_points"]
    for name in names:
        unit = record["parameters"][name].get("unit")
        header += [_label(f"{name}{part}", unit)
                   for part in ("", "_stderr", "_ci95_low", "_ci95_high")]
    time_unit = record.get("time_unit", "s")
    for key in extra:
        name, unit = quantity_column(key, time_unit)
        header += [_label(f"{name}{part}", unit)
                   for part in ("", "_stderr", "_ci95_low", "_ci95_high")]
    header += ["errors", "converged", "message", "systematic_misfit", "runs_test_p",
               "lag1_autocorrelation", "loss", "sse", "n_evaluations", "wall_time_s"]
    return header, names, extra


def summary_row(curve: str, levels: Sequence[str], record: Mapping[str, Any],
                names: Sequence[str], extra: Sequence[str]) -> list[Any]:
    """One row of ``summary.csv`` (the `names` and `extra` of :func:`summary_columns`)."""
    cells: list[Any] = [curve, *levels, record["model"], record["n_points"]]
    for entries, keys in ((record["parameters"], names), (record.get("physical") or {}, extra)):
        for key in keys:
            entry = entries.get(key) or {}
            low, high = entry.get("ci95") or (None, None)
            cells += [entry.get("value"), entry.get("stderr"), low, high]
    verdict = record.get("lack_of_fit") or {}
    cells += [(record.get("error_model") or {}).get("kind"), record["converged"],
              record["message"], verdict.get("systematic"), verdict.get("runs_test_p"),
              verdict.get("lag1_autocorrelation"), record["loss"], record["sse"],
              record["n_evaluations"], round(record["wall_time"], 4)]
    return cells


def summary_rows(records: Sequence[Mapping[str, Any]], factors: Sequence[str] = (), *,
                 curves: Sequence[str] | None = None,
                 levels: Sequence[Sequence[str]] | None = None
                 ) -> tuple[list[str], list[list[Any]]]:
    """Header and rows of ``summary.csv``: the one summary schema of every mode (files, a
    folder, a long-format study, a design table).

    **Arguments:**

    - `records`: records from :func:`fit_record`, all of the same model.
    - `factors`: the study's factor names (none for files and folders).
    - `curves`: the curve names (default: each record's ``data``).
    - `levels`: per curve the factor levels as written (default: none).

    **Returns:** ``(header, rows)``. Columns: ``curve``, the factors, ``model``,
    ``n_points``, each fitted parameter's value, standard error and 95 % interval
    (``tau [s]``, ``tau_stderr [s]``, ``tau_ci95_low [s]``, ``tau_ci95_high [s]``: units in
    brackets, none for dimensionless ones), the same for physical quantities that are not
    parameters (``velocity [m/s]``, ``dispersion [m^2/s]``, a network's equivalent ``tau [s]`` and
    ``peclet``), then
    the error model, convergence and its message, the lack-of-fit verdict and its tests,
    loss, evaluations and wall time.
    """
    if not records:
        return ["curve", *factors], []
    curves = [r["data"] for r in records] if curves is None else list(curves)
    levels = [[] for _ in records] if levels is None else list(levels)
    header, names, extra = summary_columns(records[0], factors)
    return header, [summary_row(curve, level, record, names, extra)
                    for curve, level, record in zip(curves, levels, records, strict=True)]


def _physical_keys(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The physical quantities of the records that are not parameters of theirs, in order."""
    keys: list[str] = []
    for record in records:
        own = record["parameters"]
        for key, entry in (record.get("physical") or {}).items():
            stem = key.rsplit("_", 1)[0] if key.startswith("tau_") else key
            tau = (own.get("tau") or {}).get("value")
            repeats = stem in own or (key.startswith("mean_residence_time")
                                      and entry.get("value") == tau)
            if key not in keys and not repeats and entry.get("value") is not None:
                keys.append(key)
    return keys


#: Width of the terminal the compact tables are made for (characters).
TABLE_WIDTH = 100


def summary_table(records: Sequence[Mapping[str, Any]], wide: bool = False) -> str:
    """The readable summary table of several fits.

    **Arguments:**

    - `records`: records from :func:`fit_record`, all of the same model.
    - `wide`: every column (each parameter, fixed ones too, and each physical quantity with
      its standard error, loss, evaluations, time, convergence and the lack-of-fit tests);
      otherwise the headline numbers in at most :data:`TABLE_WIDTH` characters: per curve the
      free model parameters and the equivalent ADM's tau and peclet as value ± standard
      error, and one word on the fit (``ok``, ``MISFIT`` for systematic residuals, ``NOT
      CONVERGED``), the columns that do not fit the width left out and named below the table
      (everything is in ``summary.csv``).

    **Returns:** the table as text.
    """
    if not wide:
        return _compact_summary_table(records)
    names = list(records[0]["parameters"]) if records else []
    # The moments behind a network's equivalent ADM stay in the CSV and JSON files.
    physical = [key for key in _physical_keys(records) if not key.startswith("variance")]
    with_grid = any("grid_search" in r for r in records)
    units = records[0]["parameters"] if records else {}
    labels = [_labelled(name, units[name].get("unit", "")) for name in names]
    time_unit = records[0].get("time_unit", "s") if records else "s"
    header = ["curve", *labels, *(_labelled(*quantity_unit(key, time_unit)) for key in physical),
              "loss", "evaluations", "time (s)", "converged", "lack of fit"]
    if with_grid:
        header += ["grid loss", "grid evaluations"]
    rows = []
    for record in records:
        row = [record["data"]]
        for name in names:
            entry = record["parameters"][name]
            error = _finite(entry.get("stderr"))
            row.append(_number(entry["value"], 4)
                       + ("" if error is None or not entry.get("vary", True) and
                          entry.get("expr") is None else f" +/- {error:.2g}"))
        for key in physical:
            entry = (record.get("physical") or {}).get(key, {})
            error = _finite(entry.get("stderr"))
            row.append(_number(entry.get("value"), 4)
                       + ("" if error is None else f" +/- {error:.2g}"))
        row += [_number(record["loss"], 4), f"{record['n_evaluations']:,}",
                f"{record['wall_time']:.3f}", "yes" if record["converged"] else "no",
                _verdict(record.get("lack_of_fit"))]
        if with_grid:
            grid = record.get("grid_search") or {}
            row += [_number(grid.get("loss"), 4), f"{grid.get('n_evaluations', 0):,}"]
        rows.append(row)
    return text_table(header, rows)


def _compact_summary_table(records: Sequence[Mapping[str, Any]]) -> str:
    first = records[0] if records else {"parameters": {}}
    names = [name for name, entry in first["parameters"].items()
             if name not in MEASUREMENT_PARAMETERS
             and (entry.get("vary", True) or entry.get("expr") is not None)]
    time_unit = first.get("time_unit", "s")
    derived = [key for key in _physical_keys(records)
               if quantity_column(key, time_unit)[0] in ("tau", "peclet")]
    columns = [(_labelled(name, first["parameters"][name].get("unit", "")),
                [_compact(r["parameters"].get(name, {})) for r in records]) for name in names]
    columns += [(_labelled(*quantity_unit(key, time_unit)),
                 [_compact((r.get("physical") or {}).get(key, {})) for r in records])
                for key in derived]
    verdicts = [_fit_word(r) for r in records]
    left_out: list[str] = []
    while True:
        header = ["curve", *(title for title, _ in columns), "fit"]
        rows = [[r["data"], *(cells[i] for _, cells in columns), verdicts[i]]
                for i, r in enumerate(records)]
        table = text_table(header, rows)
        if max(len(line) for line in table.splitlines()) <= TABLE_WIDTH or len(columns) <= 1:
            break
        left_out.insert(0, columns.pop()[0])
    if left_out:
        table += f"\n(left out for width: {', '.join(left_out)}; --wide shows every column)"
    return table


def _compact(entry: Mapping[str, Any]) -> str:
    """``1.358±2.7``: a value to 4 digits with its standard error to 2 (``-`` if none)."""
    value, error = _finite(entry.get("value")), _finite(entry.get("stderr"))
    if value is None:
        return "-"
    return f"{value:.4g}" + ("" if error is None else f"±{error:.2g}")


def _fit_word(record: Mapping[str, Any]) -> str:
    if not record.get("converged"):
        return "NOT CONVERGED"
    verdict = record.get("lack_of_fit") or {}
    return "MISFIT" if verdict.get("systematic") else "ok"


# --- model comparison ---------------------------------------------------------------------------


def comparison_table(comparison: ModelComparison, wide: bool = False) -> str:
    """The table of a model comparison: fitted parameters with their units, SSE (``Σ w r²``),
    AICc, BIC and lack of fit per model, followed by the recommendation.

    **Arguments:**

    - `comparison`: from :func:`fitting.diagnostics.compare_models`.
    - `wide`: one row per model with every column; by default the criteria in a table of
      at most :data:`TABLE_WIDTH` columns and each model's parameters (value±std. error,
      unit) on lines of their own below it.

    **Returns:** the table and the recommendation as text.
    """
    first = comparison.results[0]
    title = (f"{first.name or 'curve'}: {len(comparison.results)} models, {first.n_points} "
             f"points, times in {first.time_unit} (K = free parameters + the error model's; "
             "lower AICc and BIC are better)")
    if not wide:
        header = ["model", "K", "AICc", "dAICc", "BIC", "lack of fit", "converged"]
        rows, lines = [], []
        for i, result in enumerate(comparison.results):
            rows.append([comparison.names[i], str(comparison.n_parameters[i]),
                         _number(comparison.aicc[i], 6), _number(comparison.delta_aicc[i], 3),
                         _number(comparison.bic[i], 6), _verdict(result.lack_of_fit.to_dict()),
                         "yes" if result.converged else "no"])
            text = ", ".join(_parameter_cells(result, "±"))
            lines.append(textwrap.fill(text, TABLE_WIDTH,
                                       initial_indent=f"  {comparison.names[i]}: ",
                                       subsequent_indent="    "))
        return "\n".join([textwrap.fill(title, TABLE_WIDTH), text_table(header, rows),
                          "fitted parameters (value±std. error):", *lines,
                          textwrap.fill(f"Recommendation: {comparison.recommendation}",
                                        TABLE_WIDTH)])
    header = ["model", "fitted parameters (value +/- std. error)", "SSE", "K", "AICc",
              "dAICc", "BIC", "lack of fit", "converged"]
    rows = []
    for i, result in enumerate(comparison.results):
        rows.append([
            comparison.names[i], ", ".join(_parameter_cells(result, " +/- ")),
            _number(result.sse, 4),
            str(comparison.n_parameters[i]), _number(comparison.aicc[i], 6),
            _number(comparison.delta_aicc[i], 3), _number(comparison.bic[i], 6),
            _verdict(result.lack_of_fit.to_dict()), "yes" if result.converged else "no",
        ])
    return "\n".join([title, text_table(header, rows),
                      f"Recommendation: {comparison.recommendation}"])


def _parameter_cells(result: FitResult, plus_minus: str) -> list[str]:
    """``tau 7.191±0.31 s``: each fitted (free or tied) parameter with its error and unit."""
    cells = []
    units = parameter_units(result)
    for name in result.values:
        setting = result.init_params[name]
        if not setting.vary and setting.expr is None:
            continue  # fixed: in each fit's own record and table
        error = _finite(result.stderr.get(name))
        unit = "" if units.get(name, "") in ("", "1") else f" {units[name]}"
        cells.append(f"{name} {_number(result.values[name], 4)}"
                     + ("" if error is None else f"{plus_minus}{error:.2g}") + unit)
    return cells


def comparison_record(comparison: ModelComparison,
                      records: Sequence[Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """The JSON record of a model comparison, with each fit's full record when given.

    **Arguments:**

    - `comparison`: from :func:`fitting.diagnostics.compare_models`.
    - `records`: the :func:`fit_record` of each fit, in the same order, or ``None``.

    **Returns:** ``{"data", "models": [{model, parameters, n_parameters, sse,
    log_likelihood, aicc, delta_aicc, akaike_weight, bic, converged, compared,
    lack_of_fit}], "best", "indistinguishable", "recommendation"}`` plus ``"fits"`` (the
    records) when given.
    """
    record = comparison.to_dict()
    if records is not None:
        record["fits"] = list(records)
    return record


# --- plot -----------------------------------------------------------------------------------------


def plot_fit(path: str | Path, result: FitResult, grid: GridResult | None = None) -> Path:
    """Save a two-panel PNG: data with the fitted curve (top), residuals (bottom).

    **Arguments:**

    - `path`: the PNG file to write (atomically).
    - `result`: the gradient fit (its model is evaluated on a fine time grid).
    - `grid`: a grid search on the same curve, drawn as a dashed curve when given.

    **Returns:** the path.
    """
    return write_png(path, render_fit_png(result, grid))


def write_png(path: str | Path, image: bytes) -> Path:
    """Write PNG bytes (from :func:`render_fit_png`) to `path` atomically; returns the path."""
    return write_atomic(path, lambda stream: stream.write(image), binary=True)


def _drawn(count: int) -> tuple[slice, str]:
    """Every k-th point of `count`, so that at most :data:`MAX_DRAWN_POINTS` are drawn, and
    the words that say so ("" when all are drawn)."""
    stride = max(1, math.ceil(count / MAX_DRAWN_POINTS))
    if stride == 1:
        return slice(None), ""
    return slice(None, None, stride), f", every {stride}th of {count:,} points drawn"


def _plottable(values) -> np.ndarray:
    """Values as floats with NaN (a gap in the line) where they are not finite."""
    values = np.asarray(values, dtype=float)
    return np.where(np.isfinite(values), values, np.nan)


#: Points at which plots draw a model curve: one shape for every curve, so the model's compiled
#: evaluation is traced once a process (the fit command's start-value check uses it too).
PLOT_POINTS = 399


def plot_times(time) -> np.ndarray:
    """The times at which a fit's plot draws its model curve.

    **Arguments:** `time`: the curve's sample times (its time unit).

    **Returns:** :data:`PLOT_POINTS` times from just after 0 to 1.05 times the last sample.
    """
    return np.linspace(0.0, float(np.asarray(time)[-1]) * 1.05, PLOT_POINTS + 1)[1:]


def _interval_text(label: str, value: float | None, interval, unit: str) -> str:
    """``tau = 7.029 s, 95 % [6.21, 7.85]`` (the interval left out when there is none)."""
    if value is None:
        return f"{label}: -"
    unit_text = "" if unit in ("", "1") else f" {unit}"
    if interval is None or interval[0] is None or interval[1] is None:
        return f"{label} = {_number(value, 4)}{unit_text}"
    return (f"{label} = {_number(value, 4)}{unit_text}, "
            f"95 % [{_number(interval[0], 3)}, {_number(interval[1], 3)}]")


#: Equivalent-ADM quantities a fit plot states beside the model's own parameters.
_HEADLINE_QUANTITIES = ("tau", "peclet", "mean residence time")


def headline_parameters(result: FitResult) -> list[str]:
    """The lines a fit plot states: each free model parameter (the measurement model's
    amplitude, dead time and baseline left out) and the equivalent ADM's ``tau`` and ``peclet``
    where they are not parameters, each with its 95 % interval and unit."""
    units = parameter_units(result)
    lines = [_interval_text(name, result.values[name], result.ci95.get(name), units[name])
             for name in result.free_names if name not in MEASUREMENT_PARAMETERS]
    for quantity in _derived(result, None).values():
        if quantity.label in _HEADLINE_QUANTITIES:
            lines.append(_interval_text(f"{quantity.label} (equivalent ADM)", quantity.value,
                                        quantity.ci95, quantity.unit))
    return lines


def fit_figure(result: FitResult, grid: GridResult | None = None) -> FigureSpec:
    """The arrays and words of a fit's two-panel plot (see :func:`fitting.drawing.draw_fit`).

    Data, model and residuals are drawn in the units of the data (a raw signal stays a raw
    signal: the model is the measurement model's prediction ``A·(E ⊗ u)(t − t_d) + b``), and
    the headline parameters with their 95 % intervals (:func:`headline_parameters`) are
    written on the figure. A curve of more than :data:`MAX_DRAWN_POINTS` samples is drawn
    with every k-th sample (the legend and the residual axis say so); the fit used them all.
    Values that are not finite are left out of the lines (NaN).

    **Arguments:** as :func:`plot_fit`, without the path.

    **Returns:** a :data:`~fitting.drawing.FigureSpec` (times in the curve's unit).
    """
    every, note = _drawn(len(result.time))
    time = np.asarray(result.time, float)[every]
    observed = np.asarray(result.observed, float)[every]
    predicted = np.asarray(result.predicted, float)[every]
    counting = result.error_model is not None and result.error_model.kind == "poisson"
    if counting:
        # A histogram of a fraction of a particle a bin is a cloud of 0, 1, 2 ... particles:
        # drawn on the bins the lack-of-fit test merges (each expecting 10 particles), as
        # counts over exposure, it shows what the fit is judged on.
        time, observed, predicted = _merged_bins(result)
        note = (f" (bins merged to {COUNTS_PER_MERGED_BIN:g} expected particles, "
                "as the lack-of-fit test)")
    fine = plot_times(result.time)
    model = result.model
    unit = result.time_unit
    if result.curve.normalised:
        value_label = f"E (1/{unit})"
        residual_unit = f"1/{unit}"
    elif result.curve.value_unit:
        value_label = f"signal ({result.curve.value_unit})"
        residual_unit = result.curve.value_unit
    else:
        value_label = "signal (unit of the data)"
        residual_unit = "unit of the data"
    lines = headline_parameters(result)
    if result.error_model is not None:
        lines.append(f"errors: {result.error_model.kind}")
    return {
        "time": time,
        "observed": _plottable(observed),
        "fine": fine,
        "curve": _plottable(model.evaluate(fine, result.values)),
        "grid_curve": None if grid is None else _plottable(model.evaluate(fine, grid.values)),
        "residual": _plottable(predicted - observed),
        "data_label": f"data{note}",
        "fit_label": f"fit ({model.name}, {result.loss_name} = {result.loss:.3g})",
        "grid_label": "" if grid is None else f"grid search ({grid.loss_name} = {grid.loss:.3g})",
        "ylabel": value_label,
        "title": f"{result.name or 'curve'}: model {model.name}",
        "annotation": "\n".join(lines),
        "residual_label": (f"residual ({residual_unit})\nmodel - data"
                           + ("\n(points drawn as above)" if note else "")),
        "xlabel": f"time ({unit})",
        "thinned": bool(note) and not counting,
    }


def _merged_bins(result: FitResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A counting fit's data and model on the merged bins of its lack-of-fit test
    (:func:`fitting.residuals.merged_counts`): each bin's exposure-weighted mean time, and
    the merged counts and model means over the merged exposure (the data's unit)."""
    x = np.asarray(result.exposure, float)
    used = x > 0
    x = x[used]
    k = x * np.asarray(result.observed, float)[used]
    mu = np.clip(x * np.asarray(result.predicted, float)[used], 0.0, None)
    counts, means, first = merged_counts(k, mu)
    exposure = np.add.reduceat(x, first) if first.size else np.zeros(0)
    time = (np.add.reduceat(x * np.asarray(result.time, float)[used], first) / exposure
            if first.size else np.zeros(0))
    return time, counts / exposure, means / exposure


def render_fit_png(result: FitResult, grid: GridResult | None = None) -> bytes:
    """The two-panel PNG of :func:`plot_fit` as bytes, nothing written.

    Drawn by :func:`fitting.drawing.draw` (in the command line's drawing process when it
    runs) from :func:`fit_figure`.

    **Arguments:** as :func:`plot_fit`, without the path.

    **Returns:** the PNG file's bytes.
    """
    return draw(fit_figure(result, grid))
