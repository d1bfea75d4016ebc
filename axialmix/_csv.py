"""One reader for the small numeric CSV tables axialmix reads (RTD curves, trajectories).

A table file is text (UTF-8, with or without a byte-order mark) with optional ``#`` comment
lines and blank lines (a row of separators alone, as spreadsheets save empty rows, is
blank), an optional header row of column names that may carry units (``t [min]``,
``time (s)``, ``x/mm``, ``time_min``), and data rows. Cells are separated by ``,``, ``;`` or
tabs (detected from the first row, or named by a first line ``sep=;`` as spreadsheets write
it), or by runs of spaces when the first row has none of these. Decimal commas (``0,25``)
are read with ``decimal=","`` (then ``,`` cannot separate cells) or detected with
``decimal="auto"``. Rows are numbered as lines of the file
(first line = row 1), as a spreadsheet shows them.

The body is streamed row by row, so a file of millions of rows is read in memory
proportional to the numbers kept (8 bytes per cell), and a cell of any length is accepted.
A body of plain numbers (digits, ``.``, exponents and the delimiter only: no spaces, quotes,
comments or blank lines; decimal points) is read in blocks of :data:`PLAIN_BLOCK` bytes by
NumPy's compiled reader instead, to the same numbers (both round correctly) 15 times faster;
any block that is not that plain, or any problem, is read row by row, which names it.
Every problem is a :class:`DataError` with one line ``"<file>, row <r>: <problem>"``.
"""

from __future__ import annotations

import csv
import io
import math
import re
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Column", "DataError", "Table", "detect_delimiter", "read_table", "split_name_unit"]

#: Delimiters tried, in order, on the first row; ``None`` means runs of whitespace.
DELIMITERS = (",", ";", "\t")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
_UNIT_BRACKETS = re.compile(r"^(?P<name>.*?)\s*(?:\((?P<p>[^)]*)\)|\[(?P<b>[^\]]*)\])\s*$")


class DataError(ValueError):
    """A table file that cannot be used; ``str()`` is one line naming file, row and problem.

    **Arguments:**

    - `path`: the file.
    - `problem`: what is wrong, one line.
    - `row`: the line number in the file (1 = first line), or ``None`` for the whole file.
    """

    def __init__(self, path: str | Path, problem: str, row: int | None = None):
        self.path, self.problem, self.row = str(path), " ".join(str(problem).split()), row
        where = self.path if row is None else f"{self.path}, row {row}"
        super().__init__(f"{where}: {self.problem}")

    def compact(self) -> str:
        """The message as ``"<file>:<row>: <problem>"`` (compiler style, for command lines)."""
        where = self.path if self.row is None else f"{self.path}:{self.row}"
        return f"{where}: {self.problem}"


@dataclass(frozen=True)
class Column:
    """One column of a table: its position, header text, lower-case name and unit.

    - `index`: 0-based position in a row.
    - `label`: the header cell as written (``"column 3"`` without a header).
    - `name`: lower-case name without the unit (``"t"`` for ``"t [min]"``).
    - `unit`: the unit as written (``"min"``), or ``None`` when the header gives none.
    """

    index: int
    label: str
    name: str
    unit: str | None


def split_name_unit(cell: str, suffix_units: Sequence[str] = ()) -> tuple[str, str | None]:
    """Split a header cell into a lower-case name and a unit.

    Recognised: ``"t [min]"``, ``"time (s)"``, ``"x/mm"``, and ``"time_min"`` when ``min`` is
    one of `suffix_units`. ``"E(t)"`` and ``"c(t)"`` are names (a unit is never ``t``).

    **Arguments:**

    - `cell`: the header cell.
    - `suffix_units`: units accepted after a final underscore (``name_unit``).

    **Returns:** ``(name, unit)``, `unit` ``None`` when the cell gives none.
    """
    text = cell.strip().lstrip("\ufeff").strip().strip('"').strip()
    match = _UNIT_BRACKETS.match(text)
    if match and match.group("name"):
        unit = (match.group("p") if match.group("p") is not None else match.group("b")).strip()
        if unit.lower() == "t":
            return text.lower(), None
        return match.group("name").strip().lower(), unit or None
    lower = text.lower()
    if "/" in lower:
        name, _, unit = lower.rpartition("/")
        if name.strip() and unit.strip():
            return name.strip(), unit.strip()
    if "_" in lower:
        stem, _, suffix = lower.rpartition("_")
        if stem and suffix in suffix_units:
            return stem, suffix
    return lower, None


