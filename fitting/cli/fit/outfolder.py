"""The ``--out`` folder of ``axialmix fit``: checked before anything is written, locked while
a run writes into it (:data:`LOCK_NAME`, see :mod:`fitting.cli.fit`), and cleared of the
temporary files of writes that Ctrl-C cut short.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from fitting.cli._outputs import OutputError, refuse_other_results
from fitting.cli.fit.options import InputError

#: The lock file that marks an output folder as being written.
LOCK_NAME = ".axialmix-fit.lock"


def check_out(out: Path) -> None:
    """Refuse an --out that cannot be created or written, creating nothing."""
    if out.exists():
        if not out.is_dir():
            raise InputError(f"{out}: --out exists and is not a folder")
        if not os.access(out, os.W_OK | os.X_OK):
            raise InputError(f"{out}: --out is not writable")
        try:
            refuse_other_results(out, "fit")
        except OutputError as error:
            raise InputError(str(error)) from None
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{out}: --out cannot be created ({parent} is not a folder)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{out}: --out cannot be created ({parent} is not writable)")


#: The tables a run writes into its --out folder, which a later run would read as curves.
TABLES = ("summary.csv", "refused.csv")


def check_out_apart(out: Path, inputs) -> None:
    """Refuse an --out that is an input folder (its tables would be read as curves by the
    next run on that folder) or that holds an input file a table of the run would replace."""
    where = out.resolve()
    for item in inputs:
        path = Path(item)
        if path.is_dir() and path.resolve() == where:
            raise InputError(f"{out}: --out is the input folder {item}; its summary.csv would "
                             "be read as a curve by the next run: choose another folder")
        if path.is_file() and path.resolve().parent == where and path.name in TABLES:
            raise InputError(f"{out}: --out would overwrite the input {item}")


class FolderLock:
    """The lock file of an output folder (see :mod:`fitting.cli.fit`)."""

    def __init__(self, folder: Path):
        self.path = folder / LOCK_NAME
        self.held = False

    def acquire(self) -> None:
        for _ in range(2):
            try:
                handle = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self._owner()
                if owner is not None and _alive(owner):
                    raise InputError(f"{self.path.parent}: --out is being written by another "
                                     f"axialmix fit (process {owner}); wait or choose another "
                                     "folder") from None
                self.path.unlink(missing_ok=True)  # left by a process that no longer runs
                continue
            with os.fdopen(handle, "w") as stream:
                stream.write(f"{os.getpid()}\n")
            self.held = True
            return
        raise InputError(f"{self.path.parent}: --out lock file cannot be taken")

    def _owner(self) -> int | None:
        try:
            return int(self.path.read_text().strip())
        except (OSError, ValueError):
            return None

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_temporary_files(folder: Path) -> None:
    """Remove the temporary files of :func:`axialmix._files.write_atomic` from `folder`
    (``.<name>.<random>.tmp``): after Ctrl-C they would never be completed."""
    for path in folder.glob(".*.tmp"):
        with contextlib.suppress(OSError):
            path.unlink()
