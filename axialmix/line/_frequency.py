"""Damping of feeder noise: frequency response and variance reduction ratios (MODELS.md §8)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_increasing_times, require_positive
from axialmix.line._disturbance import Disturbance, outlet_response
from axialmix.line._line import Line, TabulatedRTD, as_evaluator
from axialmix.line._unit import Unit, is_concrete
from axialmix.rtd import trapezoid

__all__ = [
    "frequency_response",
    "series_variance_reduction_ratio",
    "spectral_variance_reduction_ratio",
    "white_noise_variance_reduction_ratio",
]

_TAIL_SPREADS = 40.0


def frequency_response(rtd: Unit | Line, omega: ArrayLike) -> Array:
    """Amplitude ratio ``|G(i omega)|`` of a unit or line: how much of a feed oscillation passes.

    **Arguments:**

    - `rtd`: a :class:`Unit` or :class:`Line` with a transfer function.
    - `omega`: angular frequencies (rad per time unit), any shape.

    **Returns:**

    ``|G(i omega)|`` (dimensionless, 1 at omega = 0), the shape of `omega`.
    """
    return rtd.frequency_response(omega)


def spectral_variance_reduction_ratio(
    rtd: Unit | Line, omega: ArrayLike, spectrum: ArrayLike
) -> Array:
    """VRR of feeder noise given by its power spectrum: ``∫ S dω / ∫ |G(iω)|² S dω``.

    The outlet variance of noise with spectrum S is ``∫ |G(iω)|² S(ω) dω / 2π`` (MODELS.md
    §8); both integrals are taken by the trapezoid rule over the given frequencies, which
    must cover the spectrum (a one-sided spectrum of a real signal gives the same ratio).

    **Arguments:**

    - `rtd`: a :class:`Unit` or :class:`Line` with a transfer function.
    - `omega`: angular frequencies (rad per time unit), strictly increasing, >= 0.
    - `spectrum`: power spectral density at `omega` (any unit), non-negative.

    **Returns:**

    ``VRR = sigma²_in / sigma²_out`` (dimensionless, >= 1 for an RTD).
    """
    require_increasing_times("omega", omega)
    require_finite("spectrum", spectrum)
    omega = jnp.asarray(omega, float)
    spectrum = jnp.asarray(spectrum, float)
    if omega.shape != spectrum.shape or omega.ndim != 1:
        raise ValueError(
            f"omega and spectrum must be 1-D of equal length, got {omega.shape}, {spectrum.shape}."
        )
    gain = rtd.frequency_response(omega)
    return trapezoid(spectrum, omega) / trapezoid(gain**2 * spectrum, omega)


def white_noise_variance_reduction_ratio(
    rtd: Unit | Line | TabulatedRTD,
    sample_interval: ArrayLike,
    *,
    hold: str = "linear",
    terms: int | None = None,
) -> Array:
    """VRR for white feeder noise sampled every Δt: ``1 / Σ_k w_k²`` (exact for the samples).

    Independent deviations ``u_j`` of the inlet at ``t_j = j Δt`` leave, at the same times,
    as ``y_i = Σ_k w_k u_{i-k}``, so ``VRR = var u / var y = 1 / Σ w_k²``. The weights are
    exact: with the feed held between samples (``hold="zero"``)
    ``w_k = F(k Δt) - F((k-1) Δt)``; with the feed linear between samples (``"linear"``,
    the convention of :func:`outlet_response`) ``w_k = D_{k+1} - D_k``,
    ``D_k = [R(kΔt) - R((k-1)Δt)] / Δt``. Both tend to ``w_k ≈ Δt E(kΔt)``, i.e.
    ``VRR ≈ 1 / (Δt ∫ E² dt)``, the formula of MODELS.md §8 (there with ``Σ h_k²`` standing
    for ``∫E² dt ≈ Δt Σ E(kΔt)²``), when Δt is small against the RTD's spread.

    **Arguments:**

    - `rtd`: a :class:`Unit`, :class:`Line` or :class:`TabulatedRTD`.
    - `sample_interval`: Δt (time unit, positive).
    - `hold`: ``"linear"`` or ``"zero"``: how the feed varies between samples.
    - `terms`: number of weights; default: enough to reach the mean plus 40 standard
      deviations (needs concrete parameters).

    **Returns:**

    The VRR (dimensionless).
    """
    require_positive("sample_interval", sample_interval)
    if hold not in ("linear", "zero"):
        raise ValueError(f"hold must be 'linear' or 'zero', got {hold!r}.")
    step = jnp.asarray(sample_interval, float)
    if terms is None:
        reach = rtd.mean() + _TAIL_SPREADS * jnp.sqrt(rtd.variance())
        if not is_concrete(reach, step):
            raise ValueError("give terms= when the RTD or the interval is traced.")
        terms = max(8, math.ceil(float(reach) / float(step)) + 2)
    evaluator = as_evaluator(rtd, step * (terms + 1))
    lags = jnp.arange(terms + 2) * step
    if hold == "zero":
        cumulative = evaluator.cumulative(lags)
        weights = jnp.diff(cumulative)
    else:
        ramp = evaluator.ramp_response(lags)
        means = jnp.diff(ramp) / step
        weights = jnp.diff(jnp.concatenate([jnp.zeros(1), means]))
    return 1.0 / jnp.sum(weights**2)


def series_variance_reduction_ratio(
    rtd: Unit | Line,
    times: ArrayLike,
    trace: ArrayLike,
    *,
    discard: ArrayLike | None = None,
) -> Array:
    """VRR of a sampled feeder trace: its variance over that of the predicted outlet trace.

    The outlet is computed at the sample times by :func:`outlet_response` (the trace linear
    between samples); the first `discard` time units after the first sample are left out of
    both series, and the ratio is the source's ``sigma²_in / sigma²_out`` over the remaining
    samples (:func:`axialmix.particles.variance_reduction_ratio`, MODELS.md §1).

    **Arguments:**

    - `rtd`: a :class:`Unit` or :class:`Line`.
    - `times`: sample times (time unit), strictly increasing (uniform for the FFT path).
    - `trace`: the feeder's content (or rate) at `times`, any unit.
    - `discard`: warm-up left out (time unit); default the mean plus 10 standard
      deviations of the RTD, after which the start of the trace has washed out.

    **Returns:**

    The VRR (dimensionless).
    """
    from axialmix.particles.sampling import variance_reduction_ratio

    require_increasing_times("times", times)
    times = np.asarray(times, dtype=float)
    trace = np.asarray(trace, dtype=float)
    if discard is None:
        discard = float(rtd.mean() + 10.0 * jnp.sqrt(rtd.variance()))
    keep = times - times[0] >= float(discard)
    if keep.sum() < 2:
        raise ValueError(
            f"the trace is too short: nothing is left after discarding {float(discard):g} "
            f"{rtd.time_unit} of warm-up."
        )
    response = outlet_response(rtd, Disturbance.trace(times, trace, time_unit=rtd.time_unit),
                               times)
    return jnp.asarray(
        variance_reduction_ratio(trace[keep], np.asarray(response.outlet)[keep])
    )
