"""Reading and validating residence-time curves from CSV files.

A tracer experiment gives a table of sample times and outlet concentrations. This module turns
such a file into a validated, immutable :class:`Curve`, or raises :class:`DataError` with ONE
line naming the file, the row (1-based line number, as a text editor shows it) and the
problem. Warnings (:class:`DataWarning`) are one line too.

Format accepted:

* Read by :mod:`axialmix._csv` (streamed: a file of millions of rows is read in bounded
  memory). Delimiter: comma, semicolon, tab or runs of spaces (detected from the first row,
  or named by a spreadsheet's first line ``sep=;``).
* Lines starting with ``#`` and blank lines (or rows of separators alone, ``;;``) are
  skipped (they still count for line numbers).
* An optional header line. Time column names: ``t``, ``time``, ``times``, ``time_s``,
  ``t [min]``, ``time (s)``, ...; value column names: ``c``, ``conc``, ``concentration``,
  ``E``, ``E(t) [1/s]``, ``exit_age``, ``value``, ``signal``, ``tracer``, ``y``, ...
  A unit may follow the name in brackets or parentheses, or after an underscore
  (``time_min``). Without a header, the first column is time and the second the value.
* Time units recognised: s, ms, min, h (and their spellings). Times are kept in the file's
  unit; ``Curve.time_unit`` records it, and E is then in 1/(that unit). The value column's
  unit, when the header gives one (``c [g/L]``), is kept as ``Curve.value_unit``.
* Decimal commas (``0,25`` in a file whose cells are separated by ``;``, tabs or spaces) are
  detected by default (``decimal="auto"``), or forced with ``decimal=","``.
* Counts. A column named ``count`` (``counts``, ``particles``; a histogram of particles
  leaving, as ``axialmix simulate`` writes it) makes the file a counting curve: the value
  is the count divided by its bin width (particles per time unit) and :attr:`Curve.exposure`
  holds the widths, so ``value × exposure`` is the count and the fit's error model is
  Poisson (:class:`fitting.losses.CountingErrors`). The widths come from a column ``bin``
  (``bin_width``, ``width``; its unit from its header, else the time column's), or else from
  the spacing of the times (the first bin as wide as the second). Counts must be whole and
  non-negative; a baseline cannot be subtracted from them.
* Real data are not bad input. Values below zero, detector noise around a subtracted
  baseline, are kept down to the limit the curve's own noise sets (:func:`negative_limit`:
  6 robustly estimated noise standard deviations, at least 5 % and at most 25 % of the
  peak). A value further below zero is not noise (a wrong column, a sign error, a baseline
  subtracted twice) and is refused with its row. Sparse, non-uniform sampling is fine, and
  a tail cut before the curve has decayed only gives a :class:`DataWarning`.

Fitting uses the raw values (``normalise=False``) with the measurement model of
:mod:`fitting.measurement`, whose amplitude absorbs the tracer amount: dividing the samples by
their own trapezoid area (``normalise=True``, :func:`axialmix.rtd.normalise`) biases E whenever
sampling is sparse or the tail is cut, so it is only for looking at curves and their moments.
"""

from __future__ import annotations

import fnmatch
import math
import re
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from axialmix._csv import Column, DataError, Table, read_table

__all__ = ["MAX_NEGATIVE_FRACTION", "NEGATIVE_FRACTION", "NOISE_SIGMAS", "TIME_UNIT_SECONDS",
           "Curve", "DataError", "DataWarning",
           "as_curve", "column_time_unit", "counting_columns", "curve_columns",
           "first_non_finite", "input_files",
           "read_inlet_csv",
           "negative_limit", "noise_level", "read_many", "read_rtd_csv", "seconds_per",
           "validated_curve"]

