"""The ``axialmix fit`` sub-command: fit residence-time curves from CSV files.

    axialmix fit FILE_OR_FOLDER... --model adm|adm-fv|adm-open|tanks|four-compartment|
                                           adm-exchange|tanks-exchange|adm-tank|NET.json
                 (a network file may be .toml; several models, comma-separated, to compare)
                 [--fix NAME=VALUE] [--tie NAME=OTHER] [--free dead_time,baseline]
                 [--inlet pulse|step|FILE] [--loss sse|mae] [--grid] [--starts N]
                 [--errors absolute|relative|combined|poisson] [--length METRES]
                 [--decimal auto|.|,] [--time-column C] [--value-column C] --out DIR
                 [--curve-column C [--inlet-column C] [--factors A,B] | --design FILE]
                 [--chunk N] [--workers N | --scheduler ADDRESS]

Every input is read and validated, and every option checked, before anything is written:
bad input prints one line ``axialmix fit: error: <file>:<row>: <problem>`` to stderr and
exits with status 2, leaving no output. This covers everything that can be known before
fitting: every file (read in full), every option, fixed values a model is undefined at
(``--fix tau=0``), curves too small or large for float64, and whether ``--out`` can be
created and written. Then each curve is fitted; its JSON record and PNG
plot are written to ``DIR/<name>.json`` and ``DIR/<name>.png`` as soon as it is done
(atomically), so Ctrl-C keeps finished curves. Every run also gives ``DIR/summary.json``
and ``DIR/summary.csv``.

One run at a time writes into a folder: a run holds the lock file ``DIR/.axialmix-fit.lock``
(its process id) while it writes, and a second run on the same ``--out`` is refused with
exit status 2 (a lock left by a process that no longer runs is taken over). So two runs
cannot interleave their files.

Ctrl-C: fitting runs in a worker thread; the main thread catches SIGINT at once, lets the
worker finish the file it may be writing, writes the summary of the curves already finished,
removes the lock and ends the process with status 130 via ``os._exit`` — compiled JAX work
still running is abandoned rather than waited for (its teardown could crash the process).

Each curve is fitted as measured, in the file's own units: the model is wrapped in the
measurement model ``c(t) = A (E * u)(t - t_d) + b`` (:mod:`fitting.measurement`). The amplitude
A is always fitted, so the data are never divided by their own area; the dead time t_d and
the baseline b are 0 unless freed (``--free dead_time,baseline``, short ``t_d,b``) or fixed at
a value (``--fix baseline=0.02``). The inlet u is an ideal pulse (``--inlet pulse``, the
default), an ideal step for F-curves (``--inlet step``), or a measured inlet signal
(``--inlet FILE``, a time/value CSV read like the curves), convolved exactly with the model.
Values down to 5 % of the peak below zero are noise around a subtracted baseline and are
fitted; a value further below zero is refused with its file, row and value. Decimal commas
are detected (or ``--decimal ,``); ``--time-column`` and ``--value-column`` pick columns by
name or 0-based index.

``--errors`` sets the error model: ``combined`` (the default; additive plus proportional
errors, ``Var = a² + (b model)²``, both estimated from the residuals by iterated weights, see
:mod:`fitting.losses`), ``relative`` (errors proportional to the curve: refitted weighted by
``1 / model²`` until the weights are those of its own curve, ``1 / |model|`` for the mean
absolute error) or ``absolute`` (errors of one size, unweighted least squares). Unweighted
least squares treats the peak, where proportional noise is largest, as precise as the tail,
and its intervals are then too narrow; pure relative weights let a sample where the model is
near zero (t = 0) take almost all the weight. The grid search (``--grid``) scores the
unweighted loss, as the source did, so it runs with absolute errors. ``poisson`` is for
particle counts (a histogram of tracer particles leaving, as ``axialmix simulate`` writes
with its ``count`` and ``bin [s]`` columns; chosen by itself for such files): Poisson noise of
known size, fitted by maximum likelihood, intervals from the known scale and lack of fit
tested on bins merged to 10 expected particles each (:mod:`fitting.losses`).

With ``--length L`` (m; there is no default) every ADM-family fit also reports the velocity
``v`` and axial dispersion ``D_z`` in SI, networks their equivalent ``tau``, ``Pe`` and
``D_z``, each with its standard error and 95 % interval (delta method,
:mod:`fitting.physical`). Every number carries its unit, the file's time unit included.

With ``--loss mae`` the least-squares multi-start fit is polished by a fit on the mean
absolute error (which is not smooth enough for multi-start L-BFGS alone); the evaluations
of both stages are reported.

With several models (``--model adm,adm-exchange,tanks``) each curve is fitted with each of
them and one table compares them: parameters, SSE, AICc, BIC and the lack-of-fit verdict,
with a recommendation that says when the data cannot tell the models apart
(:func:`fitting.diagnostics.compare_models`). Each fit is written to
``DIR/<name>.<model>.json`` and ``.png``, the comparison to ``DIR/<name>.comparison.json``;
several curves also give ``DIR/summary.json`` and ``DIR/summary.csv`` with one row per curve
and model. ``--fix`` and ``--tie`` apply to the models that have the parameters they name.

Studies of many curves (:mod:`fitting.study.input`, :mod:`fitting.study.batch`): with
``--curve-column C`` the input is one long table (curve id, time, concentration, an optional
``--inlet-column``, and factor columns constant within a curve); with ``--design FILE`` the
curve files get their factors from a design table. Either way (and with ``--chunk``,
``--workers`` or ``--scheduler`` on plain curve files) each curve is fitted as a single file
would be, in chunks of ``--chunk`` curves (default 64), and ``DIR/summary.csv`` and
``DIR/summary.json`` get one row per curve: its factors, each parameter with standard error and
95 % interval (units in the column names), v and D_z with ``--length``, the error model,
convergence and the lack-of-fit verdict, and ``DIR/curves/<curve>.json`` holds each curve's
full record (what ``funnel --model`` and ``divert --model`` read), with ``--plots`` beside
its PNG ``DIR/curves/<curve>.png`` (drawn as a single file's is). Finished
chunks are appended to ``DIR/summary.jsonl``; the same command run again after Ctrl-C or a
kill fits only the curves not yet in it. ``--workers N`` fits on a local Dask cluster of N
processes, ``--scheduler ADDRESS`` on a running one, with the same results. A study fits one
model by least squares (no ``--grid``, no ``--loss mae``).

With ``--grid`` the source's exhaustive grid search runs on the same loss: rates (parameters
named ``k_*``, except the dead-zone exchange rate ``k_d``) over ``[0 : 0.125 : 2.5]``
(MODELS.md section 3), any other free parameter over
21 log-spaced values from a quarter to four times its fitted value; a free rate not on that
grid (``k_out``) is held at its fitted value, so the grid is the source's three-dimensional one.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.util
import math
import os
import signal
import sys
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from axialmix._exits import BAD_INPUT, INTERRUPTED, OK, REFUSED, error_line
from fitting.cli._outputs import OutputError, refuse_other_results

__all__ = ["add_parser", "run"]

#: Rates searched on the source's grid by ``--grid``.
SOURCE_GRID_STEP, SOURCE_GRID_MAX = 0.125, 2.5
#: Free parameters held at their fitted value in the grid search (the source did not search
#: the outflow rate, and had no measurement model).
GRID_HELD = ("k_out", "amplitude", "dead_time", "baseline")
#: Rates that are not compartment fluxes: searched like other parameters, around the fit (the
#: dead-zone exchange rate of the exchange models).
NOT_SOURCE_RATES = ("k_d",)
#: Starts per compiled batch when ``--starts`` is large: progress is shown between batches.
STARTS_PER_BATCH = 256
#: The lock file that marks an output folder as being written.
LOCK_NAME = ".axialmix-fit.lock"
#: Seconds the main thread waits, after Ctrl-C, for a file being written to be finished.
WRITE_GRACE = 1.0


class InputError(Exception):
    """Bad command-line input; the message is one line, without the program prefix."""

#: Blender lengths (m) accepted without a word; outside, --length gets a warning (a length
#: in centimetres or millimetres by mistake gives a D_z off by 1e4 or 1e6).
LENGTH_RANGE_M = (0.02, 10.0)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register the ``fit`` sub-command on an argparse sub-parser collection.

    **Arguments:**

    - `subparsers`: the object returned by ``ArgumentParser.add_subparsers()``.

    **Returns:** the ``fit`` parser (its ``func`` default is :func:`run`).
    """
    parser = subparsers.add_parser(
        "fit",
        help="fit a residence-time model to RTD curves (CSV files or folders)",
        description="Fit a residence-time model to measured RTD curves; report values, "
        "standard errors, 95 % intervals and what the data determine.",
    )
    parser.add_argument("inputs", nargs="+", metavar="FILE_OR_FOLDER",
                        help="CSV files (time, concentration) or folders of them (*.csv, "
                        "any case)")
    parser.add_argument("--model", default="adm",
                        help="adm, adm-fv, adm-open, tanks, four-compartment, adm-exchange "
                        "(ADM with a dead zone), tanks-exchange, adm-tank (ADM then a stirred "
                        "tank), or a network file (.json or .toml) (default: adm); several, "
                        "comma-separated (adm,adm-exchange,tanks), are fitted and compared in "
                        "one table")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value (repeatable)")
    parser.add_argument("--tie", action="append", default=[], metavar="NAME=OTHER",
                        help="make a parameter equal to another, e.g. k_r=k_f (repeatable)")
    parser.add_argument("--loss", choices=("sse", "mae"), default="sse",
                        help="least squares (default) or the source's mean absolute error")
    parser.add_argument("--grid", action="store_true",
                        help="also run the source's exhaustive grid search and compare")
    parser.add_argument("--wide", action="store_true",
                        help="print every column of the summary and model-comparison tables "
                        "(default: the headline "
                        "numbers in 100 columns; every column is in summary.csv)")
    parser.add_argument("--starts", type=int, default=None, metavar="N",
                        help="number of starts (default: the moment estimate for ADM and "
                        "tanks models, 8 for compartment networks)")
    parser.add_argument("--errors", choices=("absolute", "relative", "combined", "poisson"),
                        default=None,
                        help="error model: combined (default: additive plus proportional, "
                        "both estimated), relative (proportional to the curve), absolute "
                        "(equal size; the default with --grid) or poisson (particle counts; "
                        "the default for files with a 'count' column)")
    parser.add_argument("--length", type=float, default=None, metavar="METRES",
                        help="blender length L (m) for v and D_z in SI with their "
                        "uncertainty (no default: without it only tau and Pe are reported)")
    parser.add_argument("--inlet", default="pulse", metavar="pulse|step|FILE",
                        help="inlet signal: an ideal pulse (default), an ideal step (F-curves) "
                        "or a measured inlet signal (a time/value CSV), convolved exactly")
    parser.add_argument("--free", action="append", default=[], metavar="NAMES",
                        help="also fit measurement parameters fixed at 0 by default: "
                        "dead_time (t_d), baseline (b); comma-separated or repeated")
    parser.add_argument("--profile", nargs="?", const="all", default=None, metavar="NAMES",
                        help="95 %% intervals from the profile likelihood: each named free "
                        "parameter (comma-separated; all free ones without NAMES) held on a "
                        "grid over a factor 1000 either way, the others refitted; for "
                        "parameters one curve leaves poorly determined (minutes, not seconds)")
    parser.add_argument("--decimal", choices=("auto", ".", ","), default="auto",
                        help="decimal separator of the files (default: detected)")
    parser.add_argument("--time-column", default=None, metavar="NAME|INDEX",
                        help="the time column by name or 0-based index (default: recognised). "
                        "Its unit is read from its header name: 't [min]', 'time (s)', "
                        "'time_min' (s, ms, min, h); seconds when the header names none")
    parser.add_argument("--value-column", default=None, metavar="NAME|INDEX",
                        help="the concentration column by name or 0-based index (default: "
                        "recognised, or the second of two columns)")
    study = parser.add_argument_group(
        "studies of many curves", "one summary row per curve with its factors, fitted in "
        "chunks, resumable; used with any of these options")
    study.add_argument("--curve-column", default=None, metavar="NAME|INDEX",
                       help="the input is one long table: this column holds the curve id, "
                       "the other columns (besides time, value and --inlet-column) are factors "
                       "constant within a curve")
    study.add_argument("--inlet-column", default=None, metavar="NAME|INDEX",
                       help="with --curve-column: a column with each curve's inlet signal at "
                       "its sample times")
    study.add_argument("--factors", default=None, metavar="A,B",
                       help="with --curve-column: only these factor columns (default: all "
                       "other columns)")
    study.add_argument("--design", default=None, metavar="FILE",
                       help="a design table mapping curve file names (first column, or a "
                       "column named file, curve, run or name) to factor columns")
    study.add_argument("--chunk", type=int, default=None, metavar="N",
                       help="curves fitted and written together, one Dask task "
                       "(default: 64)")
    study.add_argument("--workers", type=int, default=None, metavar="N",
                       help="fit on a local Dask cluster of N processes")
    study.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="fit on the Dask scheduler at ADDRESS (tcp://host:8786)")
    study.add_argument("--plots", action="store_true",
                       help="also draw each curve's fit as DIR/curves/<curve>.png (single "
                       "files and folders always get their PNGs)")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.set_defaults(func=run)
    return parser


