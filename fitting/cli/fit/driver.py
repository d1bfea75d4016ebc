"""The run of ``axialmix fit`` after parsing: every option and the input checked in order
(nothing written on bad input), then a study handed to :mod:`fitting.cli.fit.study`, or the
curve files fitted one by one on a worker thread, each curve's record and plot written as it
is done, and the summary at the end (or after Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from axialmix._exits import BAD_INPUT, INTERRUPTED, OK, error_line
from fitting.cli.fit.compare import ComparisonMode
from fitting.cli.fit.curve import fit_one, grid_for, profiled
from fitting.cli.fit.inputs import check_fixed_curves, read_curves, read_inlet
from fitting.cli.fit.options import (
    InputError,
    default_errors,
    free_names,
    models_named,
    profile_names,
    settings_for_each,
)
from fitting.cli.fit.outfolder import (
    FolderLock,
    check_out,
    check_out_apart,
    remove_temporary_files,
)
from fitting.cli.fit.report import print_single
from fitting.cli.fit.study import is_study, run_study
from fitting.cli.fit.supervise import Supervised, exit_now

#: Seconds the main thread waits, after Ctrl-C, for a file being written to be finished.
WRITE_GRACE = 1.0
#: Blender lengths (m) accepted without a word; outside, --length gets a warning (a length
#: in centimetres or millimetres by mistake gives a D_z off by 1e4 or 1e6).
LENGTH_RANGE_M = (0.02, 10.0)


def run_fit(args: argparse.Namespace) -> int:
    """Check every option and the input, then fit: the work of :func:`fitting.cli.fit.run`
    (which imports this module only to run a fit, since it loads JAX)."""
    try:
        from fitting.data import DataError, input_files
        from fitting.solve import enable_compilation_cache

        # First: the checks below evaluate the model, compiled programs worth keeping too.
        enable_compilation_cache()
        try:
            files = input_files(args.inputs)
        except DataError as error:
            raise InputError(str(error)) from None
        if args.starts is not None and args.starts < 1:
            raise InputError(f"--starts: must be at least 1, got {args.starts}")
        if args.starts is not None and args.starts > 1_000_000:
            raise InputError(f"--starts: at most 1,000,000, got {args.starts}")
        if args.grid and args.errors not in (None, "absolute"):
            raise InputError(f"--grid scores the unweighted loss, as the source did; use it "
                             f"with --errors absolute (its default), not {args.errors}")
        if args.length is not None and not (math.isfinite(args.length) and args.length > 0):
            raise InputError(f"--length: must be a positive number of metres, got {args.length}")
        if args.length is not None and not (LENGTH_RANGE_M[0] <= args.length <= LENGTH_RANGE_M[1]):
            print(f"axialmix fit: warning: --length {args.length:g} m is outside "
                  f"{LENGTH_RANGE_M[0]:g} to {LENGTH_RANGE_M[1]:g} m, unusual for a blender: "
                  "is it in metres?", file=sys.stderr)
        out = Path(args.out)
        check_out(out)
        check_out_apart(out, args.inputs)
        from fitting.measurement import Inlet, measured

        free = free_names(args.free)
        try:
            models = [measured(m, Inlet.pulse(), free) for m in models_named(args.model)]
        except ValueError as error:
            raise InputError(f"--model: {error}") from None
        if len(models) > 1 and args.grid:
            raise InputError("--grid compares a fit with the source's grid search; use it with "
                             "one --model")
        every_settings = settings_for_each(models, args.fix, args.tie)
        if args.profile is not None:
            if is_study(args) or len(models) > 1 or args.loss != "sse":
                raise InputError("--profile runs on least-squares fits of one model to single "
                                 "files or folders (not on a study, a model comparison or "
                                 "--loss mae)")
            profile_names(args.profile, models[0], every_settings[0])
        if args.no_curve_files and not is_study(args):
            raise InputError("--no-curve-files is a study's option (with --curve-column, "
                             "--design, --chunk, --workers or --scheduler): single files and "
                             "folders write each curve's record as their result")
        if is_study(args):
            return run_study(args, files, models, every_settings, free, out)
        curves = read_curves(files, args)
        args.errors = default_errors(args, curves)
        inlet = read_inlet(args.inlet, curves, args)
        try:
            models = [measured(m.base, inlet, free) for m in models]
        except ValueError as error:
            raise InputError(f"--inlet: {error}") from None
        model, settings = models[0], every_settings[0]
        for each, each_settings in zip(models, every_settings, strict=True):
            # Start values of the model's own (moment estimates clipped into its bounds) give
            # finite curves for every built-in model; --fix, --tie or a measured inlet may not.
            if each_settings or args.inlet is not None:
                check_fixed_curves(each, each_settings, curves, files)
    except InputError as error:
        return error_line("fit", str(error))
    except KeyboardInterrupt:
        print("axialmix fit: interrupted before fitting; nothing written", file=sys.stderr)
        return INTERRUPTED
    starts = args.starts or model.default_starts
    run = _Run(model, curves, files, settings, args, starts, out)
    run.compared = list(zip(models, every_settings, strict=True)) if len(models) > 1 else []
    return run.execute()


class _Run(ComparisonMode, Supervised):
    """One ``axialmix fit`` run after validation: fits in a worker thread, Ctrl-C in the main."""

    def __init__(self, model, curves, files, settings, args, starts, out: Path):
        self.model, self.curves, self.files, self.settings = model, curves, files, settings
        self.args, self.starts, self.out = args, starts, out
        self.records: list[dict[str, Any]] = []
        #: ``(model, settings)`` of each compared model (empty for one model).
        self.compared: list[tuple[Any, dict]] = []
        self.stop = threading.Event()
        self.writing = threading.Lock()
        self.failure: BaseException | None = None
        self.status = OK
        self.lock = FolderLock(out)
        #: Whether this run made the --out folder (then Ctrl-C before any result removes it).
        self.created = False

    def execute(self) -> int:
        in_main = threading.current_thread() is threading.main_thread()
        # Ctrl-C is handled here from before the folder and the lock exist until after the
        # lock is gone, so no signal can leave either behind.
        previous = signal.signal(signal.SIGINT, self._interrupt) if in_main else None
        try:
            try:
                self.created = not self.out.exists()
                self.out.mkdir(parents=True, exist_ok=True)
                self.lock.acquire()
            except InputError as error:
                return error_line("fit", str(error))
            except OSError as error:
                return error_line("fit", f"{self.out}: --out cannot be created "
                                  f"({error.strerror})")
            self._supervise("axialmix-fit")
        finally:
            self.lock.release()
            if self.created and not self.records:
                with contextlib.suppress(OSError):
                    self.out.rmdir()  # a run that wrote nothing leaves no folder
            if in_main:
                signal.signal(signal.SIGINT, previous)
        return self._outcome()

    def _leave(self) -> None:
        """After Ctrl-C: let the worker finish the files of a curve it is writing (written
        together, in milliseconds: plots are drawn before), write the summary of the finished
        curves, remove the lock (and the folder when this run made it and left it empty),
        exit 130 now."""
        written = self.writing.acquire(timeout=WRITE_GRACE)
        try:
            if written:
                self._write_summary(interrupted=len(self.records) < len(self.curves))
            else:
                remove_temporary_files(self.out)
        finally:
            self.lock.release()
            if self.created and not self.records:
                with contextlib.suppress(OSError):
                    self.out.rmdir()  # only when empty
            where = f"; finished results are in {self.out}" if self.records else "; nothing written"
            exit_now(f"axialmix fit: interrupted after {len(self.records)} of "
                     f"{len(self.curves)} curves{where}")

    def _work(self) -> None:
        try:
            self.status = self._fit_all()
        except BaseException as error:  # shown by the main thread
            self.failure = error

    def _fit_all(self) -> int:
        from axialmix._progress import progress_bar
        from fitting.gridsearch import grid_search
        from fitting.report import fit_record, fit_table, render_fit_png, write_json, write_png
        from fitting.solve import enable_compilation_cache

        enable_compilation_cache()
        args, out = self.args, self.out
        bar = progress_bar(total=len(self.curves), description="fit", unit="curve",
                           enabled=None if len(self.curves) > 1 else False)
        try:
            for index, (curve, path) in enumerate(zip(self.curves, self.files, strict=True)):
                bar.set_postfix_str(curve.name, refresh=True)
                if len(self.curves) > 1 and bar.disable:
                    # No terminal for the bar: one log line per curve instead.
                    print(f"axialmix fit: [{index + 1}/{len(self.curves)}] {curve.name}",
                          file=sys.stderr, flush=True)
                if self.compared:
                    status = self._compare(curve, path)
                    if status != OK:
                        return status
                    bar.update(1)
                    continue
                try:
                    result = fit_one(self.model, curve, self.settings, args.loss, self.starts,
                                     args.errors, self.stop)
                except ValueError as error:
                    with self.writing:
                        self.status = error_line("fit", f"{path}: {error}")
                    return BAD_INPUT
                if self.stop.is_set():
                    return INTERRUPTED
                if args.profile is not None:
                    result = profiled(result, args.profile, self.stop)
                    if self.stop.is_set():
                        return INTERRUPTED
                grid = None
                if args.grid:
                    grids, held, tied = grid_for(self.model, result)
                    grid = grid_search(self.model, curve, grids, loss=args.loss, fixed=held,
                                       tied=tied, progress=True, stop=self.stop.is_set)
                record = fit_record(result, grid, source=str(path), length_m=args.length)
                # Drawn before taking the write lock, which Ctrl-C waits for: drawing takes a
                # second or more, writing the two files milliseconds.
                image = render_fit_png(result, grid)
                with self.writing:
                    if self.stop.is_set():
                        return INTERRUPTED
                    write_json(out / f"{curve.name}.json", record)
                    write_png(out / f"{curve.name}.png", image)
                    self.records.append(record)
                if len(self.curves) == 1:
                    print_single(result, grid, record, fit_table, args.length)
                bar.update(1)
                if grid is not None and grid.interrupted:
                    self.stop.set()
                    return INTERRUPTED
        finally:
            bar.close()
        with self.writing:
            self._write_summary(interrupted=False)
        print(f"results written to {out}")
        return OK

    def _write_summary(self, interrupted: bool) -> None:
        records = list(self.records)
        if not records:
            return  # before importing: after Ctrl-C the worker may still be importing
        from fitting.report import summary_rows, summary_table, write_csv, write_json

        if self.compared:
            self._write_comparison_summary(records, interrupted)
            return
        if len(self.curves) > 1:  # one curve: its own table is the summary
            print(summary_table(records, wide=self.args.wide), flush=True)
        write_json(self.out / "summary.json", {"model": self.model.name,
                                               "loss_name": self.args.loss,
                                               "complete": not interrupted, "fits": records})
        header, rows = summary_rows(records)
        write_csv(self.out / "summary.csv", header, rows)