#: Fraction of the peak that the last sample may keep before the curve counts as "never
#: returned to baseline": a tail above 5 % of the peak leaves a visible part of the area
#: (and much of the variance) unmeasured.
TAIL_FRACTION = 0.05
#: Values down to this fraction of the peak below zero are always kept as detector noise
#: around a subtracted baseline; noisier curves keep values down to NOISE_SIGMAS times their
#: own noise (see :func:`noise_level`), at most MAX_NEGATIVE_FRACTION of the peak.
NEGATIVE_FRACTION = 0.05
#: Noise standard deviations below zero still taken as noise: Gaussian noise reaches 6 sigma
#: below its mean once in a billion samples.
NOISE_SIGMAS = 6.0
#: Whatever the noise, a value further below zero than this fraction of the peak is not noise
#: (a wrong column, a sign error, a baseline subtracted twice) and is refused.
MAX_NEGATIVE_FRACTION = 0.25

_TIME_NAMES = {"t", "time", "times", "tempo", "zeit", "elapsed", "elapsed_time", "sample_time"}
_VALUE_NAMES = {
    "c", "conc", "concentration", "e", "e(t)", "et", "exit_age", "exitage", "rtd",
    "value", "values", "signal", "tracer", "y", "intensity", "absorbance", "response",
    "mass_fraction", "fraction", "api", "c(t)", "ct",
}
#: Column names of particle counts and of their bin widths (counting curves).
_COUNT_NAMES = {"count", "counts", "particles", "particle_count", "particle_counts"}
_BIN_NAMES = {"bin", "bins", "bin_width", "width"}
_TIME_UNITS = {
    "s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s",
    "ms": "ms", "millisecond": "ms", "milliseconds": "ms",
    "min": "min", "mins": "min", "minute": "min", "minutes": "min", "m": "min",
    "h": "h", "hr": "h", "hrs": "h", "hour": "h", "hours": "h",
}
#: Seconds in one of each time unit a curve may carry.
TIME_UNIT_SECONDS = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
#: Smallest peak and largest value accepted: below, normalising underflows (denormal
#: numbers lose their precision); above, areas and squared residuals overflow float64.
SMALLEST_PEAK, LARGEST_VALUE = 1e-200, 1e200
#: Shortest and longest span of sample times accepted (in the file's unit): E is about
#: 1/span and its derivative in the time scale about 1/span², so beyond these the squared
#: residuals and the curvature over- or underflow float64.
TIME_SPAN_RANGE = (1e-100, 1e100)


def first_non_finite(record, where: str = "") -> str | None:
    """The path (``a.b[2]``) of the first non-finite float in a JSON-bound record, or None.

    **Arguments:** `record`, nested dicts, lists and numbers; `where`, the path so far.
    """
    if isinstance(record, float) and not math.isfinite(record):
        return where or "value"
    if isinstance(record, dict):
        items = ((f"{where}.{key}" if where else str(key), value)
                 for key, value in record.items())
    elif isinstance(record, list | tuple):
        items = ((f"{where}[{index}]", value) for index, value in enumerate(record))
    else:
        return None
    for path, value in items:
        found = first_non_finite(value, path)
        if found is not None:
            return found
    return None


def noise_level(value: np.ndarray) -> float:
    """A robust estimate of the additive noise's standard deviation in a sampled curve.

    From the second differences ``y[i+1] - 2 y[i] + y[i-1]``, which remove a smooth signal
    (its curvature is small between close samples) and leave ``6 sigma²`` of white noise: the
    median absolute deviation of them, times 1.4826 (normal consistency), over ``sqrt(6)``.
    A few outliers do not move the median. Sparse sampling of a sharp peak over-states the
    noise (the signal's curvature counts as noise), which only widens the negative-value limit
    up to its cap.

    **Arguments:** `value`, the samples ``(n,)`` (any unit).

    **Returns:** sigma in the unit of `value` (0 for fewer than 5 samples).
    """
    value = np.asarray(value, dtype=float)
    if value.size < 5:
        return 0.0
    second = np.diff(value, 2)
    return float(1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))