#: Deprecated name of :func:`add_parser` (kept one release).
add_fit_parser = add_parser


def _model(name: str):
    from fitting.models import MODELS, network_model

    if name in MODELS:
        return MODELS[name]
    path = Path(name)
    if path.suffix.lower() in (".json", ".toml"):
        if not path.is_file():
            raise InputError(f"{path}: network file not found")
        try:
            return network_model(path)
        except (ValueError, KeyError, TypeError, OSError, AttributeError) as error:
            raise InputError(f"{path}: {' '.join(str(error).split())}") from None
    raise InputError(f"--model: unknown model {name!r}; choose one of {', '.join(MODELS)} "
                     "or give a network file (.json or .toml)")


def _models(text: str) -> list:
    """The models of ``--model``: one name, or several separated by commas (to compare)."""
    names = [name.strip() for name in text.split(",")]
    if len(names) > 1 and not all(names):
        raise InputError(f"--model: empty name in {text!r}; separate model names by commas")
    models = [_model(name) for name in names]
    seen = set()
    for model in models:
        if model.name in seen:
            raise InputError(f"--model: {model.name!r} is given twice")
        seen.add(model.name)
    return models


def _settings_for_each(models, fixes: Sequence[str], ties: Sequence[str]) -> list[dict]:
    """--fix and --tie settings of each compared model: an option applies to the models that
    have every parameter it names, and must apply to at least one."""
    if len(models) == 1:
        return [_parameter_settings(models[0], fixes, ties)]
    for option, items in (("--fix", fixes), ("--tie", ties)):
        for name, value in _pairs(items, option):
            labels = {name} if option == "--fix" else {name, value}
            if not any(labels <= set(m.parameter_names) for m in models):
                raise InputError(f"{option}: no compared model has {' and '.join(sorted(labels))}"
                                 f" ({', '.join(m.name for m in models)})")

    from fitting.parameters import canonical_name

    def applies(model, item: str, option: str) -> bool:
        name, _, value = item.partition("=")
        name, value = canonical_name(name.strip()), canonical_name(value.strip())
        labels = {name} if option == "--fix" else {name, value}
        return labels <= set(model.parameter_names)

    return [_parameter_settings(m, [f for f in fixes if applies(m, f, "--fix")],
                                [t for t in ties if applies(m, t, "--tie")]) for m in models]


