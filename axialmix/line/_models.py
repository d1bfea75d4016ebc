"""The residence-time models a unit operation can be built from, as plain function bundles.

A :class:`UnitModel` names the functions that evaluate one kind of model from its parameters
(a dict of arrays) and its static structure (a compartment network, the sample times of a
measured curve, or None). Every function works elementwise on time arrays of any shape and is
jit-, grad- and vmap-able in the parameters. New models (series models, a generic
transfer-function inversion) plug in by building a :class:`UnitModel` from their own
functions; only ``exit_age`` and ``cumulative`` are required.

Built-in models: the closed–closed and open–open ADM and tanks in series
(:mod:`axialmix.analytic`, exact), the closed–closed ADM and tanks in series with a dead
zone and the closed–closed ADM followed by a stirred tank (MODELS.md §6; their transfer
functions from :mod:`axialmix.analytic.transfer`, inverted exactly by
:mod:`axialmix.analytic.responses`), a continuous compartment network
(:mod:`axialmix.network`, exact matrix exponentials) and a measured curve used empirically
(the piecewise-linear interpolant of its samples, zero outside them, integrated exactly).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
from jax import Array

from axialmix.analytic import (
    exit_age_closed,
    exit_age_open,
    exit_age_tanks,
    mean_closed,
    mean_open,
    mean_tanks,
    step_response_closed,
    step_response_open,
    step_response_tanks,
    transfer_function_closed,
    variance_closed,
    variance_open,
    variance_tanks,
)
from axialmix.analytic import responses as _responses
from axialmix.analytic.transfer import (
    ClosedClosedADM,
    ExchangeZone,
    Series,
    StirredTank,
    TanksInSeries,
    TransferFunction,
)
from axialmix.network import (
    cumulative_exit_age,
    exit_age,
    generator_matrix,
    outlet_response,
    residence_time_moments,
)
from axialmix.network._expm import expm

__all__ = [
    "CLOSED_CLOSED",
    "CLOSED_CLOSED_EXCHANGE",
    "CLOSED_CLOSED_TANK",
    "EMPIRICAL",
    "NETWORK",
    "OPEN_OPEN",
    "TANKS",
    "TANKS_EXCHANGE",
    "UnitModel",
    "transfer_unit_model",
]

Parameters = dict[str, Array]
CurveFunction = Callable[[Array, Parameters, Any], Array]


@dataclass(frozen=True)
class UnitModel:
    """The functions that evaluate one kind of residence-time model (hashable, static).

    Each curve function is called as ``f(t, parameters, structure)`` with ``t`` an array of
    any shape (time unit of the unit), ``parameters`` a dict of arrays and ``structure`` the
    unit's static structure; it returns an array of the shape of ``t``.

    **Arguments:**

    - `name`: the model's name (``"closed_closed"``, ...), shown in reports and plots.
    - `parameter_names`: the keys the parameter dict must have.
    - `positive`: the parameters that must be positive (checked on concrete values).
    - `exit_age`: ``E(t)`` in 1/time, zero for ``t < 0``.
    - `cumulative`: ``F(t) = ∫_0^t E``, dimensionless.
    - `ramp`: ``R(t) = ∫_0^t F``, the response to a unit ramp (time unit), or None: it is
      then integrated from ``cumulative`` on a grid (Romberg, see :mod:`axialmix.line`).
    - `transfer_function`: ``G(s) = ∫ E e^{-st} dt`` with ``s`` complex in 1/time, or None.
    - `moments`: ``(mean, variance)`` from the parameters (time, time²), or None: they are
      then taken from the derivatives of ``transfer_function`` at ``s = 0``.
    - `numerical`: True when every time costs a numerical inversion (a contour integral,
      about 0.1 ms a time): many-sample work such as a diversion's covariance samples then
      tabulates the curves once per sample (:meth:`TabulatedRTD.from_unit`).
    - `grid`: ``grid(kind, first, step, count, parameters, structure)``, the curve ``kind``
      (``"exit_age"``, ``"cumulative"`` or ``"ramp"``) at the uniformly spaced times
      ``first + j step``, ``j < count`` (time unit; `first` and `step` traceable, `count`
      static), or None: the curve is then evaluated time by time. A model whose every time
      costs a matrix exponential (a network) propagates along the grid instead, one
      matrix product a time (scans of a diversion, funnel plots).
    """

    name: str
    parameter_names: tuple[str, ...]
    exit_age: CurveFunction
    cumulative: CurveFunction
    ramp: CurveFunction | None = None
    transfer_function: CurveFunction | None = None
    moments: Callable[[Parameters, Any], tuple[Array, Array]] | None = None
    positive: tuple[str, ...] = ()
    numerical: bool = False
    grid: Callable[..., Array] | None = None


# ------------------------------------------------------------------ closed–closed ADM
def _closed_exit_age(t, p, _):
    return exit_age_closed(t, p["tau"], p["peclet"])


def _closed_cumulative(t, p, _):
    return step_response_closed(t, p["tau"], p["peclet"])


def _closed_transfer(s, p, _):
    return transfer_function_closed(s * p["tau"], p["peclet"])


def _closed_moments(p, _):
    return mean_closed(p["tau"], p["peclet"]), variance_closed(p["tau"], p["peclet"])


CLOSED_CLOSED = UnitModel(
    name="closed_closed",
    parameter_names=("tau", "peclet"),
    positive=("tau", "peclet"),
    exit_age=_closed_exit_age,
    cumulative=_closed_cumulative,
    transfer_function=_closed_transfer,
    moments=_closed_moments,
)
"""Closed–closed (Danckwerts) ADM, parameters ``tau`` (time) and ``peclet`` (MODELS.md §2)."""


# ------------------------------------------------------------------ open–open ADM
def _open_exit_age(t, p, _):
    return exit_age_open(t, p["tau"], p["peclet"])


def _open_cumulative(t, p, _):
    return step_response_open(t, p["tau"], p["peclet"])


def _open_transfer(s, p, _):
    # The open–open E is theta times the inverse-Gaussian density of mean 1 and shape Pe/2,
    # whose transform is e^{Pe(1-q)/2}; multiplying by theta differentiates it in -s, giving
    # G = e^{Pe(1-q)/2} / q with q = sqrt(1 + 4 s tau / Pe) (Levenspiel's open vessel).
    peclet = jnp.asarray(p["peclet"], float)
    q = jnp.sqrt(1.0 + 4.0 * jnp.asarray(s, complex) * p["tau"] / peclet)
    return jnp.exp(0.5 * peclet * (1.0 - q)) / q


def _open_moments(p, _):
    return mean_open(p["tau"], p["peclet"]), variance_open(p["tau"], p["peclet"])


OPEN_OPEN = UnitModel(
    name="open_open",
    parameter_names=("tau", "peclet"),
    positive=("tau", "peclet"),
    exit_age=_open_exit_age,
    cumulative=_open_cumulative,
    transfer_function=_open_transfer,
    moments=_open_moments,
)
"""Open–open ADM, parameters ``tau = L/v`` (time) and ``peclet``; mean ``(1 + 2/Pe) tau``."""


# ------------------------------------------------------------------ tanks in series
def _tanks_exit_age(t, p, _):
    return exit_age_tanks(t, p["tau"], p["n_tanks"])


def _tanks_cumulative(t, p, _):
    return step_response_tanks(t, p["tau"], p["n_tanks"])


def _tanks_ramp(t, p, _):
    # ∫_0^t F = t F(t) - ∫_0^t s E(s) ds, and s E_n(s) = tau E_{n+1}(s) for the gamma density
    # of shape n and rate n/tau, so the second term is tau P(n+1, x) with x = n t/tau; and
    # P(n+1, x) = P(n, x) - x^n e^{-x} / Γ(n+1), which leaves one incomplete gamma function
    # (the costly part to compile).
    tau, n = p["tau"], p["n_tanks"]
    t = jnp.asarray(t, float)
    positive = t > 0
    scaled = n * jnp.where(positive, t, 1.0) / tau
    term = jnp.exp(n * jnp.log(scaled) - scaled - jax.scipy.special.gammaln(n + 1.0))
    value = (t - tau) * jax.scipy.special.gammainc(n, scaled) + tau * term
    return jnp.where(positive, value, 0.0)


def _tanks_transfer(s, p, _):
    n = jnp.asarray(p["n_tanks"], float)
    return jnp.exp(-n * jnp.log1p(jnp.asarray(s, complex) * p["tau"] / n))


def _tanks_moments(p, _):
    return mean_tanks(p["tau"], p["n_tanks"]), variance_tanks(p["tau"], p["n_tanks"])


TANKS = UnitModel(
    name="tanks",
    parameter_names=("tau", "n_tanks"),
    positive=("tau", "n_tanks"),
    exit_age=_tanks_exit_age,
    cumulative=_tanks_cumulative,
    ramp=_tanks_ramp,
    transfer_function=_tanks_transfer,
    moments=_tanks_moments,
)
"""Tanks in series (gamma RTD), parameters ``tau`` (total mean, time) and ``n_tanks`` (real)."""


# ------------------------------------------------------------------ transfer-function units
def _flat_call(function: Callable[[Array], Array], t: Array) -> Array:
    """Evaluate an elementwise function of a 1-D time array at times of any shape."""
    t = jnp.asarray(t, float)
    return function(t.reshape(-1)).reshape(t.shape)


def transfer_unit_model(
    name: str,
    parameter_names: tuple[str, ...],
    build: Callable[[Parameters], TransferFunction],
    positive: tuple[str, ...] = (),
) -> UnitModel:
    """A :class:`UnitModel` from a function that builds an :mod:`axialmix.analytic` transfer unit.

    E, F and the ramp response are the exact inversions of :mod:`axialmix.analytic.responses`
    (contour integrals, any order of times), G and the moments come from the transfer unit
    itself. Make each model once (a module-level constant): units of one model share their
    compiled programs only when `build` is the same function.

    **Arguments:**

    - `name`: the model's name.
    - `parameter_names`: the keys of the parameter dict.
    - `build`: ``parameters -> TransferFunction`` (traceable).
    - `positive`: parameters that must be positive.

    **Returns:**

    A :class:`UnitModel`.
    """

    def exit_age_(t, p, _):
        return _flat_call(lambda x: _responses.exit_age(build(p), x), t)

    def cumulative_(t, p, _):
        return _flat_call(lambda x: _responses.step_response(build(p), x), t)

    def ramp_(t, p, _):
        return _flat_call(lambda x: _responses.ramp_response(build(p), x), t)

    def transfer_(s, p, _):
        return build(p).transfer(jnp.asarray(s, complex))

    def moments_(p, _):
        unit = build(p)
        return unit.mean(), unit.variance()

    return UnitModel(
        name=name,
        parameter_names=parameter_names,
        positive=positive,
        exit_age=exit_age_,
        cumulative=cumulative_,
        ramp=ramp_,
        transfer_function=transfer_,
        moments=moments_,
        numerical=True,
    )


def _closed_exchange(p):
    return ExchangeZone(ClosedClosedADM(p["tau"], p["peclet"]), p["beta"], p["k_d"])


def _tanks_exchange(p):
    return ExchangeZone(TanksInSeries(p["tau"], p["n_tanks"]), p["beta"], p["k_d"])


def _closed_tank(p):
    return Series(ClosedClosedADM(p["tau"], p["peclet"]), StirredTank(p["tau_tank"]))


CLOSED_CLOSED_EXCHANGE = transfer_unit_model(
    "closed_closed_exchange", ("tau", "peclet", "beta", "k_d"), _closed_exchange,
    positive=("tau", "peclet", "k_d"),
)
"""Closed–closed ADM with a dead zone (MODELS.md §6): ``tau`` (mobile space time), ``peclet``,
``beta`` (dead-zone to mobile hold-up, >= 0), ``k_d`` (exchange rate, 1/time); mean
``(1 + beta) tau``."""

TANKS_EXCHANGE = transfer_unit_model(
    "tanks_exchange", ("tau", "n_tanks", "beta", "k_d"), _tanks_exchange,
    positive=("tau", "n_tanks", "k_d"),
)
"""Tanks in series with a dead zone: ``tau`` (mobile mean), ``n_tanks``, ``beta``, ``k_d``."""

CLOSED_CLOSED_TANK = transfer_unit_model(
    "closed_closed_tank", ("tau", "peclet", "tau_tank"), _closed_tank,
    positive=("tau", "peclet", "tau_tank"),
)
"""Closed–closed ADM then a stirred tank: ``tau``, ``peclet``, ``tau_tank``; mean
``tau + tau_tank``."""


# ------------------------------------------------------------------ compartment network
def _sorted_call(function: Callable[[Array], Array], t: Array) -> Array:
    """Evaluate a function of increasing times at times of any shape and order."""
    t = jnp.asarray(t, float)
    flat = t.reshape(-1)
    order = jnp.argsort(flat)
    values = function(flat[order])
    return jnp.zeros_like(flat).at[order].set(values).reshape(t.shape)


def _network_system(kind: str, p: Parameters, network) -> tuple[Array, Array, Array]:
    """``(A, b, c)`` with the curve ``kind`` of a network at t >= 0 equal to
    ``c · expm(A t) b``: E from the generator and the feed split; F and the ramp response from
    the generator augmented by one and two integrators of the feed (a unit step, a unit
    ramp)."""
    generator = generator_matrix(network, p["rates"], p["outflow_rates"])
    n = network.n_compartments
    split = jnp.asarray(network.feed_split, float)
    outflow = jnp.zeros(n).at[network.outlet_indices].add(
        jnp.asarray(p["outflow_rates"], float))
    if kind == "exit_age":
        return generator, split, outflow
    size = n + (1 if kind == "cumulative" else 2)
    matrix = jnp.zeros((size, size)).at[:n, :n].set(generator).at[:n, n].set(split)
    if kind == "ramp":
        matrix = matrix.at[n, n + 1].set(1.0)
    return matrix, jnp.zeros(size).at[size - 1].set(1.0), jnp.zeros(size).at[:n].set(outflow)


def _network_mask(kind: str, t: Array, values: Array) -> Array:
    """E is 0 before t = 0, F and the ramp response up to t = 0."""
    return jnp.where(t >= 0 if kind == "exit_age" else t > 0, values, 0.0)


#: Times of a network's curve evaluated each by its own matrix exponential (root finding,
#: the ends of a scan); longer arrays are propagated from one sorted time to the next.
_DIRECT_TIMES = 16


def _network_direct(kind: str, t: Array, p: Parameters, network) -> Array:
    """The curve at a few times of any shape and order, one exponential a time."""
    matrix, start, output = _network_system(kind, p, network)
    t = jnp.asarray(t, float)
    flat = t.reshape(-1)
    values = jax.vmap(lambda lag: output @ (expm(matrix * lag) @ start))(
        jnp.maximum(flat, 0.0))
    return _network_mask(kind, flat, values).reshape(t.shape)


def _network_exit_age(t, p, network):
    if jnp.size(t) <= _DIRECT_TIMES:
        return _network_direct("exit_age", t, p, network)
    return _sorted_call(lambda x: exit_age(network, x, p["rates"], p["outflow_rates"]), t)


def _network_cumulative(t, p, network):
    if jnp.size(t) <= _DIRECT_TIMES:
        return _network_direct("cumulative", t, p, network)
    return _sorted_call(
        lambda x: cumulative_exit_age(network, x, p["rates"], p["outflow_rates"]), t
    )


def _network_ramp(t, p, network):
    if jnp.size(t) <= _DIRECT_TIMES:
        return _network_direct("ramp", t, p, network)

    # The response to the inlet signal u(t) = t is ∫_0^t F; outlet_response integrates a
    # piecewise-linear inlet exactly (augmented matrix exponential), starting empty at 0.
    def ramp(x):
        x = jnp.maximum(x, 0.0)
        times = jnp.concatenate([jnp.zeros(1), x])
        return outlet_response(network, times, times, p["rates"], p["outflow_rates"])[1:]

    return _sorted_call(ramp, t)


def _grid_values(matrix: Array, start: Array, output: Array, first: Array, step: Array,
                count: int) -> Array:
    """``c · expm(A max(t_j, 0)) b`` at the uniformly spaced times ``t_j = first + j step``,
    ``j < count``, by propagation: two exponentials and about ``m`` products a time.

    The times from the first non-negative one on are propagated by powers of
    ``M = expm(A step)``, in blocks of ``B`` about ``sqrt(count)`` times: the rows
    ``c M^0 … c M^{B-1}`` and ``M^B`` once, then the state from one block to the next by
    ``M^B``, each value the product of a row and a block's state (a sequence of about
    ``2 sqrt(count)`` products, not ``count``). Times before it hold ``c · b`` (t clipped
    to 0).

    **Arguments:**

    - `matrix`, `start`, `output`: ``A (m, m)``, ``b (m,)``, ``c (m,)``.
    - `first`, `step`: the first time and the spacing (time unit; traceable, step > 0).
    - `count`: the number of times (static).

    **Returns:** the values ``(count,)``.
    """
    first, step = jnp.asarray(first, float), jnp.asarray(step, float)
    block = max(1, math.isqrt(max(count - 1, 0)) + 1)
    blocks = -(-count // block)
    # The first index whose time is not negative (a time of -1e-17 is the origin).
    begin = jnp.clip(jnp.ceil(-first / step), 0, count).astype(int)
    state = expm(matrix * jnp.maximum(first + begin * step, 0.0)) @ start
    transition = expm(matrix * step)

    def power(carry, _):
        row, current = carry  # c M^r and M^r
        return (row @ transition, transition @ current), row

    (_, jump), rows = jax.lax.scan(power, (output, jnp.eye(matrix.shape[0])), None,
                                   length=block)

    def advance(current, _):
        return jump @ current, current

    _, states = jax.lax.scan(advance, state, None, length=blocks)
    propagated = (states @ rows.T).reshape(-1)  # [q, r]: c M^r M^(qB) x
    offset = jnp.arange(count) - begin
    return jnp.where(offset >= 0, propagated[jnp.clip(offset, 0, blocks * block - 1)],
                     output @ start)


def _network_grid(kind, first, step, count, p, network):
    matrix, start, output = _network_system(kind, p, network)
    values = _grid_values(matrix, start, output, first, step, count)
    return _network_mask(kind, first + step * jnp.arange(count), values)


def _network_transfer(s, p, network):
    generator = generator_matrix(network, p["rates"], p["outflow_rates"]).astype(complex)
    split = jnp.asarray(network.feed_split, complex)
    outflow = (
        jnp.zeros(network.n_compartments)
        .at[network.outlet_indices]
        .add(jnp.asarray(p["outflow_rates"], float))
    )
    identity = jnp.eye(network.n_compartments, dtype=complex)
    s = jnp.asarray(s, complex)

    def one(value):
        return outflow @ jnp.linalg.solve(value * identity - generator, split)

    return jax.vmap(one)(s.reshape(-1)).reshape(s.shape)


def _network_moments(p, network):
    moments = residence_time_moments(network, p["rates"], p["outflow_rates"])
    return moments.mean, moments.variance


NETWORK = UnitModel(
    name="network",
    parameter_names=("rates", "outflow_rates"),
    exit_age=_network_exit_age,
    cumulative=_network_cumulative,
    ramp=_network_ramp,
    transfer_function=_network_transfer,
    moments=_network_moments,
    grid=_network_grid,
)
"""A continuous compartment network (structure: the network; parameters: its rate arrays)."""


# ------------------------------------------------------------------ measured curve
def _segments(knots: tuple[float, ...]):
    time = jnp.asarray(knots, float)
    return time, jnp.diff(time)


def _locate(t: Array, time: Array) -> tuple[Array, Array]:
    """Segment index of each t (clipped to the curve) and the offset into that segment."""
    index = jnp.clip(jnp.searchsorted(time, t, side="right") - 1, 0, time.shape[0] - 2)
    return index, t - time[index]


def _empirical_exit_age(t, p, knots):
    time, _ = _segments(knots)
    return jnp.interp(jnp.asarray(t, float), time, p["exit_age"], left=0.0, right=0.0)


def _empirical_integrals(values: Array, steps: Array) -> tuple[Array, Array]:
    """F and R at the knots for the piecewise-linear density (exact)."""
    slopes = jnp.diff(values)
    cumulative_ = jnp.concatenate(
        [jnp.zeros(1), jnp.cumsum(steps * (values[:-1] + values[1:]) / 2)]
    )
    ramp_pieces = (
        steps * cumulative_[:-1] + steps**2 * values[:-1] / 2 + steps**2 * slopes / 6
    )
    return cumulative_, jnp.concatenate([jnp.zeros(1), jnp.cumsum(ramp_pieces)])


def _empirical_cumulative(t, p, knots):
    time, steps = _segments(knots)
    values = jnp.asarray(p["exit_age"], float)
    cumulative_, _ = _empirical_integrals(values, steps)
    t = jnp.asarray(t, float)
    index, x = _locate(t, time)
    x = jnp.clip(x, 0.0, steps[index])
    slope = (values[index + 1] - values[index]) / steps[index]
    inside = cumulative_[index] + values[index] * x + slope * x**2 / 2
    return jnp.where(t <= time[0], 0.0, inside)


def _empirical_ramp(t, p, knots):
    time, steps = _segments(knots)
    values = jnp.asarray(p["exit_age"], float)
    cumulative_, ramp_ = _empirical_integrals(values, steps)
    t = jnp.asarray(t, float)
    index, x = _locate(t, time)
    x_inside = jnp.clip(x, 0.0, steps[index])
    slope = (values[index + 1] - values[index]) / steps[index]
    inside = (
        ramp_[index]
        + cumulative_[index] * x_inside
        + values[index] * x_inside**2 / 2
        + slope * x_inside**3 / 6
    )
    beyond = ramp_[-1] + cumulative_[-1] * (t - time[-1])
    return jnp.where(t <= time[0], 0.0, jnp.where(t > time[-1], beyond, inside))


def _phi1(z: Array) -> Array:
    """(1 - e^{-z}) / z, equal to 1 at z = 0."""
    nonzero = z != 0
    safe = jnp.where(nonzero, z, 1.0)
    return jnp.where(nonzero, -jnp.expm1(-safe) / safe, 1.0)


def _phi2(z: Array) -> Array:
    """∫_0^1 x e^{-z x} dx = (1 - (1 + z) e^{-z}) / z², by its series for |z| < 0.5."""
    small = jnp.abs(z) < 0.5
    safe = jnp.where(small, 1.0, z)
    direct = (_phi1(safe) - jnp.exp(-safe)) / safe
    # Σ_k (-z)^k / (k! (k + 2)); 18 terms are exact to round-off for |z| < 0.5.
    series = jnp.zeros_like(z)
    term_factorial = 1.0
    for k in range(18):
        series = series + (-z) ** k / (term_factorial * (k + 2))
        term_factorial *= k + 1
    return jnp.where(small, series, direct)


def _empirical_transfer(s, p, knots):
    time, steps = _segments(knots)
    values = jnp.asarray(p["exit_age"], float)
    s = jnp.asarray(s, complex)[..., None]
    z = s * steps
    pieces = (
        jnp.exp(-s * time[:-1])
        * steps
        * (values[:-1] * _phi1(z) + (values[1:] - values[:-1]) * _phi2(z))
    )
    return jnp.sum(pieces, axis=-1)


def _empirical_moments(p, knots):
    time, steps = _segments(knots)
    values = jnp.asarray(p["exit_age"], float)
    slopes = values[1:] - values[:-1]
    area = jnp.sum(steps * (values[:-1] + values[1:]) / 2)
    start = time[:-1]
    first = jnp.sum(steps * (values[:-1] * (start + steps / 2) + slopes * (start / 2 + steps / 3)))
    mean = first / area
    # Central second moment with the knots shifted by the mean (no cancellation).
    shifted = start - mean
    second = jnp.sum(
        steps
        * (
            values[:-1] * (shifted**2 + shifted * steps + steps**2 / 3)
            + slopes * (shifted**2 / 2 + 2 * shifted * steps / 3 + steps**2 / 4)
        )
    )
    return mean, second / area


EMPIRICAL = UnitModel(
    name="empirical",
    parameter_names=("exit_age",),
    exit_age=_empirical_exit_age,
    cumulative=_empirical_cumulative,
    ramp=_empirical_ramp,
    transfer_function=_empirical_transfer,
    moments=_empirical_moments,
)
"""A measured curve (structure: its sample times; parameter ``exit_age``: E at those times)."""


def moments_from_transfer_function(
    transfer_function: CurveFunction, parameters: Parameters, structure: Hashable
) -> tuple[Array, Array]:
    """Mean ``-G'(0)`` and variance ``G''(0) - G'(0)²`` by differentiating G along real s."""

    def real_part(s):
        return jnp.real(transfer_function(jnp.asarray(s, float), parameters, structure))

    first = jax.grad(real_part)(0.0)
    second = jax.grad(jax.grad(real_part))(0.0)
    return -first, second - first**2
