"""One atomic file writer for every output of axialmix (JSON, CSV, PNG, text).

A file is written to a temporary file in the destination folder and moved into place with
``os.replace``, so a reader, a crash or Ctrl-C never leaves a half-written file. The file
gets the mode an ordinary ``open(path, "w")`` would give (0666 less the umask), whoever
writes it.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

#: Opened in binary mode where the system has one (Windows).
_BINARY = getattr(os, "O_BINARY", 0)

__all__ = ["csv_text", "default_mode", "json_text", "write_atomic", "write_csv", "write_json",
           "write_text"]


def default_mode() -> int:
    """The mode (permission bits) a new file gets under the process's umask."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def write_atomic(path: str | Path, write: Callable[[Any], None], binary: bool = False) -> Path:
    """Write a file through a temporary file in the same folder and an atomic rename.

    **Arguments:**

    - `path`: the destination file; its folder must exist.
    - `write`: called with the open temporary file (text, newline-neutral, or binary).
    - `binary`: open the temporary file in binary mode.

    **Returns:** the destination path.
    """
    path = Path(path)
    handle, temporary = _temporary_file(path)
    try:
        mode = "wb" if binary else "w"
        extra = {} if binary else {"newline": "", "encoding": "utf-8"}
        with os.fdopen(handle, mode, **extra) as stream:
            write(stream)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


_NAMES = itertools.count()


def _temporary_file(path: Path) -> tuple[int, str]:
    """A new file ``.<name>.<process>-<n>.tmp`` beside `path`, opened for writing (created
    exclusively, so no other writer's file is taken; with the umask's mode, as ``open``
    gives), and its name. One open call (``tempfile.mkstemp`` costs three times as much,
    and a ``chmod`` after it): a study writes a file per curve."""
    folder = path.parent if str(path.parent) else Path(".")
    while True:
        name = os.path.join(folder, f".{path.name}.{os.getpid()}-{next(_NAMES)}.tmp")
        try:
            return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _BINARY, 0o666), name
        except FileExistsError:  # left by an earlier process of the same id: the next name
            continue


def write_text(path: str | Path, text: str) -> Path:
    """Write `text` to `path` atomically (see :func:`write_atomic`)."""
    return write_atomic(path, lambda stream: stream.write(text))


def json_text(data: Mapping[str, Any]) -> str:
    """`data` as the text of every JSON result file: indented, no NaN or infinity (JSON has
    none; raises ValueError)."""
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


def csv_text(header: Sequence[str] | None, rows: Sequence[Sequence[Any]]) -> str:
    """A CSV table with one header line (none when `header` is None), as text."""
    stream = io.StringIO(newline="")
    writer = csv.writer(stream)
    if header is not None:
        writer.writerow(header)
    writer.writerows(rows)
    return stream.getvalue()


def write_json(path: str | Path, data: Mapping[str, Any]) -> Path:
    """Write `data` as indented JSON (no NaN or infinity: JSON has none), atomically."""
    return write_text(path, json_text(data))


def write_csv(path: str | Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> Path:
    """Write a CSV table with one header line, atomically (see :func:`write_atomic`)."""
    return write_text(path, csv_text(header, rows))