def _separator_hint(line: str) -> str | None:
    """The separator a first line ``sep=;`` names (as spreadsheets write it: ``,``, ``;`` or
    a tab), or ``None`` for any other line."""
    text = line.strip(" \r\n").lstrip("\ufeff").strip('"')
    if len(text) == 5 and text[:4].lower() == "sep=" and text[4] in DELIMITERS:
        return text[4]
    return None


def detect_delimiter(line: str) -> str | None:
    """The cell delimiter of a row: ``','``, ``';'``, tab, or ``None`` for runs of spaces.

    **Arguments:**

    - `line`: the first row of the file (header or data).

    **Returns:** the first of ``, ; tab`` found in `line`, else ``None``.
    """
    for delimiter in DELIMITERS:
        if delimiter in line:
            return delimiter
    return None


#: The numeric grammar of every cell and option: an optional sign, digits with an optional
#: decimal point, an optional exponent; or inf, infinity, nan (refused later with their own
#: message). Python's other float spellings (underscores, "1_0") are not numbers here.
_NUMBER = re.compile(r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf|infinity|nan)",
                     re.IGNORECASE)


def parse_number(cell: str, decimal: str = ".") -> float:
    """A number in the one grammar of cells and options (:data:`_NUMBER`); ValueError else.

    **Arguments:** `cell`, the text (surrounding spaces allowed); `decimal`, ``"."`` or
    ``","`` (then a comma is the decimal point).

    **Returns:** the float.
    """
    text = cell.strip()
    if decimal == ",":
        text = text.replace(",", ".")
    if not _NUMBER.fullmatch(text):
        raise ValueError(f"not a number: {cell!r}")
    return float(text)


def _number(cell: str, decimal: str) -> float:
    return parse_number(cell, decimal)


