"""The study mode of ``axialmix fit`` (``--curve-column``, ``--design``, ``--chunk``,
``--workers``, ``--scheduler``): its options checked, its curves read, then the study fitted
in chunks on a worker thread (:mod:`fitting.study.batch`), resumable after Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from axialmix._exits import OK, REFUSED, error_line
from fitting.cli.fit.inputs import check_fixed_curves, read_inlet, read_study
from fitting.cli.fit.options import InputError, default_errors
from fitting.cli.fit.outfolder import FolderLock
from fitting.cli.fit.supervise import Supervised, exit_now


def is_study(args: argparse.Namespace) -> bool:
    """Whether the options ask for a study (one summary of many curves, with factors)."""
    return any(getattr(args, name) is not None for name in
               ("curve_column", "design", "chunk", "workers", "scheduler"))


#: Memory a study worker process needs (JAX, the compiled solvers, a chunk of curves).
_WORKER_BYTES = 768 * 2**20


def _check_workers(workers: int) -> None:
    """--workers: at least 1, at most the cores of the machine and what its memory holds."""
    cores = os.cpu_count() or 1
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        memory = cores * _WORKER_BYTES
    limit = max(1, min(cores, memory // _WORKER_BYTES))
    if not 1 <= workers <= limit:
        raise InputError(f"--workers {workers}: this machine runs 1 to {limit} worker "
                         f"processes ({cores} cores, {memory / 2**30:.3g} GiB at "
                         f"{_WORKER_BYTES / 2**20:.0f} MiB a worker)")


def _check_scheduler(address: str) -> None:
    """--scheduler: a tcp:// or tls:// address with a host and a port that answers."""
    import socket
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(address.strip())
        port = parts.port
    except ValueError as error:
        raise InputError(f"--scheduler {address!r}: not an address ({error})") from None
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None:
        raise InputError(f"--scheduler {address!r}: expected tcp://HOST:PORT (or tls://)")
    if not 1 <= port <= 65535:
        raise InputError(f"--scheduler {address!r}: port {port} is not 1 to 65535")
    try:
        with socket.create_connection((parts.hostname, port), timeout=5.0):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise InputError(f"--scheduler {address}: no scheduler answers there ({reason})"
                         ) from None


def run_study(args: argparse.Namespace, files: Sequence[Path], models, every_settings,
              free: tuple[str, ...], out: Path) -> int:
    """Check the study options and input, then fit the study (see :mod:`fitting.cli.fit`)."""
    from fitting.study.batch import DEFAULT_CHUNK, StudyPlan, StudyRun, plan_model

    if len(models) > 1:
        raise InputError("--model: a study fits one model; compare models on single files")
    if args.grid:
        raise InputError("--grid runs on single files, not on a study")
    if args.loss != "sse":
        raise InputError("--loss mae runs on single files; a study fits least squares")
    chunk = DEFAULT_CHUNK if args.chunk is None else args.chunk
    if chunk < 1:
        raise InputError(f"--chunk: must be at least 1 curve, got {chunk}")
    if args.workers is not None and args.scheduler is not None:
        raise InputError("--workers starts a local cluster, --scheduler uses a running one: "
                         "give one of them")
    if args.workers is not None:
        _check_workers(args.workers)
    if args.scheduler is not None:
        _check_scheduler(args.scheduler)
    if (args.workers is not None or args.scheduler is not None) and (
            importlib.util.find_spec("distributed") is None):
        raise InputError("--workers and --scheduler need Dask: pip install 'axialmix[dask]'")
    study = read_study(args, files)
    args.errors = default_errors(args, study.curves)
    per_curve = any(inlet is not None for inlet in study.inlets)
    if per_curve and args.inlet != "pulse":
        raise InputError("--inlet-column gives each curve its inlet; leave out --inlet")
    inlet, samples = args.inlet, None
    if args.inlet not in ("pulse", "step"):
        given = read_inlet(args.inlet, study.curves, args)
        inlet, samples = "sampled", (tuple(given.times.tolist()), tuple(given.values.tolist()))
    name = args.model.strip()
    plan = StudyPlan(model=name if name in _registered() else str(Path(name)), free=free,
                     inlet=inlet, inlet_samples=samples,
                     parameters=tuple(every_settings[0].items()), errors=args.errors,
                     starts=args.starts, length_m=args.length)
    if every_settings[0]:
        check_fixed_curves(plan_model(plan), every_settings[0], study.curves,
                           [study.source] * len(study))
    # The folder is locked before its journal is read: another run may be appending to it.
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"{out}: --out cannot be created ({error.strerror})") from None
    lock = FolderLock(out)
    lock.acquire()
    try:
        run = StudyRun(plan, study, out, chunk, plots=args.plots,
                       curve_files=not args.no_curve_files)
    except ValueError as error:
        lock.release()
        raise InputError(str(error)) from None
    return _StudyExecution(run, args, out, lock).execute()


