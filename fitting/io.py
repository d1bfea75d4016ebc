"""Reading and validating residence-time curves from CSV files.

A tracer experiment gives a table of sample times and outlet concentrations. This module turns
such a file into a validated, immutable :class:`Curve`, or raises :class:`DataError` with ONE
line naming the file, the row (1-based line number, as a text editor shows it) and the
problem. Warnings (:class:`DataWarning`) are one line too.

Format accepted:

* Delimiter: comma, semicolon, tab or runs of spaces (detected from the header line).
* Lines starting with ``#`` and blank lines are skipped (they still count for line numbers).
* An optional header line. Time column names: ``t``, ``time``, ``times``, ``time_s``,
  ``t [min]``, ``time (s)``, ...; value column names: ``c``, ``conc``, ``concentration``,
  ``E``, ``E(t) [1/s]``, ``exit_age``, ``value``, ``signal``, ``tracer``, ``y``, ...
  A unit may follow the name in brackets or parentheses, or after an underscore
  (``time_min``). Without a header, the first column is time and the second the value.
* Time units recognised: s, ms, min, h (and their spellings). Times are kept in the file's
  unit; ``Curve.time_unit`` records it, and E is then in 1/(that unit).

Normalisation uses :func:`axialmix.rtd.normalise`, i.e. the trapezoid rule on the sampled
grid (``E = c / ∫ c dt``); a curve cut off before its tail has decayed is therefore
normalised to the observed part only, which is why such curves produce a warning.
"""

from __future__ import annotations

import csv
import math
import re
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from axialmix.rtd import normalise as _normalise_exit_age

__all__ = ["Curve", "DataError", "DataWarning", "read_many", "read_rtd_csv"]

#: Fraction of the peak that the last sample may keep before the curve counts as "never
#: returned to baseline": a tail above 5 % of the peak leaves a visible part of the area
#: (and much of the variance) unmeasured.
TAIL_FRACTION = 0.05

_TIME_NAMES = {"t", "time", "times", "tempo", "zeit", "elapsed", "elapsed_time", "sample_time"}
_VALUE_NAMES = {
    "c", "conc", "concentration", "e", "e(t)", "et", "exit_age", "exitage", "rtd",
    "value", "values", "signal", "tracer", "y", "intensity", "absorbance", "response",
    "mass_fraction", "fraction", "api", "c(t)", "ct",
}
_TIME_UNITS = {
    "s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s",
    "ms": "ms", "millisecond": "ms", "milliseconds": "ms",
    "min": "min", "mins": "min", "minute": "min", "minutes": "min", "m": "min",
    "h": "h", "hr": "h", "hrs": "h", "hour": "h", "hours": "h",
}


class DataError(ValueError):
    """A residence-time data file that cannot be used; the message is one line."""


class DataWarning(UserWarning):
    """A usable residence-time data file with a doubtful feature; the message is one line."""


@dataclass(frozen=True, eq=False)
class Curve:
    """One measured residence-time curve: sample times and values, immutable.

    **Arguments:**

    - `name`: a label (by default the file name without extension).
    - `time`: sample times, shape ``(n,)``, strictly increasing, non-negative; unit
      `time_unit`.
    - `value`: exit-age density ``E(t)`` in 1/`time_unit` when normalised, otherwise the raw
      (baseline-corrected) signal, shape ``(n,)``.
    - `time_unit`: unit of `time` as read from the header (``"s"`` when none was given).
    - `source`: where the curve came from (file path), or ``None``.
    """

    name: str
    time: np.ndarray
    value: np.ndarray
    time_unit: str = "s"
    source: str | None = None

    def __post_init__(self) -> None:
        time = np.array(self.time, dtype=float)
        value = np.array(self.value, dtype=float)
        if time.ndim != 1 or value.shape != time.shape:
            raise ValueError(
                f"curve {self.name!r}: time and value must be 1-D of equal length, got shapes "
                f"{time.shape} and {value.shape}"
            )
        time.flags.writeable = False
        value.flags.writeable = False
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "value", value)

    def __len__(self) -> int:
        return self.time.shape[0]

    def __repr__(self) -> str:
        return (
            f"Curve(name={self.name!r}, {len(self)} points, t = {self.time[0]:g}..."
            f"{self.time[-1]:g} {self.time_unit}, source={self.source!r})"
        )


def _split_name_unit(header: str) -> tuple[str, str | None]:
    """Split ``'t [min]'``, ``'time (s)'`` or ``'time_min'`` into a lower-case name and unit."""
    text = header.strip().strip('"').strip()
    match = re.fullmatch(r"(.*?)\s*[\[(]\s*([^\])]*)\s*[\])]\s*", text)
    if match and match.group(1):
        name, unit = match.group(1), match.group(2)
        # "E(t)" is a name, not a name with unit "t".
        if unit.lower() in {"t"}:
            return text.lower(), None
        return name.strip().lower(), unit.strip()
    lower = text.lower()
    if "_" in lower:
        stem, _, suffix = lower.rpartition("_")
        if suffix in _TIME_UNITS and stem in _TIME_NAMES:
            return stem, suffix
    return lower, None


