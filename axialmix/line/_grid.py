"""Curves on a uniform grid: exact piecewise-linear convolution, Romberg, interpolation.

A line's curves are computed on the grid ``t_k = k h`` (k = 0 … N), ``h = horizon / N``:

* a curve enters as its values at the start and at the end of each grid interval, so a jump
  at a node (a stirred tank's ``E(0) = 1/tau``, the ends of a measured curve) is represented
  exactly; the convolution of two such piecewise-linear curves is integrated exactly
  (each pair of intervals contributes ``h/6 (2 a0 b1 + a0 b0 + a1 b1 + 2 a1 b0)`` in the
  notation of :func:`interval_convolution`), the rule of :func:`axialmix.rtd.convolve`
  generalised to jumps and evaluated by FFT (``O(N log N)`` instead of ``O(N²)``);
* for curves that are smooth between their jumps the error of that rule has an expansion in
  even powers of h, so the results of the grids h, h/2 and h/4 are combined by Richardson
  extrapolation into a sixth-order result at the nodes of the coarsest grid (a measured
  curve whose samples lie on the grid is represented exactly on all three and is unchanged);
* values between nodes come from six-point Lagrange interpolation (sixth order).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax import Array

__all__ = [
    "LEVELS",
    "cumulative_trapezoid",
    "grid_nodes",
    "interpolate",
    "interval_convolution",
    "richardson",
]

LEVELS = 3
"""Grids h, h/2, h/4 are combined; see :func:`richardson`."""


def _fft_convolution(a: Array, b: Array) -> Array:
    """First ``len(a)`` terms of the discrete convolution of two equal-length real sequences."""
    n = a.shape[-1]
    size = 1 << math.ceil(math.log2(2 * n))
    product = jnp.fft.rfft(a, size) * jnp.fft.rfft(b, size)
    return jnp.fft.irfft(product, size)[..., :n]


def interval_convolution(
    step: Array, first: tuple[Array, Array], second: tuple[Array, Array]
) -> Array:
    """Exact ``∫_0^{t_k} a(s) b(t_k - s) ds`` at the nodes for two piecewise-linear curves.

    **Arguments:**

    - `step`: grid spacing h (time unit).
    - `first`, `second`: ``(start_values, end_values)`` of a and b on each of the N grid
      intervals (a curve is zero before t = 0).

    **Returns:**

    The convolution at the N + 1 nodes ``t_k = k h`` (first value 0).
    """
    a_start, a_end = first
    b_start, b_end = second
    # Interval j of a meets interval i = k - 1 - j of b, run backwards: the product of the
    # linear pieces a (a0 -> a1) and b (b1 -> b0) integrates to h/6 (2 a0 b1 + a0 b0 + a1 b1
    # + 2 a1 b0).
    summed = _fft_convolution(a_start, 2.0 * b_end + b_start) + _fft_convolution(
        a_end, b_end + 2.0 * b_start
    )
    zero = jnp.zeros(summed.shape[:-1] + (1,), summed.dtype)
    return jnp.concatenate([zero, step / 6.0 * summed], axis=-1)


def cumulative_trapezoid(step: Array, values: Array) -> Array:
    """Cumulative trapezoid integral of node values from 0 (exact for piecewise-linear)."""
    pieces = step * (values[..., 1:] + values[..., :-1]) / 2.0
    zero = jnp.zeros(values.shape[:-1] + (1,), values.dtype)
    return jnp.concatenate([zero, jnp.cumsum(pieces, axis=-1)], axis=-1)


def richardson(levels: list[Array]) -> Array:
    """Combine node values of grids h, h/2, h/4 (N+1, 2N+1, 4N+1 nodes) to sixth order.

    Each level's error is ``c2 h² + c4 h⁴ + O(h⁶)``; two rounds of extrapolation remove the
    first two terms at the nodes of the coarsest grid.
    """
    coarse = [level[..., :: 1 << index] for index, level in enumerate(levels)]
    pairs = zip(coarse[:-1], coarse[1:], strict=True)
    first_round = [(4.0 * fine - rough) / 3.0 for rough, fine in pairs]
    return (16.0 * first_round[1] - first_round[0]) / 15.0


_STENCIL = 6


def interpolate(step: Array, values: Array, t: Array) -> Array:
    """Six-point Lagrange interpolation of node values ``values[k] = f(k h)`` at times t.

    Times are clipped to ``[0, N h]``; the stencil is shifted inwards at the ends, so only
    nodes of the grid are used.

    **Arguments:**

    - `step`: grid spacing h.
    - `values`: node values, shape ``(N + 1,)`` with ``N + 1 >= 6``.
    - `t`: times of any shape.

    **Returns:**

    Interpolated values, the shape of `t`.
    """
    n = values.shape[0] - 1
    x = jnp.clip(jnp.asarray(t, float) / step, 0.0, float(n))
    first = jnp.clip(jnp.floor(x).astype(int) - (_STENCIL // 2 - 1), 0, n + 1 - _STENCIL)
    xi = x - first
    result = jnp.zeros_like(x)
    for j in range(_STENCIL):
        weight = jnp.ones_like(x)
        for m in range(_STENCIL):
            if m != j:
                weight = weight * (xi - m) / (j - m)
        result = result + weight * values[first + j]
    return result


def grid_nodes(step: Array, intervals: int) -> Array:
    """The nodes ``k h`` (k = 0 … intervals) of a grid."""
    return jnp.arange(intervals + 1) * step