def negative_limit(value: np.ndarray) -> tuple[float, float]:
    """The most negative value accepted as noise in a curve, and the noise it follows.

    ``-max(NEGATIVE_FRACTION × peak, min(NOISE_SIGMAS × sigma, MAX_NEGATIVE_FRACTION × peak))``
    with sigma from :func:`noise_level`.

    **Returns:** ``(limit, sigma)`` in the unit of `value` (limit <= 0).
    """
    value = np.asarray(value, dtype=float)
    peak = max(float(np.max(value)) if value.size else 0.0, 0.0)
    sigma = noise_level(value)
    depth = max(NEGATIVE_FRACTION * peak, min(NOISE_SIGMAS * sigma, MAX_NEGATIVE_FRACTION * peak))
    return -depth, sigma


def seconds_per(time_unit: str) -> float:
    """Seconds in one `time_unit` (``'s'``, ``'ms'``, ``'min'`` or ``'h'``)."""
    try:
        return TIME_UNIT_SECONDS[time_unit]
    except KeyError:
        raise ValueError(f"unknown time unit {time_unit!r}; known: "
                         f"{', '.join(TIME_UNIT_SECONDS)}") from None


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
    - `time_unit`: unit of `time` as read from the header (``"s"`` when none was given):
      ``"s"``, ``"ms"``, ``"min"`` or ``"h"``.
    - `source`: where the curve came from (file path), or ``None``.
    - `value_unit`: unit of the raw values as the header gives it (``"g/L"``), or ``None``
      when it gives none.
    - `normalised`: whether `value` was divided by its own trapezoid area (then it is E in
      1/`time_unit` and `value_unit` no longer applies).
    - `exposure`: for counts, shape ``(n,)``: ``value × exposure`` is the number of
      particles counted at each point (a histogram's bin widths in `time_unit`, times the
      area when normalised), whose noise is Poisson; ``None`` for a measured signal.
    """

    name: str
    time: np.ndarray
    value: np.ndarray
    time_unit: str = "s"
    source: str | None = None
    value_unit: str | None = None
    normalised: bool = False
    exposure: np.ndarray | None = None

    def __post_init__(self) -> None:
        time = np.array(self.time, dtype=float)
        value = np.array(self.value, dtype=float)
        if time.ndim != 1 or value.shape != time.shape:
            raise ValueError(
                f"curve {self.name!r}: time and value must be 1-D of equal length, got shapes "
                f"{time.shape} and {value.shape}"
            )
        seconds_per(self.time_unit)
        if self.exposure is not None:
            exposure = np.array(self.exposure, dtype=float)
            if exposure.shape != time.shape or not np.all(np.isfinite(exposure)) or np.any(
                    exposure < 0):
                raise ValueError(f"curve {self.name!r}: exposure must be finite, non-negative "
                                 f"and of the times' shape {time.shape}")
            exposure.flags.writeable = False
            object.__setattr__(self, "exposure", exposure)
        time.flags.writeable = False
        value.flags.writeable = False
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "value", value)

    def __len__(self) -> int:
        return self.time.shape[0]

    @property
    def seconds_per_time_unit(self) -> float:
        """Seconds in one unit of `time` (60 for a curve in minutes)."""
        return seconds_per(self.time_unit)

    def __repr__(self) -> str:
        return (
            f"Curve(name={self.name!r}, {len(self)} points, t = {self.time[0]:g}..."
            f"{self.time[-1]:g} {self.time_unit}, source={self.source!r})"
        )


def _pick_column(table: Table, wanted: str | int | None, candidates: set[str],
                 role: str) -> Column | None:
    """The column called `wanted` (name or index), else the one with a known spelling."""
    if wanted is not None:
        try:
            return table.column(wanted)
        except DataError as error:
            raise table.error(f"{role} column: {error.problem}") from None
    matches = [c for c in table.columns if c.name in candidates or c.label.lower() in candidates]
    if len(matches) > 1:
        listed = ", ".join(repr(c.label) for c in matches)
        raise table.error(f"several possible {role} columns ({listed}); choose one with "
                          f"{role}_column (--{role}-column)")
    return matches[0] if matches else None


def curve_columns(table: Table, time_column: str | int | None = None,
                  value_column: str | int | None = None) -> tuple[Column, Column]:
    """The time and value columns of a table, as :func:`read_rtd_csv` chooses them.

    **Arguments:**

    - `table`: the open table (:func:`axialmix._csv.read_table`).
    - `time_column`, `value_column`: a column name or 0-based index, or ``None`` to recognise
      it from the header spellings (or take the other of two columns).

    **Returns:** ``(time, value)`` columns; a :class:`DataError` naming the file and the
    columns when they cannot be told.
    """
    labels = ", ".join(c.label for c in table.columns)
    if len(table.columns) < 2:
        raise table.error(f"missing column: found {len(table.columns)} column, need time and "
                          "value")
    time = _pick_column(table, time_column, _TIME_NAMES, "time")
    value = _pick_column(table, value_column, _VALUE_NAMES, "value")
    two = len(table.columns) == 2
    if time is None and value is None and two:
        time, value = table.columns
    elif time is None and two:
        time = table.columns[1 - value.index]
    elif value is None and two:
        value = table.columns[1 - time.index]
    if time is None:
        raise table.error(f"missing time column (columns: {labels}); name it 't' or 'time', "
                          "or choose it with time_column (--time-column)")
    if value is None:
        raise table.error(f"extra columns, cannot tell which is the concentration (columns: "
                          f"{labels}); choose it with value_column (--value-column)")
    if time.index == value.index:
        raise table.error(f"time and value are the same column {time.label!r}")
    return time, value


def _first(mask: np.ndarray) -> int | None:
    hits = np.flatnonzero(mask)
    return int(hits[0]) if hits.size else None


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
    decimal: str = "auto",
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
      1/(time unit), for looking at a curve and its moments. Fits use the raw signal
      (``False``) with :func:`fitting.measurement.measured`: dividing by the area of the
      samples biases E when sampling is sparse or the tail is cut.
    - `min_points`: fewest data rows accepted.
    - `on_truncated`: what to do when the last value is still above 5 % of the peak (the curve
      never returned to baseline, so area and moments are biased): ``'warn'`` (default,
      :class:`DataWarning`), ``'error'`` (:class:`DataError`) or ``'ignore'``.
    - `name`: the curve's label; by default the file name without extension.
    - `decimal`: ``'auto'`` (default: decimal commas detected), ``'.'`` or ``','`` (see
      :func:`axialmix._csv.read_table`).

    **Returns:**

    A :class:`Curve` with time in the file's unit and E in 1/(that unit).

    **Raises:**

    :class:`DataError` (a ``ValueError``) with one line ``"<file>, row <r>: <problem>"`` for a
    missing, binary or UTF-16 file, missing or extra columns, non-numeric, empty or NaN cells,
    negative times, values more than ``NEGATIVE_FRACTION`` (5 %) of the peak below zero
    (smaller dips are noise and are kept), times not strictly increasing, too few points, an
    all-zero curve, or values so small or large that normalising would underflow or overflow.
    """
    path = Path(path)
    if on_truncated not in {"warn", "error", "ignore"}:
        raise ValueError(f"on_truncated must be 'warn', 'error' or 'ignore', got {on_truncated!r}")
    if not (baseline is None or baseline in ("first", "min") or (
            isinstance(baseline, int | float) and not isinstance(baseline, bool))):
        raise ValueError(f"baseline must be None, 'first', 'min' or a number, got {baseline!r}")
    table = read_table(path, decimal=decimal, suffix_units=tuple(_TIME_UNITS))

    def columns_of(table):
        counting = counting_columns(table, time_column, value_column)
        if counting is not None:
            return counting
        return (*curve_columns(table, time_column, value_column), None)

    time_col, value_col, bin_col = columns_of(table)
    time_unit = column_time_unit(table, time_col)
    wanted = [time_col.index, value_col.index] + ([bin_col.index] if bin_col else [])
    try:
        rows, data = table.numbers(wanted)
    except DataError as error:
        # Detection looks at the first data row only; a first row without decimals ("0;0")
        # leaves decimal commas further down undetected, so read once more with them.
        if not (decimal == "auto" and table.decimal == "." and table.delimiter != ","
                and error.problem.startswith("non-numeric cell") and "," in error.problem):
            raise
        table = read_table(path, decimal=",", suffix_units=tuple(_TIME_UNITS))
        time_col, value_col, bin_col = columns_of(table)
        wanted = [time_col.index, value_col.index] + ([bin_col.index] if bin_col else [])
        rows, data = table.numbers(wanted)
    label = name if name is not None else path.stem
    if value_col.name not in _COUNT_NAMES:
        return validated_curve(path, rows, data[:, 0], data[:, 1], time_unit=time_unit,
                               value_unit=value_col.unit, name=label, baseline=baseline,
                               normalise=normalise, min_points=min_points,
                               on_truncated=on_truncated)
    if baseline is not None:
        raise DataError(path, f"column {value_col.label!r} holds counts: a baseline cannot be "
                        "subtracted from them")
    time, counts = data[:, 0], data[:, 1]
    bad = _first((counts < 0) | (counts != np.rint(counts)))
    if bad is not None:
        raise DataError(path, f"count {counts[bad]:g} in column {value_col.label!r} is not a "
                        "whole number of particles at least 0", int(rows[bad]))
    if bin_col is not None:
        width = data[:, 2] * _bin_unit_factor(table, bin_col, time_unit)
        bad = _first(~(width > 0))
        if bad is not None:
            raise DataError(path, f"bin width {data[bad, 2]:g} in column {bin_col.label!r} is "
                            "not positive", int(rows[bad]))
    elif time.size >= 2:
        steps = np.diff(time)
        width = np.concatenate([steps[:1], steps])
        if np.any(steps <= 0):  # validated_curve names the row
            width = np.ones_like(time)
    else:
        width = np.ones_like(time)
    return validated_curve(path, rows, time, counts / width, time_unit=time_unit,
                           value_unit=f"particles/{time_unit}", name=label,
                           normalise=normalise, min_points=min_points,
                           on_truncated=on_truncated, exposure=width)


