"""Inversion of a transfer function on a whole uniform grid at once (Fourier series).

The saddle-point inversion of :mod:`axialmix.analytic.responses` costs a contour, some
hundreds of transfer-function values, for every time. Where a curve is wanted at every node
of a uniform grid (a table of many parameter vectors, as a diversion's covariance samples
need), the damped Fourier series of Dubner and Abate (1968) gives all nodes from one set of
transfer-function values and one FFT:

    f(t) ≈ (e^{c t} / P) [ H(c) + 2 Re Σ_{k>=1} H(c + 2 pi i k / P) e^{2 pi i k t / P} ],

with ``H = G/s`` for ``F`` and ``H = G`` for ``E``. By Poisson summation the series is exactly
``Σ_{n>=0} e^{-c n P} f(t + n P)``: the period ``P`` is twice the grid's horizon and the
damping ``c P =`` :data:`DAMPING` makes the wrapped-around copies ``e^{-24} ≈ 4e-11`` of
the curve (of 1 for ``F``); only the first half of the period is used, where rounding grows
at most by ``e^{c P / 2} ≈ 2e5``. What remains is the truncation of the series at ``M``
terms, small when the curve is smooth: it is estimated by the series of ``M / 2`` terms
(returned with the values) and the caller checks it, with the exact inversion at some nodes.

A curve with a jump at ``t = 0`` (one tank, E) converges only algebraically; such units show a
large estimate and are to be inverted exactly.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = ["DAMPING", "grid_inversion", "truncation_estimates"]

#: ``c P``, the damping over one period: the aliased copies weigh ``e^{-DAMPING}``.
DAMPING = 24.0


def _series(values: jax.Array, damping: jax.Array, period, terms: int, stride: int):
    """The damped series of ``values`` (``H`` at ``c + 2 pi i k / P``, ``k < terms``) at
    every `stride`-th of the ``terms`` points ``n P / terms`` of the first half period."""
    total = terms * jnp.fft.ifft(values[..., :terms], axis=-1)
    index = jnp.arange(0, terms // 2 + 1, stride)
    times = index * (period / terms)
    return jnp.exp(damping * times) / period * (
        2.0 * jnp.real(total[..., index]) - jnp.real(values[..., :1]))


def _estimate(g, s, damping, period, terms, intervals, horizon, exit_age):
    """The series of `terms` terms against that of half as many, at the grid's nodes."""
    stride, half = terms // (2 * intervals), terms // 2
    pairs = [(g / s, 1.0)] + ([(g, float(horizon))] if exit_age else [])
    return jnp.max(jnp.stack([scale * jnp.max(jnp.abs(
        _series(values, damping, period, terms, stride)
        - _series(values, damping, period, half, stride // 2))) for values, scale in pairs]))


def grid_inversion(
    transfer: Callable[[jax.Array], jax.Array],
    horizon: float,
    intervals: int,
    terms: int,
    *,
    exit_age: bool = True,
) -> tuple[jax.Array, jax.Array | None, jax.Array]:
    """Return F (and E) at the nodes ``j h``, ``h = horizon / intervals``, ``j = 0..intervals``.

    **Arguments:**

    - `transfer`: ``G(s)`` of a unit, for complex ``s`` of any shape (1/time unit); traceable.
    - `horizon`: the grid's last time (time unit, positive; concrete).
    - `intervals`: the grid's interval count (a power of two).
    - `terms`: terms ``M`` of the series, a power of two and a multiple of ``4 intervals``
      (the estimate uses ``M / 2``).
    - `exit_age`: whether E is wanted too.

    **Returns:**

    ``(F, E, estimate)``: F (dimensionless) and E (1/time unit, or None) with shape
    ``(intervals + 1,)``, and the largest difference of either from the series of ``M / 2``
    terms (E's times the horizon, so that both are dimensionless), an estimate of the
    truncation error of the coarser series, which bounds that of the returned one for a
    smooth curve.
    """
    if terms % (4 * intervals):
        raise ValueError(f"terms must be a multiple of 4 x {intervals}, got {terms}.")
    period = 2.0 * float(horizon)
    damping = DAMPING / period
    s = damping + 2j * jnp.pi * jnp.arange(terms) / period
    g = transfer(s)
    stride = terms // (2 * intervals)
    cumulative = _series(g / s, damping, period, terms, stride)
    density = _series(g, damping, period, terms, stride) if exit_age else None
    return cumulative, density, _estimate(g, s, damping, period, terms, intervals, horizon,
                                          exit_age)


def truncation_estimates(
    transfer: Callable[[jax.Array], jax.Array],
    horizon: float,
    intervals: int,
    max_terms: int,
    *,
    exit_age: bool = True,
) -> jax.Array:
    """The estimate of :func:`grid_inversion` for every term count ``4 intervals 2^j`` up to
    `max_terms` (one evaluation of `transfer`: the series share their first terms).

    **Returns:** the estimates (dimensionless), one per term count, coarsest first.
    """
    period = 2.0 * float(horizon)
    damping = DAMPING / period
    s = damping + 2j * jnp.pi * jnp.arange(max_terms) / period
    g = transfer(s)
    estimates = []
    terms = 4 * intervals
    while terms <= max_terms:
        estimates.append(_estimate(g, s, damping, period, terms, intervals, horizon, exit_age))
        terms *= 2
    return jnp.stack(estimates)
