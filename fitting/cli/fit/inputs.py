"""The input of ``axialmix fit`` read and checked before anything is written.

Curve files (and their warnings, one line each), the measured inlet of ``--inlet FILE``, a
study's curves (one long table with ``--curve-column``, or curve files with ``--design``), and
the check that each model is finite at its start values on every curve.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

from fitting.cli.fit.options import InputError, column_key


def read_inlet(text: str, curves: Sequence, args: argparse.Namespace):
    """The inlet signal of ``--inlet``: pulse, step, or a file read like the curves."""
    from fitting.data import DataError, read_inlet_csv
    from fitting.measurement import Inlet

    if text == "pulse":
        return Inlet.pulse()
    if text == "step":
        return Inlet.step()
    units = sorted({curve.time_unit for curve in curves})
    if len(units) > 1:
        raise InputError(f"--inlet: the curves are in different time units ({', '.join(units)});"
                         " fit them separately with one inlet each")
    try:
        signal = read_inlet_csv(text, time_unit=units[0], decimal=args.decimal,
                                time_column=column_key(args.time_column),
                                value_column=column_key(args.value_column))
        return Inlet.from_curve(signal)
    except DataError as error:
        raise InputError(f"--inlet: {error.compact()}") from None
    except ValueError as error:
        raise InputError(f"--inlet: {text}: {error}") from None


def read_curves(files: Sequence[Path], args: argparse.Namespace | None = None) -> list:
    from fitting.data import DataError, DataWarning, read_rtd_csv

    options = {}
    if args is not None:
        options = {"decimal": args.decimal, "time_column": column_key(args.time_column),
                   "value_column": column_key(args.value_column)}
    curves = []
    for path in files:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            try:
                # Raw values: the measurement model's amplitude takes the tracer amount.
                curves.append(read_rtd_csv(path, normalise=False, **options))
            except DataError as error:
                raise InputError(error.compact()) from None
        for warning in caught:
            if issubclass(warning.category, DataWarning):
                text = str(warning.message)
                print(f"axialmix fit: warning: {_compact(text)}", file=sys.stderr)
    return curves


def _compact(message: str) -> str:
    """``'<file>, row <r>: <problem>'`` as ``'<file>:<r>: <problem>'`` (compiler style)."""
    head, sep, rest = message.partition(": ")
    where, comma, row = head.rpartition(", row ")
    return f"{where}:{row}: {rest}" if comma and sep and row.isdigit() else message


def check_fixed_curves(model, settings, curves, files) -> None:
    """Evaluate the model once at its start values on each curve: a non-finite model curve
    (e.g. a fixed value outside the model's range) is refused before anything is written.

    The model is evaluated at the times the plot draws it (:func:`fitting.report.plot_times`,
    one shape for all curves), so the plot reuses the compiled evaluation."""
    import numpy as np

    from fitting.report import plot_times

    for curve, path in zip(curves, files, strict=True):
        params = model.parameters(curve)
        params.update(settings)
        values = {n: params[n].value for n in model.parameter_names}
        for name, setting in settings.items():
            if setting.expr is not None:
                values[name] = values[setting.expr]
        predicted = model.evaluate(plot_times(curve.time), values)
        if not np.all(np.isfinite(predicted)):
            raise InputError(f"{path}: the model is not finite at the start values "
                             f"({', '.join(f'{k}={v:.4g}' for k, v in values.items())}); check "
                             "--fix values")


def read_study(args: argparse.Namespace, files: Sequence[Path]):
    """The study of ``--curve-column`` (one long table) or of curve files (and ``--design``)."""
    from fitting.data import DataError
    from fitting.study.input import read_long_csv, study_from_files

    for option in ("inlet_column", "factors"):
        if getattr(args, option) is not None and args.curve_column is None:
            raise InputError(f"--{option.replace('_', '-')} belongs to a long table: give "
                             "--curve-column too")
    try:
        if args.curve_column is not None:
            if args.design is not None:
                raise InputError("--design maps curve files to factors; a long table "
                                 "(--curve-column) carries its factors in its columns")
            if len(files) != 1 or Path(args.inputs[0]).is_dir():
                raise InputError(f"--curve-column: give one long table, not {len(files)} "
                                 "files or a folder")
            factors = None if args.factors is None else [
                name.strip() for name in args.factors.split(",") if name.strip()]
            return read_long_csv(files[0], column_key(args.curve_column),
                                 time_column=column_key(args.time_column),
                                 value_column=column_key(args.value_column),
                                 inlet_column=column_key(args.inlet_column), factors=factors,
                                 decimal=args.decimal)
        return study_from_files(read_curves(files, args), args.design, decimal=args.decimal)
    except DataError as error:
        raise InputError(error.compact()) from None