def counting_columns(table: Table, time_column: str | int | None = None,
                     value_column: str | int | None = None
                     ) -> tuple[Column, Column, Column | None] | None:
    """The time, count and bin-width columns of a counting table, or ``None`` for a signal.

    A table is a counting one when its value column (`value_column`, or, when that is not
    given, the one column named as a count: ``count``, ``counts``, ``particles``) holds
    counts; the bin widths are the column named ``bin`` (``bin_width``, ``width``) if any.

    **Arguments:** as :func:`curve_columns`.

    **Returns:** ``(time, count, bin or None)``, or ``None`` when the values are no counts.
    """
    if value_column is not None:
        value = _pick_column(table, value_column, set(), "value")
        if value.name not in _COUNT_NAMES:
            return None
    else:
        found = [c for c in table.columns if c.name in _COUNT_NAMES]
        if not found:
            return None
        if len(found) > 1:
            listed = ", ".join(repr(c.label) for c in found)
            raise table.error(f"several count columns ({listed}); choose one with "
                              "value_column (--value-column)")
        value = found[0]
    time = _pick_column(table, time_column, _TIME_NAMES, "time")
    if time is None:
        time = table.columns[0] if value.index != 0 else None
    if time is None or time.index == value.index:
        raise table.error(f"missing time column beside the counts {value.label!r}; name it "
                          "'t' or 'time', or choose it with time_column (--time-column)")
    bins = [c for c in table.columns if c.name in _BIN_NAMES
            and c.index not in (time.index, value.index)]
    if len(bins) > 1:
        listed = ", ".join(repr(c.label) for c in bins)
        raise table.error(f"several bin-width columns ({listed}); keep one")
    return time, value, bins[0] if bins else None


