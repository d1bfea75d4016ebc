"""The ``axialmix`` command line: one entry point, one module per sub-command.

Each sub-command lives in its own module of this package, exposing ``add_parser(subparsers)``
(registers its argparse parser) and ``run(args) -> int`` (runs it, returns the exit status
of :mod:`axialmix._exits`). Only the chosen sub-command's module is imported, so
``axialmix --help`` starts without JAX, and ``axialmix fit`` does not load the simulator.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from types import ModuleType

__all__ = ["COMMANDS", "build_parser", "main"]

#: Sub-command name -> (module, one-line help shown by ``axialmix --help``).
COMMANDS = {
    "simulate": ("fitting.cli.simulate",
                 "simulate particles through a continuous blender (particle tracer)"),
    "fit": ("fitting.cli.fit",
            "fit a residence-time model to RTD curves (CSV files or folders)"),
    "anova": ("fitting.cli.anova",
              "analysis of variance of a response over process factors (a study table)"),
}


class _UsageError(Exception):
    """A command-line usage error, already reported on one line."""


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line (``axialmix fit: error: ...``), exit status 2.

    ``--help`` still prints the full usage. Sub-command parsers inherit the class.
    """

    def error(self, message: str):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise _UsageError(message)


def _command(name: str) -> ModuleType:
    """The module of sub-command `name` (imported now, not before)."""
    return importlib.import_module(COMMANDS[name][0])


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``axialmix`` parser; the full parser of `command` (all of them when ``None``).

    **Arguments:**

    - `command`: the sub-command to build in full; the others are listed with their help
      line only (building them would import their modules).

    **Returns:** the parser.
    """
    parser = _Parser(
        prog="axialmix",
        description="Residence-time models of continuous powder mixers.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="{" + ",".join(COMMANDS)
                                + "}")
    for name, (_, help_line) in COMMANDS.items():
        if command is None or name == command:
            _command(name).add_parser(sub)
        else:
            sub.add_parser(name, help=help_line, add_help=False)
    return parser


def _chosen(argv: list[str]) -> str | None:
    """The sub-command named in `argv` (the first argument that is one), or ``None``."""
    for item in argv:
        if item in COMMANDS:
            return item
        if not item.startswith("-"):
            return None
    return None


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _chosen(argv)
    parser = build_parser(command) if command is not None else _listing_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError:
        return 2
    return int(_command(args.command).run(args) or 0)


def _listing_parser() -> argparse.ArgumentParser:
    """The parser without any sub-command built: for ``axialmix --help`` and bad commands."""
    parser = _Parser(prog="axialmix",
                     description="Residence-time models of continuous powder mixers.")
    sub = parser.add_subparsers(dest="command", required=True,
                                metavar="{" + ",".join(COMMANDS) + "}")
    for name, (_, help_line) in COMMANDS.items():
        sub.add_parser(name, help=help_line, add_help=False)
    return parser


if __name__ == "__main__":
    sys.exit(main())
