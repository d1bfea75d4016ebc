"""Exhaustive grid search: the source work's fitting method, kept as a baseline.

The source fitted the four-compartment fluxes ``k_f, k_r, k_s`` by evaluating the model at
every point of the grid ``[0 : 0.125 : 2.5]`` per flux (21³ = 9,261 runs) and keeping the
point with the smallest error ``(1/n) Σ |y_model - y_exp|`` (MODELS.md section 3). Here the
grid points are evaluated in chunks, each chunk by one jit-compiled, vmapped call, so the
baseline is as fast as the model allows and the comparison with gradient fits is fair.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from axialmix._progress import progress_bar
from fitting.data import Curve
from fitting.losses import LOSSES
from fitting.models import Model, get_model

ProgressCallback = Callable[[int, int, float], None]


def source_flux_grid(step: float = 0.125, upper: float = 2.5) -> np.ndarray:
    """The source work's grid of flux values ``[0 : step : upper]`` (both ends included).

    **Arguments:**

    - `step`: grid spacing (1/time unit); the source used 0.125, and 0.01 for its fine grid.
    - `upper`: largest value (1/time unit); the source used 2.5, and 5 for its wide grid.

    **Returns:** the grid values as a float64 array.
    """
    if not (step > 0 and upper >= 0):
        raise ValueError(f"step must be positive and upper non-negative, got {step}, {upper}")
    count = int(round(upper / step)) + 1
    return np.arange(count, dtype=np.float64) * step


@dataclass(frozen=True)
class GridResult:
    """Outcome of an exhaustive grid search.

    `values` holds the best grid point (every model parameter, fixed ones included), `loss`
    its loss, `losses` the loss at every grid point (shape = the grid's shape, NaN where not
    evaluated because the search was interrupted), `n_evaluations` the number of model
    evaluations made, `wall_time` the seconds they took (compilation, `compile_time`, not
    included), `interrupted` whether the search was stopped
    early (then `values` is the best point so far).
    """

    values: dict[str, float]
    loss: float
    loss_name: str
    n_evaluations: int
    n_points: int
    wall_time: float
    losses: np.ndarray
    grids: dict[str, np.ndarray]
    interrupted: bool = False
    compile_time: float = 0.0
    fixed: dict[str, float] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Whether every grid point was evaluated."""
        return self.n_evaluations == self.n_points

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (without the full loss array)."""
        return {
            "method": "grid search",
            "values": {name: float(v) for name, v in self.values.items()},
            "loss": float(self.loss),
            "loss_name": self.loss_name,
            "n_evaluations": int(self.n_evaluations),
            "n_points": int(self.n_points),
            "wall_time": float(self.wall_time),
            "interrupted": bool(self.interrupted),
            "grids": {
                name: {"min": float(g.min()), "max": float(g.max()), "count": int(g.size)}
                for name, g in self.grids.items()
            },
        }

    def report(self) -> str:
        """A short readable summary."""
        lines = [
            f"grid search over {', '.join(self.grids)}: "
            f"{self.n_evaluations:,} of {self.n_points:,} points"
            + (" (interrupted: best so far)" if self.interrupted else ""),
            f"  best {self.loss_name} = {self.loss:.6g} in {self.wall_time:.2f} s",
        ]
        lines += [f"  {name:>10s} = {value:.6g}" for name, value in self.values.items()]
        return "\n".join(lines)


def _progress_display() -> ProgressCallback:
    """Progress on standard error through :func:`axialmix._progress.progress_bar`."""
    state: dict[str, Any] = {}

    def show(done: int, total: int, best: float) -> None:
        bar = state.get("bar")
        if bar is None:
            bar = state["bar"] = progress_bar(total=total, description="grid search",
                                              unit="point")
        bar.update(done - bar.n)
        bar.set_postfix_str(f"best {best:.4g}", refresh=False)
        if done >= total:
            bar.close()
            if bar.disable:  # no terminal for the bar: one log line at the end instead
                print(f"grid search: {done:,}/{total:,} points, best {best:.4g}",
                      file=sys.stderr, flush=True)

    return show


def _curve_arrays(curve: Curve | tuple) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of a :class:`~fitting.data.Curve` or of a ``(times, values)`` pair."""
    if isinstance(curve, Curve):
        return np.asarray(curve.time, dtype=float), np.asarray(curve.value, dtype=float)
    times, values = (np.asarray(a, dtype=float) for a in curve)
    if times.ndim != 1 or times.shape != values.shape:
        raise ValueError("curve must be a Curve or a (times, values) pair of equal-length arrays")
    return times, values


