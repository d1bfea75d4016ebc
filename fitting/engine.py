"""The batched fit engine: a chunk of curves fitted completely in one compiled program.

One program per (model, parameter layout, solver plan, error model, padded length) takes a
chunk of curves of one padded length and returns, for every curve, everything a fit result
is built from. Inside it, ``vmap`` over the curves of:

1. every start (``vmap`` over starts) of the single-start solver of :mod:`fitting.solve`,
   the start with the lowest finite loss kept, and its Gauss–Newton check (the status rules
   of :class:`fitting.solve.MultiStartSolver`) — the *first fit*;
2. the error model's passes (relative, additive plus proportional, or counting errors): the weights
   made from the last pass's model curve (and, for combined errors, its residuals and
   leverages, :func:`combined_errors`), a refit from the last pass's end, until the fitted
   values change by at most the model's ``change`` or ``max_passes`` fits were made — a
   bounded :func:`jax.lax.while_loop` whose stop is per curve (a curve that has stopped
   is frozen while the others go on);
3. the Jacobian of the last fit at its end (the uncertainty is then array algebra).

Only arrays cross back to Python, once per chunk. The programs are started without waiting
for them (:func:`launch_chunk_arrays`): while one runs, the caller builds the results of the
one before (and a study writes the records of its chunk before). A curve whose first fit or
one of whose passes needs what the compiled program cannot do — Newton's method on the full
Hessian where Levenberg–Marquardt stopped on a singular Gauss–Newton curvature (status
FLAT), or L-BFGS where it crawled (SLOW, MAX_STEPS) — is flagged (``needs_polish``);
:mod:`fitting.fit` then fits that curve by the multi-start solver's polishing path. Whether
a curve is flagged is a property of the curve, never of the chunk it came in, so a curve
fitted alone and inside any chunk takes the same path and gets the same numbers.

Unbounded parameters are scaled by a power of ten near their start value
(:func:`fitting.parameters.make_layout`); here that scale is an argument per curve (the
program's layout has scale 1), so curves with different scales share one program and each
is solved in its own coordinates, as it would be alone.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading
import time as _time
from collections.abc import Iterator
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from fitting.losses import LOGIT_RANGE
from fitting.parameters import Layout
from fitting.solve import (
    PLATEAU,
    RUNNING,
    Program,
    SolverPlan,
    Status,
    adam_minimise,
    export_key,
    lm_initial,
    lm_step,
    weighted_evaluation,
    weighted_residuals,
)

__all__ = ["CHUNK", "LANES", "ErrorPlan", "chunk_program", "chunk_shape", "combined_errors",
           "describe_device", "launch_chunk_arrays", "LaunchedChunk",
           "leverages"]


@dataclass(frozen=True)
class ErrorPlan:
    """The static error model of a compiled chunk fit (hashable).

    ``kind``: ``'absolute'`` (one fit), ``'relative'`` (weights ``1 / max(|m|, floor·peak)²``),
    ``'combined'`` (weights ``1 / (a² + (b m)²)``, ``a`` and ``b`` estimated each pass) or
    ``'poisson'`` (counts: weights ``x / max(m, floor·peak)``, ``x`` the exposure given as
    the curve's weights, which also weight its first fit);
    ``max_passes``: most fits in all; ``change``: relative change of every fitted value
    between passes at which the passes stop; ``floor``: of the relative weights.
    """

    kind: str = "absolute"
    max_passes: int = 1
    change: float = 0.0
    floor: float = 0.0


#: Status codes after which the multi-start solver polishes (Levenberg–Marquardt only).
_POLISHED = (int(Status.FLAT), int(Status.SLOW), int(Status.MAX_STEPS))
#: Logit grid of the combined error sizes' share (as in fitting.losses).
_GRID = np.linspace(-LOGIT_RANGE, LOGIT_RANGE, 161)
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
#: Samples from which the combined error sizes' grid is evaluated point after point.
_SIDE_BY_SIDE_SAMPLES = 16384


def _transform(layout: Layout, u, scale):
    """Free values from unconstrained coordinates, unbounded ones scaled by `scale` (JAX)."""
    values = []
    for j, kind in enumerate(layout.kinds):
        if kind == "lower":
            values.append(layout.lower[j] + jnp.exp(u[j]))
        elif kind == "upper":
            values.append(layout.upper[j] - jnp.exp(u[j]))
        elif kind == "both":
            values.append(layout.lower[j] + (layout.upper[j] - layout.lower[j])
                          * jax.nn.sigmoid(u[j]))
        else:
            values.append(scale[j] * u[j])
    return jnp.stack(values)


def leverages(jacobian, weights):
    """Leverages of a weighted least-squares fit (JAX; as :func:`fitting.losses.leverages`)."""
    root = jnp.sqrt(weights)[:, None] * jacobian
    basis, singular, _ = jnp.linalg.svd(root, full_matrices=False)
    keep = singular > 1e-12 * jnp.maximum(jnp.max(singular), 1e-300)
    return jnp.clip(jnp.sum(jnp.where(keep[None, :], basis**2, 0.0), axis=1), 0.0, 1.0)


def combined_errors(residual, model_values, leverage, used):
    """``(a, b)`` of ``Var = a² + (b m)²`` from a fit's residuals (JAX, masked).

    The same estimate as :func:`fitting.losses.estimate_combined_errors` (pseudo-likelihood
    over the proportional share ``f``: a grid in ``logit f``, then golden-section search
    between the grid's neighbours of its best point), on the points where `used` is true.
    """
    informative = used & ((residual != 0) | (model_values != 0))
    count = jnp.sum(informative)
    scale = jnp.max(jnp.where(informative, jnp.abs(model_values), 0.0))
    squared = jnp.where(informative, residual**2 / jnp.clip(1.0 - leverage, 1e-3, None), 0.0)
    safe_scale = jnp.where(scale > 0, scale, 1.0)
    relative = jnp.where(informative, (model_values / safe_scale) ** 2, 0.0)

    def shares(logit):
        return 1.0 / (1.0 + jnp.exp(logit)), 1.0 / (1.0 + jnp.exp(-logit))

    def nll(logit):
        additive, proportional = shares(logit)
        g = jnp.where(informative, additive + proportional * relative, 1.0)
        mean = jnp.sum(jnp.where(informative, squared / g, 0.0)) / jnp.maximum(count, 1)
        return jnp.sum(jnp.log(g)) + count * jnp.log(mean)

    grid = jnp.asarray(_GRID)
    # The grid side by side holds 161 curve-long arrays: one after another for long curves
    # (the same numbers; 2.7 GB at a million points otherwise).
    values = (jax.lax.map(nll, grid) if residual.shape[-1] >= _SIDE_BY_SIDE_SAMPLES
              else jax.vmap(nll)(grid))
    best = jnp.argmin(values)
    low = grid[jnp.maximum(best - 1, 0)]
    high = grid[jnp.minimum(best + 1, grid.size - 1)]

    def golden_step(state):
        low, high, left, right, f_left, f_right = state
        go_left = f_left <= f_right
        high = jnp.where(go_left, right, high)
        low = jnp.where(go_left, low, left)
        probe = jnp.where(go_left, high - _GOLDEN * (high - low), low + _GOLDEN * (high - low))
        f_probe = nll(probe)
        new_left = jnp.where(go_left, probe, right)
        new_right = jnp.where(go_left, left, probe)
        new_f_left = jnp.where(go_left, f_probe, f_right)
        new_f_right = jnp.where(go_left, f_left, f_probe)
        return low, high, new_left, new_right, new_f_left, new_f_right

    left = high - _GOLDEN * (high - low)
    right = low + _GOLDEN * (high - low)
    state = (low, high, left, right, nll(left), nll(right))
    low, high, *_ = jax.lax.while_loop(lambda s: s[1] - s[0] > 1e-6, golden_step, state)
    middle = 0.5 * (low + high)
    logit = jnp.where(nll(middle) <= values[best], middle, grid[best])
    additive, proportional = shares(logit)
    variance = jnp.sum(jnp.where(informative, squared / (additive + proportional * relative),
                                 0.0)) / jnp.maximum(count, 1)
    a = jnp.sqrt(variance * additive)
    b = jnp.sqrt(variance * proportional) / safe_scale
    empty = (count == 0) | ~jnp.any(squared > 0)
    flat = scale == 0
    a = jnp.where(empty, 0.0, jnp.where(flat, jnp.sqrt(jnp.sum(squared) / jnp.maximum(count, 1)),
                                         a))
    b = jnp.where(empty | flat, 0.0, b)
    return a, b


def _record(carry, to_free, size):
    """The outputs of a finished Levenberg–Marquardt run from its loop state."""
    u, residual, jacobian, (predicted, physical), value, *_rest = carry
    count, evaluations, status = carry[8], carry[9], carry[12]
    ones = jnp.ones_like(u)
    return {
        "u": u, "free_values": to_free(u), "predicted": predicted, "jacobian": physical,
        "derivative": jax.jvp(to_free, (u,), (ones,))[1], "scaled_loss": value,
        "scale": size, "grad_norm": jnp.linalg.norm(2.0 * jacobian.T @ residual),
        "steps": count, "evaluations": evaluations, "status": status,
        # Levenberg-Marquardt's own (scaled) residuals and Jacobian in u, for the check.
        "scaled_residual": residual, "scaled_jacobian": jacobian,
    }


#: What a finished run's record holds only until it is checked: Levenberg–Marquardt's scaled
#: residuals and Jacobian (two more curve-long arrays).
_CHECK_ONLY = ("scaled_residual", "scaled_jacobian")
#: The curve-long arrays of a record (the model's values and Jacobian at the run's end).
_CURVES = ("predicted", "jacobian")


def _without(record: dict, names) -> dict:
    """`record` without the entries `names`."""
    return {k: v for k, v in record.items() if k not in names}


def _checked(record: dict, options: SolverPlan):
    """Status after the Gauss–Newton check and that step's length, and whether the
    multi-start solver would polish here (JAX; as :meth:`fitting.solve.MultiStartSolver.
    _check` and its plateau rule)."""
    status = record["status"]
    design, residual = record["scaled_jacobian"], record["scaled_residual"]
    finite = jnp.all(jnp.isfinite(design)) & jnp.all(jnp.isfinite(residual))
    step = jnp.linalg.lstsq(jnp.where(finite, design, 0.0), -jnp.where(finite, residual, 0.0),
                            rcond=1e-10)[0]
    newton_step = jnp.where(finite, jnp.max(jnp.abs(step)), jnp.nan)
    stopped = ((status == int(Status.GRADIENT)) | (status == int(Status.LOSS_CHANGE))
               | (status == int(Status.NO_DECREASE)))
    small = newton_step <= options.xtol
    status = jnp.where(
        stopped,
        jnp.where(small, jnp.where(status == int(Status.NO_DECREASE),
                                   int(Status.PRECISION_LIMIT), status), int(Status.FLAT)),
        status)
    polish = jnp.isin(status, jnp.asarray(_POLISHED))
    status = jnp.where(record["scaled_loss"] >= PLATEAU, int(Status.MISSES_DATA), status)
    return status, newton_step, polish


def _chunk_function(model, layout: Layout, options: SolverPlan, errors: ErrorPlan,
                    lanes: int):
    """``(starts, warm, base, scale, time, observed, weights) -> outputs`` of a chunk.

    Per curve, ONE Levenberg–Marquardt loop runs phase after phase: the starts of the first
    fit one after another (the best kept), then the error model's passes, each from the end
    of the one before with the weights made from it. The model is traced once (in the loop's
    evaluation), and a curve's whole fit is one loop, so the curves of a vmapped group cost
    the iterations of the longest whole fit (not the sum of each pass's longest).
    """
    if options.method != "lm":
        raise ValueError("the batched engine runs Levenberg-Marquardt (least squares)")
    n_free = len(layout.free)

    def predict(free_values, base, time):
        return model(time, layout.all_values(free_values, base))

    def all_values(free_values, base):
        return jnp.stack(list(layout.all_values(free_values, base).values()))

    def one_curve(active, starts, warm, base, scale, time, observed, weights):
        real = weights > 0

        def to_free(u):
            return _transform(layout, u, scale)

        def loss_size(w):
            size = jnp.sum(w * observed**2)
            return jnp.where(size > 0, size, 1.0)

        def evaluator(w, size):
            return weighted_evaluation(to_free, lambda f: predict(f, base, time), observed,
                                       jnp.sqrt(w / size), w > 0)

        n = time.shape[0]
        empty = (jnp.zeros(n), jnp.zeros((n, n_free)),
                 (jnp.zeros(n), jnp.zeros((n, n_free))))
        count_starts = starts.shape[0]
        if options.warmup_steps > 0:
            size0 = loss_size(weights)

            def objective(u):
                residual = jnp.where(real, predict(to_free(u), base, time) - observed, 0.0)
                return jnp.sum(weights * residual**2) / size0

            def warm_up(u):
                u_warm, _, _, _, evaluations, _ = adam_minimise(objective, u, options,
                                                        options.warmup_steps)
                return u_warm, evaluations

            # One start after another, each warmed only if it is random (a real branch: a
            # vmap over the starts would warm every start and run the model's own branches
            # both ways — 20 times slower for a compartment network).
            starts, warm_evaluations = jax.lax.map(
                lambda row: jax.lax.cond(row[1], warm_up,
                                         lambda u: (u, jnp.asarray(0)), row[0]),
                (starts, warm))
        else:
            warm_evaluations = jnp.zeros(count_starts, dtype=int)

        def next_weights(record, w):
            """The next pass's weights from a finished fit with weights `w`; its error
            sizes; whether to go on (not for an exact fit under combined errors)."""
            predicted = record["predicted"]
            if errors.kind == "poisson":
                # Counts: Var(y) = m / x with the exposure x the curve came with (its
                # first weights); the fixed point is the Poisson maximum-likelihood fit.
                peak = jnp.maximum(jnp.max(jnp.where(real, jnp.abs(predicted), 0.0)), 1e-300)
                magnitude = jnp.maximum(predicted, errors.floor * peak)
                return (jnp.where(real, weights / magnitude, 0.0), jnp.zeros(2),
                        jnp.asarray(True))
            if errors.kind == "relative":
                magnitude = jnp.abs(predicted)
                peak = jnp.maximum(jnp.max(jnp.where(real, magnitude, 0.0)), 1e-300)
                magnitude = jnp.maximum(magnitude, errors.floor * peak)
                return (jnp.where(real, 1.0 / magnitude**2, 0.0), jnp.zeros(2),
                        jnp.asarray(True))
            residual = jnp.where(real, predicted - observed, 0.0)
            h = leverages(record["jacobian"], w)
            a, b = combined_errors(residual, predicted, h, real)
            variance = a**2 + (b * predicted) ** 2
            new = jnp.where(real, 1.0 / jnp.maximum(variance, np.finfo(float).tiny), 0.0)
            return new / jnp.max(new), jnp.stack([a, b]), ~((a == 0.0) & (b == 0.0))

        def _resumed(record, w, size):
            """Levenberg–Marquardt's state after its first iteration from a finished fit's
            end under new weights `w`: that iteration only evaluates at its start, where the
            model's values and Jacobian are the finished fit's own, so they are reused, not
            evaluated again (the same numbers; one model evaluation fewer a pass)."""
            predicted, physical = record["predicted"], record["jacobian"]
            residual, scaled = weighted_residuals(predicted, physical, record["derivative"],
                                                  observed, jnp.sqrt(w / size), w > 0)
            start = lm_initial(record["u"], empty)
            carry = lm_step(lambda u: (residual, scaled, (predicted, physical)), start, options)
            # No evaluation was made: the count stays that of the evaluations made.
            return (*carry[:9], start[9], *carry[10:])

        size = loss_size(weights)
        probe = _record(lm_initial(starts[0], empty), to_free, size)
        blank = jax.tree.map(jnp.zeros_like, _without(probe, _CHECK_ONLY))
        # Curve-long arrays are kept once each: the best start's model values and Jacobian
        # (its check done when it ended; after the starts it is the first fit), and the
        # running fit's in "lm" (at the end, those of the last pass). A finished pass keeps
        # only its numbers.
        state = {
            "lm": lm_initial(starts[0], empty), "phase": jnp.asarray(0),
            "w": weights, "size": size, "done": ~active,
            "best": {**blank, "scaled_loss": jnp.asarray(jnp.inf),
                     # The check of that blank record (zero arrays: one row says the same).
                     "checked": _checked({"status": blank["status"],
                                          "scaled_jacobian": jnp.zeros((1, n_free)),
                                          "scaled_residual": jnp.zeros(1),
                                          "scaled_loss": jnp.asarray(jnp.inf)}, options)},
            "start_losses": jnp.full(count_starts, jnp.nan),
            "start_evaluations": jnp.asarray(0),
            "first_status": jnp.asarray(0), "first_step": jnp.asarray(0.0),
            "polish_first": jnp.asarray(False), "final": _without(blank, _CURVES),
            "final_status": jnp.asarray(0), "final_step": jnp.asarray(0.0),
            "final_w": weights, "polish_passes": jnp.asarray(False),
            "passes": jnp.asarray(1), "sizes": jnp.zeros(2), "evaluations": jnp.asarray(0),
            # The relative change of the fitted values at the last pass (inf before one).
            "change": jnp.asarray(jnp.inf),
        }

        def body(state):
            lm = lm_step(evaluator(state["w"], state["size"]), state["lm"], options)
            # The checks, error sizes and weights run only where a run has ended (a real
            # branch on one lane; both sides, selected, where lanes are vmapped).
            return jax.lax.cond(lm[-1] != RUNNING, transition,
                                lambda state, lm: {**state, "lm": lm}, state, lm)

        def transition(state, lm):
            ended = jnp.asarray(True)
            record = _record(lm, to_free, state["size"])
            checked = _checked(record, options)
            record = _without(record, _CHECK_ONLY)
            phase = state["phase"]
            in_starts = phase < count_starts
            # A start ended: keep it if it is the best so far (the first of equal losses).
            value = record["scaled_loss"]
            better = jnp.isfinite(value) & (value < state["best"]["scaled_loss"])
            best = jax.tree.map(lambda a, b: jnp.where(better, a, b),
                                {**record, "checked": checked}, state["best"])
            start_losses = state["start_losses"].at[jnp.minimum(phase, count_starts - 1)].set(
                value * state["size"])
            start_evaluations = state["start_evaluations"] + record["evaluations"] + (
                warm_evaluations[jnp.minimum(phase, count_starts - 1)])
            last_start = phase == count_starts - 1
            # The first fit (after its last start), or the pass that just ended.
            finished = jax.tree.map(lambda a, b: jnp.where(in_starts, a, b), best,
                                    {**record, "checked": checked})
            status, step, polish = finished.pop("checked")
            if errors.kind == "absolute":
                w_next, sizes_next, go = state["w"], jnp.zeros(2), jnp.asarray(False)
            else:
                w_next, sizes_next, go = next_weights(finished, state["w"])
            previous = state["final"]["free_values"]
            change = jnp.max(jnp.where(previous != 0,
                                       jnp.abs(finished["free_values"]
                                               / jnp.where(previous != 0, previous, 1.0) - 1),
                                       jnp.abs(finished["free_values"])))
            passes = state["passes"] + jnp.where(in_starts, 0, 1)
            if errors.kind == "absolute":
                stop = jnp.asarray(True)
            else:
                stop = jnp.where(in_starts, ~go,
                                 (change <= errors.change) | (passes >= errors.max_passes)
                                 | ~go)
            # Which transition happens now (only where this lane's run ended).
            next_start = ended & in_starts & ~last_start
            first_done = ended & in_starts & last_start
            pass_done = ended & ~in_starts
            finishing = first_done | pass_done
            new_pass = finishing & ~stop
            fresh = lm_initial(starts[jnp.minimum(phase + 1, count_starts - 1)], empty)
            new_w = jnp.where(new_pass, w_next, state["w"])
            resumed = _resumed(finished, w_next, loss_size(w_next))
            new_lm = jax.tree.map(
                lambda a, b, c: jnp.where(next_start, a, jnp.where(new_pass, b, c)),
                fresh, resumed, lm)

            def pick(flag, a, b):
                return jax.tree.map(lambda x, y: jnp.where(flag, x, y), a, b)

            evaluations = state["evaluations"] + jnp.where(pass_done, record["evaluations"], 0)
            evaluations = jnp.where(first_done, start_evaluations, evaluations)
            return {
                "lm": new_lm, "phase": phase + jnp.where(ended, 1, 0),
                "w": new_w, "size": jnp.where(new_pass, loss_size(w_next), state["size"]),
                "done": state["done"] | (finishing & stop),
                "best": pick(ended & in_starts, best, state["best"]),
                "start_losses": jnp.where(ended & in_starts, start_losses,
                                          state["start_losses"]),
                "start_evaluations": jnp.where(ended & in_starts, start_evaluations,
                                               state["start_evaluations"]),
                "first_status": jnp.where(first_done, status, state["first_status"]),
                "first_step": jnp.where(first_done, step, state["first_step"]),
                "polish_first": jnp.where(first_done, polish, state["polish_first"]),
                "final": pick(finishing, _without(finished, _CURVES), state["final"]),
                "final_status": jnp.where(finishing, status, state["final_status"]),
                "final_step": jnp.where(finishing, step, state["final_step"]),
                "final_w": jnp.where(finishing, state["w"], state["final_w"]),
                "polish_passes": state["polish_passes"] | (pass_done & polish),
                "passes": jnp.where(pass_done, passes, state["passes"]),
                "change": jnp.where(pass_done, change, state["change"]),
                "sizes": jnp.where(new_pass, sizes_next,
                                   state["sizes"]),
                "evaluations": evaluations,
            }

        state = jax.lax.while_loop(lambda s: ~s["done"], body, state)
        # After the starts the best start is the first fit. The final fit's model values and
        # Jacobian are the last pass's, still in "lm" (the loop ends with that run), or,
        # without a pass, the first fit's.
        first = _without(state["best"], ("checked",))
        _, _, _, (predicted, physical), *_ = state["lm"]
        later = state["passes"] > 1
        final = {**state["final"],
                 "predicted": jnp.where(later, predicted, first["predicted"]),
                 "jacobian": jnp.where(later, physical, first["jacobian"])}

        def finish(record, status, step):
            out = {k: record[k] for k in ("free_values", "predicted", "jacobian",
                                          "scaled_loss", "scale", "grad_norm", "steps")}
            out["status"], out["newton_step"] = status, step
            out["all_values"] = all_values(record["free_values"], base)
            out["all_from_free"] = jax.jacfwd(lambda f: all_values(f, base))(
                record["free_values"])
            return out

        first_out = finish(first, state["first_status"], state["first_step"])
        first_out["start_losses"] = state["start_losses"]
        first_out["evaluations"] = state["start_evaluations"]
        result = {"first": first_out, "polish_first": state["polish_first"]}
        if errors.kind != "absolute":
            result.update(final=finish(final, state["final_status"], state["final_step"]),
                          weights=state["final_w"], passes=state["passes"],
                          change=state["change"],
                          sizes=state["sizes"], polish_passes=state["polish_passes"],
                          evaluations=state["evaluations"])
        return result

    def chunk(active, starts, warm, base, scale, time, observed, weights):
        return jax.lax.map(lambda row: one_curve(*row),
                           (active, starts, warm, base, scale, time, observed, weights),
                           batch_size=lanes if lanes > 1 else None)

    return chunk


#: Curves fitted side by side (vmapped) inside a chunk program, by device kind. On a CPU a
#: vmap gains nothing (a model Jacobian of a 64-sample curve: 0.35 ms alone, 0.33 ms a curve
#: at 8 lanes, 0.92 ms at 256, its arrays leaving the cache), and it costs: vmapped lanes
#: wait for the slowest, and a branch becomes both sides; so one curve after another (a
#: scan inside the program). An accelerator wants many lanes.
LANES = {"cpu": 1, "gpu": 256, "tpu": 256}
#: Curves of one chunk program at most (a study's chunk of curves is fitted in programs of
#: this many, unused lanes idle).
CHUNK = {"cpu": 64, "gpu": 4096, "tpu": 4096}
#: Samples held side by side in one vmapped group at most (lanes × padded length): a long
#: curve runs one lane at a time, so its memory stays that of one curve.
_GROUP_SAMPLES = 1 << 14


#: Device memory a chunk program may use, as a share of what the device reports.
_MEMORY_SHARE = 0.25
#: Bytes a vmapped lane holds per padded sample (the model's quadrature nodes with their
#: tangents, as complex numbers, and the solver's arrays): a generous estimate.
_BYTES_PER_SAMPLE = 1 << 16


def _device_memory() -> int | None:
    """Bytes of memory the default device reports, or ``None`` (a CPU reports none)."""
    try:
        stats = jax.devices()[0].memory_stats() or {}
    except Exception:  # noqa: BLE001  (a backend without memory statistics)
        return None
    limit = stats.get("bytes_limit")
    return int(limit) if limit else None


def chunk_shape(length: int, device: str | None = None,
                memory: int | None = None) -> tuple[int, int]:
    """``(lanes, chunk size)`` of the chunk programs for curves of padded `length` samples.

    On a CPU: one lane (see :data:`LANES`) and up to :data:`CHUNK` curves a program (fewer
    for long curves). On an accelerator: as many lanes and curves as a quarter of the
    device's memory holds at about 64 KiB a padded sample, at most :data:`LANES` and
    :data:`CHUNK`.

    **Arguments:** `length`: the padded number of samples; `device`: ``'cpu'``, ``'gpu'`` or
    ``'tpu'`` (default: JAX's default backend); `memory`: the device's memory in bytes
    (default: what it reports).

    **Returns:** the curves fitted side by side and the curves per program (a multiple of
    the lanes).
    """
    device = device or jax.default_backend()
    length = max(int(length), 1)
    if device == "cpu":
        lanes = max(1, min(LANES["cpu"], _GROUP_SAMPLES // length))
        size = max(lanes, min(CHUNK["cpu"], (_GROUP_SAMPLES * 4) // length))
        return lanes, size - size % lanes
    memory = memory if memory is not None else _device_memory()
    lanes = LANES.get(device, LANES["gpu"])
    if memory is not None:
        lanes = max(1, min(lanes, int(_MEMORY_SHARE * memory) // (length * _BYTES_PER_SAMPLE)))
    size = CHUNK.get(device, CHUNK["gpu"])
    return lanes, max(lanes, size - size % lanes)


def describe_device(length: int = 64) -> str:
    """The device and the chunk programs' shape for curves of padded `length`, in words."""
    device = jax.devices()[0]
    lanes, size = chunk_shape(length)
    memory = _device_memory()
    held = f", {memory / 2**30:.0f} GiB" if memory else ""
    return (f"{device.platform} ({device.device_kind}{held}): {size} curves a program, "
            f"{lanes} side by side")


_PROGRAMS = threading.Lock()


def chunk_program(model, layout: Layout, options: SolverPlan, errors: ErrorPlan,
                  lanes: int) -> Program:
    """The compiled chunk fit of a model, layout (its scale set to 1), plan and error model.

    **Arguments:** the model, its :class:`~fitting.parameters.Layout`, the
    :class:`~fitting.solve.SolverPlan`, the :class:`ErrorPlan` and the curves fitted side by
    side (`lanes`).

    **Returns:** a program of ``(active (curves,), starts (curves, starts, free), warm
    (curves, starts), base (curves, parameters), scale (curves, free), time, observed,
    weights (curves, samples))``, compiled once per shape; kept as an exported program
    across processes for the built-in models (:func:`fitting.solve.enable_compilation_cache`);
    one per arguments even when threads ask at once.
    """
    with _PROGRAMS:
        return _chunk_program(model, layout, options, errors, lanes)


@functools.lru_cache(maxsize=64)
def _chunk_program(model, layout: Layout, options: SolverPlan, errors: ErrorPlan,
                   lanes: int) -> Program:
    """The program of :func:`chunk_program`, kept per arguments."""
    layout = dataclasses.replace(layout, scale=(1.0,) * len(layout.free))
    return Program(_chunk_function(model, layout, options, errors, lanes),
                    f"chunk-{model.name}",
                    export_key(model, layout, options, errors, lanes, "chunk"), times=5)


chunk_program.cache_clear = _chunk_program.cache_clear  # the programs dropped, as of any cache


@dataclass(frozen=True)
class LaunchedChunk:
    """Chunk programs started on the device and not yet waited for
    (:func:`launch_chunk_arrays`): per program its outputs (device arrays) and the curves
    it holds, the compile or load seconds, and when the programs were started."""

    outputs: tuple[tuple[dict, int], ...]
    compile_seconds: float
    started: float

    def parts(self) -> Iterator[tuple[dict, int, float]]:
        """Each program's outputs as it finishes, in order: ``(outputs as NumPy arrays with
        a leading curve axis, the curves it held, seconds from the start, or the part
        before's collection, to this one's)``. The caller's work on one part overlaps the
        programs after it."""
        since = self.started
        for out, used in self.outputs:
            part = jax.tree.map(lambda a, used=used: a[:used], jax.device_get(out))
            now = _time.perf_counter()
            yield part, used, now - since
            since = now


def launch_chunk_arrays(model, layout: Layout, options: SolverPlan, errors: ErrorPlan, starts,
                        warm, base, scale, time, observed, weights) -> LaunchedChunk:
    """Start the chunk programs that fit curves of one padded length, a program per chunk of
    :func:`chunk_shape`'s size, and return without waiting for them: JAX runs them while
    the caller goes on (with the results of the programs before), and
    :meth:`LaunchedChunk.parts` gives their outputs as each finishes.

    **Arguments:** the model, layout, plan and error model; per curve (leading axis) the
    starts ``(starts, free)`` in unconstrained coordinates, their warm-up flags, all
    parameter values (fixed ones used), the scale of unbounded parameters, and the padded
    times, observed values and weights (zero: a point that does not count).

    **Returns:** a :class:`LaunchedChunk`.
    """
    arrays = [np.asarray(a, dtype=dtype) for a, dtype in (
        (starts, float), (warm, bool), (base, float), (scale, float), (time, float),
        (observed, float), (weights, float))]
    count, length = arrays[0].shape[0], arrays[4].shape[1]
    lanes, size = chunk_shape(length)
    program = chunk_program(model, layout, options, errors, lanes)
    outputs, compile_seconds = [], 0.0
    started = _time.perf_counter()
    for begin in range(0, count, size):
        part = [a[begin:begin + size] for a in arrays]
        used = part[0].shape[0]
        # Unused lanes repeat the last curve and are marked inactive: they stop at once.
        part = [np.concatenate([a, np.repeat(a[-1:], size - used, axis=0)]) for a in part]
        active = np.arange(size) < used
        executable, seconds = program.executable((active, *part))
        compile_seconds += seconds
        if seconds:
            started = _time.perf_counter()  # the run's time leaves the compilation out
        outputs.append((executable(active, *part), used))
    return LaunchedChunk(tuple(outputs), compile_seconds, started)
