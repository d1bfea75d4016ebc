"""The ``axialmix fit`` sub-command: fit residence-time curves from CSV files.

    axialmix fit FILE_OR_FOLDER... --model adm|adm-fv|adm-open|tanks|four-compartment|NET.json
                 [--fix NAME=VALUE] [--tie NAME=OTHER] [--loss sse|mae] [--grid] [--starts N]
                 [--errors absolute|relative] --out DIR

Every input is read and validated, and every option checked, before anything is written:
bad input prints one line ``axialmix fit: error: <file>:<row>: <problem>`` to stderr and
exits with status 2, leaving no output. Then each curve is fitted; its JSON record and PNG
plot are written to ``DIR/<name>.json`` and ``DIR/<name>.png`` as soon as it is done
(atomically), so Ctrl-C keeps finished curves. Several curves also give ``DIR/summary.json``
and ``DIR/summary.csv``.

With ``--errors relative`` the measurement errors are taken as proportional to the curve
(multiplicative noise, the usual case for concentration measurements): each curve is fitted,
then refitted weighted by ``1 / model²`` until the weights are those of its own curve
(``1 / |model|`` for the mean absolute error), see :func:`fitting.optimize.fit`. Unweighted
least squares treats the peak, the noisiest part, as precise as the tail, and its intervals
are then too narrow.

With ``--loss mae`` the least-squares multi-start fit is polished by a fit on the mean
absolute error (which is not smooth enough for multi-start L-BFGS alone); the evaluations
of both stages are reported.

With ``--grid`` the source's exhaustive grid search runs on the same loss: rates (parameters
named ``k_*``) over ``[0 : 0.125 : 2.5]`` (MODELS.md section 3), any other free parameter over
21 log-spaced values from a quarter to four times its fitted value; a free rate not on that
grid (``k_out``) is held at its fitted value, so the grid is the source's three-dimensional one.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Exit status for bad input (argparse's convention).
USAGE_ERROR = 2
#: Exit status after Ctrl-C.
INTERRUPTED = 130
#: Rates searched on the source's grid by ``--grid``.
SOURCE_GRID_STEP, SOURCE_GRID_MAX = 0.125, 2.5
#: Free parameters held at their fitted value in the grid search (the source did not search
#: the outflow rate).
GRID_HELD = ("k_out",)


class InputError(Exception):
    """Bad command-line input; the message is one line, without the program prefix."""


def add_fit_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register the ``fit`` sub-command on an argparse sub-parser collection.

    **Arguments:**

    - `subparsers`: the object returned by ``ArgumentParser.add_subparsers()``.

    **Returns:** the ``fit`` parser (its ``func`` default runs the command and returns the
    exit status).
    """
    parser = subparsers.add_parser(
        "fit",
        help="fit a residence-time model to RTD curves (CSV files or folders)",
        description="Fit a residence-time model to measured RTD curves; report values, "
        "standard errors, 95 %% intervals and what the data determine.",
    )
    parser.add_argument("inputs", nargs="+", metavar="FILE_OR_FOLDER",
                        help="CSV files (time, concentration) or folders of them")
    parser.add_argument("--model", default="adm",
                        help="adm, adm-fv, adm-open, tanks, four-compartment, or a network "
                        "JSON file (default: adm)")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value (repeatable)")
    parser.add_argument("--tie", action="append", default=[], metavar="NAME=OTHER",
                        help="make a parameter equal to another, e.g. k_r=k_f (repeatable)")
    parser.add_argument("--loss", choices=("sse", "mae"), default="sse",
                        help="least squares (default) or the source's mean absolute error")
    parser.add_argument("--grid", action="store_true",
                        help="also run the source's exhaustive grid search and compare")
    parser.add_argument("--starts", type=int, default=None, metavar="N",
                        help="number of starts (default: the moment estimate for ADM and "
                        "tanks models, 8 for compartment networks)")
    parser.add_argument("--errors", choices=("absolute", "relative"), default="absolute",
                        help="measurement errors of equal size (default) or proportional to "
                        "the curve (refit weighted by 1/model^2)")
    parser.add_argument("--length", type=float, default=None, metavar="METRES",
                        help="blender length for the equivalent D_z and v of network fits "
                        "(default 0.31 m)")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.set_defaults(func=run_fit)
    return parser


def _error_line(message: str) -> str:
    """``'<file>, row <r>: <problem>'`` as ``'<file>:<r>: <problem>'`` (compiler style)."""
    return re.sub(r"^(.*?), row (\d+): ", r"\1:\2: ", str(message).splitlines()[0])