def _bin_unit_factor(table: Table, column: Column, time_unit: str) -> float:
    """Time units (of the time column) in one unit of a bin-width column (its header's unit,
    read as a time column's is; none: the time column's)."""
    if column.unit is None:
        return 1.0
    return seconds_per(column_time_unit(table, column)) / seconds_per(time_unit)


def column_time_unit(table: Table, column: Column) -> str:
    """The time unit a time column's header gives (``"s"`` when it gives none).

    **Arguments:** `table`, the open table; `column`, its time column.

    **Returns:** ``"s"``, ``"ms"``, ``"min"`` or ``"h"``; a :class:`DataError` at the header
    for a unit that is not a time unit.
    """
    if column.unit is None:
        # "time_days", "t_us": a time name with a suffix that is not a known unit.
        stem, underscore, suffix = column.name.rpartition("_")
        if underscore and stem in _TIME_NAMES and suffix:
            raise table.error(f"unknown time unit {suffix!r} in {column.label!r} "
                              f"(known: s, ms, min, h)")
        # "time in min", "minutes": a unit in words the header grammar does not read, which
        # would otherwise be taken for seconds without a word.
        for word in re.findall(r"[a-z]+", column.label.lower()):
            if word in _TIME_UNITS:
                raise table.error(f"the time column {column.label!r} names its unit as "
                                  f"{word!r} in a way not read; write 'time ({word})' or "
                                  f"'time [{word}]'")
        return "s"
    if column.unit.lower() not in _TIME_UNITS:
        raise table.error(f"unknown time unit {column.unit!r} in {column.label!r} "
                          f"(known: s, ms, min, h)")
    return _TIME_UNITS[column.unit.lower()]