def _detect_delimiter(line: str) -> str | None:
    """Delimiter of a header/data line: ',', ';', tab, or None for runs of whitespace."""
    for delimiter in (",", ";", "\t"):
        if delimiter in line:
            return delimiter
    return None


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [cell.strip() for cell in next(csv.reader([line], delimiter=delimiter))]


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _pick_column(
    names: Sequence[str], wanted: str | int | None, candidates: set[str], role: str, where: str
) -> int | None:
    """Index of the column called `wanted` (name or index), else of a known spelling."""
    if isinstance(wanted, int):
        if not 0 <= wanted < len(names):
            raise DataError(
                f"{where}: {role} column {wanted} does not exist ({len(names)} columns)"
            )
        return wanted
    if wanted is not None:
        key = wanted.strip().lower()
        for index, name in enumerate(names):
            if name == key or _split_name_unit(name)[0] == key:
                return index
        raise DataError(f"{where}: no {role} column named {wanted!r} (columns: {', '.join(names)})")
    matches = [i for i, name in enumerate(names) if _split_name_unit(name)[0] in candidates]
    if len(matches) > 1:
        listed = ", ".join(repr(names[i]) for i in matches)
        raise DataError(f"{where}: several possible {role} columns ({listed}); choose one")
    return matches[0] if matches else None