def _input_files(inputs: Sequence[str]) -> list[Path]:
    files: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.glob("*.csv") if p.is_file())
            if not found:
                raise InputError(f"{path}: no CSV files in this folder")
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise InputError(f"{path}: file not found")
    stems = [p.stem for p in files]
    repeated = sorted({s for s in stems if stems.count(s) > 1})
    if repeated:
        raise InputError(f"{repeated[0]}: several input files share this name; results would "
                         "overwrite each other")
    return files


def _model(name: str):
    from fitting.models import MODELS, network_model

    if name in MODELS:
        return MODELS[name]
    path = Path(name)
    if path.suffix.lower() == ".json":
        if not path.is_file():
            raise InputError(f"{path}: network file not found")
        try:
            return network_model(path)
        except (ValueError, KeyError, TypeError, OSError, ImportError) as error:
            raise InputError(f"{path}: {_error_line(error)}") from None
    raise InputError(f"--model: unknown model {name!r}; choose one of {', '.join(MODELS)} "
                     "or give a network JSON file")


def _pairs(items: Sequence[str], option: str) -> list[tuple[str, str]]:
    pairs = []
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InputError(f"{option}: expected NAME=VALUE, got {item!r}")
        pairs.append((name.strip(), value.strip()))
    return pairs


def _parameter_settings(model, fixes: Sequence[str], ties: Sequence[str]) -> dict:
    """Parameter settings for --fix and --tie, checked against the model."""
    settings = {}
    for name, text in _pairs(fixes, "--fix"):
        if name not in model.parameter_names:
            raise InputError(f"--fix: model {model.name!r} has no parameter {name!r} "
                             f"(it has {', '.join(model.parameter_names)})")
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"--fix {name}: {text!r} is not a number") from None
        if not math.isfinite(value) or value < 0:
            raise InputError(f"--fix {name}: value must be finite and non-negative, got {text}")
        settings[name] = model.defaults[name].replace(value=value, vary=False, expr=None)
    for name, other in _pairs(ties, "--tie"):
        for label in (name, other):
            if label not in model.parameter_names:
                raise InputError(f"--tie: model {model.name!r} has no parameter {label!r} "
                                 f"(it has {', '.join(model.parameter_names)})")
        if name == other or name in settings:
            raise InputError(f"--tie {name}={other}: a parameter cannot be tied to itself or "
                             "be both fixed and tied")
        settings[name] = model.defaults[name].replace(expr=other)
    free = [n for n in model.parameter_names if n not in settings]
    if not free:
        raise InputError("--fix/--tie: nothing left to fit: every parameter is fixed or tied")
    return settings


def _read_curves(files: Sequence[Path]) -> list:
    from fitting.io import DataError, DataWarning, read_rtd_csv

    curves = []
    for path in files:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            try:
                curves.append(read_rtd_csv(path))
            except DataError as error:
                raise InputError(_error_line(error)) from None
        for warning in caught:
            if issubclass(warning.category, DataWarning):
                print(f"axialmix fit: warning: {_error_line(warning.message)}", file=sys.stderr)
    return curves


def _grid_for(model, result) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, str]]:
    """Grid axes, held values and ties for ``--grid`` (see the module docstring)."""
    from fitting.gridsearch import source_flux_grid

    grids, fixed, tied = {}, {}, {}
    for name in model.parameter_names:
        setting = result.init_params[name]
        value = float(result.values[name])
        if setting.expr is not None:
            tied[name] = setting.expr
        elif not setting.vary or name in GRID_HELD:
            fixed[name] = value
        elif name.startswith("k_"):
            grids[name] = source_flux_grid(SOURCE_GRID_STEP, SOURCE_GRID_MAX)
        else:
            grids[name] = value * np.logspace(math.log10(0.25), math.log10(4.0), 21)
    return grids, fixed, tied


def _progress(index: int, total: int, name: str) -> None:
    if total > 1:
        print(f"axialmix fit: [{index}/{total}] {name}", file=sys.stderr, flush=True)