def _is_number(cell: str, decimal: str) -> bool:
    try:
        _number(cell, decimal)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Table:
    """An open table file: its header parsed, its body read on demand (see :func:`read_table`).

    - `path`: the file.
    - `columns`: one :class:`Column` per cell of the first row.
    - `header_row`: the row number of the header, or ``None`` when the file has none.
    - `delimiter`: ``','``, ``';'``, tab or ``None`` (runs of whitespace).
    - `decimal`: ``'.'`` or ``','``.
    - `first_row`: the row number where the body starts.
    """

    path: Path
    columns: tuple[Column, ...]
    header_row: int | None
    delimiter: str | None
    decimal: str
    first_row: int

    def error(self, problem: str, row: int | None = None) -> DataError:
        """A :class:`DataError` about this file (at `row`, or at the header when ``None``)."""
        return DataError(self.path, problem, self.header_row if row is None else row)

    def column(self, wanted: str | int) -> Column:
        """The column named `wanted` (case-insensitive, with or without its unit) or at index
        `wanted`; a :class:`DataError` naming the columns when there is none."""
        if isinstance(wanted, int) and not isinstance(wanted, bool):
            if not 0 <= wanted < len(self.columns):
                raise self.error(f"column {wanted} does not exist ({len(self.columns)} columns)")
            return self.columns[wanted]
        key = str(wanted).strip().lower()
        for column in self.columns:
            if key in (column.name, column.label.lower()):
                return column
        labels = ", ".join(c.label for c in self.columns)
        raise self.error(f"no column named {wanted!r} (columns: {labels})")

    def rows(self, *, allow_extra_cells: bool = False) -> Iterator[tuple[int, list[str]]]:
        """Stream the body: ``(row number, cells)`` per data row, comments and blanks skipped.

        **Arguments:**

        - `allow_extra_cells`: accept rows longer than the first row (extra cells ignored);
          by default they are an error, as are shorter rows.

        **Returns:** an iterator; it raises :class:`DataError` on a row of the wrong length or
        on text that is not UTF-8.
        """
        width = len(self.columns)
        for number, line in _lines(self.path):
            if number < self.first_row:
                continue
            cells = _split(line, self.delimiter)
            if len(cells) < width or (len(cells) > width and not allow_extra_cells):
                kind = "missing" if len(cells) < width else "extra"
                raise DataError(self.path, f"{kind} columns: expected {width} cells, found "
                                f"{len(cells)}", number)
            yield number, cells

    def numbers(self, columns: Sequence[int], *, allow_extra_cells: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
        """Read the given columns of the body as finite float64 numbers, streaming.

        **Arguments:**

        - `columns`: 0-based column indices.
        - `allow_extra_cells`: as in :meth:`rows`.

        **Returns:** ``(row_numbers, values)``: int64 shape ``(n,)`` and float64 shape
        ``(n, len(columns))``. Empty, non-numeric, NaN and infinite cells raise
        :class:`DataError` naming the row and column.
        """
        plain = _plain_numbers(self, columns) if not allow_extra_cells else None
        if plain is not None:
            return plain
        rows, values = array("q"), array("d")
        labels = [self.columns[i].label for i in columns]
        for number, cells in self.rows(allow_extra_cells=allow_extra_cells):
            rows.append(number)
            for index, label in zip(columns, labels, strict=True):
                values.append(self._cell_number(cells[index], label, number))
        return (np.frombuffer(rows, dtype=np.int64).copy(),
                np.frombuffer(values, dtype=np.float64).reshape(-1, len(columns)).copy())

    def _cell_number(self, cell: str, label: str, row: int) -> float:
        cell = cell.strip().strip('"').strip()
        if cell == "":
            raise DataError(self.path, f"empty cell in column {label!r}", row)
        try:
            value = _number(cell, self.decimal)
        except ValueError:
            shown = cell if len(cell) <= 40 else cell[:37] + "..."
            raise DataError(self.path, f"non-numeric cell {shown!r} in column {label!r}",
                            row) from None
        if math.isnan(value):
            raise DataError(self.path, f"NaN in column {label!r}", row)
        if math.isinf(value):
            raise DataError(self.path, f"infinite value in column {label!r}", row)
        return value


#: Bytes of a plain body parsed at once by the compiled reader (see the module).
PLAIN_BLOCK = 1 << 24
#: The bytes of a plain body besides its delimiter.
_PLAIN_BYTES = np.zeros(256, dtype=bool)
_PLAIN_BYTES[np.frombuffer(b"0123456789.eE+-\n", dtype=np.uint8)] = True


def _plain_numbers(table: Table, columns: Sequence[int]
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """:meth:`Table.numbers` of a plain body by NumPy's compiled reader, or ``None`` when the
    body is not plain (or anything in it needs the row-by-row reader to be named).

    Plain: decimal points, a delimiter of one character, every line after the header a data
    row of exactly the table's width made of the bytes ``0-9 . e E + -`` (line ends ``\n``
    or ``\r\n``), so rows are lines (numbered from :attr:`Table.first_row`) and every cell
    is a number of the grammar or refused by NumPy's reader as well; finite values only.
    """
    if table.decimal != "." or table.delimiter is None or len(table.delimiter) != 1:
        return None
    allowed = _PLAIN_BYTES.copy()
    allowed[ord(table.delimiter)] = True
    width = len(table.columns)
    wanted = list(columns)
    rows_parts, value_parts = [], []
    row = table.first_row
    try:
        with open(table.path, "rb") as stream:
            for _ in range(table.first_row - 1):
                stream.readline()
            while True:
                block = stream.read(PLAIN_BLOCK)
                if not block:
                    break
                if not block.endswith(b"\n"):
                    block += stream.readline()  # whole lines only
                block = block.replace(b"\r\n", b"\n")
                codes = np.frombuffer(block, dtype=np.uint8)
                if not allowed[codes].all() or block.startswith(b"\n") or b"\n\n" in block:
                    return None
                ends = np.flatnonzero(codes == 10)
                if not block.endswith(b"\n"):
                    ends = np.append(ends, codes.size)
                lines = ends.size
                # Delimiters a line: those before its end, less those before the last end.
                before = np.searchsorted(np.flatnonzero(codes == ord(table.delimiter)), ends)
                if np.any(np.diff(before, prepend=0) != width - 1):
                    return None
                values = np.loadtxt(io.StringIO(block.decode("ascii")),
                                    delimiter=table.delimiter, dtype=np.float64, comments=None,
                                    usecols=wanted, ndmin=2)
                if values.shape != (lines, len(wanted)) or not np.all(np.isfinite(values)):
                    return None
                rows_parts.append(np.arange(row, row + lines, dtype=np.int64))
                value_parts.append(values)
                row += lines
    except (OSError, ValueError):
        return None
    if not rows_parts:
        return None
    return np.concatenate(rows_parts), np.concatenate(value_parts)


def _lines(path: Path) -> Iterator[tuple[int, str]]:
    """Numbered non-blank, non-comment lines of a UTF-8 text file, streamed."""
    with open(path, "rb") as stream:
        start = stream.read(4)
        if start[:2] in (b"\xff\xfe", b"\xfe\xff"):
            raise DataError(path, "UTF-16 text; save the file as UTF-8 (or plain CSV)")
        stream.seek(0)
        for number, raw in enumerate(stream, start=1):
            if b"\x00" in raw:
                raise DataError(path, "not a text file (it contains NUL bytes)", number)
            try:
                line = raw.decode("utf-8-sig" if number == 1 else "utf-8")
            except UnicodeDecodeError as error:
                raise DataError(path, f"not UTF-8 text ({error.reason})", number) from None
            stripped = line.strip()
            # A row of separators alone (";;", as spreadsheets save empty rows) is blank.
            if stripped.strip(",;\t ") and not stripped.startswith("#"):
                yield number, line.rstrip("\r\n")


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    if '"' not in line:
        return [cell.strip() for cell in line.split(delimiter)]
    limit = csv.field_size_limit()
    csv.field_size_limit(max(limit, len(line) + 1))  # the default 128 kB bounds one cell
    try:
        return [cell.strip() for cell in next(csv.reader([line], delimiter=delimiter))]
    except csv.Error as error:
        raise ValueError(str(error)) from None
    finally:
        csv.field_size_limit(limit)


def read_table(
    path: str | Path,
    *,
    header: bool | None = None,
    decimal: str = ".",
    suffix_units: Sequence[str] = (),
) -> Table:
    """Open a table file and parse its first row (header or data); the body is not read yet.

    **Arguments:**

    - `path`: the file.
    - `header`: whether the first row names the columns; ``None`` (default): it does when
      any of its cells is not a number.
    - `decimal`: ``'.'`` (default), ``','`` (decimal commas; cells then separated by ``;``,
      tab or spaces) or ``'auto'`` (``','`` when the first row is not comma-separated and a
      cell of the first data row looks like ``0,25``).
    - `suffix_units`: units recognised as ``name_unit`` header suffixes (see
      :func:`split_name_unit`).

    **Returns:** a :class:`Table`; read its body with :meth:`Table.numbers` or
    :meth:`Table.rows`.

    **Raises:** :class:`DataError` for a missing, unreadable, binary, UTF-16 or empty file.
    """
    path = Path(path)
    if decimal not in (".", ",", "auto"):
        raise ValueError(f"decimal must be '.', ',' or 'auto', got {decimal!r}")
    if not path.exists():
        raise DataError(path, "file not found")
    if not path.is_file():
        raise DataError(path, "not a file")
    try:
        lines = _lines(path)
        first = next(lines, None)
        hint = _separator_hint(first[1]) if first is not None else None
        if hint is not None:  # the spreadsheet's "sep=;" line: the cells' separator
            first = next(lines, None)
        second = next(lines, None) if first is not None else None
        lines.close()
    except OSError as error:
        raise DataError(path, f"cannot be read ({error.strerror})") from None
    if first is None:
        raise DataError(path, "no data (the file is empty)")
    first_number, first_line = first
    delimiter = detect_delimiter(first_line) if hint is None else hint
    if decimal == "auto":
        sample = second[1] if second is not None else first_line
        cells = _split(sample, delimiter)
        decimal = "," if delimiter != "," and any(_DECIMAL_COMMA.match(c) for c in cells) else "."
    if decimal == "," and delimiter == ",":
        raise DataError(path, "decimal commas need cells separated by ';', tabs or spaces",
                        first_number)
    cells = _split(first_line, delimiter)
    if header is None:
        header = not all(_is_number(c.strip().strip('"'), decimal) for c in cells if c.strip())
    if header:
        columns = tuple(Column(i, c.strip().strip('"').lstrip("\ufeff"),
                               *split_name_unit(c, suffix_units)) for i, c in enumerate(cells))
        return Table(path, columns, first_number, delimiter, decimal, first_number + 1)
    columns = tuple(Column(i, f"column {i + 1}", f"column {i + 1}", None)
                    for i in range(len(cells)))
    return Table(path, columns, None, delimiter, decimal, first_number)