def _pairs(items: Sequence[str], option: str) -> list[tuple[str, str]]:
    from fitting.parameters import canonical_name

    pairs = []
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InputError(f"{option}: expected NAME=VALUE, got {item!r}")
        value = canonical_name(value.strip()) if option == "--tie" else value.strip()
        pairs.append((canonical_name(name.strip()), value))
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
        default = model.defaults[name]
        signed = default.min is None  # a baseline or dead time may be negative
        if not math.isfinite(value) or (value < 0 and not signed) or abs(value) > 1e100:
            raise InputError(f"--fix {name}: value must be a finite non-negative number of "
                             f"sensible size, got {text}")
        if value == 0 and default.min is not None and default.min >= 0:
            raise InputError(f"--fix {name}: must be positive, got {text} (the model is "
                             f"undefined or has no outflow at {name} = 0)")
        settings[name] = default.replace(value=value, vary=False, expr=None)
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


def _column(text: str | None) -> str | int | None:
    """A ``--time-column``/``--value-column`` value: a 0-based index when all digits."""
    if text is None:
        return None
    return int(text) if text.strip().isdigit() else text.strip()


def _free_names(items: Sequence[str]) -> tuple[str, ...]:
    """The measurement parameters of ``--free`` (comma-separated or repeated; t_d, b allowed)."""
    from fitting.measurement import FREEABLE
    from fitting.parameters import canonical_name

    names = []
    for item in items:
        for name in item.split(","):
            name = canonical_name(name.strip())
            if name not in FREEABLE:
                raise InputError(f"--free: unknown measurement parameter {name!r}; choose "
                                 f"from {', '.join(FREEABLE)} (or t_d, b)")
            names.append(name)
    return tuple(dict.fromkeys(names))


def _inlet(text: str, curves: Sequence, args: argparse.Namespace):
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
                                time_column=_column(args.time_column),
                                value_column=_column(args.value_column))
        return Inlet.from_curve(signal)
    except DataError as error:
        raise InputError(f"--inlet: {error.compact()}") from None
    except ValueError as error:
        raise InputError(f"--inlet: {text}: {error}") from None


