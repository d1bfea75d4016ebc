"""``axialmix funnel``: the funnel plot of a unit operation's RTD (largest outlet deviations).

    axialmix funnel --model M [--curve ID] [--set NAME=VALUE ...] [--time-unit s]
                    --durations D1,D2,... --magnitudes M1,M2,... [--magnitude-unit %]
                    [--out DIR]

For every square inlet disturbance of magnitude M and duration D, the largest deviation it
causes at the outlet, ``M max_t [F(t) - F(t - D)]`` (:func:`axialmix.line.funnel`, exact and
vectorised). ``--model`` is a model name of ``axialmix fit`` (``adm``, ``adm-open``, ``tanks``,
``four-compartment``, ``adm-exchange``, ``tanks-exchange``, ``adm-tank``; ``adm-fv`` is the
closed-closed ADM, evaluated exactly) with every parameter given by ``--set NAME=VALUE`` in
``--time-unit``, or the JSON file of a fit that ``axialmix fit`` wrote (its values and its
time unit; ``--set`` then overrides values), or the ``summary.json`` of a folder or study
fit with ``--curve ID`` naming one of its curves. The table printed and the JSON key
``"max_deviation"`` have one row per magnitude and one column per duration; the JSON states
the durations, magnitudes and their units. ``--out DIR`` writes
``DIR/funnel.json`` and the plot ``DIR/funnel.png`` as one result set (all or nothing; see
:mod:`fitting.cli._outputs`); without it nothing is written. Exit status: 0 done, 2 bad input
(one line, nothing written), 130 interrupted (the line says whether the result set is
complete or nothing was written).

This module is also the adapter from fit results to :mod:`axialmix.line` units (used by
``axialmix divert``): :func:`fitted_rtd` reads a fit's JSON record into an
:class:`axialmix.line.FittedRTD` with the covariance of its free model parameters.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fitting.cli._outputs import (
    OutputError,
    OutputFolder,
    add_out_option,
    preload_plotting,
    render_png,
)

__all__ = [
    "LINE_MODELS",
    "ExportedPrograms",
    "OptionError",
    "add_model_options",
    "add_parser",
    "model_inputs",
    "fitted_rtd",
    "numbers",
    "require_finite_record",
    "rtd_from_options",
    "run",
]

_COMMAND = "funnel"

#: The result set of ``axialmix funnel --out DIR``.
FILES = ("funnel.json", "funnel.png")

#: ``axialmix fit`` model names -> :data:`axialmix.line.UNIT_BUILDERS` names. ``adm-fv`` fits
#: the closed-closed ADM by finite volumes; its unit is the exact closed-closed one.
LINE_MODELS = {
    "adm": "closed_closed",
    "adm-fv": "closed_closed",
    "adm-open": "open_open",
    "tanks": "tanks",
    "four-compartment": "four_compartment",
    "adm-exchange": "closed_closed_exchange",
    "tanks-exchange": "tanks_exchange",
    "adm-tank": "closed_closed_tank",
}


class OptionError(Exception):
    """Bad command-line input; the message is one line, without the program prefix."""


class _Exported:
    """A line program run from its exported form (:class:`axialmix.line.CompiledProgram`)."""

    def __init__(self, executable):
        self.executable = executable

    def __call__(self, *arguments):
        import equinox as eqx
        import jax

        return self.executable(*jax.tree_util.tree_leaves(eqx.filter(arguments, eqx.is_array)))

    def temporary_bytes(self) -> int:
        analysis = self.executable.memory_analysis()
        return int(getattr(analysis, "temp_size_in_bytes", 0) or 0) if analysis else 0


class ExportedPrograms:
    """The :data:`axialmix.line.ProgramRunner` of ``funnel`` and ``divert``: the line's
    programs go through the fit's cache of compiled programs (:class:`fitting.solve.Program`
    after :func:`fitting.solve.enable_compilation_cache`, called here): each is exported with
    :mod:`jax.export` to the user's cache folder under its
    :func:`axialmix.line.program_identity` and shapes, and a later process loads it from
    there (no tracing) and its compiled form from JAX's persistent cache (no compiling).
    A program without an identity (a value that cannot be named across processes) is
    compiled in this process only."""

    def __init__(self) -> None:
        from fitting.solve import enable_compilation_cache

        enable_compilation_cache()
        self._programs: dict = {}

    def __call__(self, name: str, function, arguments: tuple):
        import equinox as eqx
        import jax

        from axialmix.line import compile_program, program_identity
        from fitting.solve import Program

        identity = program_identity(function, arguments)
        if identity is None:
            return compile_program(None, name, function, arguments)
        dynamic, static = eqx.partition(arguments, eqx.is_array)
        leaves, structure = jax.tree_util.tree_flatten(dynamic)
        program = self._programs.get(identity)
        if program is None:
            def flat(*values):
                return function(*eqx.combine(jax.tree_util.tree_unflatten(structure, values),
                                             static))

            flat.__name__ = flat.__qualname__ = function.__name__  # in JAX's messages
            program = self._programs[identity] = Program(flat, name,
                                                         ("axialmix.line", *identity))
        executable, _ = program.executable(leaves)
        return _Exported(executable)


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--model``, ``--set`` and ``--time-unit`` (the RTD of a unit) to `parser`."""
    parser.add_argument("--model", required=True,
                        help="a model of axialmix fit (" + ", ".join(LINE_MODELS) + ") with "
                        "--set for its parameters, or the JSON file a fit wrote")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a parameter value (repeat for each parameter; overrides a fit's)")
    parser.add_argument("--time-unit", default=None,
                        help="unit of time of the parameters and durations (default s, or the "
                        "fit's)")
    parser.add_argument("--curve", default=None, metavar="ID",
                        help="the curve to use when --model is the summary.json of several fits "
                        "(a folder or a study that axialmix fit wrote)")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``funnel`` parser on `subparsers`; returns it."""
    parser = subparsers.add_parser(
        _COMMAND,
        help="funnel plot: largest outlet deviation of square feed disturbances",
        description="Largest outlet deviation for square inlet disturbances of each "
        "magnitude and duration (funnel plot), from a model or a fit.",
    )
    add_model_options(parser)
    parser.add_argument("--durations", required=True,
                        help="disturbance durations, comma-separated (time unit)")
    parser.add_argument("--magnitudes", required=True,
                        help="disturbance magnitudes, comma-separated (magnitude unit)")
    parser.add_argument("--magnitude-unit", default="%",
                        help="unit of the magnitudes and deviations (default %%)")
    parser.add_argument("--limit", type=float, default=5.0,
                        help="the specification: the largest outlet deviation allowed "
                        "(magnitude unit, default 5); the plot draws where it is reached")
    add_out_option(parser, "funnel.json and funnel.png", replaced=("--json", "--png"))
    return parser


# ------------------------------------------------------------------ the adapter
def numbers(option: str, text: str) -> list[float]:
    """Comma-separated finite numbers of an option (the grammar of data cells: no
    underscores); :class:`OptionError` otherwise."""
    from axialmix._csv import parse_number

    cells = [cell.strip() for cell in text.split(",")]
    if not text.strip() or any(cell == "" for cell in cells):
        raise OptionError(f"{option} needs comma-separated numbers, got {text!r}")
    values = []
    for cell in cells:
        try:
            value = parse_number(cell)
        except ValueError:
            raise OptionError(f"{option}: {cell!r} is not a number") from None
        if not math.isfinite(value):
            raise OptionError(f"{option}: {cell!r} is not a finite number")
        values.append(value)
    return values


def require_finite_record(record: Any) -> None:
    """:class:`OptionError` naming the first non-finite number in a JSON-bound record."""
    from fitting.data import first_non_finite

    where = first_non_finite(record)
    if where is not None:
        raise OptionError(f"the result {where} is not a finite number; nothing written")


def _time_unit(option: str, unit: str) -> str:
    from fitting.data import TIME_UNIT_SECONDS

    if unit not in TIME_UNIT_SECONDS:
        raise OptionError(f"{option}: unknown time unit {unit!r} (known: "
                          + ", ".join(TIME_UNIT_SECONDS) + ")")
    return unit


def _settings(items: Sequence[str]) -> dict[str, float]:
    values: dict[str, float] = {}
    for item in items:
        from fitting.parameters import canonical_name

        name, equals, text = item.partition("=")
        name = canonical_name(name.strip())
        if not equals or not name:
            raise OptionError(f"--set needs NAME=VALUE, got {item!r}")
        (values[name],) = numbers(f"--set {name}", text)
    return values


def _covariance(record: Mapping[str, Any], free: Sequence[str], source: str) -> list[list[float]]:
    """The covariance of `free` from a record's standard errors and correlation matrix."""
    correlation = record.get("correlation") or {}
    names = list(correlation.get("names") or [])
    matrix = correlation.get("matrix")
    missing = [name for name in free if name not in names]
    if missing or matrix is None:
        raise OptionError(f"{source}: the fit has no correlation for {', '.join(missing)}")
    errors = [record["parameters"][name].get("stderr") for name in free]
    if any(e is None or not math.isfinite(e) for e in errors):
        raise OptionError(f"{source}: the fit has no standard error for some of "
                          f"{', '.join(free)}")
    for name, error in zip(free, errors, strict=True):
        if not math.isfinite(float(error) * float(error)):
            raise OptionError(f"{source}: the standard error {error:g} of {name} has no "
                              "finite square (variance); the fit's covariance is unusable")
    size = len(names)
    if (not isinstance(matrix, list) or len(matrix) != size
            or any(not isinstance(row, list) or len(row) != size for row in matrix)):
        raise OptionError(f"{source}: the fit's correlation matrix is not {size} x {size} "
                          f"for its {size} names")
    index = [names.index(name) for name in free]
    covariance = []
    for a, i in enumerate(index):
        row = []
        for b, j in enumerate(index):
            r = matrix[i][j]
            if r is None:
                raise OptionError(f"{source}: the fit's correlation matrix has empty entries")
            if not isinstance(r, int | float) or not math.isfinite(r):
                raise OptionError(f"{source}: the fit's correlation matrix has a "
                                  f"non-numeric or non-finite entry {r!r}")
            row.append(float(r) * errors[a] * errors[b])
        covariance.append(row)
    return covariance


def _chosen_record(record: Any, curve: str | None, source: str) -> Any:
    """The fit record of `curve` in a summary (``"fits"`` of a folder, ``"curves"`` of a
    study), or `record` itself when it is one fit. Raises :class:`OptionError`."""
    fits = record.get("fits", record.get("curves")) if isinstance(record, Mapping) else None
    if not isinstance(fits, list):
        if curve is not None and isinstance(record, Mapping) and record.get("data") != curve:
            raise OptionError(f"--curve {curve}: {source} is the fit of "
                              f"{record.get('data')!r} only")
        return record
    names = [f.get("data") for f in fits if isinstance(f, Mapping)]
    if curve is None:
        if len(fits) == 1:
            return fits[0]
        shown = ", ".join(str(n) for n in names[:5]) + (", ..." if len(names) > 5 else "")
        raise OptionError(f"--model {source}: a summary of {len(fits)} fits; choose one with "
                          f"--curve ID ({shown})")
    for fit in fits:
        if isinstance(fit, Mapping) and fit.get("data") == curve:
            return fit
    raise OptionError(f"--curve {curve}: no such curve in {source} ({len(fits)} fits)")


def fitted_rtd(record: Mapping[str, Any], overrides: Mapping[str, float] | None = None, *,
               source: str = "fit"):
    """An :class:`axialmix.line.FittedRTD` from the JSON record ``axialmix fit`` writes.

    The model's own parameters are kept (a measurement model's amplitude, dead time and
    baseline describe the detector, not the unit); the free ones (``"vary"``, no tie) carry
    the covariance ``stderr_i r_ij stderr_j`` from the record's standard errors and
    correlation matrix, which is the marginal covariance of those parameters. Values in
    `overrides` are held fixed at the value given.

    **Arguments:**

    - `record`: the parsed JSON (``model``, ``time_unit``, ``parameters`` with ``value``,
      ``stderr`` and ``vary``, ``correlation`` with ``names`` and ``matrix``).
    - `overrides`: ``{name: value}`` to hold fixed.
    - `source`: the file name, for messages.

    **Returns:** ``(fitted, name)``: the :class:`~axialmix.line.FittedRTD` and the fit's model
    name. Raises :class:`OptionError` (one line) when the record is not a usable fit.
    """
    from axialmix.line import UNIT_BUILDERS, FittedRTD

    overrides = dict(overrides or {})
    if not isinstance(record, Mapping) or not isinstance(record.get("parameters"), Mapping):
        raise OptionError(f"{source}: not the JSON record of a fit (no \"parameters\"); a "
                          "network file cannot be used here")
    model = record.get("model")
    if model not in LINE_MODELS:
        raise OptionError(f"{source}: a fit of model {model!r} cannot be made a unit; models: "
                          + ", ".join(LINE_MODELS))
    line_model = LINE_MODELS[model]
    names = UNIT_BUILDERS[line_model][0]
    parameters = record["parameters"]
    unknown = [name for name in overrides if name not in names]
    if unknown:
        raise OptionError(f"--set {unknown[0]}: the {model} model has no such parameter "
                          f"({', '.join(names)})")
    values = {}
    for name in names:
        entry = parameters.get(name)
        value = None if not isinstance(entry, Mapping) else entry.get("value")
        if name in overrides:
            value = overrides[name]
        if value is None or not isinstance(value, int | float) or not math.isfinite(value):
            raise OptionError(f"{source}: no finite value of {name}")
        values[name] = float(value)
    free = [name for name in names if name not in overrides
            and parameters[name].get("vary") and not parameters[name].get("expr")]
    covariance = _covariance(record, free, source) if free else []
    time_unit = _time_unit(f"{source}: time_unit", record.get("time_unit") or "s")
    try:
        fitted = FittedRTD.from_parameters(line_model, values, free=free,
                                           covariance=covariance or None, time_unit=time_unit,
                                           name=str(record.get("data") or model))
        fitted.unit()  # parameter checks (positive values) on the fitted values
    except ValueError as error:
        raise OptionError(f"{source}: {error}") from None
    return fitted, model


def rtd_from_options(args: argparse.Namespace):
    """The fitted RTD the options ``--model``, ``--set`` and ``--time-unit`` describe.

    **Returns:** ``(fitted, description)``: an :class:`axialmix.line.FittedRTD` (no free
    parameters for a named model) and a dict for the JSON output (``model``,
    ``unit_model``, ``source``, ``parameters`` with values and standard errors). Raises
    :class:`OptionError`.
    """
    from axialmix.line import UNIT_BUILDERS, FittedRTD

    overrides = _settings(args.set)
    if args.time_unit is not None:
        _time_unit("--time-unit", args.time_unit)
    model = args.model
    path = Path(model)
    if model in LINE_MODELS:
        line_model = LINE_MODELS[model]
        names = UNIT_BUILDERS[line_model][0]
        unknown = [name for name in overrides if name not in names]
        if unknown:
            raise OptionError(f"--set {unknown[0]}: the {model} model has no such parameter "
                              f"({', '.join(names)})")
        missing = [name for name in names if name not in overrides]
        if missing:
            raise OptionError(f"--model {model} needs --set for {', '.join(missing)}")
        try:
            fitted = FittedRTD.from_parameters(line_model, overrides,
                                               time_unit=args.time_unit or "s", name=model)
            fitted.unit()
        except ValueError as error:
            raise OptionError(f"--model {model}: {error}") from None
        source = None
    elif path.suffix.lower() == ".json" or path.exists():
        if not path.is_file():
            raise OptionError(f"--model {model}: no such model or file (models: "
                              + ", ".join(LINE_MODELS) + ")")
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise OptionError(f"{model}: cannot be read as JSON ({error})") from None
        record = _chosen_record(record, getattr(args, "curve", None), str(path))
        fitted, model = fitted_rtd(record, overrides, source=str(path))
        if args.time_unit is not None and args.time_unit != fitted.time_unit:
            raise OptionError(f"--time-unit {args.time_unit}: the fit {path} is in "
                              f"{fitted.time_unit}")
        source = str(path)
    else:
        raise OptionError(f"--model {model}: no such model or file (models: "
                          + ", ".join(LINE_MODELS) + ")")
    if source is None and getattr(args, "curve", None) is not None:
        raise OptionError("--curve picks a curve of a summary.json given to --model")
    _check_ranges(fitted, "--set" if source is None else source, overrides)
    errors = dict(zip(fitted.free, [float(e) for e in fitted.standard_errors], strict=True))
    description = {
        "model": model,
        "unit_model": fitted.model,
        "source": source,
        "parameters": {
            name: {"value": float(value), "stderr": errors.get(name)}
            for name, value in zip(fitted.parameter_names, fitted.values.tolist(), strict=True)
        },
        "time_unit": fitted.time_unit,
    }
    return fitted, description


def _check_ranges(fitted, source: str, overrides: Mapping[str, float]) -> None:
    """Refuse a Peclet number or tank count outside the range where the models are verified
    (beyond it their curves may be wrong without a sign: Pe 1e308 gives a zero response)."""
    from axialmix.analytic import ClosedClosedADM, TanksInSeries, unverified_parameters

    units = {"peclet": lambda v: ClosedClosedADM(1.0, v),
             "n_tanks": lambda v: TanksInSeries(1.0, v)}
    for name, value in zip(fitted.parameter_names, fitted.values.tolist(), strict=True):
        problems = unverified_parameters(units[name](value)) if name in units else []
        if problems:
            where = f"--set {name}" if name in overrides else source
            raise OptionError(f"{where}: {name} = {value:g}: {problems[0]}; the model's curves "
                              "are not verified there")


def _table(result) -> str:
    durations = [f"{d:g}" for d in result.durations.tolist()]
    header = [f"M ({result.magnitude_unit}) \\ D ({result.time_unit})", *durations]
    rows = [[f"{m:g}", *(f"{x:.4g}" for x in row)]
            for m, row in zip(result.magnitudes.tolist(), result.max_deviation.tolist(),
                              strict=True)]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(r, widths, strict=True))
             for r in [header, *rows]]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix funnel`` with parsed `args`; returns the exit status."""
    from axialmix import _exits

    try:
        durations = numbers("--durations", args.durations)
        magnitudes = numbers("--magnitudes", args.magnitudes)
        if any(d <= 0 for d in durations):
            raise OptionError("--durations must be positive")
        if not (math.isfinite(args.limit) and args.limit > 0):
            raise OptionError(f"--limit must be a positive number, got {args.limit:g}")
        out = OutputFolder(_COMMAND, args.out, FILES, inputs=model_inputs(args))
        out.check()
        fitted, description = rtd_from_options(args)
    except (OptionError, OutputError) as error:
        return _exits.error_line(_COMMAND, str(error))
    if args.out is not None:
        preload_plotting()  # matplotlib loads while the program runs

    import numpy as np

    from axialmix._files import json_text
    from axialmix.line import FunnelResult, funnel, funnel_map_durations

    programs = ExportedPrograms()  # compiled programs kept on disk for the next run
    unit = fitted.unit()
    durations = np.asarray(durations, float)
    count = durations.size
    # The table's durations and, for the plot, its map's, in one program.
    drawn = args.out is not None and durations.max() > durations.min()
    asked = np.concatenate([durations, funnel_map_durations(durations)]) if drawn else durations
    both = funnel(unit, asked, np.asarray(magnitudes, float),
                  magnitude_unit=args.magnitude_unit, programs=programs)

    def part(columns):
        return FunnelResult(both.durations[columns], both.magnitudes,
                            both.max_deviation[:, columns], both.max_fraction[columns],
                            both.worst_time[columns], both.time_unit, both.magnitude_unit,
                            both.mean_residence_time)

    result = part(slice(0, count))
    fine = part(slice(count, None)) if drawn else None
    mean = float(both.mean_residence_time)
    values = ", ".join(f"{name}={value:g}" for name, value in
                       zip(fitted.parameter_names, fitted.values.tolist(), strict=True))
    if not (np.all(np.isfinite(np.asarray(result.max_deviation))) and math.isfinite(mean)):
        return _exits.error_line(_COMMAND, f"the model gives no finite funnel at {values}")
    print(f"funnel of {description['model']} ({unit.model.name}), mean residence time "
          f"{mean:.4g} {unit.time_unit}: largest outlet deviation, rows "
          f"magnitudes, columns durations")
    print(_table(result))
    if args.out is None:
        return _exits.OK
    record = {
        **description,
        "mean_residence_time": mean,
        **result.to_dict(),
        "rows": "magnitudes",
        "columns": "durations",
    }
    try:
        require_finite_record(record)
    except OptionError as error:
        return _exits.error_line(_COMMAND, f"{values}: {error}")
    from axialmix.line import plot_funnel

    title = (f"Funnel of {description['model']}: largest outlet deviation "
             f"({args.magnitude_unit})")
    png = render_png(lambda ax: plot_funnel(result, ax=ax, rtd=unit, limit=args.limit,
                                            title=title, fine=fine), (7, 4.5))
    for path in out.commit({"funnel.json": json_text(record), "funnel.png": png}):
        print(f"wrote {path}")
    return _exits.OK


def model_inputs(args: argparse.Namespace) -> list[str]:
    """The input file among the model options (a fit's JSON given to ``--model``)."""
    return [args.model] if args.model.endswith(".json") or Path(args.model).is_file() else []
