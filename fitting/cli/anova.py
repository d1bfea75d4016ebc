"""``axialmix anova``: analysis of variance of one column of a study table over its factors.

``axialmix anova TABLE.csv --response NAME --factors A,B[,C] --interactions N --out DIR``
reads a table with one row per run (``#`` comment lines allowed, a header row naming the
columns) and prints the ANOVA table; ``--out DIR`` writes it as ``DIR/anova.json``
``{"sources": [{"source", "df", "ss", "ms", "F", "p"}, ..., {"source": "error", ...}], ...}``
and ``DIR/anova.csv`` (one row per source), all or nothing; interaction sources are named like
``A:B``. Unbalanced designs use type II sums of squares unless ``--ss-type`` says otherwise,
and the output says which. Exit status: 0 done, 2 bad input (one line, nothing written).
"""

from __future__ import annotations

import argparse

from fitting.cli._outputs import OutputError, OutputFolder, add_out_option

__all__ = ["add_parser", "run"]

_COMMAND = "anova"
#: The result set of ``axialmix anova --out DIR``.
FILES = ("anova.json", "anova.csv")


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``anova`` parser on `subparsers`; returns it."""
    parser = subparsers.add_parser(
        _COMMAND,
        help="analysis of variance of a response over process factors (a study table)",
        description=__doc__.split("\n\n")[1].replace("``", ""),
    )
    parser.add_argument("table", help="CSV table, one row per run, header naming the columns")
    parser.add_argument("--response", required=True, help="the column to analyse")
    parser.add_argument("--factors", required=True,
                        help="factor columns, comma-separated (e.g. angle,rpm,cohesion)")
    parser.add_argument("--interactions", type=int, default=1,
                        help="highest interaction order: 1 main effects only (default), "
                             "2 adds two-way interactions, ...")
    parser.add_argument("--numeric", default="",
                        help="factors to treat as a linear trend (1 degree of freedom) rather "
                             "than as categories, comma-separated")
    parser.add_argument("--ss-type", type=int, choices=(1, 2, 3), default=None,
                        help="sums of squares for unbalanced designs (default 2; balanced "
                             "designs give the same table with every type)")
    parser.add_argument("--log", action="store_true",
                        help="analyse the natural logarithm of the response (positive values; "
                             "for responses such as Pe whose factor effects multiply)")
    add_out_option(parser, "anova.json and the table anova.csv", replaced=("--json",))
    return parser


def _logarithm(table: dict[str, list[str]], response: str) -> str:
    """Add ``ln(response)`` to `table` (text cells, as read); its name. A cell that is not a
    positive number is a one-line ``ValueError`` naming the run."""
    import math

    logged = []
    for number, cell in enumerate(table[response], start=1):
        try:
            value = float(cell)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"--log: the response {response!r} of run {number} is "
                             f"{cell!r}, not a positive number")
        logged.append(repr(math.log(value)))
    name = f"ln({response})"
    table[name] = logged
    return name


#: Largest and smallest non-zero magnitude of a response: beyond, its sums of squares
#: over- or underflow float64.
_RESPONSE_RANGE = (1e-150, 1e150)


def _check_response(table: dict[str, list[str]], response: str) -> None:
    """A one-line ``ValueError`` naming the run whose response's square would over- or
    underflow (the other cell problems are the analysis's to report)."""
    import math

    from axialmix._csv import parse_number

    low, high = _RESPONSE_RANGE
    for number, cell in enumerate(table.get(response, []), start=1):
        try:
            value = parse_number(cell)
        except ValueError:
            continue
        if math.isfinite(value) and value != 0 and not low <= abs(value) <= high:
            raise ValueError(f"the response {response!r} of run {number} is {value:g}, "
                             f"outside {low:g} to {high:g} in size: its sums of squares would "
                             "over- or underflow; rescale the column")


def _names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix anova`` with parsed `args`; returns the exit status."""
    from axialmix import _exits
    from axialmix._csv import DataError
    from axialmix._files import csv_text, json_text
    from fitting.study import anova, read_study_table

    factors = _names(args.factors)
    if not factors:
        return _exits.error_line(_COMMAND, "--factors names no column")
    out = OutputFolder(_COMMAND, args.out, FILES, inputs=[args.table])
    try:
        out.check()
    except OutputError as error:
        return _exits.error_line(_COMMAND, str(error))
    try:
        table = read_study_table(args.table, [args.response, *factors])
        _check_response(table, args.response)
        response = _logarithm(table, args.response) if args.log else args.response
        result = anova(table, response, factors, interactions=args.interactions,
                       numeric=_names(args.numeric), ss_type=args.ss_type)
    except DataError as error:
        return _exits.error_line(_COMMAND, error.compact())
    except ValueError as error:
        return _exits.error_line(_COMMAND, f"{args.table}: {error}")
    from fitting.data import first_non_finite

    record = result.to_dict()
    where = first_non_finite(record)
    if where is not None:
        return _exits.error_line(_COMMAND, f"{args.table}: the result {where} is not a finite "
                                 "number; nothing written")
    print(result.report())
    columns = ("source", "df", "ss", "ms", "F", "p")
    rows = [[row.get(c) for c in columns] for row in record["sources"]]
    for path in out.commit({"anova.json": json_text(record),
                            "anova.csv": csv_text(columns, rows)}):
        print(f"wrote {path}")
    return _exits.OK
