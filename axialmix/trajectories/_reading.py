"""Reading PEPT trajectory files (CSV with a header naming columns and units)."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path
from typing import Literal

import numpy as np

from ._trajectory import Trajectory

_COLUMN_ALIASES = {
    "time": {"t", "time", "times", "timestamp"},
    "x": {"x", "xpos", "x_position", "position_x", "pos_x"},
    "y": {"y", "ypos", "y_position", "position_y", "pos_y"},
    "z": {"z", "zpos", "z_position", "position_z", "pos_z", "axial", "axial_position"},
    "id": {
        "id", "trajectory", "trajectory_id", "traj", "traj_id", "track", "track_id",
        "particle", "particle_id", "tracer", "tracer_id", "pid",
    },
}
_LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3}
_UNIT_IN_HEADER = re.compile(r"^(?P<name>.*?)\s*(?:\((?P<p>[^)]*)\)|\[(?P<b>[^\]]*)\])\s*$")


def _parse_header_cell(cell: str) -> tuple[str, str | None]:
    """Split a header cell such as ``'x (mm)'``, ``'x [mm]'``, ``'X_mm'`` into name and unit."""
    text = cell.strip().lstrip("\ufeff").strip().lower()
    match = _UNIT_IN_HEADER.match(text)
    if match:
        unit = (match.group("p") or match.group("b") or "").strip()
        return match.group("name").strip().replace(" ", "_"), unit or None
    if "/" in text:
        name, unit = text.rsplit("/", 1)
        return name.strip().replace(" ", "_"), unit.strip() or None
    text = text.replace(" ", "_")
    for unit in ("_mm", "_cm", "_ms", "_m", "_s"):
        stem = text[: -len(unit)]
        if text.endswith(unit) and any(stem in aliases for aliases in _COLUMN_ALIASES.values()):
            return stem, unit[1:]
    return text, None


def _resolve_unit(
    path: Path, kind: str, requested: str | None, stated: set[str], table: dict[str, float]
) -> float:
    """Scale factor to SI for a quantity whose unit may be requested and/or stated in headers."""
    for unit in stated | ({requested} if requested else set()):
        if unit not in table:
            raise ValueError(
                f"{path}: row 1: unknown {kind} unit {unit!r} (known: {', '.join(table)})."
            )
    if len(stated) > 1:
        raise ValueError(f"{path}: row 1: {kind} columns state different units {sorted(stated)}.")
    if requested and stated and requested not in stated:
        raise ValueError(
            f"{path}: row 1: header states {kind} unit {next(iter(stated))!r} but "
            f"{kind}_unit={requested!r} was requested."
        )
    unit = requested or (next(iter(stated)) if stated else ("m" if kind == "length" else "s"))
    return table[unit]


def read_trajectories(
    path: str | Path,
    *,
    length_unit: Literal["m", "cm", "mm"] | None = None,
    time_unit: Literal["s", "ms"] | None = None,
    min_points: int = 3,
) -> list[Trajectory]:
    """Read tracked-particle trajectories from a CSV file into SI units.

    The file has a header row naming the columns ``t, x, y, z`` and optionally a trajectory
    id column; header spellings such as ``time``, ``T``, ``x (mm)``, ``x [mm]``, ``x_mm``,
    ``z/m``, ``trajectory_id``, ``track``, ``particle`` are recognised (case-insensitive) and
    extra columns are ignored. Cells are separated by commas, semicolons or tabs (or by
    spaces when the header has none of these; header names then have no spaces); blank
    lines and lines starting with ``#`` are skipped. Without an id column the whole file is
    one trajectory named after the file. Rows of one trajectory need not be contiguous but
    must have strictly increasing times. Errors are one-line ``ValueError`` messages naming
    the file, the row (the line number in the file, header = row 1, as in a spreadsheet)
    and the problem.

    **Arguments:**

    - `path`: the CSV file.
    - `length_unit`: unit of x, y, z in the file, ``"m"``, ``"cm"`` or ``"mm"``. ``None``
      (default) takes the unit stated in the header (``x (mm)``), else metres. A requested
      unit that contradicts the header is an error.
    - `time_unit`: unit of t in the file, ``"s"`` or ``"ms"``; ``None`` as for lengths,
      default seconds.
    - `min_points`: fewest samples accepted per trajectory (at least 2).

    **Returns:**

    The trajectories in order of first appearance, times in s and positions in m.
    """
    path = Path(path)
    if int(min_points) != min_points or min_points < 2:
        raise ValueError(f"min_points must be an integer of at least 2, got {min_points!r}.")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as error:
        raise ValueError(f"{path}: cannot be read ({error.strerror}).") from None
    numbered = [
        (number, line)
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise ValueError(f"{path}: the file is empty (a header row t, x, y, z is needed).")
    header_row, header_line = numbered[0]
    delimiter = max([",", ";", "\t"], key=header_line.count)

    def split_cells(line: str) -> list[str]:
        if header_line.count(delimiter) == 0:
            return line.split()
        return next(csv.reader([line], delimiter=delimiter))

    header = split_cells(header_line)
    parsed = [_parse_header_cell(cell) for cell in header]

    columns: dict[str, int] = {}
    units: dict[str, str | None] = {}
    for index, (name, unit) in enumerate(parsed):
        for role, aliases in _COLUMN_ALIASES.items():
            if name in aliases:
                if role in columns:
                    raise ValueError(
                        f"{path}: row {header_row}: two columns give {role!r} "
                        f"({header[columns[role]].strip()!r} and {header[index].strip()!r})."
                    )
                columns[role] = index
                units[role] = unit
    missing = [role for role in ("time", "x", "y", "z") if role not in columns]
    if missing:
        found = ", ".join(cell.strip() for cell in header)
        raise ValueError(
            f"{path}: row {header_row}: missing column(s) {', '.join(missing)} "
            f"(found: {found}); expected t, x, y, z and optionally a trajectory id."
        )
    length_scale = _resolve_unit(
        path, "length", length_unit,
        {units[r] for r in ("x", "y", "z") if units[r] is not None}, _LENGTH_UNITS,
    )
    time_scale = _resolve_unit(
        path, "time", time_unit,
        {units["time"]} if units["time"] is not None else set(), _TIME_UNITS,
    )

    records: dict[str, list[tuple[int, float, float, float, float]]] = {}
    default_id = path.stem
    for row, line in numbered[1:]:
        cells = split_cells(line)
        if len(cells) < len(header):
            raise ValueError(
                f"{path}: row {row}: expected {len(header)} cells, found {len(cells)}."
            )
        values = []
        for role in ("time", "x", "y", "z"):
            cell = cells[columns[role]].strip()
            column = header[columns[role]].strip()
            if not cell:
                raise ValueError(f"{path}: row {row}: column {column!r} is empty.")
            try:
                value = float(cell)
            except ValueError:
                raise ValueError(
                    f"{path}: row {row}: column {column!r} is not a number: {cell!r}."
                ) from None
            if not math.isfinite(value):
                raise ValueError(
                    f"{path}: row {row}: column {column!r} is {cell!r}; finite numbers needed."
                )
            values.append(value)
        if "id" in columns:
            trajectory_id = cells[columns["id"]].strip()
            if not trajectory_id:
                column = header[columns["id"]].strip()
                raise ValueError(f"{path}: row {row}: column {column!r} is empty.")
        else:
            trajectory_id = default_id
        previous = records.setdefault(trajectory_id, [])
        if previous and values[0] <= previous[-1][1]:
            raise ValueError(
                f"{path}: row {row}: time {values[0]:g} of trajectory {trajectory_id!r} is not "
                f"greater than the previous time {previous[-1][1]:g} (row {previous[-1][0]})."
            )
        previous.append((row, *values))
    if not records:
        raise ValueError(f"{path}: the file has a header but no data rows.")

    trajectories = []
    for trajectory_id, rows in records.items():
        if len(rows) < min_points:
            raise ValueError(
                f"{path}: row {rows[0][0]}: trajectory {trajectory_id!r} has {len(rows)} "
                f"point(s) (rows {rows[0][0]}-{rows[-1][0]}); at least {min_points} are needed."
            )
        data = np.array([r[1:] for r in rows], dtype=float)
        trajectories.append(
            Trajectory(
                time=data[:, 0] * time_scale,
                x=data[:, 1] * length_scale,
                y=data[:, 2] * length_scale,
                z=data[:, 3] * length_scale,
                trajectory_id=trajectory_id,
            )
        )
    return trajectories
