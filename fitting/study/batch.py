"""Fitting the curves of a study in chunks: shared compiled solvers, a resumable summary, Dask.

Every curve is fitted exactly as ``axialmix fit`` fits one file (:func:`fitting.fit.fit` with
the measurement model and the error model of a :class:`StudyPlan`) and rendered by
:func:`fitting.report.fit_record`; this module computes no physics. What it adds is the
study around the fits:

* **One compiled solver for all curves.** The solver core compiles one single-start program
  per model, parameter layout and settings, and pads every curve with zero-weight points to
  16, 32, 64, ... samples (:func:`fitting.solve.padded_length`), so ragged time grids share a
  program per length class (curves of 15 to 60 samples: three programs, compiled once per
  process). A zero weight is an exact mask: the padded points add exactly zero to the loss,
  gradient and Jacobian (tested bit for bit). A curve with its own measured inlet signal has
  its own model, so its own program (compiled for that curve alone: slow for many curves).
* **Chunks.** Curves are fitted in chunks (:data:`DEFAULT_CHUNK` curves); only a chunk's
  results are held before they are written; afterwards the records stay in the journal and
  their summary-table lines in a temporary file beside it, and memory keeps only where each
  lies (32 bytes a curve): a study's memory is that of its chunks in flight, whatever the
  number of curves. ``summary.csv`` and ``summary.json`` are streamed from those files. In
  this process each chunk's compiled fits are started before the records of the chunk
  before are made and written (:func:`launch_chunk`), so that the two overlap.
* **Resumable.** Each finished chunk is appended to the journal ``summary.jsonl`` in the
  output folder (its first line describes the study and the settings; then one JSON line per
  curve) by one ``write`` and ``fsync`` (each curve's record in ``curves/`` is written beside
  it by a thread of its own, unless ``curve_files`` is false, and the summary waits for
  those files);
  ``summary.csv`` is rewritten atomically after the first chunk and then as often as keeps
  its rewriting under a tenth of the run (at most once a second; a table of 100,000 rows
  rewritten after every chunk would cost more than the fits), and always at the end. A run
  started again on the same folder, with the same study and settings, reads the journal and
  fits only the curves not in it: after Ctrl-C or a kill no finished curve is lost or fitted
  twice (a line torn by a kill during the write is dropped and its curve fitted again).
  ``summary.json`` (every curve's full record) is written at the end, and after Ctrl-C.
* **Dask.** With ``workers=N`` (a local cluster of N single-threaded processes) or a
  scheduler address, chunks are tasks (:func:`fit_chunk`, through :func:`map_chunks`); each
  worker process compiles its programs once and reuses them for every chunk it gets. A
  curve's fit does not depend on the chunk it is in or the process it runs in (every curve
  starts from its own moments with the plan's seed, as a single file does), so the summary
  equals the one-process summary (bit for bit in the tests; only the wall times differ).
  Dask is imported only then. Particle-simulation ensembles take the same path
  (:mod:`fitting.study.ensemble`).
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import functools
import json
import logging
import math
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import equinox as eqx
import numpy as np

from axialmix._files import csv_text, write_atomic, write_csv, write_json
from axialmix._heap import long_lived_frozen
from axialmix._progress import progress_bar
from fitting.data import Curve
from fitting.fit import fit, launch_many
from fitting.losses import ERROR_KINDS
from fitting.measurement import FREEABLE, INLET_KINDS, Inlet, measured
from fitting.models import MODELS, Model, network_model
from fitting.parameters import Parameter
from fitting.report import (
    fit_record,
    render_fit_png,
    summary_columns,
    summary_row,
    summary_rows,
    write_png,
)
from fitting.solve import MultiStart, enable_compilation_cache
from fitting.study.input import Study, factor_value

__all__ = ["CURVE_FOLDER", "DEFAULT_CHUNK", "JOURNAL_NAME", "StudyPlan", "StudyRun", "fit_chunk",
           "fit_chunk_drawn", "default_threads", "launch_chunk", "local_cluster", "map_chunks",
           "plan_model", "study_table"]

#: Curves per chunk (and per Dask task) unless told.
DEFAULT_CHUNK = 64
#: The journal of finished curves in an output folder.
JOURNAL_NAME = "summary.jsonl"
#: Chunks in flight per Dask worker (one running, one waiting).
CHUNKS_PER_WORKER = 2


class StudyPlan(eqx.Module):
    """How every curve of a study is fitted: model, measurement, parameter settings, errors.

    Plain values only (names, numbers, tuples), so that a plan travels to Dask workers and
    each worker builds the same model once.

    **Arguments:**

    - `model`: a registered model name (``"adm"``, ...) or a network file (``.json``/``.toml``).
    - `free`: measurement parameters fitted as well (``"dead_time"``, ``"baseline"``).
    - `inlet`: ``"pulse"`` (default), ``"step"``, or ``"sampled"`` with `inlet_samples`;
      curves with their own inlet signal (:attr:`fitting.study.input.Study.inlets`) use it.
    - `inlet_samples`: ``(times, values)`` of a measured inlet signal (the curves' time unit).
    - `parameters`: ``(name, Parameter)`` pairs: fixed, tied or bounded parameters.
    - `errors`: ``"combined"`` (default), ``"relative"`` or ``"absolute"``.
    - `starts`: number of starts, ``None`` for the model's default.
    - `length_m`: blender length (m) for ``v`` and ``D_z``, or ``None``.
    """

    model: str
    free: tuple[str, ...] = ()
    inlet: str = "pulse"
    inlet_samples: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    parameters: tuple[tuple[str, Parameter], ...] = ()
    errors: str = "combined"
    starts: int | None = None
    length_m: float | None = None

    def __check_init__(self):
        if self.errors not in ERROR_KINDS:
            raise ValueError(f"errors must be one of {', '.join(ERROR_KINDS)}, got "
                             f"{self.errors!r}")
        unknown = [name for name in self.free if name not in FREEABLE]
        if unknown:
            raise ValueError(f"free: {unknown[0]!r} is not a measurement parameter (choose "
                             f"from {', '.join(FREEABLE)})")
        if self.inlet not in INLET_KINDS:
            raise ValueError(f"inlet must be one of {', '.join(INLET_KINDS)}, got "
                             f"{self.inlet!r}")
        if (self.inlet == "sampled") != (self.inlet_samples is not None):
            raise ValueError("a sampled inlet needs its samples, and only a sampled inlet has "
                             "them")
        if self.starts is not None and self.starts < 1:
            raise ValueError(f"starts must be at least 1, got {self.starts}")
        if self.length_m is not None and not self.length_m > 0:
            raise ValueError(f"the length must be a positive number of metres, got "
                             f"{self.length_m}")

    def describe(self) -> dict[str, Any]:
        """The plan as plain JSON (the journal's record of how its curves were fitted)."""
        return {
            "model": self.model, "free": list(self.free), "inlet": self.inlet,
            "inlet_samples": None if self.inlet_samples is None
            else [list(self.inlet_samples[0]), list(self.inlet_samples[1])],
            "parameters": {name: {"value": _plain(p.value), "vary": p.vary,
                                  "min": _plain(p.min), "max": _plain(p.max), "expr": p.expr}
                           for name, p in self.parameters},
            "errors": self.errors, "starts": self.starts, "length_m": self.length_m,
        }


def _plain(number: float | None) -> float | str | None:
    """A number for JSON: infinite bounds as text."""
    return number if number is None or math.isfinite(number) else str(number)


@functools.lru_cache(maxsize=8)
def _base_model(name: str) -> Model:
    """The model of a plan's name, built once per process (a network file is read once)."""
    return MODELS[name] if name in MODELS else network_model(name)


@functools.lru_cache(maxsize=8)
def _study_inlet(kind: str, samples: tuple | None) -> Inlet:
    if kind == "pulse":
        return Inlet.pulse()
    if kind == "step":
        return Inlet.step()
    return Inlet.sampled(samples[0], samples[1], "inlet")


def plan_model(plan: StudyPlan, inlet: Curve | None = None) -> Model:
    """The measured model a plan fits a curve with (built once per process and inlet).

    **Arguments:** `plan`, the :class:`StudyPlan`; `inlet`, the curve's own inlet signal or
    ``None`` for the plan's.

    **Returns:** the :class:`~fitting.measurement.MeasuredModel`.
    """
    signal = Inlet.from_curve(inlet) if inlet is not None else _study_inlet(
        plan.inlet, plan.inlet_samples)
    return measured(_base_model(plan.model), signal, plan.free)


_CACHE_ENABLED = threading.Event()


def _launch_results(plan: StudyPlan, curves: Sequence[Curve],
                    inlets: Sequence[Curve | None] | None
                    ) -> Callable[[], tuple[list, dict[int, str]]]:
    """A chunk's fits started: the compiled fits run while the caller goes on; the returned
    function waits for them and gives the fits (``None`` for a refused curve) and the
    refused curves' reasons, by position."""
    if not _CACHE_ENABLED.is_set():
        enable_compilation_cache()
        _CACHE_ENABLED.set()
    settings = dict(plan.parameters)
    inlets = inlets if inlets is not None else [None] * len(curves)
    # Curves with the plan's inlet share one model: one batched fit for all of them.
    shared = [i for i, inlet in enumerate(inlets) if inlet is None]
    own = [i for i, inlet in enumerate(inlets) if inlet is not None]
    options = dict(loss="sse", errors=plan.errors, multistart=MultiStart(n_starts=plan.starts))
    launched = None
    if shared:
        try:
            launched = launch_many(plan_model(plan), [curves[i] for i in shared], settings,
                                   **options)
        except ValueError:
            own = sorted(own + shared)  # some curve cannot be fitted: find it, curve by curve

    def finish() -> tuple[list, dict[int, str]]:
        results: list = [None] * len(curves)
        alone = own
        if launched is not None:
            try:
                fitted = launched()
            except ValueError:
                alone = sorted(own + shared)  # as above, found only when the fits ended
            else:
                for i, result in zip(shared, fitted, strict=True):
                    results[i] = result
        refused: dict[int, str] = {}
        for i in alone:
            try:
                results[i] = fit(plan_model(plan, inlets[i]), curves[i], settings, **options)
            except ValueError as error:  # this curve is listed with its reason, the rest fitted
                refused[i] = f"curve {curves[i].name!r}: {' '.join(str(error).split())}"
                results[i] = None
        return results, refused

    return finish


def fit_chunk(plan: StudyPlan, curves: Sequence[Curve],
              inlets: Sequence[Curve | None] | None = None) -> list[dict[str, Any]]:
    """Fit a chunk of curves with a plan and render each fit as its JSON record.

    This is the task a Dask worker runs; the one-process run calls it too, so both give the
    same numbers.

    **Arguments:**

    - `plan`: the :class:`StudyPlan`.
    - `curves`: the curves (raw values, their files' units).
    - `inlets`: per curve its own inlet signal or ``None`` (then the plan's inlet).

    **Returns:** one :func:`fitting.report.fit_record` per curve, in order; for a curve that
    cannot be fitted, ``{"refused": reason}`` (one line naming the curve).
    """
    return launch_chunk(plan, curves, inlets)()


def launch_chunk(plan: StudyPlan, curves: Sequence[Curve],
                 inlets: Sequence[Curve | None] | None = None, *, drawn: bool = False
                 ) -> Callable[[], Any]:
    """:func:`fit_chunk` (with `drawn`: :func:`fit_chunk_drawn`) started: the chunk's
    compiled fits run while the caller goes on (it writes the records of the chunk before);
    the returned function waits for them and gives the task's result."""
    finish = _launch_results(plan, curves, inlets)

    def records() -> Any:
        results, refused = finish()
        rendered = [{"refused": refused[i]} if i in refused else
                    fit_record(result, None, source=curve.source, length_m=plan.length_m)
                    for i, (result, curve) in enumerate(zip(results, curves, strict=True))]
        if not drawn:
            return rendered
        return rendered, [None if result is None else render_fit_png(result)
                          for result in results]

    return records


def fit_chunk_drawn(plan: StudyPlan, curves: Sequence[Curve],
                    inlets: Sequence[Curve | None] | None = None
                    ) -> tuple[list[dict[str, Any]], list[bytes | None]]:
    """:func:`fit_chunk` and each fit's PNG (:func:`fitting.report.render_fit_png`, the
    figure a single file's fit draws; ``None`` for a refused curve): the task of a study run
    with plots.

    **Returns:** ``(records, images)``, both in the curves' order.
    """
    return launch_chunk(plan, curves, inlets, drawn=True)()


def study_table(rows: Sequence[Mapping[str, Any]], factors: Sequence[str]
                ) -> tuple[list[str], list[list[Any]]]:
    """The summary table of a study: one row per curve, rendered from the curves' records.

    **Arguments:**

    - `rows`: per curve ``{"curve": id, "levels": [factor text...], "record": fit record}``.
    - `factors`: the factor names.

    **Returns:** ``(header, rows)`` in the one summary schema of
    :func:`fitting.report.summary_rows`.
    """
    return summary_rows([row["record"] for row in rows], factors,
                        curves=[row["curve"] for row in rows],
                        levels=[row["levels"] for row in rows])


class StudyRun:
    """One run of a study into an output folder: resumes its journal, fits the rest in
    chunks (in this process or on Dask), keeps the summary files current.

    **Arguments:**

    - `plan`: the :class:`StudyPlan`.
    - `study`: the :class:`~fitting.study.input.Study`.
    - `folder`: the output folder (created if missing).
    - `chunk`: curves per chunk (and per Dask task).
    - `plots`: also draw each fitted curve's PNG (``curves/<curve>.png``, the figure of a
      single file's fit), written before the curve's record is journaled, so every curve
      the journal holds has its PNG.
    - `curve_files`: write each fitted curve's record as ``curves/<curve>.json`` too
      (``summary.json`` holds every record either way; ``funnel`` and ``divert`` take a
      curve of it by ``--curve``). Creating a file per curve is a third of a study's time
      on some disks: a study of many curves may leave them out.

    Opening a folder whose journal describes another study or other settings (``plots``
    and ``curve_files`` included: a resumed run draws or files all of its curves or none)
    is a one-line
    ``ValueError``. :attr:`lock` is held while results are appended and summaries written
    (a caller handling Ctrl-C takes it before writing the summary itself).
    """

    def __init__(self, plan: StudyPlan, study: Study, folder: str | Path,
                 chunk: int = DEFAULT_CHUNK, *, plots: bool = False,
                 curve_files: bool = True):
        if chunk < 1:
            raise ValueError(f"chunk must be at least 1 curve, got {chunk}")
        self.plan, self.study, self.chunk, self.plots = plan, study, int(chunk), bool(plots)
        self.curve_files = bool(curve_files)
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.journal = self.folder / JOURNAL_NAME
        if self.journal.exists() and not self.journal.is_file():
            raise ValueError(f"{self.journal} is not a file (a folder?): it cannot be the "
                             "study's journal; remove it or give another --out")
        self.lock = threading.Lock()
        self.header = {"study": study.source, "digest": study.digest(), "n_curves": len(study),
                       "factors": list(study.factors), "plan": plan.describe(),
                       "plots": self.plots, "curve_files": self.curve_files}
        #: Each curve's file name stem in ``curves/`` (:meth:`stem`): :func:`curve_file_stem`,
        #: with the study position appended to a stem an earlier curve took; only those
        #: renamed stems are kept, by study position.
        self._renamed: dict[int, str] = {}
        taken: set[str] = set()
        for position, name in enumerate(study.ids):
            stem = curve_file_stem(name)
            if stem in taken:
                stem = f"{stem}-{position + 1}"
                self._renamed[position] = stem
            taken.add(stem)
        self._columns: tuple[list[str], list[str], list[str]] | None = None
        #: Finished curves, by study position: where each one's record lies in the journal and
        #: its summary-table line in :attr:`_rows` (offset and size in bytes, -1 while not
        #: finished). Memory holds these 32 bytes a curve, whatever the study's size; the
        #: records and lines themselves stay on disk.
        self._finished = np.full((len(study), 4), -1, dtype=np.int64)
        #: The summary-table lines of the finished curves, as they finished (a temporary
        #: file, gone when the run is; a resumed run rebuilds it from the journal).
        self._rows = tempfile.TemporaryFile(dir=self.folder, prefix=".summary-rows-")
        #: Curves that could not be fitted, with their one-line reasons: those the study
        #: left out as read, then those refused by the fit (kept in the journal as well).
        self.refused: dict[str, str] = dict(study.refused)
        #: Curves (study positions) whose ``curves/`` record this run has written (as their
        #: chunk finished), by :attr:`_writer`, a thread of its own; :attr:`_file_writes` are
        #: its tasks.
        self._filed = np.zeros(len(study), dtype=bool)
        self._writer = concurrent.futures.ThreadPoolExecutor(1, "axialmix-records")
        self._file_writes: list[concurrent.futures.Future] = []
        #: When ``summary.csv`` was last rewritten (monotonic s), and how long that took.
        self._table_written = -math.inf
        self._table_seconds = 0.0
        self._resume()
        #: Curves the journal held when this run began.
        self.resumed = self.done

    @property
    def done(self) -> int:
        """The number of finished (fitted and journaled) curves."""
        return int(np.count_nonzero(self._finished[:, 0] >= 0))

    def stem(self, position: int) -> str:
        """The file name stem in ``curves/`` of the curve at study `position`."""
        renamed = self._renamed.get(position)
        return renamed if renamed is not None else curve_file_stem(self.study.ids[position])

    @property
    def pending(self) -> list[int]:
        """Indices (study order) of the curves not fitted yet."""
        ids, refused = self.study.ids, self.refused
        return [int(i) for i in np.flatnonzero(self._finished[:, 0] < 0)
                if ids[i] not in refused]

    def _resume(self) -> None:
        if not self.journal.exists():
            line = json.dumps(self.header, allow_nan=False) + "\n"
            write_atomic(self.journal, lambda stream: stream.write(line))
            return
        data = self.journal.read_bytes()
        lines = data.split(b"\n")
        kept = len(data) if data.endswith(b"\n") else len(data) - len(lines[-1])
        try:
            header = json.loads(lines[0])
        except ValueError:
            header = None
        if not isinstance(header, dict):
            raise ValueError(f"{self.journal}: not a study journal; choose another --out "
                             "folder or remove the file")
        same = ("digest", "n_curves", "factors", "plan")
        if {k: header.get(k) for k in same} != json.loads(json.dumps(
                {k: self.header[k] for k in same})):
            what = "data" if header.get("digest") != self.header["digest"] else "settings"
            raise ValueError(f"{self.journal}: holds a study with other {what}; continue it "
                             "with the same input and options, or choose another --out folder")
        if bool(header.get("plots", False)) != self.plots:
            earlier = "with" if header.get("plots", False) else "without"
            raise ValueError(f"{self.journal}: holds a study fitted {earlier} --plots; continue "
                             f"it {earlier} --plots (so that every curve has its PNG or none "
                             "has), or choose another --out folder")
        if bool(header.get("curve_files", True)) != self.curve_files:
            earlier = "without" if header.get("curve_files", True) else "with"
            raise ValueError(f"{self.journal}: holds a study fitted {earlier} "
                             f"--no-curve-files; continue it {earlier} --no-curve-files (so "
                             "that every curve has its record file or none has), or choose "
                             "another --out folder")
        index = {name: i for i, name in enumerate(self.study.ids)}
        offset = len(lines[0]) + 1
        for line in lines[1:-1]:
            try:
                row = json.loads(line)
            except ValueError:  # torn by a kill during its write: fitted again
                kept = offset
                break
            position = index.get(row.get("curve"))
            if position is None:
                raise ValueError(f"{self.journal}: curve {row.get('curve')!r} is not in the "
                                 "study")
            if self._finished[position, 0] < 0 and row["curve"] not in self.refused:
                self._keep(position, row, offset, len(line))
            offset += len(line) + 1
        if kept < len(data):
            with open(self.journal, "r+b") as stream:
                stream.truncate(kept)

    def _keep(self, position: int, row: Mapping[str, Any], offset: int, size: int) -> None:
        if "refused" in row["record"]:
            self.refused[row["curve"]] = row["record"]["refused"]
            return
        if self._columns is None:
            self._columns = summary_columns(row["record"], self.study.factors)
        _, names, extra = self._columns
        line = csv_text(None, [summary_row(row["curve"], row["levels"], row["record"], names,
                                           extra)]).encode("utf-8")
        self._rows.seek(0, os.SEEK_END)
        start = self._rows.tell()
        self._rows.write(line)
        self._finished[position] = (offset, size, start, len(line))

    def _append(self, indices: Sequence[int], records: Sequence[Mapping[str, Any]]) -> None:
        rows = [{"curve": self.study.ids[i], "levels": list(self.study.levels[i]),
                 "record": record} for i, record in zip(indices, records, strict=True)]
        lines = [json.dumps(row, allow_nan=False).encode() + b"\n" for row in rows]
        text = b"".join(lines)
        # The curves' record files are written by a thread of their own (creating a file
        # can take a millisecond on a busy disk, time the fits need not wait for); the
        # summary waits for them, and a resumed run rewrites every earlier curve's file.
        if self.curve_files:
            folder = self.folder / CURVE_FOLDER
            folder.mkdir(exist_ok=True)
            files = [(folder / f"{self.stem(i)}.json", self._curve_record(row))
                     for i, row in zip(indices, rows, strict=True)]

            def write_files() -> None:
                for path, record in files:
                    write_json(path, record)

            # Finished writes are let go (a write's error is raised here, at the next
            # chunk): what a study holds does not grow with its chunks.
            for write in [w for w in self._file_writes if w.done()]:
                self._file_writes.remove(write)
                write.result()
            self._file_writes.append(self._writer.submit(write_files))
        with self.lock:
            handle = os.open(self.journal, os.O_WRONLY | os.O_APPEND)
            try:
                offset = os.lseek(handle, 0, os.SEEK_END)
                written = os.write(handle, text)
                while written < len(text):  # a regular file takes it at once; be sure
                    written += os.write(handle, text[written:])
                os.fsync(handle)
            finally:
                os.close(handle)
            for i, row, line in zip(indices, rows, lines, strict=True):
                self._keep(i, row, offset, len(line) - 1)
                offset += len(line)
            self._filed[list(indices)] = True
            if time.monotonic() - self._table_written >= max(1.0, 10.0 * self._table_seconds):
                self._write_table()

    def _curve_head(self, name: str, levels: Sequence[str]) -> dict[str, Any]:
        """What a curve's record starts with: its id and its factors' values."""
        return {"curve": name, "factors": {f: factor_value(v) for f, v in
                                           zip(self.study.factors, levels, strict=True)}}

    def _curve_record(self, row: Mapping[str, Any]) -> dict[str, Any]:
        """A journal row as the record of its curve: its id, its factors, then the fit."""
        return {**self._curve_head(row["curve"], row["levels"]), **row["record"]}

    def records(self, skip: np.ndarray | None = None) -> Iterator[dict[str, Any]]:
        """The finished curves' records (:func:`fitting.report.fit_record`, with ``curve``
        and ``factors``), in study order, read back from the journal one at a time; `skip`:
        a boolean mask over study positions of curves left out."""
        finished = self._finished[:, 0] >= 0
        if skip is not None:
            finished &= ~skip
        with open(self.journal, "rb") as stream:
            for position in np.flatnonzero(finished):
                offset, size = self._finished[position, :2]
                stream.seek(offset)
                yield self._curve_record(json.loads(stream.read(size)))

    def _record_texts(self) -> Iterator[str]:
        """The JSON text of each of :meth:`records`, in study order: a journal line's record
        as written (with ``curve`` and ``factors`` before it), not read and written anew,
        which a study of 10,000 curves would spend a second on."""
        with open(self.journal, "rb") as stream:
            for position in np.flatnonzero(self._finished[:, 0] >= 0):
                offset, size = self._finished[position, :2]
                stream.seek(offset)
                line = stream.read(size).decode("utf-8")
                name, levels = self.study.ids[position], list(self.study.levels[position])
                head = json.dumps({"curve": name, "levels": levels}, allow_nan=False)
                head = f'{head[:-1]}, "record": {{'
                if not line.startswith(head) or not line.endswith("}}"):
                    # Not as this run writes it: read and written anew.
                    yield json.dumps(self._curve_record(json.loads(line)), allow_nan=False)
                    continue
                front = json.dumps(self._curve_head(name, levels), allow_nan=False)
                yield f"{front[:-1]}, {line[len(head):-1]}"

    def _write_table(self) -> None:
        """``summary.csv`` in study order, streamed from :attr:`_rows` (and ``refused.csv``)."""
        began = time.monotonic()
        header = self._columns[0] if self._columns else ["curve", *self.study.factors]
        self._rows.flush()

        def fill(stream) -> None:
            stream.write(csv_text(header, []).encode("utf-8"))
            rows = self._rows.fileno()
            for position in np.flatnonzero(self._finished[:, 2] >= 0):
                start, size = self._finished[position, 2:]
                stream.write(os.pread(rows, int(size), int(start)))

        write_atomic(self.folder / "summary.csv", fill, binary=True)
        if self.refused:
            write_csv(self.folder / "refused.csv", ["curve", "reason"],
                      [[name, reason] for name, reason in self.refused.items()])
        self._table_written = time.monotonic()
        self._table_seconds = self._table_written - began

    def write_summary(self) -> None:
        """Write ``summary.csv`` and ``summary.json`` (every finished curve's full record, in
        study order, streamed from the journal)."""
        with self.lock:
            self._write_table()
            head = {"study": self.study.source, "model": self.plan.model,
                    "factors": list(self.study.factors),
                    "n_curves": len(self.study) + len(self.study.refused),
                    "n_fitted": self.done, "n_refused": len(self.refused),
                    "complete": self.done + len(self.refused)
                    == len(self.study) + len(self.study.refused),
                    "refused": [{"curve": name, "reason": reason}
                                for name, reason in self.refused.items()],
                    "plan": self.plan.describe()}

            def fill(stream) -> None:
                stream.write(json.dumps(head, indent=2, allow_nan=False)[:-2])
                stream.write(',\n  "curves": [')
                for count, text in enumerate(self._record_texts()):
                    stream.write(",\n" if count else "\n")
                    stream.write(text)
                stream.write("\n  ]\n}\n")

            write_atomic(self.folder / "summary.json", fill)
            self._write_curve_records()

    def _write_curve_records(self) -> None:
        """One JSON record per fitted curve in ``curves/`` (what ``funnel --model`` and
        ``divert --model`` read, as they read a single file's fit), named by :attr:`stems`
        (characters other than letters, digits, ``.``, ``-`` and ``_`` become ``_``; a name
        taken twice that way gets its study position appended). Each is written atomically;
        those of this run were written as their chunks finished, so here only the curves an
        earlier run of the same study fitted are (re)written."""
        writes, self._file_writes = self._file_writes, []
        for write in writes:
            write.result()  # raises what a write raised
        if not self.curve_files:
            return
        folder = self.folder / CURVE_FOLDER
        folder.mkdir(exist_ok=True)
        positions = np.flatnonzero((self._finished[:, 0] >= 0) & ~self._filed)
        for position, record in zip(positions, self.records(skip=self._filed), strict=True):
            write_json(folder / f"{self.stem(int(position))}.json", record)

    def _write_images(self, indices: Sequence[int], images: Sequence[bytes | None]) -> None:
        """Each drawn curve's PNG, atomically, into ``curves/<stem>.png``."""
        folder = self.folder / CURVE_FOLDER
        folder.mkdir(exist_ok=True)
        for i, image in zip(indices, images, strict=True):
            if image is not None:
                write_png(folder / f"{self.stem(i)}.png", image)

    def _chunks(self) -> Iterator[list[int]]:
        pending = self.pending
        for start in range(0, len(pending), self.chunk):
            yield pending[start:start + self.chunk]

    def _task(self, indices: Sequence[int]) -> tuple:
        curves = [self.study.curves[i] for i in indices]
        inlets = [self.study.inlets[i] for i in indices]
        return self.plan, curves, inlets if any(x is not None for x in inlets) else None

    def run(self, *, workers: int | None = None, scheduler: str | None = None,
            stop: Callable[[], bool] | None = None, progress: bool | None = None,
            threads: int | None = None) -> int:
        """Fit the pending curves, appending each finished chunk; then write the summary.

        **Arguments:**

        - `workers`: fit on a local Dask cluster of this many processes; `scheduler`: on the
          Dask scheduler at this address; neither: in this process.
        - `stop`: called between chunks; when it returns true the run stops (the finished
          chunks stay written).
        - `progress`: show a progress bar (``None``: when standard error is a terminal,
          else a line per chunk).
        - `threads`: in this process, chunks fitted side by side (``None``:
          :func:`default_threads`); the records are the same with any number.

        **Returns:** the number of curves fitted by this call.
        """
        stop = stop or (lambda: False)
        pending = len(self.pending)
        bar = progress_bar(total=pending, description="study", unit="curve",
                           enabled=progress)
        count = 0

        def finished(indices, payload) -> None:
            nonlocal count
            if self.plots:  # the PNGs first: a journaled curve always has its PNG
                records, images = payload
                self._write_images(indices, images)
            else:
                records = payload
            self._append(indices, records)
            count += len(indices)
            bar.update(len(indices))
            if bar.disable and progress is None:
                print(f"axialmix fit: {self.resumed + count} of {len(self.study)} curves "
                      "fitted", file=sys.stderr, flush=True)

        try:
            task = fit_chunk_drawn if self.plots else fit_chunk
            with long_lived_frozen():
                map_chunks(task, ((indices, self._task(indices)) for indices in self._chunks()),
                           workers, scheduler, stop, finished,
                           threads=default_threads() if threads is None else threads,
                           launch=functools.partial(launch_chunk, drawn=self.plots))
        finally:
            bar.close()
        if not stop():
            self.write_summary()
        return count


#: The sub-folder of a study's output that holds one fit record per curve.
CURVE_FOLDER = "curves"


def curve_file_stem(name: str) -> str:
    """A file name for a curve id: letters, digits, ``.``, ``-`` and ``_`` kept, any other
    character ``_`` (``"run 1/2"`` -> ``"run_1_2"``; an empty or dot-only name -> ``"curve"``)."""
    stem = "".join(c if c.isascii() and (c.isalnum() or c in "._-") else "_" for c in name)
    return stem if stem.strip(".") else "curve"


def default_threads() -> int:
    """Threads of an in-process study: one, which starts each chunk's compiled fits before it
    writes the records of the chunk before (:func:`launch_chunk`), so that the compiled
    work, which runs without Python's lock, overlaps the Python (starts, results, records).
    Two threads, each fitting and writing chunks of its own, were no faster on 2 cores
    (386 against 388 curves/s, medians of five runs each): both wait on the lock.
    """
    return 1


def map_chunks(task: Callable, chunks: Iterator[tuple[Any, tuple]], workers: int | None,
               scheduler: str | None, stop: Callable[[], bool],
               finished: Callable[[Any, Any], None], *, threads: int = 1,
               launch: Callable | None = None) -> None:
    """Run a task on each chunk, in this process or on Dask, handing on each result.

    **Arguments:**

    - `task`: a module-level function (Dask sends it to the workers by reference).
    - `chunks`: ``(key, arguments)`` pairs; ``task(*arguments)`` is run for each.
    - `workers`: a local Dask cluster of this many single-threaded processes; `scheduler`:
      the Dask scheduler at this address; neither: in this process.
    - `stop`: asked between chunks; true stops the run (tasks in flight are cancelled on
      Dask; in this process a chunk once begun is finished and handed on).
    - `finished`: called as ``finished(key, result)`` in this process: in this process in
      the chunks' order, on Dask in the order they finish, with :data:`CHUNKS_PER_WORKER`
      tasks per worker in flight.
    - `threads`: in this process, chunks run side by side on this many threads (the task
      must be thread-safe and its result independent of the thread; :func:`fit_chunk` is);
      1: one after another.
    - `launch`: in this process on one thread, ``launch(*arguments)`` starts a chunk and
      returns the function that finishes it (``launch(*a)()`` is ``task(*a)``): the next
      chunk is started before the last is finished and handed on, so that work of the
      task that runs without Python's lock (compiled programs) overlaps the rest.

    **Returns:** ``None``; a task's exception is raised here.
    """
    if workers is None and scheduler is None:
        if threads <= 1:
            start = launch or (lambda *arguments: functools.partial(task, *arguments))
            begun = None
            for key, arguments in chunks:
                if stop():
                    break
                try:
                    following = (key, start(*arguments))
                except BaseException:
                    if begun is not None:  # what was fitted is handed on before the error
                        finished(begun[0], begun[1]())
                    raise
                if begun is not None:
                    finished(begun[0], begun[1]())
                begun = following
            if begun is not None:  # a begun chunk is finished and handed on, stopped or not
                finished(begun[0], begun[1]())
            return
        _map_on_threads(task, chunks, stop, finished, threads)
        return
    from dask.distributed import as_completed

    with _dask_client(workers, scheduler) as client:
        slots = CHUNKS_PER_WORKER * max(1, len(client.scheduler_info()["workers"]))
        running: dict = {}
        queue = as_completed([])

        def submit() -> None:
            chunk = next(chunks, None)
            if chunk is not None:
                future = client.submit(task, *chunk[1], pure=False)
                running[future] = chunk[0]
                queue.add(future)

        for _ in range(slots):
            submit()
        for future in queue:
            finished(running.pop(future), future.result())
            if stop():
                for other in running:
                    other.cancel()
                return
            submit()


def _map_on_threads(task: Callable, chunks: Iterator[tuple[Any, tuple]],
                    stop: Callable[[], bool], finished: Callable[[Any, Any], None],
                    threads: int) -> None:
    """:func:`map_chunks` in this process with `threads` chunks in flight, each handed on
    in the chunks' order as soon as it and those before it are done."""
    pool = concurrent.futures.ThreadPoolExecutor(threads, thread_name_prefix="axialmix-chunk")
    in_flight: collections.deque = collections.deque()
    try:
        for key, arguments in chunks:
            if stop():
                break
            in_flight.append((key, pool.submit(task, *arguments)))
            if len(in_flight) >= threads:
                key, future = in_flight.popleft()
                finished(key, future.result())
        while in_flight:  # begun chunks are finished and handed on, stopped or not
            key, future = in_flight.popleft()
            finished(key, future.result())
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def _dask_client(workers: int | None, scheduler: str | None):
    """A Dask client on the scheduler at `scheduler`, or on a local cluster of `workers`
    single-threaded processes (closed afterwards)."""
    from dask.distributed import Client

    if scheduler is not None:
        client = Client(scheduler)
        try:
            yield client
        finally:
            client.close()
        return
    cluster = local_cluster(workers)
    try:
        with Client(cluster) as client:
            yield client
    finally:
        cluster.close()


#: The environment of a local cluster's worker processes. ``PJRT_NPROC=1``: JAX's CPU runtime
#: gives each process one compute thread instead of one per core. A worker fits one chunk at
#: a time, and a second thread of the runtime mostly spins while the first computes (measured
#: on 2 cores: the compiled fit of a chunk took 1.8 times its wall time in CPU time, 12 %
#: faster than on one thread), taking the core the other worker needs. The fitted numbers do
#: not depend on it (the Dask test compares them with one process's bit for bit).
WORKER_ENVIRONMENT = {"PJRT_NPROC": "1"}


def local_cluster(workers: int):
    """A local Dask cluster of `workers` single-threaded worker processes, each with
    :data:`WORKER_ENVIRONMENT` (no dashboard, quiet logs); the caller closes it."""
    from dask.distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                        dashboard_address=None, silence_logs=logging.ERROR,
                        env=dict(WORKER_ENVIRONMENT))
