"""Drawing a fit's two-panel plot from plain arrays and words, in this process or in a drawing
process started before JAX is imported.

A fit's plot needs matplotlib, whose import and first figure take about 0.45 s, a third of a
one-curve ``axialmix fit``. The command line starts :func:`start_worker` first thing: a
second Python process that imports matplotlib while the first imports JAX and fits (on
another core), then draws each figure it is sent. :func:`draw` uses that process when it
runs and draws in this one otherwise (or when the process fails), so the bytes are the same
either way. The drawing process ignores Ctrl-C (the command line answers it) and ends when
its input closes, that is when this process ends.

A figure is described by a :data:`FigureSpec` (built by :func:`fitting.report.fit_figure`):
arrays of floats and strings only, so that drawing derives nothing.
"""

from __future__ import annotations

import io
import os
import pickle
import signal
import struct
import subprocess
import sys
import threading
from typing import Any

__all__ = ["FigureSpec", "draw", "draw_fit", "fit_figure", "serve", "start_worker",
           "stop_worker"]

#: The keys of a figure: ``time``, ``observed``, ``fine``, ``curve``, ``grid_curve`` (or
#: ``None``), ``residual`` (float arrays); ``data_label``, ``fit_label``, ``grid_label``,
#: ``ylabel``, ``title``, ``annotation`` (the headline parameters with their intervals, one a
#: line, written on the figure), ``residual_label``, ``xlabel`` (strings); ``thinned`` (bool:
#: the samples are every k-th of a long curve, drawn smaller).
FigureSpec = dict[str, Any]

_HEADER = struct.Struct("<Q")
_REPLY = struct.Struct("<BQ")


def draw_fit(spec: FigureSpec) -> bytes:
    """Draw the two-panel fit plot (data and model above, with the headline parameters in the
    legend's box, placed where it hides none of them; residuals below; all in the units of
    the data) as PNG bytes.

    **Arguments:** `spec`: a :data:`FigureSpec`.

    **Returns:** the PNG file's bytes (7 × 6 inches at 100 dpi).
    """
    buffer = io.BytesIO()
    fit_figure(spec).savefig(buffer, format="png", dpi=100)
    return buffer.getvalue()


def fit_figure(spec: FigureSpec):
    """The matplotlib figure that :func:`draw_fit` saves (Agg, 7 × 6 inches).

    **Arguments:** `spec`: a :data:`FigureSpec`.

    **Returns:** a :class:`matplotlib.figure.Figure`; its top axes hold the legend.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    thinned = bool(spec["thinned"])
    # Fixed margins: a constrained layout costs about 0.15 s a figure, half the drawing time.
    figure = Figure(figsize=(7, 6))
    figure.subplots_adjust(left=0.16, right=0.97, top=0.95, bottom=0.08, hspace=0.12)
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[3, 1.3])
    top.plot(spec["time"], spec["observed"], "o", color="black", label=spec["data_label"],
             markersize=2 if thinned else 6)
    top.plot(spec["fine"], spec["curve"], "-", color="tab:blue", label=spec["fit_label"])
    if spec["grid_curve"] is not None:
        top.plot(spec["fine"], spec["grid_curve"], "--", color="tab:orange",
                 label=spec["grid_label"])
    top.set_ylabel(spec["ylabel"])
    top.set_title(spec["title"], fontsize=10)
    bottom.axhline(0.0, color="grey", linewidth=0.8)
    bottom.plot(spec["time"], spec["residual"], "o-", color="tab:blue",
                markersize=1.5 if thinned else 4, linewidth=0.5 if thinned else 1.0)
    bottom.set_ylabel(spec["residual_label"])
    bottom.set_xlabel(spec["xlabel"])
    _place_legend(figure, top, spec)
    return figure


def _place_legend(figure, axes, spec: FigureSpec) -> None:
    """The legend, headed by the headline parameters, where it hides none of the data.

    Its box goes where it covers the least of the points and curves (matplotlib's "best" of
    nine places). Where that still covers some (a curve that fills the panel), the panel is
    made taller above the data by the box's height and the box goes to the top right, over
    the room made for it: a box fixed in a corner hid points of curves whose peak is late or
    whose tail is cut.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    legend = axes.legend(fontsize=8, loc="best", title=spec["annotation"] or None,
                         title_fontsize=8, alignment="left")
    axes.get_ylim()  # the limits the data set, before the box is placed against them
    renderer = FigureCanvasAgg(figure).get_renderer()
    legend.draw(renderer)  # places the box (drawn again with the figure)
    box = legend.get_window_extent(renderer).padded(2.0)
    # The points and curves drawn, in display coordinates (NaN compares false: never inside).
    hidden = False
    for line in axes.get_lines():
        shown = axes.transData.transform(line.get_xydata())
        inside = ((shown[:, 0] >= box.x0) & (shown[:, 0] <= box.x1)
                  & (shown[:, 1] >= box.y0) & (shown[:, 1] <= box.y1))
        hidden = hidden or bool(inside.any())
    if not hidden:
        return
    panel = axes.get_window_extent(renderer)
    share = min(box.height / panel.height + 0.03, 0.6)  # of the panel, above the data
    low, high = axes.get_ylim()
    axes.set_ylim(low, low + (high - low) / (1.0 - share))
    legend.set_loc("upper right")


