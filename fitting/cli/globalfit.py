"""``axialmix global-fit``: fit the curves of a study jointly, with factor laws and shared values.

``axialmix global-fit STUDY.csv --curve-column run --law "log(peclet)=speed+flow"`` reads a
long-format table (one row per sample: a curve-id column, time, the raw signal, and factor
columns constant within a curve), fits every curve alone, then all curves jointly with the
parameters given by the laws or shared (``--shared``) and the rest per curve, and prints the
laws' coefficients with standard errors and 95 % intervals beside those of the two-stage
analysis (fit one by one, then regress). ``--out DIR`` writes the result as
``DIR/global-fit.json`` and one row per curve as ``DIR/curves.csv``, all or nothing. Exit
status: 0 done, 1 the joint fit did not converge, 2 bad input (one line,
nothing written).
"""

from __future__ import annotations

import argparse
import math
import re

from fitting.cli._outputs import OutputError, OutputFolder, add_out_option

__all__ = ["add_parser", "parse_law", "run"]

_COMMAND = "global-fit"
#: The result set of ``axialmix global-fit --out DIR``.
FILES = ("global-fit.json", "curves.csv")
_LAW = re.compile(r"^\s*(?:(log|ln)\s*\(\s*(\w+)\s*\)|(\w+))\s*=\s*(.+?)\s*$")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``global-fit`` parser on `subparsers`; returns it."""
    parser = subparsers.add_parser(
        _COMMAND,
        help="joint fit of a study: factor laws, shared parameters",
        description=__doc__.split("\n\n")[1].replace("``", ""),
    )
    parser.add_argument("table", help="long-format CSV: curve id, time, signal, factor columns")
    parser.add_argument("--curve-column", required=True, help="the column naming each curve")
    parser.add_argument("--time-column", default=None,
                        help="the time column (recognised from the header as axialmix fit "
                             "does; a unit in the header such as 'time_min' or 't [min]' sets "
                             "the time unit, else seconds)")
    parser.add_argument("--value-column", default=None,
                        help="the raw tracer signal column (recognised from the header by "
                             "default)")
    parser.add_argument("--decimal", choices=("auto", ".", ","), default="auto",
                        help="decimal mark of the table (default: detected)")
    parser.add_argument("--law", action="append", default=[], metavar="LAW",
                        help="a factor law, e.g. 'log(peclet)=speed+flow' (ln Pe linear in "
                             "the factor columns) or 'tau=flow' (tau itself linear); a term "
                             "'speed:flow' is a product; repeat for several parameters")
    parser.add_argument("--shared", default="",
                        help="parameters with one value for all curves, comma-separated")
    parser.add_argument("--model", default="adm", help="the residence-time model (default adm)")
    parser.add_argument("--free", default="",
                        help="measurement parameters fitted per curve besides the amplitude: "
                             "dead_time, baseline (comma-separated)")
    parser.add_argument("--weights", choices=("combined", "per-curve", "equal"),
                        default="combined",
                        help="weigh each sample by its curve's additive plus proportional error "
                             "model as axialmix fit estimates it (combined, the default), each "
                             "curve by its own noise level (per-curve), or all equally")
    parser.add_argument("--length", type=float, default=None, metavar="METRES",
                        help="blender length (m): each curve's velocity v and axial dispersion "
                        "D_z (SI units) with standard errors and 95 %% intervals from the "
                        "joint covariance (there is no default length)")
    add_out_option(parser, "global-fit.json and curves.csv (one row per curve)",
                   replaced=("--json", "--csv"))
    return parser


def _names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def parse_law(text: str):
    """A :class:`~fitting.study.FactorLaw` from ``'log(peclet)=speed+flow'`` or ``'tau=flow'``.

    **Arguments:** `text`: ``[log(]PARAMETER[)]=TERM+TERM...``, a term a factor column or a
    product ``a:b``.

    **Returns:** the law; a one-line ``ValueError`` for text of another shape.
    """
    from fitting.study import FactorLaw

    match = _LAW.match(text)
    if match is None:
        raise ValueError(f"--law {text!r}: write it as 'log(peclet)=speed+flow' or 'tau=flow'")
    transform, logged, plain, right = match.groups()
    terms = [term.strip() for term in right.split("+")]
    if any(not re.fullmatch(r"\w+(:\w+)*", term) for term in terms):
        raise ValueError(f"--law {text!r}: terms are factor columns joined by '+' (a product "
                         "as a:b)")
    return FactorLaw(logged or plain, tuple(terms), "log" if transform else "identity")


def _read_study(path, curve_column: str, time_column: str | None, value_column: str | None,
                factor_columns: list[str], decimal: str = "auto"):
    """Curves (in order of first appearance) and their numeric factor levels from a long
    table, read as ``axialmix fit --curve-column`` reads it
    (:func:`fitting.study.read_long_csv`)."""
    from axialmix._csv import DataError
    from fitting.study import read_long_csv

    study = read_long_csv(path, curve_column, time_column=time_column,
                          value_column=value_column, factors=factor_columns, decimal=decimal,
                          factors_option="--law", leave_out=False)
    if study.refused:  # one law over every curve: a curve left out would change the fit
        raise ValueError(study.refused[0][1])
    factors = {}
    for j, name in enumerate(study.factors):
        column = []
        for curve, row in zip(study.curves, study.levels, strict=True):
            try:
                column.append(float(row[j]))
            except ValueError:
                problem = (f"factor {name!r} of curve {curve.name!r} is not a number "
                           f"({row[j]!r}): factor laws take numeric factors")
                raise DataError(path, problem) from None
        factors[name] = column
    return list(study.curves), factors


#: Per-curve physical quantities shown in the table and files (the others repeat parameters).
_PHYSICAL = ("velocity_m_per_s", "dispersion_m2_per_s")


def _table(result, physical) -> dict[str, list]:
    """The per-curve columns of the result, with each curve's v and D_z when a length was
    given (``velocity_m_per_s``, ``..._stderr``, ``..._low``, ``..._high``)."""
    table = result.table()
    for key in _PHYSICAL:
        if not physical or key not in physical[0]:
            continue
        entries = [quantities[key] for quantities in physical]
        if all(e.value is None for e in entries):  # no --length: the hook gives no v, D_z
            continue
        table[key] = [e.value for e in entries]
        table[f"{key}_stderr"] = [e.stderr for e in entries]
        table[f"{key}_low"] = [None if e.ci95 is None else e.ci95[0] for e in entries]
        table[f"{key}_high"] = [None if e.ci95 is None else e.ci95[1] for e in entries]
    return table


def _cell(value, form: str) -> str:
    width = int(form.split(".")[0])
    return "-".rjust(width) if value is None else format(value, form)


def _to_dict(result, two_stage, physical) -> dict:
    """The JSON form of a global fit and its two-stage comparison."""

    def law_entry(estimate) -> dict:
        law = estimate.law
        return {"parameter": law.parameter, "transform": law.transform,
                "terms": list(law.terms), "law": law.describe(), "method": estimate.method,
                "dof": estimate.dof,
                "coefficients": [{"name": n, "value": v, "stderr": e, "ci95": list(c),
                                  "unit": result.units.get(n, "")}
                                 for n, v, e, c in zip(estimate.names, estimate.values,
                                                       estimate.stderr, estimate.ci95,
                                                       strict=True)]}

    table = _table(result, physical)
    curves = [{key: column[i] for key, column in table.items()}
              for i in range(len(result.curve_names))]
    spec = result.spec
    return {
        "model": spec.model, "inlet": spec.inlet, "per_curve": list(spec.per_curve),
        "shared": [{"name": n, "value": result.values[n], "stderr": result.stderr[n],
                    "ci95": list(result.ci95[n]), "unit": result.units.get(n, "")}
                   for n in spec.shared],
        "laws": [law_entry(e) for e in result.laws],
        "two_stage": [law_entry(e) for e in two_stage],
        "units": {n: result.units.get(n, "") for n in spec.fitted},
        "curves": curves,
        "n_curves": len(result.curve_names), "n_points": result.n_points, "dof": result.dof,
        "sigma": result.sigma, "sse": result.sse, "weights": result.weighting,
        "converged": result.converged, "status": int(result.status), "message": result.message,
        "steps": result.n_steps, "wall_time_s": result.wall_time,
    }


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix global-fit`` with parsed `args`; returns the exit status."""
    from axialmix import _exits
    from axialmix._csv import DataError
    from axialmix._files import csv_text, json_text

    out = OutputFolder(_COMMAND, args.out, FILES, inputs=[args.table])
    try:
        out.check()
    except OutputError as error:
        return _exits.error_line(_COMMAND, str(error))
    if args.length is not None and not (math.isfinite(args.length) and args.length > 0):
        return _exits.error_line(_COMMAND, f"--length must be a positive number of metres, "
                                 f"got {args.length:g}")
    try:
        from fitting.study import GlobalModel, global_fit, two_stage_law

        laws = tuple(parse_law(text) for text in args.law)
        spec = GlobalModel(args.model, laws=laws, shared=tuple(_names(args.shared)),
                           free=tuple(_names(args.free)))
    except ValueError as error:
        return _exits.error_line(_COMMAND, str(error))
    try:
        curves, factors = _read_study(args.table, args.curve_column, args.time_column,
                                      args.value_column, list(spec.factors), args.decimal)
        result = global_fit(spec, curves, factors, weights=args.weights)
        two_stage = []
        for law in spec.laws:
            try:
                two_stage.append(two_stage_law(law, result.first, factors))
            except ValueError as error:  # too few curves for the regression: say so
                print(f"two-stage regression of {law.parameter}: {error}")
    except DataError as error:
        return _exits.error_line(_COMMAND, error.compact())
    except ValueError as error:
        return _exits.error_line(_COMMAND, f"{args.table}: {error}")
    from fitting.data import first_non_finite
    from fitting.study.global_fit import curve_physical_quantities

    physical = curve_physical_quantities(result, args.length)
    record = _to_dict(result, two_stage, physical)
    where = first_non_finite(record)
    if where is not None:
        return _exits.error_line(_COMMAND, f"{args.table}: the {spec.model} fit with "
                                 f"{' and '.join(args.law) or 'no law'}: the result {where} is "
                                 "not a finite number; nothing written")
    print(result.report())
    for estimate in two_stage:
        print(estimate.report(result.units))
    table = _table(result, physical)
    names = list(spec.fitted)
    labels = [f"{n} ({result.units[n]})" if result.units.get(n) else n for n in names]
    print(f"\n{'curve':<12} " + " ".join(f"{label:>16} {'se':>9}" for label in labels))
    for i, curve in enumerate(table["curve"]):
        print(f"{curve:<12} " + " ".join(f"{table[n][i]:>16.5g} {table[n + '_stderr'][i]:>9.3g}"
                                         for n in names))
    if "velocity_m_per_s" in table:
        print(f"\n{'curve':<12} {'v (m/s)':>16} {'se':>9} {'D_z (m^2/s)':>16} {'se':>9}")
        for i, curve in enumerate(table["curve"]):
            print(f"{curve:<12} " + " ".join(
                f"{_cell(table[k][i], '16.5g')} {_cell(table[k + '_stderr'][i], '9.3g')}"
                for k in _PHYSICAL))
    for path in out.commit({"global-fit.json": json_text(record),
                            "curves.csv": csv_text(list(table),
                                                   list(zip(*table.values(), strict=True)))}):
        print(f"wrote {path}")
    return _exits.OK if result.converged else _exits.FAILED