def validated_curve(
    path: str | Path,
    rows: np.ndarray,
    time: np.ndarray,
    value: np.ndarray,
    *,
    time_unit: str = "s",
    value_unit: str | None = None,
    name: str | None = None,
    baseline: None | str | float = None,
    normalise: bool = True,
    min_points: int = 5,
    on_truncated: str = "warn",
    exposure: np.ndarray | None = None,
) -> Curve:
    """Check the samples of one curve read from a file and make them a :class:`Curve`.

    The checks and options of :func:`read_rtd_csv`, for samples read by any reader (one
    curve of a long study table, say), with errors naming `path` and the row.

    **Arguments:**

    - `path`: the file the samples come from.
    - `rows`: the line number in the file of each sample, shape ``(n,)``.
    - `time`, `value`: the samples, shape ``(n,)``; time in `time_unit`.
    - `time_unit`, `value_unit`: their units (`value_unit` ``None`` when unknown).
    - `name`: the curve's label (default: the file name without extension).
    - `baseline`, `normalise`, `min_points`, `on_truncated`: as in :func:`read_rtd_csv`.
    - `exposure`: for counts, ``value × exposure`` the count at each point (see
      :class:`Curve`); ``None`` for a signal.

    **Returns:** the :class:`Curve`; :class:`DataError` naming file and row for bad samples.
    """
    path = Path(path)
    time = np.asarray(time, dtype=float)
    value = np.asarray(value, dtype=float)
    data = np.stack([time, value], axis=1)
    problems = []
    bad = _first(time < 0)
    if bad is not None:
        problems.append((bad, f"negative time {time[bad]:g}"))
    peak_value = float(np.max(value)) if value.size else 0.0
    limit, sigma = negative_limit(value)
    bad = _first(value < limit)
    if bad is not None:
        if peak_value > 0:
            depth = f"{100 * -value[bad] / peak_value:.3g} % of the peak {peak_value:.4g}"
            accepted = (f"noise around a baseline is accepted down to {limit:.3g} "
                        f"({100 * -limit / peak_value:.3g} % of the peak; the curve's noise "
                        f"is {sigma:.3g})")
        else:
            depth = "and no value above zero"
            accepted = "no tracer signal above the baseline"
        label = f"curve {name!r}: " if name is not None and name != path.stem else ""
        problems.append((bad, f"{label}negative value {value[bad]:g} ({depth}; {accepted})"))
    bad = _first(np.diff(time) <= 0)
    if bad is not None:
        kind = "repeated" if time[bad + 1] == time[bad] else "not increasing"
        problems.append((bad + 1, f"times not increasing ({time[bad + 1]:g} after "
                         f"{time[bad]:g}; {kind})"))
    bad = _first(np.any(np.abs(data) > LARGEST_VALUE, axis=1))  # the row, not the cell
    if bad is not None:
        problems.append((bad, f"value {np.max(np.abs(data[bad])):g} is too large (above "
                         f"{LARGEST_VALUE:g}); rescale the column"))
    if problems:
        index, problem = min(problems)
        raise DataError(path, problem, int(rows[index]))
    if len(time) < min_points:
        label = f"curve {name!r}: " if name is not None and name != path.stem else ""
        where = f" (row {int(rows[0])})" if len(rows) == 1 else (
            f" (rows {int(rows[0])} to {int(rows[-1])})" if len(rows) else "")
        raise DataError(path, f"too few points: {label}{len(time)} data "
                        f"row{'s' if len(time) != 1 else ''}, at least {min_points} "
                        f"needed{where}")
    span = float(time[-1] - time[0])
    if not TIME_SPAN_RANGE[0] <= span <= TIME_SPAN_RANGE[1]:
        raise DataError(path, f"the times span {span:.3g} {time_unit}, outside "
                        f"{TIME_SPAN_RANGE[0]:g} to {TIME_SPAN_RANGE[1]:g} {time_unit}: a model's "
                        "values and derivatives would over- or underflow; rescale the time column")
    if baseline == "first":
        value = value - value[0]
    elif baseline == "min":
        value = value - value.min()
    elif baseline is not None:
        value = value - float(baseline)
    peak = float(np.max(np.abs(value)))
    if peak == 0.0:
        raise DataError(path, "all-zero curve (no tracer signal above the baseline)")
    if peak < SMALLEST_PEAK:
        raise DataError(path, f"values too small (peak {peak:.3g}, below {SMALLEST_PEAK:g}): "
                        "normalising would underflow; rescale the value column")
    area = float(np.trapezoid(value / peak, time)) * peak
    if not math.isfinite(area):
        raise DataError(path, "the area under the curve overflows; rescale the columns")
    if area <= 0.0:
        raise DataError(path, "the curve has no positive area above the baseline")
    if on_truncated != "ignore" and value[-1] > TAIL_FRACTION * peak:
        error = DataError(
            path, f"the curve never returns to baseline (last value {value[-1]:.3g} is "
            f"{100 * value[-1] / peak:.0f} % of the peak); its own area and moments are "
            "underestimated (a fit of the raw curve is not: the model supplies the tail)",
            int(rows[-1]))
        if on_truncated == "error":
            raise error
        warnings.warn(str(error), DataWarning, stacklevel=2)
    if normalise:
        # Divide by the peak first, so that neither the area nor E under- or overflows.
        value = (value / peak) / (area / peak)
        if exposure is not None:
            exposure = np.asarray(exposure, float) * area
        if not np.all(np.isfinite(value)):
            raise DataError(path, "normalising the curve overflows (the sampled time span is "
                            "too short for its values); rescale the columns")
    return Curve(
        name=name if name is not None else path.stem,
        time=time,
        value=value,
        time_unit=time_unit,
        source=str(path),
        value_unit=None if normalise else value_unit,
        normalised=bool(normalise),
        exposure=exposure,
    )