def grid_search(
    model: Model | str,
    curve: Curve | tuple,
    grids: Mapping[str, Sequence[float] | np.ndarray],
    loss: str = "mae",
    chunk_size: int = 1024,
    progress: bool | ProgressCallback = True,
    fixed: Mapping[str, float] | None = None,
    tied: Mapping[str, str] | None = None,
    keep_losses: bool = True,
    stop: Callable[[], bool] | None = None,
) -> GridResult:
    """Evaluate a model at every point of a Cartesian grid and keep the best.

    Points are evaluated ``chunk_size`` at a time by one jit-compiled ``vmap`` (the last
    chunk is padded, so there is a single compilation). Ctrl-C (``KeyboardInterrupt``)
    stops the search and returns the best point so far with ``interrupted=True``.

    **Arguments:**

    - `model`: a :class:`~fitting.models.Model` or a built-in model name.
    - `curve`: the measured curve (a :class:`fitting.data.Curve` or ``(times, values)``).
    - `grids`: ``{parameter name: grid values}``; the search runs over their product.
    - `loss`: ``'mae'`` (the source's score) or ``'sse'``.
    - `chunk_size`: grid points per compiled call (memory ~ chunk_size × samples).
    - `progress`: ``True`` shows a progress bar on stderr, ``False`` is silent, a callable gets
      ``(points done, points in all, best loss so far)`` after each chunk.
    - `fixed`: values for model parameters not searched (defaults: the model's own).
    - `tied`: ``{name: other}``: parameter `name` takes the value of parameter `other` at
      every point (e.g. ``{"k_r": "k_f"}``); tied names are not searched.
    - `keep_losses`: keep the loss at every point (``False`` saves memory on huge grids).
    - `stop`: optional ``() -> bool`` asked after each chunk; ``True`` stops the search as
      Ctrl-C does (the command line's interrupt flag).

    **Returns:** a :class:`GridResult`.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {sorted(LOSSES)}, got {loss!r}")
    if not grids:
        raise ValueError("grids is empty: give at least one parameter to search")
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be at least 1, got {chunk_size}")
    names = list(grids)
    axes = [np.asarray(grids[name], dtype=np.float64).ravel() for name in names]
    for name, axis in zip(names, axes, strict=True):
        if axis.size == 0 or not np.all(np.isfinite(axis)):
            raise ValueError(f"grid for {name!r} must be a non-empty list of finite numbers")
    shape = tuple(axis.size for axis in axes)
    total = math.prod(shape)

    model = get_model(model)
    unknown = [name for name in names if name not in model.parameter_names]
    if unknown:
        raise ValueError(
            f"grids name parameter(s) {unknown} that model {model.name!r} does not have "
            f"(it has {', '.join(model.parameter_names)})"
        )
    fixed = dict(fixed or {})
    tied = dict(tied or {})
    for name, other in tied.items():
        if name in grids or other not in model.parameter_names or name == other:
            raise ValueError(
                f"cannot tie {name!r} to {other!r}: tie a parameter that is not searched to "
                "another parameter of the model"
            )
    base = {
        name: float(fixed.get(name, model.defaults[name].value))
        for name in model.parameter_names
        if name not in grids and name not in tied
    }
    times, observed = _curve_arrays(curve)
    score = LOSSES[loss]
    observed_j = jnp.asarray(observed)
    times_j = jnp.asarray(times)
    axes_j = [jnp.asarray(axis) for axis in axes]
    chunk = int(min(chunk_size, total))

    @jax.jit
    def chunk_losses(start: jax.Array, count: jax.Array) -> jax.Array:
        flat = start + jnp.arange(chunk)
        valid = jnp.arange(chunk) < count
        flat = jnp.where(valid, flat, start)
        index = jnp.unravel_index(flat, shape)
        points = {name: axis[i] for name, axis, i in zip(names, axes_j, index, strict=True)}

        def one(point: dict[str, jax.Array]) -> jax.Array:
            values = {**base, **point}
            for name, other in tied.items():
                values[name] = values[other]
            value = score(model(times_j, values) - observed_j)
            return jnp.where(jnp.isfinite(value), value, jnp.inf)

        return jnp.where(valid, jax.vmap(one)(points), jnp.inf)

    # Compile once, outside the timed loop, so `wall_time` measures evaluations only.
    compile_started = time.perf_counter()
    compiled = chunk_losses.lower(jnp.asarray(0), jnp.asarray(chunk)).compile()
    compile_time = time.perf_counter() - compile_started

    report = _progress_display() if progress is True else (progress or None)
    losses = np.full(total if keep_losses else 0, np.nan)
    best_loss, best_flat, done = math.inf, 0, 0
    interrupted = False
    started = time.perf_counter()
    try:
        while done < total:
            count = min(chunk, total - done)
            values = np.asarray(compiled(jnp.asarray(done), jnp.asarray(count)))[:count]
            if keep_losses:
                losses[done : done + count] = values
            local = int(np.argmin(values))
            if values[local] < best_loss:
                best_loss, best_flat = float(values[local]), done + local
            done += count
            if report is not None:
                report(done, total, best_loss)
            if stop is not None and done < total and stop():
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True
    wall_time = time.perf_counter() - started

    best_index = np.unravel_index(best_flat, shape)
    best = {name: float(axis[i]) for name, axis, i in zip(names, axes, best_index, strict=True)}
    found = {**base, **best}
    found.update({name: found[other] for name, other in tied.items()})
    all_values = {name: found[name] for name in model.parameter_names}
    return GridResult(
        values=all_values,
        loss=best_loss,
        loss_name=loss,
        n_evaluations=done,
        n_points=total,
        wall_time=wall_time,
        losses=losses.reshape(shape) if keep_losses else losses,
        grids=dict(zip(names, axes, strict=True)),
        interrupted=interrupted,
        compile_time=compile_time,
        fixed={name: float(v) for name, v in base.items()},
    )
