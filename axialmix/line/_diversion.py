"""Diversion: when to divert out-of-specification material, and how much (MODELS.md §8).

Diversion starts when the predicted outlet content leaves the specification limits and ends
when it returns; the diverted amount is the flow integrated over that window. With several
excursions the window runs from the first exit to the last return (everything in between is
diverted, which is what a diverter valve does).

The uncertainty of a fitted RTD enters by sampling the fit's (normal or log-normal)
parameter distribution. Two conservative windows are offered:

* ``method="region"`` (default): the earliest start and the latest stop over parameter
  vectors filling the ``coverage`` confidence region of that distribution (the ellipsoid
  ``(p - p̂)ᵀ C⁻¹ (p - p̂) <= chi²_k(coverage)``, sampled on its surface and inside). Whenever
  the true parameters lie in the region the true window lies inside, so it is covered with
  at least the region's probability, whatever the shape of the map from parameters to window.
* ``method="quantile"``: from a low quantile of the sampled starts to a high quantile of the
  sampled stops (the miss rate split between the two ends). Tighter, and close to the stated
  coverage when the window ends move monotonically with the parameters, but not guaranteed:
  when both ends move together the two misses exclude each other and the coverage is just the
  nominal one, below it when the fit's covariance is itself too small.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_increasing_times, require_positive
from axialmix.line._disturbance import Disturbance, lag_horizon, response_at
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._throughput import FlowSchedule
from axialmix.line._unit import Unit

__all__ = [
    "ConservativeDiversion",
    "DiversionWindow",
    "conservative_diversion_window",
    "diversion_window",
    "sample_units",
]

_ROOT_STEPS = 24


class DiversionWindow(eqx.Module):
    """When diversion starts and stops, and the amount diverted, for one RTD.

    **Arguments:**

    - `start`: time the outlet content first leaves the limits (time unit; NaN when it never
      does; the first output time when it is already out there).
    - `stop`: time it last returns (time unit; NaN when it never leaves; +inf when it is
      still out at the last output time).
    - `diverted_amount`: ``∫_start^stop Q dt`` (amount unit; 0 or +inf as above).
    - `diverts`: whether the content leaves the limits at any output time.
    - `times`, `outlet`: the output times and the predicted outlet content there.
    - `lower`, `upper`: the specification limits (content unit).
    - `time_unit`, `content_unit`, `amount_unit`: units.
    """

    start: Array
    stop: Array
    diverted_amount: Array
    diverts: Array
    times: Array
    outlet: Array
    lower: Array
    upper: Array
    time_unit: str = eqx.field(static=True, default="s")
    content_unit: str = eqx.field(static=True, default="")
    amount_unit: str = eqx.field(static=True, default="")

    def to_dict(self) -> dict:
        """Plain JSON-ready dict of the window (NaN and infinities as None and "inf")."""
        return {
            "diverts": bool(self.diverts),
            "start": _number(self.start),
            "stop": _number(self.stop),
            "diverted_amount": _number(self.diverted_amount),
            "lower": _number(self.lower),
            "upper": _number(self.upper),
            "time_unit": self.time_unit,
            "content_unit": self.content_unit,
            "amount_unit": self.amount_unit,
        }


def _number(value) -> float | str | None:
    number = float(value)
    if np.isnan(number):
        return None
    if np.isinf(number):
        return "inf" if number > 0 else "-inf"
    return number


def _amount(flow, start: Array, stop: Array) -> Array:
    if isinstance(flow, FlowSchedule):
        return flow.throughput(stop) - flow.throughput(start)
    return jnp.asarray(flow, float) * (stop - start)


def _crossing(excess, low: Array, high: Array) -> Array:
    """The sign change of `excess` in [low, high] (signs differ at the ends), to round-off.

    Illinois' regula falsi: the bracket is kept, and an end that stays twice has its value
    halved, so convergence is superlinear (about 1e-15 of the bracket after a dozen steps
    for a smooth excess; a fixed number of steps keeps it traceable and vmappable).
    """
    f_low, f_high = excess(low), excess(high)

    def body(_, state):
        a, b, fa, fb, side = state
        guess = jnp.clip(b - fb * (b - a) / jnp.where(fb != fa, fb - fa, 1.0), a, b)
        guess = jnp.where(jnp.isfinite(guess) & (fb != fa), guess, 0.5 * (a + b))
        fg = excess(guess)
        same_as_a = (fg > 0) == (fa > 0)
        # Replace the end on the guess's side; halve the other end's value if it stays twice.
        new_a = jnp.where(same_as_a, guess, a)
        new_b = jnp.where(same_as_a, b, guess)
        new_fa = jnp.where(same_as_a, fg, jnp.where(side == -1, fa / 2, fa))
        new_fb = jnp.where(same_as_a, jnp.where(side == 1, fb / 2, fb), fg)
        return new_a, new_b, new_fa, new_fb, jnp.where(same_as_a, 1, -1)

    a, b, fa, fb, _ = jax.lax.fori_loop(
        0, _ROOT_STEPS, body, (low, high, f_low, f_high, jnp.asarray(0))
    )
    return jnp.where(jnp.abs(fa) < jnp.abs(fb), a, b)


def _window(evaluator, disturbance, times, target, lower, upper, flow):
    """Start, stop, amount, diverts and the outlet content on the times (traceable)."""
    outlet = target + response_at(evaluator, disturbance, times)

    def excess_at(t):
        content = target + response_at(evaluator, disturbance, t)
        return jnp.maximum(content - upper, lower - content)

    out = jnp.maximum(outlet - upper, lower - outlet) > 0
    diverts = jnp.any(out)
    last_index = times.shape[0] - 1
    first = jnp.argmax(out)
    last = last_index - jnp.argmax(out[::-1])
    start = jnp.where(
        first == 0,
        times[0],
        _crossing(excess_at, times[jnp.maximum(first - 1, 0)], times[first]),
    )
    stop = jnp.where(
        last == last_index,
        jnp.inf,
        _crossing(excess_at, times[last], times[jnp.minimum(last + 1, last_index)]),
    )
    amount = jnp.where(stop == jnp.inf, jnp.inf, _amount(flow, start, jnp.where(
        stop == jnp.inf, start, stop)))
    start = jnp.where(diverts, start, jnp.nan)
    stop = jnp.where(diverts, stop, jnp.nan)
    amount = jnp.where(diverts, amount, 0.0)
    return start, stop, amount, diverts, outlet


@eqx.filter_jit
def _window_jit(evaluator, disturbance, times, target, lower, upper, flow):
    return _window(evaluator, disturbance, times, target, lower, upper, flow)


def _check(rtd, disturbance, times, target, lower, upper, flow):
    require_increasing_times("times", times)
    for name, value in (("target", target), ("lower", lower), ("upper", upper)):
        require_finite(name, value)
    if np.ndim(times) != 1 or np.shape(times)[0] < 2:
        raise ValueError("times must be one-dimensional with at least two samples.")
    if not isinstance(disturbance, Disturbance):
        raise ValueError(f"disturbance must be a Disturbance, got {type(disturbance).__name__}.")
    if disturbance.time_unit != rtd.time_unit:
        raise ValueError(
            f"the disturbance is in {disturbance.time_unit!r} but the RTD in {rtd.time_unit!r}."
        )
    if not isinstance(flow, FlowSchedule):
        require_positive("flow", flow)
    if (
        np.ndim(lower) == 0
        and np.ndim(upper) == 0
        and not isinstance(lower, jax.core.Tracer)
        and not isinstance(upper, jax.core.Tracer)
        and not float(lower) < float(upper)
    ):
        raise ValueError(f"lower ({float(lower):g}) must be below upper ({float(upper):g}).")


def diversion_window(
    rtd: Unit | Line | TabulatedRTD,
    disturbance: Disturbance,
    times: ArrayLike,
    *,
    target: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    flow: ArrayLike | FlowSchedule = 1.0,
    content_unit: str = "",
    amount_unit: str = "",
) -> DiversionWindow:
    """When to start and stop diverting after a disturbance, and how much material that is.

    The outlet content ``target + E ⊗ δu`` (:func:`outlet_response`) is scanned on `times`;
    the first exit from ``[lower, upper]`` and the last return are then located exactly by
    root finding on the model between the neighbouring times (to round-off).

    **Arguments:**

    - `rtd`: a :class:`Unit`, :class:`Line` or :class:`TabulatedRTD`.
    - `disturbance`: the inlet deviation (in content units, e.g. a feeder trace).
    - `times`: scan times (time unit), strictly increasing; fine enough that no excursion
      falls between two of them.
    - `target`: the content at steady state (content unit).
    - `lower`, `upper`: specification limits (content unit), e.g. ``0.95 × target`` and
      ``1.05 × target`` for ±5 %.
    - `flow`: the outlet flow, a number (amount per time unit) or a
      :class:`~axialmix.line.FlowSchedule`.
    - `content_unit`, `amount_unit`: units carried to the result.

    **Returns:**

    A :class:`DiversionWindow`.
    """
    _check(rtd, disturbance, times, target, lower, upper, flow)
    times = jnp.asarray(times, float)
    evaluator = as_evaluator(rtd, lag_horizon(disturbance, times))
    target, lower, upper = (jnp.asarray(x, float) for x in (target, lower, upper))
    start, stop, amount, diverts, outlet = _window_jit(
        evaluator, disturbance, times, target, lower, upper, flow
    )
    return DiversionWindow(
        start, stop, amount, diverts, times, outlet, lower, upper,
        rtd.time_unit, content_unit, amount_unit,
    )


# ------------------------------------------------------------------ uncertainty
def _distribution(values, covariance, scale):
    values = jnp.atleast_1d(jnp.asarray(values, float))
    covariance = jnp.atleast_2d(jnp.asarray(covariance, float))
    require_finite("values", values)
    require_finite("covariance", covariance)
    p = values.shape[0]
    if values.ndim != 1 or covariance.shape != (p, p):
        raise ValueError(f"covariance must have shape ({p}, {p}), got {covariance.shape}.")
    if scale not in ("linear", "log"):
        raise ValueError(f"scale must be 'linear' or 'log', got {scale!r}.")
    if scale == "log":
        require_positive("values", values)
    eigenvalues, vectors = np.linalg.eigh(np.asarray(covariance))
    if eigenvalues.min() < -1e-10 * max(eigenvalues.max(), 1e-300):
        raise ValueError("covariance must be positive semi-definite.")
    root = jnp.asarray(vectors * np.sqrt(np.clip(eigenvalues, 0.0, None)))
    centre = jnp.log(values) if scale == "log" else values
    return centre, root


def _draw(values, covariance, samples, seed, scale, region):
    """Parameter vectors: normal draws, or (region) points filling the confidence ellipsoid."""
    if not isinstance(samples, int) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}.")
    centre, root = _distribution(values, covariance, scale)
    p = centre.shape[0]
    key_direction, key_radius = jax.random.split(jax.random.PRNGKey(seed))
    normal = jax.random.normal(key_direction, (samples, p))
    if region is not None:
        # Half of the points on the surface of the region (radius sqrt(chi²_p(region)) in
        # whitened coordinates, where the extremes of a monotone map lie), half uniformly
        # inside it, and the centre.
        from scipy.stats import chi2

        radius = float(np.sqrt(chi2.ppf(region, p)))
        directions = normal / jnp.linalg.norm(normal, axis=1, keepdims=True)
        uniform = jax.random.uniform(key_radius, (samples,))
        inside = jnp.arange(samples) % 2 == 1
        radii = radius * jnp.where(inside, uniform ** (1.0 / p), 1.0)
        normal = (directions * radii[:, None]).at[0].set(0.0)
    drawn = centre + normal @ root.T
    return jnp.exp(drawn) if scale == "log" else drawn


def sample_units(
    unit_factory: Callable[[Array], Unit | Line],
    values: ArrayLike,
    covariance: ArrayLike,
    samples: int,
    *,
    seed: int = 0,
    scale: str = "linear",
) -> tuple[Unit | Line, Array]:
    """Units (or lines) for samples of a fitted parameter vector: the hook for fit results.

    Parameter vectors are drawn from ``N(values, covariance)`` (``scale="linear"``) or,
    for positive parameters, ``log p ~ N(log values, covariance)`` with the covariance of
    the logarithms (``scale="log"``, the relative-error form of a fit's covariance), and
    mapped through `unit_factory` under ``jax.vmap``.

    **Arguments:**

    - `unit_factory`: function of one parameter vector ``(p,)`` returning a :class:`Unit`
      or :class:`Line` (it must be traceable: build units from the array entries).
    - `values`: the fitted values ``(p,)``.
    - `covariance`: their covariance ``(p, p)`` (of the logarithms for ``scale="log"``),
      symmetric positive semi-definite.
    - `samples`: number of draws.
    - `seed`: random seed.
    - `scale`: ``"linear"`` or ``"log"``.

    **Returns:**

    ``(units, parameters)``: a batched Unit or Line whose leaves carry a leading axis of
    length `samples` (use it with ``jax.vmap``), and the drawn parameters ``(samples, p)``.
    """
    parameters = _draw(values, covariance, samples, seed, scale, None)
    return jax.vmap(unit_factory)(parameters), parameters


class ConservativeDiversion(eqx.Module):
    """A diversion window with its uncertainty, from samples of a fit's parameters.

    **Arguments:**

    - `nominal`: the :class:`DiversionWindow` at the fitted values.
    - `start`, `stop`, `diverted_amount`: the conservative window (time unit, amount unit),
      NaN start and stop (amount 0) when no sample calls for diversion.
    - `coverage`: the stated probability.
    - `method`: ``"region"`` or ``"quantile"`` (see :mod:`axialmix.line`'s diversion notes
      and :func:`conservative_diversion_window`).
    - `sample_parameters`: the parameter vectors used ``(samples, p)``.
    - `sample_starts`, `sample_stops`: their windows (``+inf``/``-inf`` for vectors that do
      not divert, NaN for vectors whose prediction is not finite).
    - `diverting_fraction`: share of the valid samples that divert.
    - `valid_samples`: samples with a finite prediction (the others are left out).
    - `time_unit`, `amount_unit`: units.
    """

    nominal: DiversionWindow
    start: Array
    stop: Array
    diverted_amount: Array
    coverage: float = eqx.field(static=True)
    method: str = eqx.field(static=True)
    sample_parameters: Array
    sample_starts: Array
    sample_stops: Array
    diverting_fraction: Array
    valid_samples: int = eqx.field(static=True)
    time_unit: str = eqx.field(static=True, default="s")
    amount_unit: str = eqx.field(static=True, default="")

    def to_dict(self) -> dict:
        """Plain JSON-ready dict: the nominal and the conservative window and how it was made."""
        return {
            "nominal": self.nominal.to_dict(),
            "conservative": {
                "start": _number(self.start),
                "stop": _number(self.stop),
                "diverted_amount": _number(self.diverted_amount),
            },
            "coverage": self.coverage,
            "method": self.method,
            "samples": int(self.sample_parameters.shape[0]),
            "valid_samples": self.valid_samples,
            "diverting_fraction": float(self.diverting_fraction),
            "time_unit": self.time_unit,
            "amount_unit": self.amount_unit,
        }


@eqx.filter_jit
def _sample_windows(unit_factory, parameters, disturbance, times, target, lower, upper, flow,
                    horizon):
    def one(vector):
        evaluator = as_evaluator(unit_factory(vector), horizon)
        start, stop, _, diverts, outlet = _window(
            evaluator, disturbance, times, target, lower, upper, flow
        )
        return start, stop, diverts, jnp.all(jnp.isfinite(outlet))

    return jax.vmap(one)(parameters)


def conservative_diversion_window(
    unit_factory: Callable[[Array], Unit | Line],
    values: ArrayLike,
    covariance: ArrayLike,
    disturbance: Disturbance,
    times: ArrayLike,
    *,
    target: ArrayLike,
    lower: ArrayLike,
    upper: ArrayLike,
    flow: ArrayLike | FlowSchedule = 1.0,
    coverage: float = 0.95,
    method: str = "region",
    samples: int = 1000,
    seed: int = 0,
    scale: str = "linear",
    content_unit: str = "",
    amount_unit: str = "",
) -> ConservativeDiversion:
    """A diversion window that covers the true one with a stated probability, by sampling.

    ``method="region"`` (default) fills the `coverage` confidence region of the parameter
    distribution (normal, or log-normal with ``scale="log"``) with `samples` vectors, half on
    its surface, and returns the earliest start and the latest stop among them: it contains
    the true window whenever the true parameters lie in the region, i.e. with probability at
    least `coverage` under the fit's distribution. ``method="quantile"`` draws from the
    distribution itself and returns the ``(1 - coverage)/2`` quantile of the starts and the
    ``(1 + coverage)/2`` quantile of the stops: tighter, about the stated coverage when the
    ends move monotonically with the parameters, not guaranteed. Vectors that do not divert
    count as windows from +inf to -inf. Sampling rather than first-order propagation through
    JAX derivatives is used because a window need not exist for every parameter vector and
    its ends are not smooth where an excursion appears or merges with another.

    **Arguments:**

    - `unit_factory`: function of a parameter vector returning a :class:`Unit` or :class:`Line`
      (traceable; it is vmapped).
    - `values`, `covariance`: the fit's parameter vector and covariance (see `scale`).
    - `disturbance`, `times`, `target`, `lower`, `upper`, `flow`: as in
      :func:`diversion_window`.
    - `coverage`: the probability to cover (between 0 and 1).
    - `method`: ``"region"`` or ``"quantile"``.
    - `samples`: number of parameter vectors.
    - `seed`: random seed.
    - `scale`: ``"linear"`` or ``"log"`` (see :func:`sample_units`).
    - `content_unit`, `amount_unit`: units of the content and of the diverted amount.

    **Returns:**

    A :class:`ConservativeDiversion`.
    """
    if not 0.0 < coverage < 1.0:
        raise ValueError(f"coverage must lie between 0 and 1, got {coverage!r}.")
    if method not in ("region", "quantile"):
        raise ValueError(f"method must be 'region' or 'quantile', got {method!r}.")
    nominal = diversion_window(
        unit_factory(jnp.atleast_1d(jnp.asarray(values, float))), disturbance, times,
        target=target, lower=lower, upper=upper, flow=flow, content_unit=content_unit,
        amount_unit=amount_unit,
    )
    parameters = _draw(values, covariance, samples, seed, scale,
                       coverage if method == "region" else None)
    times = jnp.asarray(times, float)
    target, lower, upper = (jnp.asarray(x, float) for x in (target, lower, upper))
    starts, stops, diverts, finite = _sample_windows(
        unit_factory, parameters, disturbance, times, target, lower, upper, flow,
        float(lag_horizon(disturbance, times)),  # static: a measured curve's grid needs it
    )
    starts = jnp.where(finite, jnp.where(diverts, starts, jnp.inf), jnp.nan)
    stops = jnp.where(finite, jnp.where(diverts, stops, -jnp.inf), jnp.nan)
    valid = np.asarray(finite)
    if not valid.any():
        raise ValueError("no sampled parameter vector gives a finite prediction.")
    kept_starts = np.asarray(starts)[valid]
    kept_stops = np.asarray(stops)[valid]
    if method == "region":
        start, stop = kept_starts.min(), kept_stops.max()
    else:
        miss = (1.0 - coverage) / 2.0
        start = np.quantile(kept_starts, miss, method="lower")
        stop = np.quantile(kept_stops, 1.0 - miss, method="higher")
    if not np.isfinite(start) or not stop >= start:
        start = stop = np.nan
        amount = jnp.asarray(0.0)
    elif np.isinf(stop):
        amount = jnp.asarray(np.inf)
    else:
        amount = _amount(flow, jnp.asarray(start), jnp.asarray(stop))
    return ConservativeDiversion(
        nominal,
        jnp.asarray(start),
        jnp.asarray(stop),
        amount,
        float(coverage),
        method,
        parameters,
        starts,
        stops,
        jnp.asarray(np.asarray(diverts)[valid].mean()),
        int(valid.sum()),
        nominal.time_unit,
        amount_unit,
    )