class _WorkerFailed(Exception):
    """The drawing process did not answer; draw here instead."""


class _Worker:
    """The drawing process: figures go in on its standard input, PNG bytes come back."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-c", "from fitting.drawing import serve; serve()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        )
        self.lock = threading.Lock()
        self.owner = os.getpid()  # a forked copy of this process must not share the pipes

    def draw(self, spec: FigureSpec) -> bytes:
        message = pickle.dumps(spec, protocol=pickle.HIGHEST_PROTOCOL)
        with self.lock:
            try:
                self.process.stdin.write(_HEADER.pack(len(message)) + message)
                self.process.stdin.flush()
                reply = self._read(_REPLY.size)
                status, size = _REPLY.unpack(reply)
                payload = self._read(size)
            except (OSError, ValueError, struct.error) as error:
                raise _WorkerFailed(str(error)) from None
        if status != 0:  # drawing failed there: drawn here, the error is raised here
            raise _WorkerFailed(payload.decode(errors="replace"))
        return payload

    def _read(self, size: int) -> bytes:
        data = self.process.stdout.read(size)
        if len(data) != size:
            raise _WorkerFailed("the drawing process ended")
        return data

    def close(self) -> None:
        for stream in (self.process.stdin, self.process.stdout):
            try:
                stream.close()
            except OSError:
                pass
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()


_worker: _Worker | None = None


def start_worker() -> None:
    """Start the drawing process (once a process; nothing happens if it cannot start)."""
    global _worker
    if _worker is None:
        try:
            _worker = _Worker()
        except OSError:
            _worker = None


def stop_worker() -> None:
    """Close the drawing process, if one runs (it ends when its input closes)."""
    global _worker
    worker, _worker = _worker, None
    if worker is not None:
        worker.close()


def draw(spec: FigureSpec) -> bytes:
    """Draw `spec` (see :func:`draw_fit`) in the drawing process when one runs, else here.

    **Arguments:** `spec`: a :data:`FigureSpec`.

    **Returns:** the PNG file's bytes, the same wherever they were drawn.
    """
    worker = _worker
    if worker is not None and worker.owner == os.getpid():
        try:
            return worker.draw(spec)
        except _WorkerFailed:
            stop_worker()  # not used again; the figure is drawn here
    return draw_fit(spec)


def serve() -> None:
    """The drawing process: import matplotlib, then draw each figure read from standard input
    until it closes (length-prefixed pickles in; a status byte, a length and the PNG bytes
    or the error's words out)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command line's to answer
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    Figure(figsize=(1, 1)).savefig(io.BytesIO(), format="png")  # font and renderer loaded
    source, sink = sys.stdin.buffer, sys.stdout.buffer
    while True:
        header = source.read(_HEADER.size)
        if len(header) != _HEADER.size:
            return
        (size,) = _HEADER.unpack(header)
        message = source.read(size)
        if len(message) != size:
            return
        try:
            payload, status = draw_fit(pickle.loads(message)), 0  # noqa: S301 (our own parent)
        except Exception as error:  # noqa: BLE001  (reported to the parent, which draws again)
            payload, status = f"{type(error).__name__}: {error}".encode(), 1
        try:
            sink.write(_REPLY.pack(status, len(payload)) + payload)
            sink.flush()
        except OSError:
            return