def _read_curves(files: Sequence[Path], args: argparse.Namespace | None = None) -> list:
    from fitting.data import DataError, DataWarning, read_rtd_csv

    options = {}
    if args is not None:
        options = {"decimal": args.decimal, "time_column": _column(args.time_column),
                   "value_column": _column(args.value_column)}
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


def _default_errors(args: argparse.Namespace, curves: Sequence | None) -> str:
    """The error model: ``--errors`` when given; else counting errors for files of particle
    counts (said in one line), absolute errors with ``--grid``, combined ones otherwise."""
    counting = [] if curves is None else [c.exposure is not None for c in curves]
    if args.errors is not None:
        if args.errors != "poisson" and any(counting):
            names = ", ".join(c.source or c.name for c, k in zip(curves, counting, strict=True)
                              if k)
            print(f"axialmix fit: warning: {names} hold(s) particle counts, fitted with "
                  f"--errors {args.errors} as asked; their noise is Poisson (--errors poisson)",
                  file=sys.stderr)
        return args.errors
    if counting and all(counting):
        if args.grid:
            raise InputError("--grid scores the unweighted loss; these files hold particle "
                             "counts, whose noise is Poisson: fit them without --grid")
        files = ", ".join(c.source or c.name for c in curves)
        print(f"counting errors: {files} hold{'s' if len(curves) == 1 else ''} particle counts "
              "(Poisson noise of known size), fitted by maximum likelihood (--errors poisson)")
        return "poisson"
    if any(counting):
        listed = ", ".join(c.source or c.name for c, k in zip(curves, counting, strict=True) if k)
        raise InputError(f"{listed} hold particle counts and the other files signals: fit them "
                         "apart, or choose one error model with --errors")
    return "absolute" if args.grid else "combined"


def _compact(message: str) -> str:
    """``'<file>, row <r>: <problem>'`` as ``'<file>:<r>: <problem>'`` (compiler style)."""
    head, sep, rest = message.partition(": ")
    where, comma, row = head.rpartition(", row ")
    return f"{where}:{row}: {rest}" if comma and sep and row.isdigit() else message


def _check_out(out: Path) -> None:
    """Refuse an --out that cannot be created or written, creating nothing."""
    if out.exists():
        if not out.is_dir():
            raise InputError(f"{out}: --out exists and is not a folder")
        if not os.access(out, os.W_OK | os.X_OK):
            raise InputError(f"{out}: --out is not writable")
        try:
            refuse_other_results(out, "fit")
        except OutputError as error:
            raise InputError(str(error)) from None
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{out}: --out cannot be created ({parent} is not a folder)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{out}: --out cannot be created ({parent} is not writable)")


def _check_fixed_curves(model, settings, curves, files) -> None:
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


class _Lock:
    """The lock file of an output folder (see the module docstring)."""

    def __init__(self, folder: Path):
        self.path = folder / LOCK_NAME
        self.held = False

    def acquire(self) -> None:
        for _ in range(2):
            try:
                handle = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self._owner()
                if owner is not None and _alive(owner):
                    raise InputError(f"{self.path.parent}: --out is being written by another "
                                     f"axialmix fit (process {owner}); wait or choose another "
                                     "folder") from None
                self.path.unlink(missing_ok=True)  # left by a process that no longer runs
                continue
            with os.fdopen(handle, "w") as stream:
                stream.write(f"{os.getpid()}\n")
            self.held = True
            return
        raise InputError(f"{self.path.parent}: --out lock file cannot be taken")

    def _owner(self) -> int | None:
        try:
            return int(self.path.read_text().strip())
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_temporary_files(folder: Path) -> None:
    """Remove the temporary files of :func:`axialmix._files.write_atomic` from `folder`
    (``.<name>.<random>.tmp``): after Ctrl-C they would never be completed."""
    for path in folder.glob(".*.tmp"):
        with contextlib.suppress(OSError):
            path.unlink()


def _exit_now(message: str) -> None:
    """Print `message` on standard error and end the process with status 130 at once.

    ``os._exit`` skips interpreter teardown, which could wait for or crash on compiled JAX
    work still running in the worker thread. Output is flushed first; a closed stream does
    not stop the exit.
    """
    with contextlib.suppress(OSError, ValueError):
        print(message, file=sys.stderr, flush=True)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(INTERRUPTED)


def _grid_for(model, result):
    """Grid axes, held values and ties for ``--grid`` (see the module docstring)."""
    import numpy as np

    from fitting.gridsearch import source_flux_grid

    grids, fixed, tied = {}, {}, {}
    for name in model.parameter_names:
        setting = result.init_params[name]
        value = float(result.values[name])
        if setting.expr is not None:
            tied[name] = setting.expr
        elif not setting.vary or name in GRID_HELD:
            fixed[name] = value
        elif name.startswith("k_") and name not in NOT_SOURCE_RATES:
            grids[name] = source_flux_grid(SOURCE_GRID_STEP, SOURCE_GRID_MAX)
        else:
            grids[name] = value * np.logspace(math.log10(0.25), math.log10(4.0), 21)
    return grids, fixed, tied


def _is_study(args: argparse.Namespace) -> bool:
    """Whether the options ask for a study (one summary of many curves, with factors)."""
    return any(getattr(args, name) is not None for name in
               ("curve_column", "design", "chunk", "workers", "scheduler"))


def _read_study(args: argparse.Namespace, files: Sequence[Path]):
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
            return read_long_csv(files[0], _column(args.curve_column),
                                 time_column=_column(args.time_column),
                                 value_column=_column(args.value_column),
                                 inlet_column=_column(args.inlet_column), factors=factors,
                                 decimal=args.decimal)
        return study_from_files(_read_curves(files, args), args.design, decimal=args.decimal)
    except DataError as error:
        raise InputError(error.compact()) from None


#: Memory a study worker process needs (JAX, the compiled solvers, a chunk of curves).
_WORKER_BYTES = 768 * 2**20


