"""One output convention for the sub-commands: ``--out DIR``, fixed file names, all or nothing.

A sub-command that writes results takes ``--out DIR`` and writes a fixed set of files there
(``funnel.json`` and ``funnel.png`` for ``axialmix funnel``, and so on); without ``--out`` it
prints its table and writes nothing. :class:`OutputFolder` is the contract:

* **Checked before any work** (:meth:`OutputFolder.check`): the folder can be created or
  written, is not a file, is not one of the inputs and holds none of them where a result
  would go, and does not hold another sub-command's results (each result set leaves a marker
  file ``.axialmix-<command>``; a folder marked by another command is refused, as is one
  holding ``axialmix fit`` results). Each failure is one line naming ``--out``.
* **Written as a whole** (:meth:`OutputFolder.commit`): every file is rendered in memory
  first (the PNG included), then all are written to hidden temporary files in the folder and
  renamed into place. Ctrl-C before the commit leaves nothing (the command line says
  "interrupted; nothing written"); during the commit it is held back until every file is in
  place, and the process then ends with status 130 saying the result set is complete.

The Ctrl-C guard of :mod:`fitting.cli` registers itself here (:func:`register_guard`) so that
a commit can hold it off; this module imports nothing heavy (the command line's ``--help``
stays free of JAX).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path

__all__ = ["MARKER_PREFIX", "OutputError", "OutputFolder", "add_out_option", "refuse_other_results",
           "preload_plotting", "register_guard", "render_png"]

#: Name prefix of the marker file a result set leaves in its folder (``.axialmix-funnel``).
MARKER_PREFIX = ".axialmix-"
#: Files that show a folder holds ``axialmix fit`` results (it writes no marker of this kind).
_FIT_FILES = ("summary.json", "summary.csv", "summary.jsonl", ".axialmix-fit.lock")

_GUARD = None


def register_guard(guard) -> None:
    """Let commits hold off the command line's Ctrl-C guard `guard` (``None``: none)."""
    global _GUARD
    _GUARD = guard


class OutputError(ValueError):
    """An ``--out`` that cannot take the results; the message is one line naming it."""


class OutputFolder:
    """The ``--out DIR`` of one sub-command: checked first, then written as a whole.

    **Arguments:**

    - `command`: the sub-command (``"funnel"``); names the marker file.
    - `path`: the folder, or ``None`` (nothing is written).
    - `names`: the file names the result set may hold (fixed per command).
    - `inputs`: the input files of the run (none of them may be overwritten).
    """

    def __init__(self, command: str, path: str | os.PathLike | None, names: Iterable[str],
                 inputs: Iterable[str | os.PathLike | None] = ()):
        self.command = command
        self.path = None if path is None else Path(path)
        self.names = tuple(names)
        self.inputs = tuple(Path(p) for p in inputs if p is not None)

    @property
    def marker(self) -> str:
        """The marker file's name."""
        return MARKER_PREFIX + self.command

    def check(self) -> None:
        """Raise :class:`OutputError` (one line) unless the folder can take the results."""
        out = self.path
        if out is None:
            return
        if out.exists():
            if not out.is_dir():
                raise OutputError(f"--out {out}: exists and is not a folder")
            if not os.access(out, os.W_OK | os.X_OK):
                raise OutputError(f"--out {out}: the folder is not writable")
            self._check_contents(out)
        else:
            parent = out.parent
            while not parent.exists():
                parent = parent.parent
            if not parent.is_dir():
                raise OutputError(f"--out {out}: cannot be created ({parent} is not a folder)")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise OutputError(f"--out {out}: cannot be created ({parent} is not writable)")
        resolved = out.resolve()
        for source in self.inputs:
            where = source.resolve()
            if where == resolved:
                raise OutputError(f"--out {out}: is the input {source}")
            if where.parent == resolved and where.name in (*self.names, self.marker):
                raise OutputError(f"--out {out}: would overwrite the input {source}")

    def _check_contents(self, out: Path) -> None:
        refuse_other_results(out, self.command)
        for entry in out.iterdir():
            name = entry.name
            if name in self.names and entry.is_dir():
                raise OutputError(f"--out {out}: {name} is a folder; it would be replaced")

    def commit(self, files: Mapping[str, bytes | str]) -> list[Path]:
        """Write the result set `files` (name -> content) into the folder, all or nothing.

        Ctrl-C during the commit is held back until every file is in place; the process
        then ends with status 130, saying the results are complete.

        **Returns:** the paths written (empty without a folder).
        """
        if self.path is None:
            return []
        unknown = set(files) - set(self.names)
        if unknown:
            raise ValueError(f"not a result file of axialmix {self.command}: {sorted(unknown)}")
        interrupted: list[int] = []
        with self._holding_interrupts(interrupted):
            written = self._write(files)
        if interrupted:
            _interrupted_after_commit(self.command, self.path)
        return written

    @contextlib.contextmanager
    def _holding_interrupts(self, interrupted: list[int]):
        guard = _GUARD
        in_main = threading.current_thread() is threading.main_thread()
        exiting = getattr(guard, "exiting", None)
        # Our handler first, then the guard's exit lock (a Ctrl-C its watcher thread sees
        # waits for the commit); released in the opposite order, so the guard's own handler
        # never runs while this thread holds its lock.
        previous = signal.signal(signal.SIGINT, lambda *_: interrupted.append(1)) \
            if in_main else None
        held = exiting.acquire() if exiting is not None else False
        try:
            yield
        finally:
            if guard is not None:
                guard.message = (f"axialmix {self.command}: interrupted; the results in "
                                 f"{self.path} are complete")
            if held:
                exiting.release()
            if previous is not None:
                signal.signal(signal.SIGINT, previous)

    def _write(self, files: Mapping[str, bytes | str]) -> list[Path]:
        out = self.path
        out.mkdir(parents=True, exist_ok=True)
        items = [*files.items(), (self.marker, f"axialmix {self.command}\n")]
        temporary: list[tuple[Path, Path]] = []
        from axialmix._files import default_mode

        mode = default_mode()
        try:
            for name, content in items:
                final = out / name
                staged = out / f".{name}.{os.getpid()}.tmp"
                data = content.encode() if isinstance(content, str) else bytes(content)
                handle = os.open(staged, os.O_CREAT | os.O_EXCL | os.O_WRONLY, mode)
                with os.fdopen(handle, "wb") as stream:
                    stream.write(data)
                    stream.flush()
                    os.fsync(stream.fileno())
                temporary.append((staged, final))
            for staged, final in temporary:
                os.replace(staged, final)
        except BaseException:
            for staged, _ in temporary:
                with contextlib.suppress(OSError):
                    staged.unlink()
            raise
        return [final for _, final in temporary if not final.name.startswith(MARKER_PREFIX)]