def read_inlet_csv(
    path: str | Path,
    *,
    time_unit: str | None = None,
    time_column: str | int | None = None,
    value_column: str | int | None = None,
    decimal: str = "auto",
) -> Curve:
    """Read a measured inlet signal (the injected tracer pulse) with the curve reader.

    The file is read and checked like a residence-time curve (:func:`read_rtd_csv`, raw
    values, noise down to -5 % of the peak kept); an inlet need not return to zero within
    the file. Its area is left as measured: :class:`fitting.measurement.Inlet` normalises it.

    **Arguments:**

    - `path`: the CSV file (time and inlet signal, any value unit).
    - `time_unit`: convert the times to this unit (the outlet curve's), or ``None`` to keep
      the file's.
    - `time_column`, `value_column`, `decimal`: as in :func:`read_rtd_csv`.

    **Returns:** a :class:`Curve` of the inlet signal (at least two samples).

    **Raises:** :class:`DataError` naming the file and row, as :func:`read_rtd_csv`.
    """
    curve = read_rtd_csv(path, time_column=time_column, value_column=value_column,
                         normalise=False, min_points=2, on_truncated="ignore", decimal=decimal)
    if time_unit is not None and time_unit != curve.time_unit:
        factor = seconds_per(curve.time_unit) / seconds_per(time_unit)
        curve = Curve(name=curve.name, time=curve.time * factor, value=curve.value,
                      time_unit=time_unit, source=curve.source, value_unit=curve.value_unit)
    return curve


