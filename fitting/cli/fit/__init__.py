"""The ``axialmix fit`` sub-command: fit residence-time curves from CSV files.

    axialmix fit FILE_OR_FOLDER... --model adm|adm-fv|adm-open|tanks|four-compartment|
                                           adm-exchange|tanks-exchange|adm-tank|NET.json
                 (a network file may be .toml; several models, comma-separated, to compare)
                 [--fix NAME=VALUE] [--tie NAME=OTHER] [--free dead_time,baseline]
                 [--inlet pulse|step|FILE] [--loss sse|mae] [--grid] [--starts N]
                 [--errors absolute|relative|combined|poisson] [--length METRES]
                 [--decimal auto|.|,] [--time-column C] [--value-column C] --out DIR
                 [--curve-column C [--inlet-column C] [--factors A,B] | --design FILE]
                 [--chunk N] [--workers N | --scheduler ADDRESS]

Every input is read and validated, and every option checked, before anything is written:
bad input prints one line ``axialmix fit: error: <file>:<row>: <problem>`` to stderr and
exits with status 2, leaving no output. This covers everything that can be known before
fitting: every file (read in full), every option, fixed values a model is undefined at
(``--fix tau=0``), curves too small or large for float64, and whether ``--out`` can be
created and written. Then each curve is fitted; its JSON record and PNG
plot are written to ``DIR/<name>.json`` and ``DIR/<name>.png`` as soon as it is done
(atomically), so Ctrl-C keeps finished curves. Every run also gives ``DIR/summary.json``
and ``DIR/summary.csv``.

One run at a time writes into a folder: a run holds the lock file ``DIR/.axialmix-fit.lock``
(its process id) while it writes, and a second run on the same ``--out`` is refused with
exit status 2 (a lock left by a process that no longer runs is taken over). So two runs
cannot interleave their files.

Ctrl-C: fitting runs in a worker thread; the main thread catches SIGINT at once, lets the
worker finish the file it may be writing, writes the summary of the curves already finished,
removes the lock and ends the process with status 130 via ``os._exit`` — compiled JAX work
still running is abandoned rather than waited for (its teardown could crash the process).

Each curve is fitted as measured, in the file's own units: the model is wrapped in the
measurement model ``c(t) = A (E * u)(t - t_d) + b`` (:mod:`fitting.measurement`). The amplitude
A is always fitted, so the data are never divided by their own area; the dead time t_d and
the baseline b are 0 unless freed (``--free dead_time,baseline``, short ``t_d,b``) or fixed at
a value (``--fix baseline=0.02``). The inlet u is an ideal pulse (``--inlet pulse``, the
default), an ideal step for F-curves (``--inlet step``), or a measured inlet signal
(``--inlet FILE``, a time/value CSV read like the curves), convolved exactly with the model.
Values down to 5 % of the peak below zero are noise around a subtracted baseline and are
fitted; a value further below zero is refused with its file, row and value. Decimal commas
are detected (or ``--decimal ,``); ``--time-column`` and ``--value-column`` pick columns by
name or 0-based index.

``--errors`` sets the error model: ``combined`` (the default; additive plus proportional
errors, ``Var = a² + (b model)²``, both estimated from the residuals by iterated weights, see
:mod:`fitting.losses`), ``relative`` (errors proportional to the curve: refitted weighted by
``1 / model²`` until the weights are those of its own curve, ``1 / |model|`` for the mean
absolute error) or ``absolute`` (errors of one size, unweighted least squares). Unweighted
least squares treats the peak, where proportional noise is largest, as precise as the tail,
and its intervals are then too narrow; pure relative weights let a sample where the model is
near zero (t = 0) take almost all the weight. The grid search (``--grid``) scores the
unweighted loss, as the source did, so it runs with absolute errors. ``poisson`` is for
particle counts (a histogram of tracer particles leaving, as ``axialmix simulate`` writes
with its ``count`` and ``bin [s]`` columns; chosen by itself for such files): Poisson noise of
known size, fitted by maximum likelihood, intervals from the known scale and lack of fit
tested on bins merged to 10 expected particles each (:mod:`fitting.losses`).

With ``--length L`` (m; there is no default) every ADM-family fit also reports the velocity
``v`` and axial dispersion ``D_z`` in SI, networks their equivalent ``tau``, ``Pe`` and
``D_z``, each with its standard error and 95 % interval (delta method,
:mod:`fitting.physical`). Every number carries its unit, the file's time unit included.

With ``--loss mae`` the least-squares multi-start fit is polished by a fit on the mean
absolute error (which is not smooth enough for multi-start L-BFGS alone); the evaluations
of both stages are reported.

With several models (``--model adm,adm-exchange,tanks``) each curve is fitted with each of
them and one table compares them: parameters, SSE, AICc, BIC and the lack-of-fit verdict,
with a recommendation that says when the data cannot tell the models apart
(:func:`fitting.diagnostics.compare_models`). Each fit is written to
``DIR/<name>.<model>.json`` and ``.png``, the comparison to ``DIR/<name>.comparison.json``;
several curves also give ``DIR/summary.json`` and ``DIR/summary.csv`` with one row per curve
and model. ``--fix`` and ``--tie`` apply to the models that have the parameters they name.

Studies of many curves (:mod:`fitting.study.input`, :mod:`fitting.study.batch`): with
``--curve-column C`` the input is one long table (curve id, time, concentration, an optional
``--inlet-column``, and factor columns constant within a curve); with ``--design FILE`` the
curve files get their factors from a design table. Either way (and with ``--chunk``,
``--workers`` or ``--scheduler`` on plain curve files) each curve is fitted as a single file
would be, in chunks of ``--chunk`` curves (default 64), and ``DIR/summary.csv`` and
``DIR/summary.json`` get one row per curve: its factors, each parameter with standard error and
95 % interval (units in the column names), v and D_z with ``--length``, the error model,
convergence and the lack-of-fit verdict, and ``DIR/curves/<curve>.json`` holds each curve's
full record (what ``funnel --model`` and ``divert --model`` read), with ``--plots`` beside
its PNG ``DIR/curves/<curve>.png`` (drawn as a single file's is); ``--no-curve-files``
leaves the record files out (``summary.json`` holds them all). Finished
chunks are appended to ``DIR/summary.jsonl``; the same command run again after Ctrl-C or a
kill fits only the curves not yet in it. ``--workers N`` fits on a local Dask cluster of N
processes, ``--scheduler ADDRESS`` on a running one, with the same results. A study fits one
model by least squares (no ``--grid``, no ``--loss mae``).

With ``--grid`` the source's exhaustive grid search runs on the same loss: rates (parameters
named ``k_*``, except the dead-zone exchange rate ``k_d``) over ``[0 : 0.125 : 2.5]``
(MODELS.md section 3), any other free parameter over
21 log-spaced values from a quarter to four times its fitted value; a free rate not on that
grid (``k_out``) is held at its fitted value, so the grid is the source's three-dimensional one.

This module holds the parser and the entry point; the run itself is in modules of one concept
each: :mod:`~fitting.cli.fit.options` (option values checked), :mod:`~fitting.cli.fit.inputs`
(curves, inlet and study read), :mod:`~fitting.cli.fit.outfolder` (``--out`` checked and
locked), :mod:`~fitting.cli.fit.supervise` (Ctrl-C), :mod:`~fitting.cli.fit.curve` (one
curve's fit), :mod:`~fitting.cli.fit.report` (a single curve's printed table),
:mod:`~fitting.cli.fit.compare` (several models), :mod:`~fitting.cli.fit.study` (studies) and
:mod:`~fitting.cli.fit.driver` (the run in order). ``--help`` imports none of the JAX ones.
"""