def _registered() -> tuple[str, ...]:
    from fitting.models import MODELS

    return tuple(MODELS)


class _StudyExecution(Supervised):
    """A study run in a worker thread, Ctrl-C in the main thread (as the run of curve files,
    :class:`fitting.cli.fit.driver._Run`); the output folder's `lock` is held already and
    released at the end."""

    def __init__(self, run, args: argparse.Namespace, out: Path, lock: FolderLock):
        self.run, self.args, self.out, self.lock = run, args, out, lock
        self.stop = threading.Event()
        self.failure: BaseException | None = None
        self.status = OK

    def execute(self) -> int:
        in_main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, self._interrupt) if in_main else None
        try:
            self._supervise("axialmix-study")
        finally:
            self.lock.release()
            if in_main:
                signal.signal(signal.SIGINT, previous)
        return self._outcome()

    def _leave(self) -> None:
        """After Ctrl-C: the summary of the finished curves (the journal holds them already),
        then exit 130 at once; a later run on the same --out continues."""
        run = self.run
        try:
            if run.done:
                run.write_summary()
        finally:
            self.lock.release()
            exit_now(f"axialmix fit: interrupted after {run.done} of {len(run.study)} "
                     f"curves; run the same command again to continue ({self.out})")

    def _work(self) -> None:
        run = self.run
        try:
            if run.resumed:
                print(f"axialmix fit: continuing {self.out}: {run.resumed} of {len(run.study)} "
                      "curves were fitted before", file=sys.stderr, flush=True)
            if self.args.workers is None and self.args.scheduler is None:
                from fitting.engine import describe_device
                from fitting.study.batch import default_threads

                pending = len(run.pending)
                at_once = max(1, min(default_threads(), -(-pending // run.chunk)))
                way = (f"{at_once} at once" if at_once > 1 else
                       "each started while the last is written")
                print(f"axialmix fit: {pending} curves in this process, in chunks of "
                      f"{run.chunk}, {way}; {describe_device()}",
                      file=sys.stderr, flush=True)
            run.run(workers=self.args.workers, scheduler=self.args.scheduler,
                    stop=self.stop.is_set)
        except ValueError as error:
            self.status = error_line("fit", f"{run.study.source}: {error}")
            return
        except OSError as error:  # a scheduler that cannot be reached, a full disk
            self.status = error_line("fit", f"{self.out}: {' '.join(str(error).split())}")
            return
        except BaseException as error:  # shown by the main thread
            self.failure = error
            return
        rows = list(run.records())
        converged = sum(bool(r["converged"]) for r in rows)
        misfit = sum(bool((r.get("lack_of_fit") or {}).get("systematic")) for r in rows)
        for name, reason in run.refused.items():
            named = "" if repr(name) in reason else f"curve {name!r}: "
            print(f"axialmix fit: refused {named}{reason}", file=sys.stderr)
        refused = (f"; {len(run.refused)} refused, listed in {self.out / 'refused.csv'} "
                   f"(exit status {REFUSED})" if run.refused else "")
        print(f"{len(rows)} curves: {converged} converged, {misfit} with systematic misfit; "
              f"summary in {self.out / 'summary.csv'} and {self.out / 'summary.json'}"
              f"{refused}")
        if run.refused:
            self.status = REFUSED
