"""Curve utilities for residence time distributions: normalise, moments, E <-> F, convolution.

Every function takes sampled curves on a time grid and is written in ``jax.numpy``, so it can
sit inside a jitted, differentiated or vmapped fit; NumPy arrays and lists are accepted too.

Quadrature, stated once for the module (MODELS.md section 2 defines the quantities):

* Integrals are the trapezoid rule on the given, possibly non-uniform, times. For a smooth
  curve the error is ``(h**2 / 12) * (f'(t_end) - f'(t_start)) + O(h**4)`` (Euler-Maclaurin),
  so it is second order, and much better when the curve starts and ends flat (a dispersion
  curve that rises from zero and decays to baseline). Curves with a slope at the ends (a
  stirred tank, ``E'(0) = -1/tau**2``) carry an ``O(h**2)`` bias; coarse sampling of such a
  curve over-estimates its area, mean and variance. A curve cut off before it returns to
  baseline under-estimates them, whatever the sampling.
* Convolution is exact for curves that are piecewise linear between the samples of a uniform
  grid (see :func:`convolve`).

Units: times in any unit (say s); an exit-age density ``E`` in 1/(that unit); ``F`` is
dimensionless.
"""

from typing import Self

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import concrete_value, require_finite, require_increasing_times

__all__ = [
    "RTD",
    "convolve",
    "cumulative",
    "exit_age_from_cumulative",
    "mean_residence_time",
    "moments",
    "normalise",
    "trapezoid",
    "variance",
]

_UNIFORM_GRID_RTOL = 1e-6


def _is_concrete(*values: object) -> bool:
    """True when no value is a JAX tracer, so it is safe to inspect it in Python."""
    return all(concrete_value(v) is not None for v in values)


def _check_curve(time: ArrayLike, values: ArrayLike, name: str) -> None:
    """Raise a one-line ValueError for a malformed sampled curve (concrete inputs only)."""
    require_increasing_times("time", time)
    require_finite(name, values)
    if not _is_concrete(time, values):
        return
    time_shape, values_shape = np.shape(time), np.shape(values)
    if len(time_shape) != 1:
        raise ValueError(f"time must be a one-dimensional array, got shape {time_shape}")
    if time_shape[0] < 2:
        raise ValueError("time needs at least two samples")
    if values_shape[-1:] != time_shape:
        raise ValueError(
            f"{name} has {values_shape[-1:]} samples on its last axis but time has {time_shape[0]}"
        )


def _check_uniform(time: ArrayLike) -> None:
    """Raise a one-line ValueError if a concrete time grid is not uniformly spaced."""
    if not _is_concrete(time):
        return
    steps = np.diff(np.asarray(time, dtype=float))
    if np.max(np.abs(steps - steps.mean())) > _UNIFORM_GRID_RTOL * steps.mean():
        raise ValueError(
            "time must be uniformly spaced for convolution "
            f"(steps range from {steps.min():.6g} to {steps.max():.6g})"
        )


def trapezoid(values: ArrayLike, time: ArrayLike) -> Array:
    """Integrate a sampled curve over time with the trapezoid rule on the given grid.

    **Arguments:**

    - `values`: samples ``f(t_i)``, shape ``(..., times)``; any unit U.
    - `time`: sample times ``t_i``, shape ``(times,)``, strictly increasing; unit T.

    **Returns:**

    ``sum_i (t_{i+1} - t_i) (f_i + f_{i+1}) / 2``, shape ``(...)``; unit U·T.
    """
    values = jnp.asarray(values)
    time = jnp.asarray(time)
    steps = jnp.diff(time)
    return jnp.sum(steps * (values[..., 1:] + values[..., :-1]), axis=-1) / 2


def normalise(time: ArrayLike, concentration: ArrayLike) -> Array:
    """Scale a measured tracer curve so that its trapezoid integral is one: the exit age E.

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T (e.g. s).
    - `concentration`: outlet tracer signal, shape ``(..., times)``; any unit.

    **Returns:**

    The exit-age density ``E = c / trapezoid(c, t)``, same shape; unit 1/T.
    """
    _check_curve(time, concentration, "concentration")
    concentration = jnp.asarray(concentration)
    return concentration / trapezoid(concentration, time)[..., None]


def moments(time: ArrayLike, exit_age: ArrayLike) -> tuple[Array, Array]:
    """Mean residence time and variance of a sampled exit-age curve by the trapezoid rule.

    The moments are divided by the curve's own trapezoid area, so a curve that is not exactly
    normalised still gives the moments of its shape: ``mean = ∫ t E dt / ∫ E dt`` and
    ``variance = ∫ (t - mean)² E dt / ∫ E dt``. Second-order accurate in the sample spacing
    for smooth curves; see the module docstring for the bias of coarse sampling and of
    curves cut off before they return to baseline.

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T.
    - `exit_age`: exit-age density (or any non-negative tracer curve), ``(..., times)``.

    **Returns:**

    ``(mean, variance)``, each of shape ``(...)``; units T and T².
    """
    _check_curve(time, exit_age, "exit_age")
    time = jnp.asarray(time)
    exit_age = jnp.asarray(exit_age)
    area = trapezoid(exit_age, time)
    mean = trapezoid(time * exit_age, time) / area
    deviation = time - mean[..., None]
    return mean, trapezoid(deviation**2 * exit_age, time) / area


