"""How ``axialmix fit`` fits one curve: least-squares multi-start (in batches, with progress,
when ``--starts`` is large), polished on the mean absolute error with ``--loss mae``, with
profile-likelihood intervals for ``--profile``, and the axes of the source's grid search for
``--grid``.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading

#: Rates searched on the source's grid by ``--grid``.
SOURCE_GRID_STEP, SOURCE_GRID_MAX = 0.125, 2.5
#: Free parameters held at their fitted value in the grid search (the source did not search
#: the outflow rate, and had no measurement model).
GRID_HELD = ("k_out", "amplitude", "dead_time", "baseline")
#: Rates that are not compartment fluxes: searched like other parameters, around the fit (the
#: dead-zone exchange rate of the exchange models).
NOT_SOURCE_RATES = ("k_d",)
#: Starts per compiled batch when ``--starts`` is large: progress is shown between batches.
STARTS_PER_BATCH = 256


def grid_for(model, result):
    """Grid axes, held values and ties for ``--grid`` (see :mod:`fitting.cli.fit`)."""
    import numpy as np

    from fitting.gridsearch import source_flux_grid

    grids, fixed, tied = {}, {}, {}
    for name in model.parameter_names:
        setting = result.init_params[name]
        value = float(result.values[name])
        if setting.expr is not None:
            tied[name] = setting.expr
        elif not setting.vary or name in GRID_HELD:
            fixed[name] = value
        elif name.startswith("k_") and name not in NOT_SOURCE_RATES:
            grids[name] = source_flux_grid(SOURCE_GRID_STEP, SOURCE_GRID_MAX)
        else:
            grids[name] = value * np.logspace(math.log10(0.25), math.log10(4.0), 21)
    return grids, fixed, tied


def profiled(result, text: str, stop: threading.Event):
    """The fit with profile-likelihood intervals for the parameters ``--profile`` names."""
    from fitting.diagnostics import profile_intervals, with_profile_intervals
    from fitting.parameters import canonical_name

    names = None if text.strip() == "all" else [canonical_name(n.strip())
                                                 for n in text.split(",") if n.strip()]
    names = [n for n in (result.free_names if names is None else names)
             if n in result.free_names]

    def said(name: str) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        print(f"axialmix fit: profiling {name} ({names.index(name) + 1} of {len(names)})",
              file=sys.stderr, flush=True)

    try:
        return with_profile_intervals(result, profile_intervals(result, names, progress=said))
    except KeyboardInterrupt:
        stop.set()
        return result


def fit_one(model, curve, settings: dict, loss: str, starts: int | None,
            errors: str = "absolute", stop: threading.Event | None = None):
    """Fit one curve; the mean absolute error is polished from the least-squares optimum.

    The MAE is not smooth, so multi-start L-BFGS on it stalls at kinks; the least-squares
    multi-start finds the basin and a single MAE fit from there finishes. The evaluations
    and times of both stages are reported together. With `errors` ``"relative"`` or
    ``"combined"`` the least-squares fit is the weighted fit of that error model and the
    MAE polish is weighted by the square root of its weights (``1 / |model|`` for relative
    errors). Many starts run in batches of :data:`STARTS_PER_BATCH`, with progress between
    them.
    """
    import numpy as np

    from axialmix._progress import progress_bar
    from fitting.fit import fit
    from fitting.solve import MultiStart

    if starts is not None and starts > STARTS_PER_BATCH:
        first, done = None, 0
        bar = progress_bar(total=starts, description=f"starts ({curve.name})", unit="start")
        try:
            while done < starts and not (stop is not None and stop.is_set()):
                count = min(STARTS_PER_BATCH, starts - done)
                batch = fit(model, curve, settings, loss="sse", errors=errors,
                            multistart=MultiStart(n_starts=max(count, 2), seed=done))
                if first is None or batch.loss < first.loss:
                    evaluations = batch.n_evaluations + (first.n_evaluations if first else 0)
                    wall = batch.wall_time + (first.wall_time if first else 0.0)
                    first = dataclasses.replace(batch, n_evaluations=evaluations,
                                                wall_time=wall, n_starts=done + count)
                else:
                    first = dataclasses.replace(
                        first, n_evaluations=first.n_evaluations + batch.n_evaluations,
                        wall_time=first.wall_time + batch.wall_time, n_starts=done + count)
                done += count
                bar.update(count)
        finally:
            bar.close()
    else:
        first = fit(model, curve, settings, loss="sse", errors=errors,
                    multistart=MultiStart(n_starts=starts))
    if loss == "sse" or (stop is not None and stop.is_set()):
        return first
    weights = np.sqrt(first.weights) if errors != "absolute" else None
    second = fit(model, curve, first.restart_parameters(), loss=loss, weights=weights,
                 multistart=MultiStart(n_starts=1))
    return dataclasses.replace(
        second,
        n_evaluations=first.n_evaluations + second.n_evaluations,
        wall_time=first.wall_time + second.wall_time,
        n_starts=first.n_starts,
        error_model=first.error_model,
    )
