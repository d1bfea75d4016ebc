"""Plots of units, lines, responses, funnels and diversion windows (matplotlib, imported lazily)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jax.typing import ArrayLike

__all__ = ["plot_diversion", "plot_funnel", "plot_line", "plot_response"]

_CURVES = {"exit_age": "E(t)", "cumulative": "F(t)"}


def _axes(ax):
    if ax is not None:
        return ax
    import matplotlib.pyplot as plt

    return plt.subplots()[1]


def plot_line(
    rtds, times: ArrayLike, *, curve: str = "exit_age", ax=None, labels: Sequence[str] | None = None
):
    """Plot E (or F) of a line and of each of its units, or of any units and lines.

    **Arguments:**

    - `rtds`: a :class:`~axialmix.line.Line` (its units and the line are drawn), or a
      sequence of units and lines.
    - `times`: times to draw (time unit), strictly increasing.
    - `curve`: ``"exit_age"`` or ``"cumulative"``.
    - `ax`: matplotlib axes (a new figure when None).
    - `labels`: legend labels, one per curve drawn.

    **Returns:**

    The axes.
    """
    from axialmix.line._line import Line

    if curve not in _CURVES:
        raise ValueError(f"curve must be 'exit_age' or 'cumulative', got {curve!r}.")
    if isinstance(rtds, Line):
        items = list(rtds.units) + ([rtds] if len(rtds.units) > 1 else [])
    elif isinstance(rtds, Sequence):
        items = list(rtds)
    else:
        items = [rtds]
    if labels is not None and len(labels) != len(items):
        raise ValueError(f"labels must name the {len(items)} curves drawn, got {len(labels)}.")
    ax = _axes(ax)
    times = np.asarray(times, dtype=float)
    for index, item in enumerate(items):
        values = np.asarray(getattr(item, curve)(times))
        label = labels[index] if labels is not None else item.name
        ax.plot(times, values, label=label, linewidth=2.0 if isinstance(item, Line) else 1.2)
    unit = items[0].time_unit
    ax.set_xlabel(f"time ({unit})")
    ax.set_ylabel(f"{_CURVES[curve]}" + (f" (1/{unit})" if curve == "exit_age" else ""))
    ax.legend()
    return ax


def plot_response(response, *, ax=None):
    """Plot the inlet and outlet deviations of an :class:`~axialmix.line.OutletResponse`."""
    ax = _axes(ax)
    times = np.asarray(response.times)
    ax.plot(times, np.asarray(response.inlet), label="inlet", color="0.5")
    ax.plot(times, np.asarray(response.outlet), label="outlet")
    ax.set_xlabel(f"time ({response.time_unit})")
    ax.set_ylabel(f"deviation ({response.value_unit})" if response.value_unit else "deviation")
    ax.legend()
    return ax


def plot_funnel(result, *, ax=None, levels: int = 12):
    """Funnel plot: the largest outlet deviation over duration (x, log) and magnitude (y).

    **Arguments:**

    - `result`: a :class:`~axialmix.line.FunnelResult`.
    - `ax`: matplotlib axes (a new figure when None).
    - `levels`: number of filled contour levels.

    **Returns:**

    The axes.
    """
    ax = _axes(ax)
    durations = np.asarray(result.durations)
    magnitudes = np.asarray(result.magnitudes)
    deviation = np.asarray(result.max_deviation)
    if durations.size > 1 and magnitudes.size > 1:
        order_d, order_m = np.argsort(durations), np.argsort(magnitudes)
        filled = ax.contourf(
            durations[order_d], magnitudes[order_m], deviation[np.ix_(order_m, order_d)],
            levels=levels,
        )
        ax.figure.colorbar(filled, ax=ax, label=f"largest outlet deviation {result.magnitude_unit}")
        ax.set_xscale("log")
    else:
        for row, magnitude in zip(deviation, magnitudes, strict=True):
            ax.plot(durations, row, marker="o", label=f"M = {magnitude:g}")
        ax.legend()
    ax.set_xlabel(f"disturbance duration ({result.time_unit})")
    ax.set_ylabel(f"disturbance magnitude {result.magnitude_unit}".strip())
    return ax


def plot_diversion(window, *, ax=None):
    """Plot the outlet content, the limits and the diversion window (and its conservative one).

    **Arguments:**

    - `window`: a :class:`~axialmix.line.DiversionWindow` or
      :class:`~axialmix.line.ConservativeDiversion`.
    - `ax`: matplotlib axes (a new figure when None).

    **Returns:**

    The axes.
    """
    ax = _axes(ax)
    nominal = getattr(window, "nominal", window)
    times = np.asarray(nominal.times)
    ax.plot(times, np.asarray(nominal.outlet), label="outlet content")
    for limit in (nominal.lower, nominal.upper):
        ax.axhline(float(limit), color="k", linestyle="--", linewidth=0.8)
    end = times[-1]
    if bool(nominal.diverts):
        ax.axvspan(float(nominal.start), min(float(nominal.stop), end), alpha=0.25,
                   color="tab:red", label="diversion")
    if window is not nominal and np.isfinite(float(window.start)):
        ax.axvspan(float(window.start), min(float(window.stop), end), alpha=0.12,
                   color="tab:orange", label=f"conservative ({window.coverage:.0%})")
    ax.set_xlabel(f"time ({nominal.time_unit})")
    ax.set_ylabel(f"content {nominal.content_unit}".strip())
    ax.legend()
    return ax
