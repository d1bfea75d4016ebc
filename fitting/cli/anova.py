"""``axialmix anova``: analysis of variance of one column of a study table over its factors.

``axialmix anova TABLE.csv --response NAME --factors A,B[,C] --interactions N --json OUT``
reads a table with one row per run (``#`` comment lines allowed, a header row naming the
columns), prints the ANOVA table and writes it as JSON ``{"sources": [{"source", "df", "ss",
"ms", "F", "p"}, ..., {"source": "error", ...}], ...}``; interaction sources are named like
``A:B``. Unbalanced designs use type II sums of squares unless ``--ss-type`` says otherwise,
and the output says which. Exit status: 0 done, 2 bad input (one line, nothing written).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_parser", "run"]

_COMMAND = "anova"


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
    parser.add_argument("--json", metavar="OUT", help="write the table as JSON to OUT")
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
    from axialmix._files import write_json
    from fitting.study import anova, read_study_table

    factors = _names(args.factors)
    if not factors:
        return _exits.error_line(_COMMAND, "--factors names no column")
    if args.json is not None:
        folder = Path(args.json).resolve().parent
        if not folder.is_dir():
            return _exits.error_line(_COMMAND, f"--json: folder {folder} does not exist")
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
    if args.json is not None:
        write_json(args.json, record)
    return _exits.OK
