"""The ``axialmix`` command line: one entry point, one sub-command per job."""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    args = parser.parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
