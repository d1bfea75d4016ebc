"""One atomic file writer for every output of axialmix (JSON, CSV, PNG, text).

A file is written to a temporary file in the destination folder and moved into place with
``os.replace``, so a reader, a crash or Ctrl-C never leaves a half-written file. The file
gets the mode an ordinary ``open(path, "w")`` would give (0666 less the umask), whoever
writes it.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

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
    folder = path.parent if str(path.parent) else Path(".")
    handle, temporary = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    try:
        mode = "wb" if binary else "w"
        extra = {} if binary else {"newline": "", "encoding": "utf-8"}
        with os.fdopen(handle, mode, **extra) as stream:
            write(stream)
        os.chmod(temporary, default_mode())  # mkstemp makes the file private
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


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