def refuse_other_results(out: Path, command: str) -> None:
    """Raise :class:`OutputError` if folder `out` holds the results of another sub-command
    than `command` (its marker file, or the files of ``axialmix fit``)."""
    for entry in out.iterdir():
        name = entry.name
        if name.startswith(MARKER_PREFIX) and not name.endswith(".tmp"):
            other = name[len(MARKER_PREFIX):].split(".")[0]
            if other not in (command, "fit"):
                raise OutputError(f"--out {out}: holds the results of axialmix {other}; "
                                  "choose another folder")
        if name in _FIT_FILES and command != "fit":
            raise OutputError(f"--out {out}: holds the results of axialmix fit; choose "
                              "another folder")


def _interrupted_after_commit(command: str, folder: Path) -> None:
    """Ctrl-C came during a commit: say the results are complete, end with status 130."""
    import sys

    with contextlib.suppress(OSError, ValueError):
        print(f"axialmix {command}: interrupted; the results in {folder} are complete",
              file=sys.stderr, flush=True)
        sys.stdout.flush()
    os._exit(130)


def add_out_option(parser, files: str, replaced: Iterable[str] = ()) -> None:
    """Add ``--out DIR`` (writing `files`, a phrase for the help) to an argparse `parser`, and
    a one-line refusal for each option of `replaced` (``--json``) that ``--out`` took over."""
    import argparse

    parser.add_argument("--out", metavar="DIR", default=None,
                        help=f"folder for the results: {files} (nothing is written without it)")

    class _Replaced(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            parser.error(f"{option_string} was replaced by --out DIR, which writes {files}")

    for option in replaced:
        parser.add_argument(option, action=_Replaced, help=argparse.SUPPRESS)


def _load_plotting() -> None:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure(figsize=(1, 1))
    try:
        figure.savefig(io.BytesIO(), format="png")  # fonts and the renderer loaded
    finally:
        plt.close(figure)


_PLOTTING: threading.Thread | None = None


def preload_plotting() -> None:
    """Import matplotlib (Agg) and draw an empty figure in a background thread, so that a
    plot asked for later (:func:`render_png`) finds them loaded: a command that will draw
    calls it first, and the import runs while the main thread waits on compiled programs
    (which release the interpreter). Once a process; a failure there is left for
    :func:`render_png` to meet."""
    global _PLOTTING
    if _PLOTTING is None:
        def load():
            with contextlib.suppress(Exception):
                _load_plotting()

        _PLOTTING = threading.Thread(target=load, name="preload-plotting", daemon=True)
        _PLOTTING.start()


def render_png(draw, size: tuple[float, float]) -> bytes:
    """Draw one plot with `draw(ax)` on a figure of `size` inches; returns the PNG bytes
    (matplotlib is imported here, only when a plot is asked for, unless
    :func:`preload_plotting` has begun)."""
    import io

    if _PLOTTING is not None:
        _PLOTTING.join()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, ax = plt.subplots(figsize=size)
    try:
        draw(ax)
        buffer = io.BytesIO()
        figure.savefig(buffer, format="png", dpi=100)
    finally:
        plt.close(figure)
    return buffer.getvalue()
