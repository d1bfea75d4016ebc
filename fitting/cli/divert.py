"""``axialmix divert``: when to divert off-specification material after a feed disturbance.

    axialmix divert --model M [--set NAME=VALUE ...] [--time-unit s]
                    (--disturbance KIND:KEY=VALUE,... | --trace FILE)
                    [--target 100] [--limits -5,5] [--absolute-limits] [--content-unit %]
                    [--flow KG_PER_H] [--until T] [--points N]
                    [--coverage 0.95] [--samples N] [--method region|quantile] [--seed N]
                    [--out DIR]

The outlet content is ``target + E ⊗ δu`` for the inlet deviation δu; diversion starts when
it first leaves the specification limits and stops when it last returns
(:func:`axialmix.line.diversion_window`); the diverted amount is the flow over that window,
in kg for ``--flow`` in kg/h (the time unit of the RTD converted). Limits are percentages of
``--target`` (``--limits -5,5``: from 95 % to 105 % of it) or, with ``--absolute-limits``,
contents in the unit of the target.

The disturbance is ``--disturbance`` ``step:magnitude=M,start=T``,
``square:magnitude=M,duration=D,start=T``, ``ramp:magnitude=M,duration=D,start=T`` (then held)
or ``pulse:amount=A,at=T`` (content unit × time unit), magnitudes in the content unit; or
``--trace FILE``, a feeder's measured content over time (a CSV of time and content in the
RTD's time unit and the content unit, linear between samples), whose deviation from the
target enters.

The RTD is ``--model`` with ``--set`` (as for ``axialmix funnel``), or a fit's JSON file. A
fit's covariance makes the window uncertain: the conservative window covers the window of
the true RTD with probability ``--coverage`` (:func:`axialmix.line.conservative_diversion_window`,
``--method region``: earliest start and latest stop over ``--samples`` parameter vectors
filling the fit's confidence region, log-normal for positive parameters). Samples whose
prediction is not finite, or whose outlet has not settled by the end of the scan, are counted
(``failed_samples`` in the JSON); past 1 % of them the conservative window is refused (exit 2,
one line with the nominal window) rather than made of the samples that worked. The scan runs
to ``--until`` at least and continues, at the same spacing, until the disturbance's effect has
settled, so no window is cut by it. ``--points`` and ``--samples`` are bounded (1,000,000
each, and the library's bound on model evaluations and memory), refused up front with the
estimate. ``--out DIR`` writes ``DIR/divert.json`` and the plot ``DIR/divert.png`` as one
result set (all or nothing, :mod:`fitting.cli._outputs`); without it nothing is written.
Exit status: 0 done, 2 bad input (one line, nothing written), 130 interrupted (the line says
whether the result set is complete or nothing was written).
"""

from __future__ import annotations

import argparse
import math
import re

from fitting.cli._outputs import (
    OutputError,
    OutputFolder,
    add_out_option,
    preload_plotting,
    render_png,
)
from fitting.cli.funnel import (
    ExportedPrograms,
    OptionError,
    add_model_options,
    model_inputs,
    numbers,
    require_finite_record,
    rtd_from_options,
)

__all__ = ["DISTURBANCES", "add_parser", "run"]

_COMMAND = "divert"
#: The result set of ``axialmix divert --out DIR``.
FILES = ("divert.json", "divert.png")