def mean_residence_time(time: ArrayLike, exit_age: ArrayLike) -> Array:
    """Mean residence time ``∫ t E dt / ∫ E dt`` of a sampled curve (trapezoid rule).

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T.
    - `exit_age`: exit-age density, shape ``(..., times)``.

    **Returns:**

    The mean residence time, shape ``(...)``; unit T.
    """
    return moments(time, exit_age)[0]


def variance(time: ArrayLike, exit_age: ArrayLike) -> Array:
    """Variance ``∫ (t - mean)² E dt / ∫ E dt`` of a sampled curve (trapezoid rule).

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T.
    - `exit_age`: exit-age density, shape ``(..., times)``.

    **Returns:**

    The variance ``sigma²``, shape ``(...)``; unit T².
    """
    return moments(time, exit_age)[1]


def cumulative(time: ArrayLike, exit_age: ArrayLike) -> Array:
    """Cumulative distribution F from an exit-age curve E by the cumulative trapezoid rule.

    ``F(t_0) = 0`` and ``F(t_k) = sum_{i<k} (t_{i+1} - t_i) (E_i + E_{i+1}) / 2``.

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T.
    - `exit_age`: exit-age density, shape ``(..., times)``; unit 1/T.

    **Returns:**

    ``F`` on the same times, same shape as `exit_age`; dimensionless.
    """
    _check_curve(time, exit_age, "exit_age")
    time = jnp.asarray(time)
    exit_age = jnp.asarray(exit_age)
    pieces = jnp.diff(time) * (exit_age[..., 1:] + exit_age[..., :-1]) / 2
    zero = jnp.zeros(exit_age.shape[:-1] + (1,), dtype=pieces.dtype)
    return jnp.concatenate([zero, jnp.cumsum(pieces, axis=-1)], axis=-1)


def exit_age_from_cumulative(time: ArrayLike, cumulative_fraction: ArrayLike) -> Array:
    """Exit-age curve E = dF/dt from a cumulative curve F by second-order finite differences.

    Interior samples use the three-point central formula for non-uniform grids, the two end
    samples the three-point one-sided formula; all are exact for quadratic F. This is not the
    algebraic inverse of :func:`cumulative` (inverting the trapezoid sum amplifies noise into
    an alternating oscillation), so ``E -> F -> E`` returns E up to ``O(h²)``.

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing, at least 3; unit T.
    - `cumulative_fraction`: ``F`` samples, shape ``(..., times)``; dimensionless.

    **Returns:**

    ``E`` on the same times, same shape; unit 1/T.
    """
    _check_curve(time, cumulative_fraction, "cumulative_fraction")
    if _is_concrete(time) and np.shape(time)[0] < 3:
        raise ValueError("time needs at least three samples to differentiate F")
    time = jnp.asarray(time)
    f = jnp.asarray(cumulative_fraction)
    h = jnp.diff(time)
    h_left, h_right = h[:-1], h[1:]
    interior = (
        -h_right / (h_left * (h_left + h_right)) * f[..., :-2]
        + (h_right - h_left) / (h_left * h_right) * f[..., 1:-1]
        + h_left / (h_right * (h_left + h_right)) * f[..., 2:]
    )
    a, b = h[0], h[1]
    first = (
        -(2 * a + b) / (a * (a + b)) * f[..., 0]
        + (a + b) / (a * b) * f[..., 1]
        - a / (b * (a + b)) * f[..., 2]
    )
    a, b = h[-1], h[-2]
    last = (
        (2 * a + b) / (a * (a + b)) * f[..., -1]
        - (a + b) / (a * b) * f[..., -2]
        + a / (b * (a + b)) * f[..., -3]
    )
    return jnp.concatenate([first[..., None], interior, last[..., None]], axis=-1)


def convolve(time: ArrayLike, exit_age: ArrayLike, inlet: ArrayLike) -> Array:
    """Outlet signal of a unit with exit age E for an inlet signal: ``∫_0^t E(t-s) c_in(s) ds``.

    Both curves are taken as zero before ``time[0]`` (which is the injection start, t = 0 in
    the convolution) and linear between samples; for such piecewise-linear curves on a
    uniform grid the result at every sample time is exact. Each grid interval contributes
    ``h/6 (2 u_0 w_0 + u_0 w_1 + u_1 w_0 + 2 u_1 w_1)`` (the exact integral of a product of two
    linear functions), assembled from four discrete convolutions. For smooth curves the
    error is ``O(h²)``.

    **Arguments:**

    - `time`: uniformly spaced sample times, shape ``(times,)``; unit T. Only the spacing
      matters: sample ``k`` is at ``k * h`` after the start.
    - `exit_age`: exit-age density on `time`, shape ``(times,)``; unit 1/T.
    - `inlet`: inlet signal on `time`, shape ``(..., times)``; any unit U (for a second
      exit age, 1/T: the result is then the exit age of the two units in series).

    **Returns:**

    The outlet signal on `time`, same shape as `inlet`; unit U.
    """
    _check_curve(time, exit_age, "exit_age")
    _check_curve(time, inlet, "inlet")
    _check_uniform(time)
    time = jnp.asarray(time)
    exit_age = jnp.asarray(exit_age)
    inlet = jnp.asarray(inlet)
    if inlet.ndim > 1:
        flat = inlet.reshape(-1, inlet.shape[-1])
        result = jax.vmap(lambda row: _convolve_piecewise_linear(time, exit_age, row))(flat)
        return result.reshape(inlet.shape)
    return _convolve_piecewise_linear(time, exit_age, inlet)


