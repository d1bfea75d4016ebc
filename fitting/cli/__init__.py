"""The ``axialmix`` command line: one entry point, one sub-command per job."""

from __future__ import annotations

import argparse
import sys


class _UsageError(Exception):
    """A command-line usage error, already reported on one line."""


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line (``axialmix fit: error: ...``), exit status 2.

    ``--help`` still prints the full usage. Sub-command parsers inherit the class.
    """

    def error(self, message: str):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise _UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    """The ``axialmix`` parser with its ``simulate`` and ``fit`` sub-commands."""
    parser = _Parser(
        prog="axialmix",
        description="Residence-time models of continuous powder mixers.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    try:
        from axialmix.particles.cli import add_simulate_parser
    except ImportError:  # the simulator is optional while it is being built
        add_simulate_parser = None
    if add_simulate_parser is not None:
        add_simulate_parser(sub)
    try:
        from fitting.fitcli import add_fit_parser
    except ImportError:
        add_fit_parser = None
    if add_fit_parser is not None:
        add_fit_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError:
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
