"""Ctrl-C during ``axialmix fit``: the work runs on a worker thread while the main thread
waits, catches SIGINT at once, saves what is finished and ends the process with status 130.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

from axialmix._exits import INTERRUPTED


class Supervised:
    """Work on a worker thread while the main thread waits for it: Ctrl-C (:meth:`_interrupt`,
    installed by the subclass) sets `stop`, and the main thread then calls ``_leave``, which
    saves what is finished and ends the process. Subclasses set `stop`, `failure`, `status`
    and define ``_work`` and ``_leave``."""

    stop: threading.Event
    failure: BaseException | None
    status: int

    def _interrupt(self, signum, frame) -> None:
        self.stop.set()

    def _supervise(self, name: str) -> None:
        """Run ``_work`` on a thread named `name` and wait for it, leaving on Ctrl-C."""
        worker = threading.Thread(target=self._work, name=name, daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
            if self.stop.is_set():
                self._leave()

    def _outcome(self) -> int:
        """The exit status of the finished work (its exception raised again, if any)."""
        if self.failure is not None:
            raise self.failure
        return self.status


def exit_now(message: str) -> None:
    """Print `message` on standard error and end the process with status 130 at once.

    ``os._exit`` skips interpreter teardown, which could wait for or crash on compiled JAX
    work still running in the worker thread. Output is flushed first; a closed stream does
    not stop the exit.
    """
    with contextlib.suppress(OSError, ValueError):
        print(message, file=sys.stderr, flush=True)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(INTERRUPTED)