from __future__ import annotations

import argparse
from typing import Any

from fitting.cli.fit.options import parameter_settings as _parameter_settings  # noqa: F401

__all__ = ["add_parser", "run"]


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register the ``fit`` sub-command on an argparse sub-parser collection.

    **Arguments:**

    - `subparsers`: the object returned by ``ArgumentParser.add_subparsers()``.

    **Returns:** the ``fit`` parser (its ``func`` default is :func:`run`).
    """
    parser = subparsers.add_parser(
        "fit",
        help="fit a residence-time model to RTD curves (CSV files or folders)",
        description="Fit a residence-time model to measured RTD curves; report values, "
        "standard errors, 95 % intervals and what the data determine.",
    )
    parser.add_argument("inputs", nargs="+", metavar="FILE_OR_FOLDER",
                        help="CSV files (time, concentration) or folders of them (*.csv, "
                        "any case)")
    parser.add_argument("--model", default="adm",
                        help="adm, adm-fv, adm-open, tanks, four-compartment, adm-exchange "
                        "(ADM with a dead zone), tanks-exchange, adm-tank (ADM then a stirred "
                        "tank), or a network file (.json or .toml) (default: adm); several, "
                        "comma-separated (adm,adm-exchange,tanks), are fitted and compared in "
                        "one table")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value (repeatable)")
    parser.add_argument("--tie", action="append", default=[], metavar="NAME=OTHER",
                        help="make a parameter equal to another, e.g. k_r=k_f (repeatable)")
    parser.add_argument("--loss", choices=("sse", "mae"), default="sse",
                        help="least squares (default) or the source's mean absolute error")
    parser.add_argument("--grid", action="store_true",
                        help="also run the source's exhaustive grid search and compare")
    parser.add_argument("--wide", action="store_true",
                        help="print every column of the summary and model-comparison tables "
                        "(default: the headline "
                        "numbers in 100 columns; every column is in summary.csv)")
    parser.add_argument("--starts", type=int, default=None, metavar="N",
                        help="number of starts (default: the moment estimate for ADM and "
                        "tanks models, 8 for compartment networks)")
    parser.add_argument("--errors", choices=("absolute", "relative", "combined", "poisson"),
                        default=None,
                        help="error model: combined (default: additive plus proportional, "
                        "both estimated), relative (proportional to the curve), absolute "
                        "(equal size; the default with --grid) or poisson (particle counts; "
                        "the default for files with a 'count' column)")
    parser.add_argument("--length", type=float, default=None, metavar="METRES",
                        help="blender length L (m) for v and D_z in SI with their "
                        "uncertainty (no default: without it only tau and Pe are reported)")
    parser.add_argument("--inlet", default="pulse", metavar="pulse|step|FILE",
                        help="inlet signal: an ideal pulse (default), an ideal step (F-curves) "
                        "or a measured inlet signal (a time/value CSV), convolved exactly")
    parser.add_argument("--free", action="append", default=[], metavar="NAMES",
                        help="also fit measurement parameters fixed at 0 by default: "
                        "dead_time (t_d), baseline (b); comma-separated or repeated")
    parser.add_argument("--profile", nargs="?", const="all", default=None, metavar="NAMES",
                        help="95 %% intervals from the profile likelihood: each named free "
                        "parameter (comma-separated; all free ones without NAMES) held on a "
                        "grid over a factor 1000 either way, the others refitted; for "
                        "parameters one curve leaves poorly determined (minutes, not seconds)")
    parser.add_argument("--decimal", choices=("auto", ".", ","), default="auto",
                        help="decimal separator of the files (default: detected)")
    parser.add_argument("--time-column", default=None, metavar="NAME|INDEX",
                        help="the time column by name or 0-based index (default: recognised). "
                        "Its unit is read from its header name: 't [min]', 'time (s)', "
                        "'time_min' (s, ms, min, h); seconds when the header names none")
    parser.add_argument("--value-column", default=None, metavar="NAME|INDEX",
                        help="the concentration column by name or 0-based index (default: "
                        "recognised, or the second of two columns)")
    study = parser.add_argument_group(
        "studies of many curves", "one summary row per curve with its factors, fitted in "
        "chunks, resumable; used with any of these options")
    study.add_argument("--curve-column", default=None, metavar="NAME|INDEX",
                       help="the input is one long table: this column holds the curve id, "
                       "the other columns (besides time, value and --inlet-column) are factors "
                       "constant within a curve")
    study.add_argument("--inlet-column", default=None, metavar="NAME|INDEX",
                       help="with --curve-column: a column with each curve's inlet signal at "
                       "its sample times")
    study.add_argument("--factors", default=None, metavar="A,B",
                       help="with --curve-column: only these factor columns (default: all "
                       "other columns)")
    study.add_argument("--design", default=None, metavar="FILE",
                       help="a design table mapping curve file names (first column, or a "
                       "column named file, curve, run or name) to factor columns")
    study.add_argument("--chunk", type=int, default=None, metavar="N",
                       help="curves fitted and written together, one Dask task "
                       "(default: 64)")
    study.add_argument("--workers", type=int, default=None, metavar="N",
                       help="fit on a local Dask cluster of N processes (each runs JAX on "
                       "one compute thread, PJRT_NPROC=1)")
    study.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="fit on the Dask scheduler at ADDRESS (tcp://host:8786)")
    study.add_argument("--plots", action="store_true",
                       help="also draw each curve's fit as DIR/curves/<curve>.png (single "
                       "files and folders always get their PNGs)")
    study.add_argument("--no-curve-files", action="store_true",
                       help="write no DIR/curves/<curve>.json (summary.json holds every "
                       "curve's record; funnel and divert take one by --curve): a file per "
                       "curve costs time, a third of a study's on some disks")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for the results")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Run ``axialmix fit`` with parsed arguments; returns the exit status.

    **Arguments:**

    - `args`: the namespace from the ``fit`` parser (see :func:`add_parser`).

    **Returns:** 0 on success, 2 for bad input (nothing written), 3 when a study finished
    with some curves refused (listed in its ``refused.csv``), 130 after Ctrl-C.
    """
    from fitting.cli.fit.driver import run_fit  # imports JAX: not loaded for --help

    return run_fit(args)