#: Disturbance kind -> (required keys, optional keys with defaults).
DISTURBANCES = {
    "step": (("magnitude",), {"start": 0.0}),
    "square": (("magnitude", "duration"), {"start": 0.0}),
    "ramp": (("magnitude", "duration"), {"start": 0.0}),
    "pulse": (("amount",), {"at": 0.0}),
}
#: Seconds per hour: ``--flow`` is in kg/h.
_HOUR = 3600.0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``divert`` parser on `subparsers`; returns it."""
    parser = subparsers.add_parser(
        _COMMAND,
        help="diversion window after a feed disturbance, with a fit's uncertainty",
        description="When to start and stop diverting material after a feed disturbance, "
        "and how much, from a model or a fit (with a conservative window from its "
        "covariance).",
    )
    # "--limits -5,5" (the documented form): a value that starts with a minus sign and holds
    # only numbers and commas is a value, not an option.
    parser._negative_number_matcher = re.compile(r"^-[\d.,eE+-]+$")
    add_model_options(parser)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--disturbance", metavar="KIND:KEY=VALUE,...",
                        help="step:magnitude=M,start=T | square:magnitude=M,duration=D,"
                        "start=T | ramp:magnitude=M,duration=D,start=T | pulse:amount=A,at=T")
    source.add_argument("--trace", metavar="FILE",
                        help="a feeder's content over time (CSV: time, content)")
    parser.add_argument("--target", type=float, default=100.0,
                        help="content at steady state (default 100, in --content-unit)")
    parser.add_argument("--limits", default="-5,5",
                        help="LOW,HIGH specification limits in percent of the target "
                        "(default -5,5), or contents with --absolute-limits")
    parser.add_argument("--absolute-limits", action="store_true",
                        help="--limits are contents, not percentages of the target")
    parser.add_argument("--content-unit", default="%",
                        help="unit of the content, target and magnitudes (default %%)")
    parser.add_argument("--flow", type=float, default=None,
                        help="mass flow through the line (kg/h) for the diverted amount (kg)")
    parser.add_argument("--until", type=float, default=None,
                        help="end of the time scanned (time unit; default the last event "
                        "plus the mean residence time and 10 standard deviations)")
    parser.add_argument("--points", type=int, default=2001,
                        help="scan times (default 2001); crossings are then found exactly")
    parser.add_argument("--coverage", type=float, default=0.95,
                        help="probability that the conservative window covers the true one "
                        "(default 0.95; needs a fit with a covariance)")
    parser.add_argument("--samples", type=int, default=1000,
                        help="parameter vectors sampled for the conservative window "
                        "(default 1000)")
    parser.add_argument("--method", choices=("region", "quantile"), default="region",
                        help="conservative window over the confidence region (default, "
                        "guaranteed) or from quantiles of the sampled windows")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the sampling")
    add_out_option(parser, "divert.json and divert.png", replaced=("--json", "--png"))
    return parser


def _disturbance_spec(text: str) -> tuple[str, dict[str, float]]:
    kind, colon, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind not in DISTURBANCES:
        raise OptionError(f"--disturbance: unknown kind {kind!r}; kinds: "
                          + ", ".join(DISTURBANCES))
    required, optional = DISTURBANCES[kind]
    values = dict(optional)
    for item in (rest.split(",") if colon and rest.strip() else []):
        key, equals, number = item.partition("=")
        key = key.strip()
        if not equals or key not in (*required, *optional):
            raise OptionError(f"--disturbance {kind}: expected KEY=VALUE with keys "
                              f"{', '.join((*required, *optional))}, got {item.strip()!r}")
        (values[key],) = numbers(f"--disturbance {kind} {key}", number)
    missing = [key for key in required if key not in values]
    if missing:
        raise OptionError(f"--disturbance {kind} needs {', '.join(missing)}")
    if "duration" in values and values["duration"] <= 0:
        raise OptionError(f"--disturbance {kind}: duration must be positive")
    return kind, values


def _read_trace(path: str):
    import numpy as np

    from axialmix._csv import DataError, read_table

    try:
        table = read_table(path, decimal="auto")
        if len(table.columns) < 2:
            raise table.error("needs two columns: time and content")
        rows, values = table.numbers([0, 1])
    except DataError as error:
        raise OptionError(error.compact()) from None
    if rows.size < 2:
        raise OptionError(f"{path}: a trace needs at least two rows")
    steps = np.diff(values[:, 0])
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise OptionError(f"{path}:{rows[k]}: time {values[k, 0]:g} does not increase")
    return values[:, 0], values[:, 1], table.columns[0].unit


def _limits(args) -> tuple[float, float]:
    given = numbers("--limits", args.limits)
    if len(given) != 2:
        raise OptionError(f"--limits needs LOW,HIGH, got {args.limits!r}")
    low, high = given
    if not math.isfinite(args.target):
        raise OptionError("--target must be a finite number")
    if not args.absolute_limits and not args.target > 0:
        raise OptionError(f"--target {args.target:g}: limits in percent of the target need a "
                          "positive target (or give --absolute-limits)")
    if not args.absolute_limits:
        low, high = args.target * (1 + low / 100), args.target * (1 + high / 100)
    if not low < high:
        raise OptionError(f"--limits: the lower limit {low:g} must be below the upper {high:g}")
    if not low <= args.target <= high:
        raise OptionError(f"--limits [{low:g}, {high:g}] do not contain the target "
                          f"{args.target:g}")
    return low, high


#: Largest --points and --samples accepted (with the evaluation bound of the library).
MAX_POINTS = 1_000_000
MAX_SAMPLES = 1_000_000


def _check(args) -> None:
    if args.points < 16:
        raise OptionError("--points must be at least 16")
    if args.points > MAX_POINTS:
        raise OptionError(f"--points {args.points}: a scan of that many times needs about "
                          f"{args.points * 64 / 2**30:.3g} GiB and {2 * args.points:.3g} "
                          f"model evaluations per event; at most {MAX_POINTS:,} are accepted")
    if not 0 < args.coverage < 1:
        raise OptionError("--coverage must lie between 0 and 1")
    if args.samples < 2:
        raise OptionError("--samples must be at least 2")
    if args.samples > MAX_SAMPLES:
        raise OptionError(f"--samples {args.samples}: about {args.samples * 256:.3g} model "
                          f"evaluations per disturbance event and {args.samples * 64 / 2**20:.3g}"
                          f" MiB of samples; at most {MAX_SAMPLES:,} are accepted")
    if args.flow is not None and not (math.isfinite(args.flow) and args.flow > 0):
        raise OptionError("--flow must be a positive number (kg/h)")
    if args.until is not None and not math.isfinite(args.until):
        raise OptionError("--until must be a finite number")
    if not 0 <= args.seed < 2**31:
        raise OptionError("--seed must be a whole number from 0 to 2**31 - 1")
    OutputFolder(_COMMAND, args.out, FILES, inputs=[*model_inputs(args), args.trace]).check()


def _describe(window, time_unit: str, amount: str) -> str:
    start, stop = float(window.start), float(window.stop)
    if math.isnan(start):
        return "no diversion: the outlet content stays within the limits"
    end = "still out of limits at the end of the scan" if math.isinf(stop) else (
        f"stop {stop:.4g} {time_unit}")
    text = f"start {start:.4g} {time_unit}, {end}, {stop - start:.4g} {time_unit} long"
    if amount and math.isfinite(stop):
        text += f", {float(window.diverted_amount):.4g} {amount} diverted"
    return text


#: The widest scan spacing accepted, as a share of the RTD's spread (standard deviation).
_FINEST_SHARE = 0.25


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix divert`` with parsed `args`; returns the exit status."""
    from axialmix import _exits

    try:
        _check(args)
        lower, upper = _limits(args)
        spec = _disturbance_spec(args.disturbance) if args.disturbance is not None else None
        trace = _read_trace(args.trace) if args.trace is not None else None
        fitted, description = rtd_from_options(args)
        if trace is not None and trace[2] not in (None, fitted.time_unit):
            raise OptionError(f"{args.trace}: times are in {trace[2]}, the RTD in "
                              f"{fitted.time_unit}")
        if args.flow is not None:
            from fitting.data import seconds_per

            try:
                seconds = seconds_per(fitted.time_unit)
            except ValueError as error:
                raise OptionError(f"--flow: {error}") from None
    except (OptionError, OutputError) as error:
        return _exits.error_line(_COMMAND, str(error))
    out = OutputFolder(_COMMAND, args.out, FILES, inputs=[*model_inputs(args), args.trace])
    if args.out is not None:
        preload_plotting()  # matplotlib loads while the programs run

    import numpy as np

    from axialmix._files import json_text
    from axialmix.line import (
        Disturbance,
        conservative_diversion_window,
        diversion_window,
        rtd_moments,
    )

    programs = ExportedPrograms()  # compiled programs kept on disk for the next run
    unit = fitted.unit()
    time_unit, content_unit = fitted.time_unit, args.content_unit
    units = {"value_unit": content_unit, "time_unit": time_unit}
    if spec is not None:
        kind, values = spec
        if kind == "pulse":
            disturbance = Disturbance.pulse(values["amount"], values["at"], **units)
        else:
            make = {"step": Disturbance.step, "square": Disturbance.square,
                    "ramp": Disturbance.ramp}[kind]
            extra = () if kind == "step" else (values["duration"],)
            disturbance = make(values["magnitude"], *extra, values["start"], **units)
        first = values.get("start", values.get("at"))
        last = first + values.get("duration", 0.0)
        disturbance_record = {"kind": kind, **values}
    else:
        trace_times, contents, _ = trace
        disturbance = Disturbance.trace(trace_times, contents - args.target, **units)
        first, last = float(trace_times[0]), float(trace_times[-1])
        disturbance_record = {"kind": "trace", "file": args.trace, "samples": int(contents.size)}
    mean, variance = rtd_moments(unit, programs=programs)
    spread = math.sqrt(variance) if variance >= 0 else math.nan
    source = args.model if description.get("source") else "--model"
    until = args.until if args.until is not None else last + mean + 10 * spread
    if not (math.isfinite(mean) and math.isfinite(spread) and math.isfinite(until)):
        values = ", ".join(f"{name}={value:g}" for name, value in
                           zip(fitted.parameter_names, fitted.values.tolist(), strict=True))
        return _exits.error_line(_COMMAND, f"{source}: the RTD at {values} has no finite "
                                 f"mean residence time and spread ({mean:g}, {spread:g} "
                                 f"{time_unit}) to scan over")
    begin = min(0.0, first)
    if not until > begin:
        return _exits.error_line(_COMMAND, f"--until {until:g} must be after {begin:g}")
    # The outlet's narrowest excursion is about as wide as the RTD's spread (a pulse comes
    # out that wide): a scan spaced wider than a quarter of it can step over an excursion and
    # say "no diversion" (an --until of hours for a blender of a minute), so it is refused.
    spacing = (until - begin) / (args.points - 1)
    if spacing > _FINEST_SHARE * spread:
        needed = math.ceil((until - begin) / (_FINEST_SHARE * spread)) + 1
        return _exits.error_line(
            _COMMAND, f"--points {args.points}: the scan from {begin:g} to {until:g} "
            f"{time_unit} is spaced by {spacing:.3g} {time_unit}, more than a quarter of the "
            f"RTD's spread ({spread:.3g} {time_unit}): an excursion could pass between its "
            f"points; use --points {needed} or a shorter --until")
    times = np.linspace(begin, until, args.points)
    flow = 1.0 if args.flow is None else args.flow * seconds / _HOUR  # kg per time unit
    amount_unit = "kg" if args.flow is not None else ""
    limits = {"target": args.target, "lower": lower, "upper": upper}
    from axialmix.line import DiversionRefused, DiversionTooLarge

    try:
        nominal = diversion_window(unit, disturbance, times, flow=flow,
                                   content_unit=content_unit, amount_unit=amount_unit,
                                   programs=programs, **limits)
    except DiversionTooLarge as error:
        return _exits.error_line(_COMMAND, f"--points {args.points}: {error}")
    except ValueError as error:
        return _exits.error_line(_COMMAND, f"{source}: {error}")
    conservative = None
    scale = "linear"
    if fitted.free:
        values = np.asarray(fitted.free_values)
        covariance = np.asarray(fitted.covariance)
        scale = "log" if (values > 0).all() else "linear"
        if scale == "log":
            covariance = covariance / np.outer(values, values)  # delta method for log p
        try:
            conservative = conservative_diversion_window(
                fitted, values, covariance, disturbance, times, flow=flow,
                coverage=args.coverage, method=args.method, samples=args.samples,
                seed=args.seed, scale=scale, content_unit=content_unit,
                amount_unit=amount_unit, programs=programs, **limits)
        except DiversionTooLarge as error:
            return _exits.error_line(_COMMAND, f"--{error.option} "
                                     f"{getattr(args, error.option)}: {error}")
        except DiversionRefused as error:
            relative = np.sqrt(np.clip(np.diagonal(covariance), 0.0, None))
            widest = int(np.argmax(relative))
            kind = "relative " if scale == "log" else ""
            return _exits.error_line(
                _COMMAND, f"{source}: conservative window refused: {error} (widest: "
                f"{fitted.free[widest]} with a {kind}standard error of "
                f"{relative[widest]:.3g}); nominal window: {_describe(nominal, time_unit, '')}")
        except ValueError as error:
            return _exits.error_line(_COMMAND, f"{source}: {error}")
    numbers_out = [nominal.start, nominal.stop, nominal.diverted_amount]
    if any(math.isinf(float(x)) and float(x) < 0 for x in numbers_out):
        return _exits.error_line(_COMMAND, f"{source}: the window has no finite start")
    outlet = np.asarray(nominal.outlet)
    print(f"diversion for {description['model']} ({unit.model.name}), mean residence time "
          f"{mean:.4g} {time_unit}; limits [{lower:g}, {upper:g}] {content_unit}"
          f", outlet content from {outlet.min():.4g} to {outlet.max():.4g}")
    scan_end = float(nominal.times[-1])
    if scan_end > until * (1 + 1e-12):
        print(f"scan continued to {scan_end:.4g} {time_unit} (the outlet had not settled by "
              f"{until:g} {time_unit})")
    print("nominal: " + _describe(nominal, time_unit, amount_unit))
    if conservative is not None:
        failed = (f", {conservative.failed_samples} failed samples left out"
                  if conservative.failed_samples else "")
        print(f"conservative ({args.coverage:.0%}, {args.method} over {args.samples} samples "
              f"of the fit's covariance, {scale} scale{failed}): "
              + _describe(conservative, time_unit, amount_unit))
    elif not fitted.free:
        print("no conservative window: the RTD has no covariance (give a fit's JSON file)")
    if args.out is None:
        return _exits.OK
    record = {
        **description,
        "disturbance": disturbance_record,
        "content_unit": content_unit,
        "target": args.target,
        "lower": lower,
        "upper": upper,
        "flow": None if args.flow is None else {"value": args.flow, "unit": "kg/h"},
        "scan": {"start": begin, "end": scan_end, "points": int(nominal.times.shape[0]),
                 "requested_end": until},
        "nominal": nominal.to_dict(),
        "conservative": None,
    }
    if conservative is not None:
        summary = conservative.to_dict()
        record["conservative"] = {**summary["conservative"],
                                  **{k: summary[k] for k in ("coverage", "method", "samples",
                                                             "valid_samples", "failed_samples",
                                                             "scan_end", "diverting_fraction",
                                                             "sample_table") if k in summary},
                                  "scale": scale, "seed": args.seed}
    try:
        require_finite_record(record)
    except OptionError as error:
        return _exits.error_line(_COMMAND, f"{source}: {error}")
    from axialmix.line import plot_diversion

    window = conservative if conservative is not None else nominal
    png = render_png(lambda ax: plot_diversion(window, ax=ax), (7, 4))
    for path in out.commit({"divert.json": json_text(record), "divert.png": png}):
        print(f"wrote {path}")
    return _exits.OK