def _convolve_piecewise_linear(time: Array, e: Array, c: Array) -> Array:
    """Exact convolution at the grid points of two piecewise-linear curves (1-D arrays)."""
    n = time.shape[0]
    step = (time[-1] - time[0]) / (n - 1)
    full = jnp.convolve(c, e, mode="full", precision=jax.lax.Precision.HIGHEST)[:n]
    tail = jnp.convolve(c[1:], e[1:], mode="full", precision=jax.lax.Precision.HIGHEST)
    # Sums over intervals j = 0..k-1 pairing c on [t_j, t_j+1] with E on [t_k-j-1, t_k-j]:
    c_j_e_kmj = full - c * e[0]
    c_j_e_kmjm1 = jnp.concatenate([jnp.zeros(1, full.dtype), full[:-1]])
    c_jp1_e_kmj = jnp.concatenate([jnp.zeros(1, tail.dtype), tail[: n - 1]])
    c_jp1_e_kmjm1 = full - c[0] * e
    weighted = 2 * c_j_e_kmj + c_j_e_kmjm1 + c_jp1_e_kmj + 2 * c_jp1_e_kmjm1
    return step / 6 * weighted


class RTD(eqx.Module):
    """A sampled residence time distribution: times and exit-age density (like rtdpy's RTD).

    Immutable and a JAX pytree, so it can be passed through ``jit``/``vmap``. Moments use the
    trapezoid rule (see the module docstring).

    **Arguments:**

    - `time`: sample times, shape ``(times,)``, strictly increasing; unit T (e.g. s).
    - `exit_age`: exit-age density ``E(t)`` on `time`; unit 1/T.
    """

    time: Array = eqx.field(converter=jnp.asarray)
    exit_age: Array = eqx.field(converter=jnp.asarray)

    def __check_init__(self) -> None:
        _check_curve(self.time, self.exit_age, "exit_age")
        if _is_concrete(self.exit_age) and np.ndim(self.exit_age) != 1:
            raise ValueError(f"exit_age must be one-dimensional, got {np.shape(self.exit_age)}")

    @classmethod
    def from_signal(cls, time: ArrayLike, concentration: ArrayLike) -> Self:
        """Build an RTD from a measured tracer curve, normalised to unit trapezoid area.

        **Arguments:**

        - `time`: sample times, strictly increasing; unit T.
        - `concentration`: outlet tracer signal on `time`; any unit.

        **Returns:**

        An :class:`RTD` whose exit age integrates to one.
        """
        return cls(time, normalise(time, concentration))

    def integral(self) -> Array:
        """Trapezoid integral of the exit age (one for a normalised curve); dimensionless."""
        return trapezoid(self.exit_age, self.time)

    def mean(self) -> Array:
        """Mean residence time ``∫ t E dt / ∫ E dt``; unit T."""
        return moments(self.time, self.exit_age)[0]

    def variance(self) -> Array:
        """Variance ``∫ (t - mean)² E dt / ∫ E dt``; unit T²."""
        return moments(self.time, self.exit_age)[1]

    def cumulative(self) -> Array:
        """Cumulative distribution ``F`` on the same times (cumulative trapezoid)."""
        return cumulative(self.time, self.exit_age)

    def output(self, inlet: ArrayLike) -> Array:
        """Outlet signal for an inlet signal sampled on this RTD's (uniform) times.

        **Arguments:**

        - `inlet`: inlet signal on ``self.time``; any unit U.

        **Returns:**

        The outlet signal on ``self.time``; unit U (see :func:`convolve`).
        """
        return convolve(self.time, self.exit_age, inlet)

    def convolve(self, other: Self) -> Self:
        """RTD of this unit followed by another in series, on the same uniform time grid.

        **Arguments:**

        - `other`: an :class:`RTD` on the same times.

        **Returns:**

        An :class:`RTD` with exit age ``(E_self * E_other)(t)``; its mean and variance are
        the sums of the two (up to truncation of the grid).
        """
        if _is_concrete(self.time, other.time) and not np.allclose(
            np.asarray(self.time), np.asarray(other.time), rtol=1e-12, atol=0.0
        ):
            raise ValueError("other must be sampled on the same times to convolve")
        return type(self)(self.time, convolve(self.time, self.exit_age, other.exit_age))
