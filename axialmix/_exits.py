"""One exit-status policy for every ``axialmix`` sub-command.

* ``0``: done.
* ``2``: bad input or bad options (one line on standard error naming file, row, option or
  network file); nothing was written.
* ``3``: a study finished with some curves refused (each listed with its reason in the
  study's ``refused.csv`` and ``summary.json``); the other curves' results are written.
* ``130``: interrupted (Ctrl-C, 128 + SIGINT); results finished before the interruption are
  kept, and no partial file is left.
* ``1``: anything else (a bug: the traceback is shown).
"""

from __future__ import annotations

import sys

__all__ = ["BAD_INPUT", "FAILED", "INTERRUPTED", "OK", "REFUSED", "error_line"]

OK = 0
FAILED = 1
BAD_INPUT = 2
REFUSED = 3
INTERRUPTED = 130


def error_line(command: str, message: str) -> int:
    """Print ``axialmix COMMAND: error: MESSAGE`` as one line on standard error.

    **Arguments:**

    - `command`: the sub-command name (``"fit"``, ``"simulate"``, ...).
    - `message`: the problem; newlines are folded so the message stays one line.

    **Returns:** :data:`BAD_INPUT`, the status to exit with.
    """
    text = " ".join(str(message).split())
    print(f"axialmix {command}: error: {text}", file=sys.stderr, flush=True)
    return BAD_INPUT
