"""Reading PEPT trajectory files (CSV with a header naming columns and units)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from .._csv import DataError, Table, read_table
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
_SUFFIX_UNITS = ("mm", "cm", "ms", "m", "s")  # header suffixes such as ``X_mm``, ``time_s``


def _resolve_unit(
    table: Table, kind: str, requested: str | None, stated: set[str], scales: dict[str, float]
) -> float:
    """Scale factor to SI for a quantity whose unit may be requested and/or stated in headers."""
    for unit in stated | ({requested} if requested else set()):
        if unit not in scales:
            raise table.error(f"unknown {kind} unit {unit!r} (known: {', '.join(scales)})")
    if len(stated) > 1:
        raise table.error(f"{kind} columns state different units {sorted(stated)}")
    if requested and stated and requested not in stated:
        raise table.error(
            f"header states {kind} unit {next(iter(stated))!r} but "
            f"{kind}_unit={requested!r} was requested"
        )
    unit = requested or (next(iter(stated)) if stated else ("m" if kind == "length" else "s"))
    return scales[unit]


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
    must have strictly increasing times. The file is read by the shared table reader
    (:mod:`axialmix._csv`, streamed); errors are one-line ``DataError`` (a ``ValueError``)
    messages ``"<file>, row <r>: <problem>"``, the row being the line number in the file.

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
    table = read_table(path, header=True, suffix_units=_SUFFIX_UNITS)
    header = [column.label for column in table.columns]

    columns: dict[str, int] = {}
    units: dict[str, str | None] = {}
    for column in table.columns:
        name = column.name.replace(" ", "_")
        for role, aliases in _COLUMN_ALIASES.items():
            if name in aliases:
                if role in columns:
                    raise table.error(
                        f"two columns give {role!r} ({header[columns[role]]!r} and "
                        f"{column.label!r})"
                    )
                columns[role] = column.index
                units[role] = column.unit.lower() if column.unit else None
    missing = [role for role in ("time", "x", "y", "z") if role not in columns]
    if missing:
        found = ", ".join(header)
        raise table.error(
            f"missing column(s) {', '.join(missing)} (found: {found}); expected t, x, y, z "
            "and optionally a trajectory id"
        )
    length_scale = _resolve_unit(
        table, "length", length_unit,
        {units[r] for r in ("x", "y", "z") if units[r] is not None}, _LENGTH_UNITS,
    )
    time_scale = _resolve_unit(
        table, "time", time_unit,
        {units["time"]} if units["time"] is not None else set(), _TIME_UNITS,
    )
    numbered, values = table.numbers(
        [columns[role] for role in ("time", "x", "y", "z")], allow_extra_cells=True
    )
    if "id" in columns:
        index, label = columns["id"], header[columns["id"]]
        ids = []
        for row, cells in table.rows(allow_extra_cells=True):
            identifier = cells[index].strip().strip('"').strip()
            if not identifier:
                raise table.error(f"empty cell in column {label!r}", row)
            ids.append(identifier)
    else:
        ids = [path.stem] * len(numbered)

    records: dict[str, list[tuple[int, float, float, float, float]]] = {}
    for row, trajectory_id, sample in zip(numbered.tolist(), ids, values.tolist(), strict=True):
        previous = records.setdefault(trajectory_id, [])
        if previous and sample[0] <= previous[-1][1]:
            raise table.error(
                f"time {sample[0]:g} of trajectory {trajectory_id!r} is not greater than the "
                f"previous time {previous[-1][1]:g} (row {previous[-1][0]})",
                row,
            )
        previous.append((row, *sample))
    if not records:
        raise DataError(path, "the file has a header but no data rows")

    trajectories = []
    for trajectory_id, rows in records.items():
        if len(rows) < min_points:
            raise table.error(
                f"trajectory {trajectory_id!r} has {len(rows)} point(s) (rows "
                f"{rows[0][0]}-{rows[-1][0]}); at least {min_points} are needed",
                rows[0][0],
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
