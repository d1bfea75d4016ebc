"""Plots of units, lines, responses, funnels and diversion windows (matplotlib, imported lazily)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jax.typing import ArrayLike

__all__ = ["FUNNEL_MAP_POINTS", "funnel_map_durations", "plot_diversion", "plot_funnel",
           "plot_line", "plot_response"]

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


#: Points per axis of the funnel map drawn by :func:`plot_funnel` when it is given the RTD.
FUNNEL_MAP_POINTS = 160


def _window_text(start: float, stop: float, amount: float, time_unit: str,
                 amount_unit: str) -> str:
    if not np.isfinite(start):
        return "no diversion"
    stop_text = f"{stop:.4g} {time_unit}" if np.isfinite(stop) else "beyond the end"
    amount_text = (f", {amount:.4g} {amount_unit} diverted".rstrip() if np.isfinite(amount)
                   else "")
    return f"{start:.4g} to {stop_text}{amount_text}"


def funnel_map_durations(durations: ArrayLike) -> np.ndarray:
    """The durations :func:`plot_funnel` draws its map on: :data:`FUNNEL_MAP_POINTS`
    log-spaced over the range of `durations` and a little beyond (time unit).

    **Arguments:** `durations`: the durations of a funnel (positive, time unit).

    **Returns:** the map's durations ``(FUNNEL_MAP_POINTS,)``.
    """
    durations = np.asarray(durations, float)
    return np.geomspace(float(durations.min()) / 1.5, float(durations.max()) * 1.5,
                        FUNNEL_MAP_POINTS)


def plot_funnel(result, *, ax=None, rtd=None, limit: float | None = None,
                title: str | None = None, levels: int = 24, fine=None):
    """Funnel plot: the largest outlet deviation over duration (x, log) and magnitude (y).

    With `rtd` the map is drawn smooth on a fine grid, whatever grid `result` was computed
    on: :data:`FUNNEL_MAP_POINTS` durations, log-spaced over the range of
    ``result.durations`` and a little beyond, by :func:`~axialmix.line.funnel`; the
    deviation ``M · max_u [F(u + d) - F(u)]`` is exactly linear in the magnitude, so the
    magnitudes need no more solves. The points of `result` are marked on the map. Without
    `rtd` the map is the contour of `result`'s own grid. With `limit` the specification
    contour ``|deviation| = limit`` is drawn and labelled: the disturbances above it take
    the outlet out of specification (the funnel itself).

    **Arguments:**

    - `result`: a :class:`~axialmix.line.FunnelResult`.
    - `ax`: matplotlib axes (a new figure when None).
    - `rtd`: the :class:`~axialmix.line.Unit`, :class:`~axialmix.line.Line` or
      :class:`~axialmix.line.TabulatedRTD` `result` was computed from (None: its grid only).
    - `limit`: the specification, the largest deviation allowed (magnitude unit, positive;
      None: no contour).
    - `title`: the axes title (None: a description of the plot).
    - `levels`: number of filled contour levels.
    - `fine`: the funnel of the same RTD on :func:`funnel_map_durations` of `result`'s
      durations, computed beforehand (with `result`, in one program, say); the map is then
      drawn from it and `rtd` is not needed.

    **Returns:**

    The axes.
    """

    ax = _axes(ax)
    durations = np.asarray(result.durations, float)
    magnitudes = np.asarray(result.magnitudes, float)
    deviation = np.asarray(result.max_deviation, float)
    unit = result.magnitude_unit
    if limit is not None and not (np.isfinite(limit) and limit > 0):
        raise ValueError(f"limit must be a positive number, got {limit!r}.")
    low, high = float(durations.min()), float(durations.max())
    smooth = (rtd is not None or fine is not None) and high > low
    if smooth and fine is not None:
        map_durations = np.asarray(fine.durations, float)
        fraction = np.asarray(fine.max_fraction, float)
    elif smooth:
        from axialmix.line._funnel import funnel

        map_durations = funnel_map_durations(durations)
        fraction = np.asarray(funnel(rtd, map_durations, np.ones(1)).max_fraction)
    else:
        order = np.argsort(durations)
        map_durations, fraction = durations[order], np.asarray(result.max_fraction)[order]
    m_low = 1.1 * min(0.0, float(magnitudes.min()))
    m_high = 1.1 * max(0.0, float(magnitudes.max()))
    if rtd is not None or fine is not None or magnitudes.size > 1:
        map_magnitudes = np.linspace(m_low, m_high, FUNNEL_MAP_POINTS)
    else:
        map_magnitudes = magnitudes
    if map_durations.size > 1 and map_magnitudes.size > 1:
        surface = np.abs(map_magnitudes[:, None] * fraction[None, :])
        filled = ax.contourf(map_durations, map_magnitudes, surface, levels=levels,
                             cmap="viridis")
        ax.figure.colorbar(filled, ax=ax,
                           label=f"largest outlet deviation ({unit})" if unit
                           else "largest outlet deviation")
        if limit is not None and surface.max() > limit:
            ax.contour(map_durations, map_magnitudes, surface, levels=[limit],
                              colors="red", linewidths=2.0)
            ax.plot([], [], color="red", linewidth=2.0,
                    label=f"outlet leaves ±{limit:g} {unit} above this line".replace(" %", "%"))
        ax.plot(np.repeat(durations, magnitudes.size), np.tile(magnitudes, durations.size),
                "o", color="white", markeredgecolor="black", markersize=4,
                label="computed points (JSON)")
        ax.legend(fontsize=8, loc="lower left")
        ax.set_xscale("log")
        ax.set_xlim(map_durations[0], map_durations[-1])
    else:
        for row, magnitude in zip(deviation, magnitudes, strict=True):
            ax.plot(durations, row, marker="o", label=f"M = {magnitude:g}")
        if limit is not None:
            ax.axhline(limit, color="red", label=f"specification ±{limit:g} {unit}".strip())
        ax.legend(fontsize=8)
    ax.set_xlabel(f"disturbance duration ({result.time_unit})")
    ax.set_ylabel(f"disturbance magnitude ({unit})" if unit else "disturbance magnitude")
    ax.set_title(title if title is not None else
                 "Funnel plot: largest outlet deviation of square feed disturbances",
                 fontsize=10)
    return ax


def plot_diversion(window, *, ax=None, title: str | None = None):
    """Plot the outlet content, the limits and the diversion window (and its conservative one).

    The nominal window is shaded and its start and stop are marked by lines; each window is
    also drawn as a bar of its own near the bottom (the conservative one, of a
    :class:`~axialmix.line.ConservativeDiversion`, below the nominal one, with dashed start
    and stop lines), labelled with its start, stop and the amount diverted, so that both stay
    visible where they overlap.

    **Arguments:**

    - `window`: a :class:`~axialmix.line.DiversionWindow` or
      :class:`~axialmix.line.ConservativeDiversion`.
    - `ax`: matplotlib axes (a new figure when None).
    - `title`: the axes title (None: a description of the plot).

    **Returns:**

    The axes.
    """
    ax = _axes(ax)
    nominal = getattr(window, "nominal", window)
    times = np.asarray(nominal.times)
    end = float(times[-1])
    unit, amount_unit = nominal.time_unit, nominal.amount_unit
    ax.plot(times, np.asarray(nominal.outlet), color="tab:blue", label="outlet content",
            zorder=3)
    for limit in (nominal.lower, nominal.upper):
        ax.axhline(float(limit), color="k", linestyle="--", linewidth=0.8, zorder=2)
    ax.plot([], [], color="k", linestyle="--", linewidth=0.8,
            label=f"limits {float(nominal.lower):g} and {float(nominal.upper):g} "
            f"{nominal.content_unit}".strip())
    bar = ax.get_xaxis_transform()  # x in data, y in axes fraction

    def draw_window(start, stop, amount, row, colour, words, label):
        text = f"{words}: " + _window_text(start, stop, amount, unit, amount_unit)
        if not np.isfinite(start):
            ax.text(0.01, row + 0.03, text, transform=ax.transAxes, fontsize=8, color=colour,
                    va="center")
            return
        shown = min(stop, end)
        for edge in (start, shown):
            ax.axvline(edge, color=colour, linewidth=1.2, zorder=2,
                       linestyle="-" if words == "nominal" else "--")
        ax.fill_between([start, shown], row, row + 0.06, transform=bar, color=colour,
                        alpha=0.8, zorder=3, label=label, linewidth=0)
        ax.text(shown, row + 0.03, "  " + text, transform=bar, fontsize=8, color=colour,
                va="center", ha="left", zorder=4)

    start, stop = float(nominal.start), float(nominal.stop)
    if bool(nominal.diverts):
        ax.axvspan(start, min(stop, end), alpha=0.15, color="tab:red", zorder=1)
    draw_window(start, stop, float(nominal.diverted_amount), 0.19, "tab:red", "nominal",
                "nominal window (start and stop)")
    if window is not nominal:
        draw_window(float(window.start), float(window.stop), float(window.diverted_amount),
                    0.11, "tab:orange", f"conservative {window.coverage:.0%}",
                    f"conservative window ({window.coverage:.0%}, dashed)")
    ax.set_xlabel(f"time ({unit})")
    ax.set_ylabel(f"outlet content ({nominal.content_unit})" if nominal.content_unit
                  else "outlet content")
    ax.set_title(title if title is not None else
                 "Diversion: outlet content against its limits", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    return ax