def _check_workers(workers: int) -> None:
    """--workers: at least 1, at most the cores of the machine and what its memory holds."""
    cores = os.cpu_count() or 1
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        memory = cores * _WORKER_BYTES
    limit = max(1, min(cores, memory // _WORKER_BYTES))
    if not 1 <= workers <= limit:
        raise InputError(f"--workers {workers}: this machine runs 1 to {limit} worker "
                         f"processes ({cores} cores, {memory / 2**30:.3g} GiB at "
                         f"{_WORKER_BYTES / 2**20:.0f} MiB a worker)")


def _check_scheduler(address: str) -> None:
    """--scheduler: a tcp:// or tls:// address with a host and a port that answers."""
    import socket
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(address.strip())
        port = parts.port
    except ValueError as error:
        raise InputError(f"--scheduler {address!r}: not an address ({error})") from None
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None:
        raise InputError(f"--scheduler {address!r}: expected tcp://HOST:PORT (or tls://)")
    if not 1 <= port <= 65535:
        raise InputError(f"--scheduler {address!r}: port {port} is not 1 to 65535")
    try:
        with socket.create_connection((parts.hostname, port), timeout=5.0):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise InputError(f"--scheduler {address}: no scheduler answers there ({reason})"
                         ) from None


def _run_study(args: argparse.Namespace, files: Sequence[Path], models, every_settings,
               free: tuple[str, ...], out: Path) -> int:
    """Check the study options and input, then fit the study (see the module docstring)."""
    from fitting.study.batch import DEFAULT_CHUNK, StudyPlan, StudyRun, plan_model

    if len(models) > 1:
        raise InputError("--model: a study fits one model; compare models on single files")
    if args.grid:
        raise InputError("--grid runs on single files, not on a study")
    if args.loss != "sse":
        raise InputError("--loss mae runs on single files; a study fits least squares")
    chunk = DEFAULT_CHUNK if args.chunk is None else args.chunk
    if chunk < 1:
        raise InputError(f"--chunk: must be at least 1 curve, got {chunk}")
    if args.workers is not None and args.scheduler is not None:
        raise InputError("--workers starts a local cluster, --scheduler uses a running one: "
                         "give one of them")
    if args.workers is not None:
        _check_workers(args.workers)
    if args.scheduler is not None:
        _check_scheduler(args.scheduler)
    if (args.workers is not None or args.scheduler is not None) and (
            importlib.util.find_spec("distributed") is None):
        raise InputError("--workers and --scheduler need Dask: pip install 'axialmix[dask]'")
    study = _read_study(args, files)
    args.errors = _default_errors(args, study.curves)
    per_curve = any(inlet is not None for inlet in study.inlets)
    if per_curve and args.inlet != "pulse":
        raise InputError("--inlet-column gives each curve its inlet; leave out --inlet")
    inlet, samples = args.inlet, None
    if args.inlet not in ("pulse", "step"):
        given = _inlet(args.inlet, study.curves, args)
        inlet, samples = "sampled", (tuple(given.times.tolist()), tuple(given.values.tolist()))
    name = args.model.strip()
    plan = StudyPlan(model=name if name in _registered() else str(Path(name)), free=free,
                     inlet=inlet, inlet_samples=samples,
                     parameters=tuple(every_settings[0].items()), errors=args.errors,
                     starts=args.starts, length_m=args.length)
    if every_settings[0]:
        _check_fixed_curves(plan_model(plan), every_settings[0], study.curves,
                            [study.source] * len(study))
    # The folder is locked before its journal is read: another run may be appending to it.
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"{out}: --out cannot be created ({error.strerror})") from None
    lock = _Lock(out)
    lock.acquire()
    try:
        run = StudyRun(plan, study, out, chunk, plots=args.plots)
    except ValueError as error:
        lock.release()
        raise InputError(str(error)) from None
    return _StudyExecution(run, args, out, lock).execute()


def _registered() -> tuple[str, ...]:
    from fitting.models import MODELS

    return tuple(MODELS)


class _Supervised:
    """Work on a worker thread while the main thread waits for it: Ctrl-C (:meth:`_interrupt`,
    installed by the subclass) sets `stop`, and the main thread then calls ``_leave``, which
    saves what is finished and ends the process. Subclasses set `stop`, `failure`, `status`
    and define ``_work`` and ``_leave``."""

    stop: threading.Event
    failure: BaseException | None
    status: int

    def _interrupt(self, signum, frame) -> None:
        self.stop.set()

    def _supervise(self, name: str) -> None:
        """Run ``_work`` on a thread named `name` and wait for it, leaving on Ctrl-C."""
        worker = threading.Thread(target=self._work, name=name, daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
            if self.stop.is_set():
                self._leave()

    def _outcome(self) -> int:
        """The exit status of the finished work (its exception raised again, if any)."""
        if self.failure is not None:
            raise self.failure
        return self.status


class _StudyExecution(_Supervised):
    """A study run in a worker thread, Ctrl-C in the main thread (as :class:`_Run`); the
    output folder's `lock` is held already and released at the end."""

    def __init__(self, run, args: argparse.Namespace, out: Path, lock: _Lock):
        self.run, self.args, self.out, self.lock = run, args, out, lock
        self.stop = threading.Event()
        self.failure: BaseException | None = None
        self.status = OK

    def execute(self) -> int:
        in_main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, self._interrupt) if in_main else None
        try:
            self._supervise("axialmix-study")
        finally:
            self.lock.release()
            if in_main:
                signal.signal(signal.SIGINT, previous)
        return self._outcome()

    def _leave(self) -> None:
        """After Ctrl-C: the summary of the finished curves (the journal holds them already),
        then exit 130 at once; a later run on the same --out continues."""
        run = self.run
        try:
            if run.done:
                run.write_summary()
        finally:
            self.lock.release()
            _exit_now(f"axialmix fit: interrupted after {len(run.done)} of {len(run.study)} "
                      f"curves; run the same command again to continue ({self.out})")

    def _work(self) -> None:
        run = self.run
        try:
            if run.resumed:
                print(f"axialmix fit: continuing {self.out}: {run.resumed} of {len(run.study)} "
                      "curves were fitted before", file=sys.stderr, flush=True)
            run.run(workers=self.args.workers, scheduler=self.args.scheduler,
                    stop=self.stop.is_set)
        except ValueError as error:
            self.status = error_line("fit", f"{run.study.source}: {error}")
            return
        except OSError as error:  # a scheduler that cannot be reached, a full disk
            self.status = error_line("fit", f"{self.out}: {' '.join(str(error).split())}")
            return
        except BaseException as error:  # shown by the main thread
            self.failure = error
            return
        rows = list(run.records())
        converged = sum(bool(r["converged"]) for r in rows)
        misfit = sum(bool((r.get("lack_of_fit") or {}).get("systematic")) for r in rows)
        for name, reason in run.refused.items():
            named = "" if repr(name) in reason else f"curve {name!r}: "
            print(f"axialmix fit: refused {named}{reason}", file=sys.stderr)
        refused = (f"; {len(run.refused)} refused, listed in {self.out / 'refused.csv'} "
                   f"(exit status {REFUSED})" if run.refused else "")
        print(f"{len(rows)} curves: {converged} converged, {misfit} with systematic misfit; "
              f"summary in {self.out / 'summary.csv'} and {self.out / 'summary.json'}"
              f"{refused}")
        if run.refused:
            self.status = REFUSED


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix fit`` with parsed arguments; returns the exit status.

    **Arguments:**

    - `args`: the namespace from the ``fit`` parser (see :func:`add_parser`).

    **Returns:** 0 on success, 2 for bad input (nothing written), 3 when a study finished
    with some curves refused (listed in its ``refused.csv``), 130 after Ctrl-C.
    """
    try:
        from fitting.data import DataError, input_files
        from fitting.solve import enable_compilation_cache

        # First: the checks below evaluate the model, compiled programs worth keeping too.
        enable_compilation_cache()
        try:
            files = input_files(args.inputs)
        except DataError as error:
            raise InputError(str(error)) from None
        if args.starts is not None and args.starts < 1:
            raise InputError(f"--starts: must be at least 1, got {args.starts}")
        if args.starts is not None and args.starts > 1_000_000:
            raise InputError(f"--starts: at most 1,000,000, got {args.starts}")
        if args.grid and args.errors not in (None, "absolute"):
            raise InputError(f"--grid scores the unweighted loss, as the source did; use it "
                             f"with --errors absolute (its default), not {args.errors}")
        if args.length is not None and not (math.isfinite(args.length) and args.length > 0):
            raise InputError(f"--length: must be a positive number of metres, got {args.length}")
        if args.length is not None and not (LENGTH_RANGE_M[0] <= args.length <= LENGTH_RANGE_M[1]):
            print(f"axialmix fit: warning: --length {args.length:g} m is outside "
                  f"{LENGTH_RANGE_M[0]:g} to {LENGTH_RANGE_M[1]:g} m, unusual for a blender: "
                  "is it in metres?", file=sys.stderr)
        out = Path(args.out)
        _check_out(out)
        from fitting.measurement import Inlet, measured

        free = _free_names(args.free)
        try:
            models = [measured(m, Inlet.pulse(), free) for m in _models(args.model)]
        except ValueError as error:
            raise InputError(f"--model: {error}") from None
        if len(models) > 1 and args.grid:
            raise InputError("--grid compares a fit with the source's grid search; use it with "
                             "one --model")
        every_settings = _settings_for_each(models, args.fix, args.tie)
        if args.profile is not None:
            if _is_study(args) or len(models) > 1 or args.loss != "sse":
                raise InputError("--profile runs on least-squares fits of one model to single "
                                 "files or folders (not on a study, a model comparison or "
                                 "--loss mae)")
            _profile_names(args.profile, models[0], every_settings[0])
        if _is_study(args):
            return _run_study(args, files, models, every_settings, free, out)
        curves = _read_curves(files, args)
        args.errors = _default_errors(args, curves)
        inlet = _inlet(args.inlet, curves, args)
        try:
            models = [measured(m.base, inlet, free) for m in models]
        except ValueError as error:
            raise InputError(f"--inlet: {error}") from None
        model, settings = models[0], every_settings[0]
        for each, each_settings in zip(models, every_settings, strict=True):
            # Start values of the model's own (moment estimates clipped into its bounds) give
            # finite curves for every built-in model; --fix, --tie or a measured inlet may not.
            if each_settings or args.inlet is not None:
                _check_fixed_curves(each, each_settings, curves, files)
    except InputError as error:
        return error_line("fit", str(error))
    except KeyboardInterrupt:
        print("axialmix fit: interrupted before fitting; nothing written", file=sys.stderr)
        return INTERRUPTED
    starts = args.starts or model.default_starts
    run = _Run(model, curves, files, settings, args, starts, out)
    run.compared = list(zip(models, every_settings, strict=True)) if len(models) > 1 else []
    return run.execute()


class _Run(_Supervised):
    """One ``axialmix fit`` run after validation: fits in a worker thread, Ctrl-C in the main."""

    def __init__(self, model, curves, files, settings, args, starts, out: Path):
        self.model, self.curves, self.files, self.settings = model, curves, files, settings
        self.args, self.starts, self.out = args, starts, out
        self.records: list[dict[str, Any]] = []
        #: ``(model, settings)`` of each compared model (empty for one model).
        self.compared: list[tuple[Any, dict]] = []
        self.stop = threading.Event()
        self.writing = threading.Lock()
        self.failure: BaseException | None = None
        self.status = OK
        self.lock = _Lock(out)
        #: Whether this run made the --out folder (then Ctrl-C before any result removes it).
        self.created = False

    def execute(self) -> int:
        in_main = threading.current_thread() is threading.main_thread()
        # Ctrl-C is handled here from before the folder and the lock exist until after the
        # lock is gone, so no signal can leave either behind.
        previous = signal.signal(signal.SIGINT, self._interrupt) if in_main else None
        try:
            try:
                self.created = not self.out.exists()
                self.out.mkdir(parents=True, exist_ok=True)
                self.lock.acquire()
            except InputError as error:
                return error_line("fit", str(error))
            except OSError as error:
                return error_line("fit", f"{self.out}: --out cannot be created "
                                  f"({error.strerror})")
            self._supervise("axialmix-fit")
        finally:
            self.lock.release()
            if self.created and not self.records:
                with contextlib.suppress(OSError):
                    self.out.rmdir()  # a run that wrote nothing leaves no folder
            if in_main:
                signal.signal(signal.SIGINT, previous)
        return self._outcome()

    def _leave(self) -> None:
        """After Ctrl-C: let the worker finish the files of a curve it is writing (written
        together, in milliseconds: plots are drawn before), write the summary of the finished
        curves, remove the lock (and the folder when this run made it and left it empty),
        exit 130 now."""
        written = self.writing.acquire(timeout=WRITE_GRACE)
        try:
            if written:
                self._write_summary(interrupted=len(self.records) < len(self.curves))
            else:
                _remove_temporary_files(self.out)
        finally:
            self.lock.release()
            if self.created and not self.records:
                with contextlib.suppress(OSError):
                    self.out.rmdir()  # only when empty
            where = f"; finished results are in {self.out}" if self.records else "; nothing written"
            _exit_now(f"axialmix fit: interrupted after {len(self.records)} of "
                      f"{len(self.curves)} curves{where}")

    def _work(self) -> None:
        try:
            self.status = self._fit_all()
        except BaseException as error:  # shown by the main thread
            self.failure = error

    def _fit_all(self) -> int:
        from axialmix._progress import progress_bar
        from fitting.gridsearch import grid_search
        from fitting.report import fit_record, fit_table, render_fit_png, write_json, write_png
        from fitting.solve import enable_compilation_cache

        enable_compilation_cache()
        args, out = self.args, self.out
        bar = progress_bar(total=len(self.curves), description="fit", unit="curve",
                           enabled=None if len(self.curves) > 1 else False)
        try:
            for index, (curve, path) in enumerate(zip(self.curves, self.files, strict=True)):
                bar.set_postfix_str(curve.name, refresh=True)
                if len(self.curves) > 1 and bar.disable:
                    # No terminal for the bar: one log line per curve instead.
                    print(f"axialmix fit: [{index + 1}/{len(self.curves)}] {curve.name}",
                          file=sys.stderr, flush=True)
                if self.compared:
                    status = self._compare(curve, path)
                    if status != OK:
                        return status
                    bar.update(1)
                    continue
                try:
                    result = _fit_one(self.model, curve, self.settings, args.loss, self.starts,
                                      args.errors, self.stop)
                except ValueError as error:
                    with self.writing:
                        self.status = error_line("fit", f"{path}: {error}")
                    return BAD_INPUT
                if self.stop.is_set():
                    return INTERRUPTED
                if args.profile is not None:
                    result = _profiled(result, args.profile, self.stop)
                    if self.stop.is_set():
                        return INTERRUPTED
                grid = None
                if args.grid:
                    grids, held, tied = _grid_for(self.model, result)
                    grid = grid_search(self.model, curve, grids, loss=args.loss, fixed=held,
                                       tied=tied, progress=True, stop=self.stop.is_set)
                record = fit_record(result, grid, source=str(path), length_m=args.length)
                # Drawn before taking the write lock, which Ctrl-C waits for: drawing takes a
                # second or more, writing the two files milliseconds.
                image = render_fit_png(result, grid)
                with self.writing:
                    if self.stop.is_set():
                        return INTERRUPTED
                    write_json(out / f"{curve.name}.json", record)
                    write_png(out / f"{curve.name}.png", image)
                    self.records.append(record)
                if len(self.curves) == 1:
                    _print_single(result, grid, record, fit_table, args.length)
                bar.update(1)
                if grid is not None and grid.interrupted:
                    self.stop.set()
                    return INTERRUPTED
        finally:
            bar.close()
        with self.writing:
            self._write_summary(interrupted=False)
        print(f"results written to {out}")
        return OK

    def _compare(self, curve, path) -> int:
        """Fit one curve with every compared model; print and write the comparison."""
        from fitting.diagnostics import compare_models
        from fitting.report import (
            comparison_record,
            comparison_table,
            fit_record,
            render_fit_png,
            write_json,
            write_png,
        )

        args, out = self.args, self.out
        results, records = [], []
        for model, settings in self.compared:
            try:
                result = _fit_one(model, curve, settings, args.loss,
                                  args.starts or model.default_starts,
                                  args.errors, self.stop)
            except ValueError as error:
                with self.writing:
                    self.status = error_line("fit", f"{path}: model {model.name}: {error}")
                return BAD_INPUT
            if self.stop.is_set():
                return INTERRUPTED
            results.append(result)
            records.append(fit_record(result, None, source=str(path), length_m=args.length))
        comparison = compare_models(results)
        record = comparison_record(comparison, records)
        record["source"] = str(path)
        images = [render_fit_png(result) for result in results]  # before the write lock
        with self.writing:
            if self.stop.is_set():
                return INTERRUPTED
            for result, fitted, image in zip(results, records, images, strict=True):
                write_json(out / f"{curve.name}.{result.model.name}.json", fitted)
                write_png(out / f"{curve.name}.{result.model.name}.png", image)
            write_json(out / f"{curve.name}.comparison.json", record)
            self.records.append(record)
        print(comparison_table(comparison, wide=self.args.wide), flush=True)
        return OK

    def _write_comparison_summary(self, records, interrupted: bool) -> None:
        from fitting.report import write_csv, write_json

        write_json(self.out / "summary.json", {
            "models": [m.name for m, _ in self.compared], "loss_name": self.args.loss,
            "complete": not interrupted,
            "comparisons": [{k: v for k, v in r.items() if k != "fits"} for r in records]})
        header = ["curve", "model", "sse", "aicc", "delta_aicc", "bic", "systematic_misfit",
                  "converged", "recommended"]
        rows = [[r["data"], m["model"], m["sse"], m["aicc"], m["delta_aicc"], m["bic"],
                 m["lack_of_fit"]["systematic"], m["converged"], m["model"] == r["best"]]
                for r in records for m in r["models"]]
        write_csv(self.out / "summary.csv", header, rows)

    def _write_summary(self, interrupted: bool) -> None:
        records = list(self.records)
        if not records:
            return  # before importing: after Ctrl-C the worker may still be importing
        from fitting.report import summary_rows, summary_table, write_csv, write_json

        if self.compared:
            self._write_comparison_summary(records, interrupted)
            return
        if len(self.curves) > 1:  # one curve: its own table is the summary
            print(summary_table(records, wide=self.args.wide), flush=True)
        write_json(self.out / "summary.json", {"model": self.model.name,
                                               "loss_name": self.args.loss,
                                               "complete": not interrupted, "fits": records})
        header, rows = summary_rows(records)
        write_csv(self.out / "summary.csv", header, rows)


def _profile_names(text: str, model, settings: dict) -> tuple[str, ...] | None:
    """The parameters ``--profile`` names (``None``: every free one), checked up front."""
    if text.strip() == "all":
        return None
    from fitting.parameters import canonical_name

    names = tuple(dict.fromkeys(canonical_name(n.strip()) for n in text.split(",")
                                if n.strip()))
    known = model.parameter_names
    for name in names:
        if name not in known:
            raise InputError(f"--profile: {name!r} is not a parameter of {model.name} "
                             f"({', '.join(known)})")
        setting = settings.get(name)
        if setting is not None and (not setting.vary or setting.expr is not None):
            raise InputError(f"--profile: {name} is fixed or tied; profile a free parameter")
    if not names:
        raise InputError("--profile: name at least one parameter (or none, for all)")
    return names


def _profiled(result, text: str, stop: threading.Event):
    """The fit with profile-likelihood intervals for the parameters ``--profile`` names."""
    from fitting.diagnostics import profile_intervals, with_profile_intervals
    from fitting.parameters import canonical_name

    names = None if text.strip() == "all" else [canonical_name(n.strip())
                                                 for n in text.split(",") if n.strip()]
    names = [n for n in (result.free_names if names is None else names)
             if n in result.free_names]

    def said(name: str) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        print(f"axialmix fit: profiling {name} ({names.index(name) + 1} of {len(names)})",
              file=sys.stderr, flush=True)

    try:
        return with_profile_intervals(result, profile_intervals(result, names, progress=said))
    except KeyboardInterrupt:
        stop.set()
        return result


def _fit_one(model, curve, settings: dict, loss: str, starts: int | None,
             errors: str = "absolute", stop: threading.Event | None = None):
    """Fit one curve; the mean absolute error is polished from the least-squares optimum.

    The MAE is not smooth, so multi-start L-BFGS on it stalls at kinks; the least-squares
    multi-start finds the basin and a single MAE fit from there finishes. The evaluations
    and times of both stages are reported together. With `errors` ``"relative"`` or
    ``"combined"`` the least-squares fit is the weighted fit of that error model and the
    MAE polish is weighted by the square root of its weights (``1 / |model|`` for relative
    errors). Many starts run in batches of :data:`STARTS_PER_BATCH`, with progress between
    them.
    """
    import numpy as np

    from axialmix._progress import progress_bar
    from fitting.fit import fit
    from fitting.solve import MultiStart

    if starts is not None and starts > STARTS_PER_BATCH:
        first, done = None, 0
        bar = progress_bar(total=starts, description=f"starts ({curve.name})", unit="start")
        try:
            while done < starts and not (stop is not None and stop.is_set()):
                count = min(STARTS_PER_BATCH, starts - done)
                batch = fit(model, curve, settings, loss="sse", errors=errors,
                            multistart=MultiStart(n_starts=max(count, 2), seed=done))
                if first is None or batch.loss < first.loss:
                    evaluations = batch.n_evaluations + (first.n_evaluations if first else 0)
                    wall = batch.wall_time + (first.wall_time if first else 0.0)
                    first = dataclasses.replace(batch, n_evaluations=evaluations,
                                                wall_time=wall, n_starts=done + count)
                else:
                    first = dataclasses.replace(
                        first, n_evaluations=first.n_evaluations + batch.n_evaluations,
                        wall_time=first.wall_time + batch.wall_time, n_starts=done + count)
                done += count
                bar.update(count)
        finally:
            bar.close()
    else:
        first = fit(model, curve, settings, loss="sse", errors=errors,
                    multistart=MultiStart(n_starts=starts))
    if loss == "sse" or (stop is not None and stop.is_set()):
        return first
    weights = np.sqrt(first.weights) if errors != "absolute" else None
    second = fit(model, curve, first.restart_parameters(), loss=loss, weights=weights,
                 multistart=MultiStart(n_starts=1))
    return dataclasses.replace(
        second,
        n_evaluations=first.n_evaluations + second.n_evaluations,
        wall_time=first.wall_time + second.wall_time,
        n_starts=first.n_starts,
        error_model=first.error_model,
    )


def _print_single(result, grid, record, fit_table, length: float | None = None) -> None:
    print(fit_table(result, grid, length))
    for sentence in record["identifiability"]:
        print(f"  * {sentence}")
    for name, meaning in record.get("meanings", {}).items():
        if name in ("tau", "amplitude") and name in result.values:
            print(f"  * {meaning[0].upper()}{meaning[1:]}.")
    if result.error_model is not None:
        unit = result.curve.value_unit or ""
        print(f"  * Errors: {result.error_model.describe(unit)}.")
    equivalent = record.get("equivalent_adm")
    if equivalent is not None and "variance_ratio" in equivalent:
        unit = result.time_unit
        length = equivalent["length_m"]
        transport = ("" if length is None else
                     f", v = {_show(equivalent['velocity_m_per_s'])} m/s, D_z = "
                     f"{_show(equivalent['dispersion_m2_per_s'])} m^2/s (L = {length:g} m)")
        print("  equivalent closed-closed ADM (same mean and variance): tau = "
              f"{_show(equivalent[f'tau_{unit}'])} {unit}, Pe = {_show(equivalent['peclet'])}"
              f"{transport}")


def _show(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"