def read_rtd_csv(
    path: str | Path,
    *,
    time_column: str | int | None = None,
    value_column: str | int | None = None,
    baseline: None | str | float = None,
    normalise: bool = True,
    min_points: int = 5,
    on_truncated: str = "warn",
    name: str | None = None,
) -> Curve:
    """Read one residence-time curve from a CSV file, validate it and normalise it to E(t).

    **Arguments:**

    - `path`: the CSV file (see the module docstring for the accepted layout).
    - `time_column`, `value_column`: column name (case-insensitive, with or without the unit)
      or 0-based index; by default recognised from the header spellings, or the first two
      columns of a two-column file.
    - `baseline`: subtracted from the values before normalising: ``None`` (nothing),
      ``'first'`` (the first sample), ``'min'`` (the smallest sample) or a number in the
      file's value unit. After subtraction values may be slightly negative (noise); they are
      kept, so as not to bias the fit.
    - `normalise`: divide by the trapezoid area so the values are the exit-age density E in
      1/(time unit). Set ``False`` to keep the raw signal.
    - `min_points`: fewest data rows accepted.
    - `on_truncated`: what to do when the last value is still above 5 % of the peak (the curve
      never returned to baseline, so area and moments are biased): ``'warn'`` (default,
      :class:`DataWarning`), ``'error'`` (:class:`DataError`) or ``'ignore'``.
    - `name`: the curve's label; by default the file name without extension.

    **Returns:**

    A :class:`Curve` with time in the file's unit and E in 1/(that unit).

    **Raises:**

    :class:`DataError` (a ``ValueError``) with one line ``"<file>, row <r>: <problem>"`` for a
    missing file, missing or extra columns, non-numeric, empty or NaN cells, negative values or
    times, times not strictly increasing, too few points, or an all-zero curve.
    """
    path = Path(path)
    where = str(path)
    if on_truncated not in {"warn", "error", "ignore"}:
        raise ValueError(f"on_truncated must be 'warn', 'error' or 'ignore', got {on_truncated!r}")
    if not path.is_file():
        raise DataError(f"{where}: file not found")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as error:
        raise DataError(f"{where}: not a text file ({error.reason})") from None

    rows = [
        (number, line)
        for number, line in enumerate(lines, start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not rows:
        raise DataError(f"{where}: no data (the file is empty)")
    delimiter = _detect_delimiter(rows[0][1])
    first_cells = _split(rows[0][1], delimiter)
    has_header = not all(_is_number(cell) for cell in first_cells if cell)
    if has_header:
        header_row = rows[0][0]
        names = [cell.strip().strip('"') for cell in first_cells]
        data_rows = rows[1:]
    else:
        header_row = None
        names = [f"column {i + 1}" for i in range(len(first_cells))]
        data_rows = rows
    lowered = [n.lower() for n in names]
    header_where = f"{where}, row {header_row}" if header_row else where

    if len(names) < 2:
        raise DataError(
            f"{header_where}: missing column: found {len(names)} column, need time and value"
        )
    time_index = _pick_column(lowered, time_column, _TIME_NAMES, "time", header_where)
    value_index = _pick_column(lowered, value_column, _VALUE_NAMES, "value", header_where)
    if time_index is None and value_index is None and len(names) == 2:
        time_index, value_index = 0, 1
    elif time_index is None and len(names) == 2:
        time_index = 1 - value_index
    elif value_index is None and len(names) == 2:
        value_index = 1 - time_index
    if time_index is None:
        raise DataError(
            f"{header_where}: missing time column (columns: {', '.join(names)}); "
            "name it 't' or 'time', or pass time_column"
        )
    if value_index is None:
        raise DataError(
            f"{header_where}: extra columns, cannot tell which is the concentration "
            f"(columns: {', '.join(names)}); pass value_column"
        )
    if time_index == value_index:
        raise DataError(f"{header_where}: time and value are the same column {names[time_index]!r}")

    time_unit = "s"
    unit = _split_name_unit(names[time_index])[1] if has_header else None
    if unit is not None:
        if unit.lower() not in _TIME_UNITS:
            raise DataError(f"{header_where}: unknown time unit {unit!r} in {names[time_index]!r}")
        time_unit = _TIME_UNITS[unit.lower()]

    times: list[float] = []
    values: list[float] = []
    row_numbers: list[int] = []
    for number, line in data_rows:
        cells = _split(line, delimiter)
        here = f"{where}, row {number}"
        if len(cells) != len(names):
            kind = "missing" if len(cells) < len(names) else "extra"
            raise DataError(
                f"{here}: {kind} columns: expected {len(names)} cells, found {len(cells)}"
            )
        parsed = []
        for index in (time_index, value_index):
            cell = cells[index].strip().strip('"')
            if cell == "":
                raise DataError(f"{here}: empty cell in column {names[index]!r}")
            try:
                number_value = float(cell)
            except ValueError:
                raise DataError(
                    f"{here}: non-numeric cell {cell!r} in column {names[index]!r}"
                ) from None
            if math.isnan(number_value):
                raise DataError(f"{here}: NaN in column {names[index]!r}")
            if math.isinf(number_value):
                raise DataError(f"{here}: infinite value in column {names[index]!r}")
            if number_value < 0:
                role = "time" if index == time_index else "value"
                raise DataError(f"{here}: negative {role} {number_value:g}")
            parsed.append(number_value)
        if times and parsed[0] <= times[-1]:
            raise DataError(
                f"{here}: times not increasing ({parsed[0]:g} after {times[-1]:g})"
            )
        times.append(parsed[0])
        values.append(parsed[1])
        row_numbers.append(number)

    if len(times) < min_points:
        raise DataError(
            f"{where}: too few points: {len(times)} data rows, at least {min_points} needed"
        )
    time = np.asarray(times)
    value = np.asarray(values)
    if baseline is not None:
        if baseline == "first":
            offset = value[0]
        elif baseline == "min":
            offset = value.min()
        elif isinstance(baseline, int | float) and not isinstance(baseline, bool):
            offset = float(baseline)
        else:
            raise ValueError(f"baseline must be None, 'first', 'min' or a number, got {baseline!r}")
        value = value - offset
    peak = np.max(np.abs(value))
    if peak == 0.0:
        raise DataError(f"{where}: all-zero curve (no tracer signal above the baseline)")
    if np.trapezoid(value, time) <= 0.0:
        raise DataError(f"{where}: the curve has no positive area above the baseline")
    if on_truncated != "ignore" and value[-1] > TAIL_FRACTION * peak:
        message = (
            f"{where}, row {row_numbers[-1]}: the curve never returns to baseline (last value "
            f"{value[-1]:.3g} is {100 * value[-1] / peak:.0f} % of the peak); area and moments "
            "are underestimated"
        )
        if on_truncated == "error":
            raise DataError(message)
        warnings.warn(message, DataWarning, stacklevel=2)
    if normalise:
        value = np.asarray(_normalise_exit_age(time, value))
    return Curve(
        name=name if name is not None else path.stem,
        time=time,
        value=value,
        time_unit=time_unit,
        source=str(path),
    )


def read_many(
    paths_or_folder: str | Path | Iterable[str | Path], *, pattern: str = "*.csv", **options
) -> list[Curve]:
    """Read several residence-time CSV files (a list of paths, or every CSV in a folder).

    **Arguments:**

    - `paths_or_folder`: a folder (all files matching `pattern`, sorted by name), one file,
      or an iterable of file paths.
    - `pattern`: glob pattern used inside a folder.
    - `options`: passed to :func:`read_rtd_csv` (``baseline``, ``normalise``, ...).

    **Returns:**

    A list of :class:`Curve`, in file-name order for a folder, in the given order otherwise.
    The first bad file raises its :class:`DataError`.
    """
    if isinstance(paths_or_folder, str | Path):
        folder = Path(paths_or_folder)
        if folder.is_dir():
            paths = sorted(folder.glob(pattern))
            if not paths:
                raise DataError(f"{folder}: no files matching {pattern!r}")
        else:
            paths = [folder]
    else:
        paths = [Path(p) for p in paths_or_folder]
    return [read_rtd_csv(p, **options) for p in paths]