def input_files(inputs: Iterable[str | Path], pattern: str = "*.csv") -> list[Path]:
    """The data files named by paths of files and folders (every CSV file in a folder).

    **Arguments:**

    - `inputs`: file and folder paths.
    - `pattern`: file-name pattern inside folders, matched case-insensitively (``*.csv``
      finds ``RUN.CSV`` too).

    **Returns:** the files, folders expanded in file-name order.

    **Raises:** :class:`DataError` for a missing path, an empty folder, a file given twice,
    or two files with the same name (their results would overwrite each other).
    """
    files: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.iterdir()
                           if p.is_file() and fnmatch.fnmatch(p.name.lower(), pattern.lower()))
            if not found:
                raise DataError(path, f"no files matching {pattern!r} in this folder")
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise DataError(path, "file not found")
    seen: dict[str, Path] = {}
    for path in files:
        first = seen.setdefault(path.stem, path)
        if first is path:
            continue
        if first.resolve() == path.resolve():
            raise DataError(path, "given twice")
        raise DataError(path, f"has the name {path.stem!r} of {first} too; their results "
                        "would overwrite each other")
    return files


def read_many(
    paths_or_folder: str | Path | Iterable[str | Path], *, pattern: str = "*.csv", **options
) -> list[Curve]:
    """Read several residence-time CSV files (a list of paths, or every CSV in a folder).

    **Arguments:**

    - `paths_or_folder`: a folder (all files matching `pattern`, case-insensitively, sorted
      by name), one file, or an iterable of file paths.
    - `pattern`: glob pattern used inside a folder.
    - `options`: passed to :func:`read_rtd_csv` (``baseline``, ``normalise``, ...).

    **Returns:**

    A list of :class:`Curve`, in file-name order for a folder, in the given order otherwise.
    The first bad file raises its :class:`DataError`.
    """
    if isinstance(paths_or_folder, str | Path):
        paths = input_files([paths_or_folder], pattern)
    else:
        paths = [Path(p) for p in paths_or_folder]
    return [read_rtd_csv(p, **options) for p in paths]


def as_curve(data: Curve | Sequence) -> Curve:
    """A :class:`Curve` from a curve or a ``(time, values)`` pair (time unit seconds)."""
    if isinstance(data, Curve):
        return data
    try:
        time, value = data
    except (TypeError, ValueError):
        raise ValueError("data must be a Curve or a (time, values) pair") from None
    return Curve(name="", time=np.asarray(time, dtype=float), value=np.asarray(value, float))