def run_fit(args: argparse.Namespace) -> int:
    """Run ``axialmix fit`` with parsed arguments; returns the exit status.

    **Arguments:**

    - `args`: the namespace from the ``fit`` parser (see :func:`add_fit_parser`).

    **Returns:** 0 on success, 2 for bad input (nothing written), 130 after Ctrl-C.
    """
    try:
        files = _input_files(args.inputs)
        model = _model(args.model)
        settings = _parameter_settings(model, args.fix, args.tie)
        if args.starts is not None and args.starts < 1:
            raise InputError(f"--starts: must be at least 1, got {args.starts}")
        if args.grid and args.errors == "relative":
            raise InputError("--grid scores the unweighted loss, as the source did; use it "
                             "without --errors relative")
        if args.length is not None and not (math.isfinite(args.length) and args.length > 0):
            raise InputError(f"--length: must be a positive number of metres, got {args.length}")
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise InputError(f"{out}: --out exists and is not a folder")
        curves = _read_curves(files)
    except InputError as error:
        print(f"axialmix fit: error: {error}", file=sys.stderr)
        return USAGE_ERROR
    starts = args.starts or (None if model.name in ("adm", "adm-fv", "adm-open", "tanks")
                             else 8)
    return _fit_all(model, curves, files, settings, args, starts, out)


def _fit_all(model, curves, files, settings, args, starts: int, out: Path) -> int:
    from fitting.gridsearch import grid_search
    from fitting.optimize import fit
    from fitting.report import (
        BLENDER_LENGTH_M,
        fit_record,
        fit_table,
        plot_fit,
        summary_rows,
        summary_table,
        write_csv,
        write_json,
    )

    length = args.length or BLENDER_LENGTH_M
    records: list[dict[str, Any]] = []
    interrupted = False
    try:
        for index, (curve, path) in enumerate(zip(curves, files, strict=True), start=1):
            _progress(index, len(curves), curve.name)
            try:
                result = _fit_one(fit, model, curve, settings, args.loss, starts,
                                  args.errors == "relative")
            except ValueError as error:
                print(f"axialmix fit: error: {path}: {_error_line(error)}", file=sys.stderr)
                return USAGE_ERROR
            grid = None
            if args.grid:
                grids, held, tied = _grid_for(model, result)
                grid = grid_search(model, curve, grids, loss=args.loss, fixed=held, tied=tied,
                                   progress=True)
            record = fit_record(result, grid, source=str(path), length_m=length)
            records.append(record)
            out.mkdir(parents=True, exist_ok=True)
            write_json(out / f"{curve.name}.json", record)
            plot_fit(out / f"{curve.name}.png", result, grid)
            if len(curves) == 1:
                _print_single(result, grid, record, fit_table)
            if grid is not None and grid.interrupted:
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True
    if len(curves) > 1 and records:
        print(summary_table(records))
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "summary.json", {"model": model.name, "loss_name": args.loss,
                                           "complete": not interrupted, "fits": records})
        header, rows = summary_rows(records)
        write_csv(out / "summary.csv", header, rows)
    if interrupted:
        print(f"axialmix fit: interrupted after {len(records)} of {len(curves)} curves; "
              f"finished results are in {out}", file=sys.stderr)
        return INTERRUPTED
    print(f"results written to {out}")
    return 0


def _fit_one(fit, model, curve, settings: dict, loss: str, starts: int | None,
             relative: bool = False):
    """Fit one curve; the mean absolute error is polished from the least-squares optimum.

    The MAE is not smooth, so multi-start L-BFGS on it stalls at kinks; the least-squares
    multi-start finds the basin and a single MAE fit from there finishes. The evaluations
    and times of both stages are reported together. With `relative` the least-squares fit
    is the relative-error fit and the MAE polish is weighted by ``1 / |model|``.
    """
    first = fit(model, curve, settings, loss="sse", n_starts=starts, relative_errors=relative)
    if loss == "sse":
        return first
    weights = np.sqrt(first.weights) if relative else None
    second = fit(model, curve, first.restart_parameters(), loss=loss, n_starts=1,
                 weights=weights)
    return dataclasses.replace(
        second,
        n_evaluations=first.n_evaluations + second.n_evaluations,
        wall_time=first.wall_time + second.wall_time,
        n_starts=first.n_starts,
    )


def _print_single(result, grid, record, fit_table) -> None:
    print(fit_table(result, grid))
    for sentence in record["identifiability"]:
        print(f"  * {sentence}")
    equivalent = record.get("equivalent_adm")
    if equivalent is not None:
        print("  equivalent closed-closed ADM (same mean and variance, L = "
              f"{equivalent['length_m']:g} m): tau = {_show(equivalent['tau_s'])} s, "
              f"Pe = {_show(equivalent['peclet'])}, v = {_show(equivalent['velocity_m_per_s'])}"
              f" m/s, D_z = {_show(equivalent['dispersion_m2_per_s'])} m^2/s")


def _show(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"
