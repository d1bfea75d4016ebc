"""Deprecated: the ``fit`` sub-command moved to :mod:`fitting.cli.fit` (kept one release)."""

from fitting.cli.fit import (
    GRID_HELD,
    SOURCE_GRID_MAX,
    SOURCE_GRID_STEP,
    InputError,
    add_fit_parser,
    add_parser,
    run,
)

#: Deprecated name of :func:`fitting.cli.fit.run`.
run_fit = run
#: Exit statuses, now in :mod:`axialmix._exits`.
USAGE_ERROR, INTERRUPTED = 2, 130

__all__ = ["GRID_HELD", "SOURCE_GRID_MAX", "SOURCE_GRID_STEP", "InputError", "add_fit_parser",
           "add_parser", "run", "run_fit"]
