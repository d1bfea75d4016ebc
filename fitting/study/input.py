"""Study input: the curves of a study of many runs, each with the process factors it ran at.

Two layouts are read:

* **One long table** (:func:`read_long_csv`): one row per sample, a curve-id column (``run``),
  time, concentration, optionally the inlet signal sampled at the same times, and factor
  columns (``rpm``, ``flow``, ``angle``, ...) whose value is constant within a curve. Rows of
  one curve need not be adjacent; within a curve the times increase in row order.
* **A folder of curve files and a design table** (:func:`study_from_files` with
  :func:`read_design`): the design has one row per file (its name, with or without ``.csv``,
  in the first column or in a column named ``file``, ``curve``, ``run`` or ``name``) and one
  column per factor.

Each curve is checked as :func:`fitting.data.read_rtd_csv` checks a file (raw values, noise
down to -5 % of the peak kept), with errors naming the file and row. A factor that changes
within a curve, a curve without a design row, a design row without a curve and a name given
twice are one-line :class:`~fitting.data.DataError` messages naming file, row and column.
Factor values are kept as written (text); :func:`factor_value` reads a number where the text
is one.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from axialmix._csv import read_table
from fitting.data import (
    Curve,
    DataError,
    column_time_unit,
    counting_columns,
    curve_columns,
    validated_curve,
)

__all__ = ["DESIGN_NAME_COLUMNS", "Study", "factor_value", "read_design", "read_long_csv",
           "study_from_files"]

#: Column names that hold the file name in a design table (else its first column).
DESIGN_NAME_COLUMNS = ("file", "curve", "run", "name")
#: Time-unit suffixes recognised in header names (``time_min``), as the curve reader does.
_SUFFIX_UNITS = ("s", "ms", "min", "h")


@dataclass(frozen=True, eq=False)
class Study:
    """The curves of a study and the factor levels of each.

    **Fields:**

    - `curves`: the measured curves (raw values, file units), in the order first met; each
      curve's ``name`` is its id.
    - `factors`: the factor names, in table order.
    - `levels`: per curve, its factor values as written, in the order of `factors`.
    - `inlets`: per curve, its measured inlet signal (a :class:`~fitting.data.Curve`), or
      ``None`` for curves without one (then the study's inlet applies).
    - `source`: the long table, or the design table, the study was read from.
    - `refused`: ``(curve id, reason)`` of each curve of the table that was left out because
      it cannot be fitted as read (too few points, a gross negative value, times out of
      order: the one-line reason names file, curve and row); the others are the study.
    """

    curves: tuple[Curve, ...]
    factors: tuple[str, ...]
    levels: tuple[tuple[str, ...], ...]
    inlets: tuple[Curve | None, ...]
    source: str
    refused: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        count = len(self.curves)
        if len(self.levels) != count or len(self.inlets) != count:
            raise ValueError(f"a study needs one factor row and one inlet entry per curve: "
                             f"{count} curves, {len(self.levels)} rows, {len(self.inlets)} "
                             "inlets")
        if any(len(row) != len(self.factors) for row in self.levels):
            raise ValueError(f"every curve needs a value for each of {len(self.factors)} "
                             "factors")
        names = [curve.name for curve in self.curves]
        if len(set(names)) != count:
            raise ValueError("curve ids of a study must be distinct")

    def __len__(self) -> int:
        return len(self.curves)

    @functools.cached_property
    def ids(self) -> tuple[str, ...]:
        """The curve ids, in study order (made once: a study's curves are fixed)."""
        return tuple(curve.name for curve in self.curves)

    def factor_row(self, index: int) -> dict[str, str]:
        """The factor values of curve `index` as ``{factor: text as written}``."""
        return dict(zip(self.factors, self.levels[index], strict=True))

    def digest(self) -> str:
        """A fingerprint of the study's data (ids, samples, units, factors, inlets): a
        restarted run continues only the same study."""
        hasher = hashlib.sha256()
        hasher.update(repr(self.factors).encode())
        for curve, row, inlet in zip(self.curves, self.levels, self.inlets, strict=True):
            hasher.update(repr((curve.name, curve.time_unit, curve.value_unit, row)).encode())
            hasher.update(curve.time.tobytes() + curve.value.tobytes())
            if inlet is not None:
                hasher.update(inlet.time.tobytes() + inlet.value.tobytes())
        return hasher.hexdigest()[:24]


def factor_value(text: str) -> float | str:
    """A factor level as a number where its text is a finite number, else the text."""
    try:
        value = float(text)
    except ValueError:
        return text
    return value if math.isfinite(value) else text


def read_long_csv(
    path: str | Path,
    curve_column: str | int,
    *,
    time_column: str | int | None = None,
    value_column: str | int | None = None,
    inlet_column: str | int | None = None,
    factors: Sequence[str] | None = None,
    decimal: str = "auto",
    factors_option: str = "--factors",
    leave_out: bool = True,
) -> Study:
    """Read a study from one long table: a curve-id column, samples, and factor columns.

    **Arguments:**

    - `path`: the CSV file (a header row naming the columns is required).
    - `curve_column`: the column of curve ids (name or 0-based index).
    - `time_column`, `value_column`: as in :func:`fitting.data.read_rtd_csv` (recognised
      from the header when ``None``; the time unit comes from the time column's header).
    - `inlet_column`: a column with the inlet signal at the same times, or ``None``.
    - `factors`: the factor columns; ``None`` (default): every other column.
    - `decimal`: ``'auto'``, ``'.'`` or ``','`` as in :func:`axialmix._csv.read_table`.
    - `factors_option`: the option that named `factors`, for messages.

    **Returns:** a :class:`Study`, curves in the order their ids first appear.

    **Raises:** :class:`~fitting.data.DataError` with one line naming the file, the row and
    the column: no header, unknown columns, an empty curve id, a factor that changes within
    a curve, and every problem the curve reader finds in a curve's samples.
    """
    path = Path(path)
    table = read_table(path, header=True, decimal=decimal, suffix_units=_SUFFIX_UNITS)
    if table.header_row is None:
        raise DataError(path, "a study table needs a header row naming its columns")

    def column(wanted, option):
        try:
            return table.column(wanted)
        except DataError as error:
            raise table.error(f"{option}: {error.problem}") from None

    curve_col = column(curve_column, "--curve-column")
    inlet_col = column(inlet_column, "--inlet-column") if inlet_column is not None else None
    taken = {curve_col.index} | ({inlet_col.index} if inlet_col is not None else set())
    rest = [c for c in table.columns if c.index not in taken]
    # The time and value columns are chosen among the others as in a curve file.
    narrowed = dataclasses.replace(table, columns=tuple(rest))
    counting = counting_columns(narrowed, _wanted(table, time_column),
                                _wanted(table, value_column))
    if counting is not None:
        raise table.error(f"column {counting[1].label!r} holds particle counts: a long-format "
                          "study fits signals; fit the histograms as files or a folder, where "
                          "their counting (Poisson) errors apply")
    time_col, value_col = curve_columns(narrowed, _wanted(table, time_column),
                                        _wanted(table, value_column))
    taken |= {time_col.index, value_col.index}
    if factors is None:
        factor_cols = [c for c in table.columns if c.index not in taken]
    else:
        factor_cols = [column(name, factors_option) for name in factors]
        roles = {curve_col.index: "curve id column (--curve-column)",
                 time_col.index: "time column (--time-column)",
                 value_col.index: "value column (--value-column)"}
        if inlet_col is not None:
            roles[inlet_col.index] = "inlet column (--inlet-column)"
        for factor in factor_cols:
            if factor.index in taken:
                role = roles.get(factor.index, "curve id, time, value or inlet column")
                raise table.error(f"{factors_option}: column {factor.label!r} is the {role}; "
                                  "a factor must be another column")
    time_unit = column_time_unit(table, time_col)

    groups: dict[str, list[int]] = {}
    first_seen: dict[str, tuple[int, list[str]]] = {}
    for position, (row, cells) in enumerate(table.rows()):
        key = cells[curve_col.index].strip().strip('"').strip()
        if not key:
            raise DataError(path, f"empty curve id in column {curve_col.label!r}", row)
        levels = [cells[f.index].strip().strip('"').strip() for f in factor_cols]
        seen = first_seen.get(key)
        if seen is None:
            first_seen[key] = (row, levels)
            groups[key] = [position]
            continue
        groups[key].append(position)
        for factor, level, first in zip(factor_cols, levels, seen[1], strict=True):
            if level != first:
                raise DataError(path, f"factor {factor.label!r} changes within curve {key!r}: "
                                f"{level!r} here, {first!r} on row {seen[0]}", row)
    if not groups:
        raise DataError(path, "no data rows below the header")
    numeric = [time_col.index, value_col.index] + ([inlet_col.index] if inlet_col else [])
    rows, data = table.numbers(numeric)

    curves, inlets, levels, refused = [], [], [], []
    for key, positions in groups.items():
        index = np.asarray(positions)
        # A curve that cannot be fitted as read is left out with its reason; the others
        # make the study (a malformed file, above, is refused as a whole).
        try:
            curve = validated_curve(
                path, rows[index], data[index, 0], data[index, 1], time_unit=time_unit,
                value_unit=value_col.unit, name=key, normalise=False, on_truncated="ignore")
            inlet = None if inlet_col is None else validated_curve(
                path, rows[index], data[index, 0], data[index, 2], time_unit=time_unit,
                value_unit=inlet_col.unit, name=f"{key} inlet", normalise=False,
                min_points=2, on_truncated="ignore")
        except DataError as error:
            if not leave_out or len(groups) == 1:
                raise
            refused.append((key, str(error)))  # names file, row and curve
            continue
        curves.append(curve)
        inlets.append(inlet)
        levels.append(tuple(first_seen[key][1]))
    if not curves:
        raise DataError(path, f"no curve can be fitted: {refused[0][1]}"
                        + (f" (and {len(refused) - 1} more)" if len(refused) > 1 else ""))
    return Study(tuple(curves), tuple(f.label for f in factor_cols), tuple(levels),
                 tuple(inlets), str(path), tuple(refused))


def _wanted(table, wanted: str | int | None) -> str | int | None:
    """A column given by index in the whole table, as its label (the narrowed table of the
    remaining columns keeps the original indices)."""
    if isinstance(wanted, int) and not isinstance(wanted, bool):
        return table.column(wanted).label
    return wanted


def read_design(path: str | Path, *, name_column: str | int | None = None,
                decimal: str = "auto") -> tuple[tuple[str, ...], dict[str, tuple[str, ...]]]:
    """Read a design table: one row per curve file, one column per factor.

    **Arguments:**

    - `path`: the CSV file (a header row naming the factors is required).
    - `name_column`: the column of file names; default the first of
      :data:`DESIGN_NAME_COLUMNS` found, else the first column. A name may carry the
      ``.csv`` ending or not.
    - `decimal`: as in :func:`axialmix._csv.read_table`.

    **Returns:** ``(factors, rows)``: the factor names and ``{file stem: factor values}``.

    **Raises:** :class:`~fitting.data.DataError` naming the row for an empty or repeated name.
    """
    path = Path(path)
    table = read_table(path, header=True, decimal=decimal)
    if name_column is not None:
        try:
            names = table.column(name_column)
        except DataError as error:
            raise table.error(f"--design-column: {error.problem}") from None
    else:
        found = [c for c in table.columns if c.name in DESIGN_NAME_COLUMNS]
        names = found[0] if found else table.columns[0]
    factor_cols = [c for c in table.columns if c.index != names.index]
    if not factor_cols:
        raise table.error("a design table needs at least one factor column beside the names")
    rows: dict[str, tuple[str, ...]] = {}
    where: dict[str, int] = {}
    for row, cells in table.rows():
        name = cells[names.index].strip().strip('"').strip()
        stem = name[:-4] if name.lower().endswith(".csv") else name
        if not stem:
            raise DataError(path, f"empty file name in column {names.label!r}", row)
        if stem in rows:
            raise DataError(path, f"{name!r} in column {names.label!r} is named on row "
                            f"{where[stem]} too", row)
        rows[stem] = tuple(cells[c.index].strip().strip('"').strip() for c in factor_cols)
        where[stem] = row
    if not rows:
        raise DataError(path, "no data rows below the header")
    return tuple(c.label for c in factor_cols), rows


def study_from_files(curves: Sequence[Curve], design: str | Path | None = None, *,
                     name_column: str | int | None = None, decimal: str = "auto") -> Study:
    """A study of curves read from files, with their factors from a design table.

    **Arguments:**

    - `curves`: the curves (read with :func:`fitting.data.read_rtd_csv`); each is matched to
      the design row of its name (the file name without ``.csv``).
    - `design`: the design table (:func:`read_design`), or ``None`` for a study without
      factors.
    - `name_column`, `decimal`: as in :func:`read_design`.

    **Returns:** a :class:`Study` in the order of `curves`.

    **Raises:** :class:`~fitting.data.DataError` for a curve the design does not name, or a
    design row that names no curve (a misspelt name), naming the design file.
    """
    curves = tuple(curves)
    if design is None:
        return Study(curves, (), tuple(() for _ in curves), tuple(None for _ in curves),
                     str(Path(curves[0].source).parent) if curves and curves[0].source
                     else "")
    factors, rows = read_design(design, name_column=name_column, decimal=decimal)
    names = {curve.name for curve in curves}
    missing = [curve.name for curve in curves if curve.name not in rows]
    if missing:
        raise DataError(design, f"no row for curve file {missing[0]!r}"
                        + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    unused = [name for name in rows if name not in names]
    if unused:
        raise DataError(design, f"row for {unused[0]!r}, which is not among the curve files"
                        + (f" (and {len(unused) - 1} more)" if len(unused) > 1 else ""))
    return Study(curves, factors, tuple(rows[c.name] for c in curves),
                 tuple(None for _ in curves), str(design))
