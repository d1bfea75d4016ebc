"""The closed–closed E on many points: exact at the nodes of Chebyshev panels, interpolated.

The exact E (:func:`axialmix.analytic.exit_age_closed`) costs a 33-node Bromwich quadrature
per time point, about 4 µs with its Jacobian: a curve of a million samples takes seconds per
evaluation. E(theta) (theta = t / tau) is smooth in ``s = ln theta`` on its support, so a curve
of many points is evaluated here as

1. the support ``theta_lo <= theta <= theta_hi`` where E exceeds about ``e^-50`` (outside
   it E is set to zero, :func:`closed_support`), cut into :data:`PANELS` panels of equal
   width in ``s``;
2. the exact E at the ``DEGREE + 1`` Chebyshev points (extrema) of every panel;
3. at each time, the panel's Chebyshev interpolant (coefficients from the node values by
   the discrete cosine transform, summed by Clenshaw's recurrence).

The interpolant is linear in the node values, and the node *times* ``t_j = tau theta_j`` are
held fixed under differentiation (like the Bromwich line of :mod:`axialmix.analytic._contour`),
so the derivatives in ``tau`` and ``Pe`` are the interpolants of the exact derivatives at the
nodes; a derivative in the times themselves (a dead time) is the interpolant's own.

Accuracy (measured against the exact E on 300,000 points a curve, Pe 0.05 to 2000, with
``PANELS = 64`` and ``DEGREE = 8``): at most 3.3e-13 of the peak (the largest at Pe >= 300,
where the peak is narrowest in ``s``), the derivatives in tau and Pe to 1.5e-12 and 3.2e-12 of
their largest values. Because the layout follows tau and Pe, a peak that is narrow compared
with the sampled span (tau = 2, Pe = 1000 over 0 to 100) is resolved like any other.

Every evaluation checks itself (``check=True``): the exact E is also computed at the
``DEGREE`` points between the nodes of every panel (where a Chebyshev interpolant's error
peaks), and at the two ends of the support (where the cut-off E must be negligible). Where
the interpolant misses any of them by more than :data:`CHECK_TOLERANCE` of the peak, the curve
is evaluated exactly on every point instead (a branch: the answer is never the interpolant
then). :func:`closed_panel_check` gives that deviation, :func:`closed_panel_deviation` the
deviation from the exact E on every given point.

The panels pay off only when a curve has many more points than the ``PANELS × (2 DEGREE +
1)`` = 1,088 exact evaluations they cost; :data:`LONG_CURVE` is the length from which the
models of :mod:`fitting` use them.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from axialmix._validation import require_finite, require_positive
from axialmix.analytic._contour import closed_closed_exit_age

__all__ = [
    "CHECK_TOLERANCE",
    "DEGREE",
    "LONG_CURVE",
    "PANELS",
    "closed_panel_check",
    "closed_panel_deviation",
    "closed_support",
    "exit_age_closed_panels",
]

#: Panels of equal width in ln(theta) over the support.
PANELS = 64
#: Polynomial degree of each panel's interpolant (DEGREE + 1 exact values a panel).
DEGREE = 8
#: Largest deviation from the exact E, as a share of the peak, at the check points of an
#: evaluation; beyond it the evaluation is exact on every point. (A tenth of the 1e-10 of the
#: peak promised for fits; the interpolant's error between check points is of the same size
#: as at them.)
CHECK_TOLERANCE = 1e-11
#: Points of a curve from which the panels are used by the models of :mod:`fitting`
#: (about fifteen times the exact evaluations one panel evaluation makes).
LONG_CURVE = 16384
#: The support ends where ``Pe (1 - theta)² / (4 theta)`` reaches this exponent (E there is
#: below ``e^-50`` times a prefactor of at most a few thousand, under 1e-18).
CUT_EXPONENT = 50.0
#: The support ends here at the latest: the tail decays at least as ``e^(-0.99 theta)`` (the
#: slowest rate of any Pe, near Pe = 1) from a prefactor near 1.
LAST_THETA = 60.0


def closed_support(peclet: ArrayLike) -> tuple[jax.Array, jax.Array]:
    """The dimensionless times outside which the closed–closed E is negligible.

    **Arguments:**

    - `peclet`: Peclet number (dimensionless, positive; any shape).

    **Returns:**

    ``(theta_lo, theta_hi)`` (dimensionless times t / tau): the roots of
    ``Pe (1 - theta)² / (4 theta) = 50``, the upper one at most 60. Below ``theta_lo`` and
    above ``theta_hi``, E is below about 1e-18 (times 1/tau); every evaluation of
    :func:`exit_age_closed_panels` checks this at both ends.
    """
    peclet = jnp.asarray(peclet, float)
    centre = 1.0 + 2.0 * CUT_EXPONENT / peclet
    half = jnp.sqrt(centre * centre - 1.0)
    # The lower root centre - half, written without cancellation.
    return 1.0 / (centre + half), jnp.minimum(centre + half, LAST_THETA)


def _chebyshev(degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(nodes, to_coefficients, at_checks)`` of a panel on [-1, 1]: the Chebyshev extrema
    ``cos(pi j / degree)`` in increasing order, the matrix from values at them to Chebyshev
    coefficients (the discrete cosine transform), and the matrix from coefficients to the
    values at the check points ``cos(pi (j + 1/2) / degree)`` between the nodes."""
    j = np.arange(degree + 1)
    angles = np.pi * j / degree
    nodes = -np.cos(angles)  # increasing
    # Values f_j at x_j = -cos(pi j / m) = cos(pi (m - j) / m); c_k = (2/m) Σ'' f_j T_k(x_j).
    halves = np.where((j == 0) | (j == degree), 0.5, 1.0)
    to_coefficients = (2.0 / degree) * np.cos(np.outer(j, np.pi * (degree - j) / degree)) * halves
    to_coefficients[0] *= 0.5
    to_coefficients[degree] *= 0.5
    checks = -np.cos(np.pi * (np.arange(degree) + 0.5) / degree)
    at_checks = np.cos(np.outer(np.arccos(checks), j))  # T_k(x) at the check points
    return nodes, to_coefficients, at_checks


def _layout(tau, peclet, panels: int, degree: int):
    """The panels of a curve: ``(s_lo, width, node times, check times)``, all held fixed
    under differentiation."""
    tau = jax.lax.stop_gradient(jnp.asarray(tau, float))
    peclet = jax.lax.stop_gradient(jnp.asarray(peclet, float))
    lo, hi = closed_support(peclet)
    s_lo = jnp.log(lo)
    width = (jnp.log(hi) - s_lo) / panels
    nodes, _, _ = _chebyshev(degree)
    checks = -np.cos(np.pi * (np.arange(degree) + 0.5) / degree)
    starts = s_lo + width * jnp.arange(panels)
    node_times = tau * jnp.exp(starts[:, None] + 0.5 * width * (1.0 + nodes[None, :]))
    check_times = tau * jnp.exp(starts[:, None] + 0.5 * width * (1.0 + checks[None, :]))
    return s_lo, width, node_times, check_times


def _exact(t, tau, peclet):
    """The exact E at times `t` (any shape), 1/(time unit)."""
    tau = jnp.asarray(tau, float)
    exit_age = closed_closed_exit_age(t / tau, peclet)
    return exit_age / tau


def _interpolate(t, coefficients, s_lo, width, tau_fixed):
    """Clenshaw's sum of each time's panel interpolant (zero outside the support)."""
    panels, size = coefficients.shape
    positive = t > 0
    s = jnp.log(jnp.where(positive, t, 1.0) / tau_fixed)
    z = (s - s_lo) / width
    index = jnp.clip(jnp.floor(z), 0, panels - 1).astype(jnp.int32)
    x = 2.0 * (z - index) - 1.0
    inside = positive & (z >= 0.0) & (z <= panels)
    later = jnp.zeros_like(x)
    latest = jnp.zeros_like(x)
    for k in range(size - 1, 0, -1):
        later, latest = coefficients[index, k] + 2.0 * x * later - latest, later
    value = coefficients[index, 0] + x * later - latest
    return jnp.where(inside, value, 0.0)


def _panel_curve(t, tau, peclet, panels: int, degree: int):
    """``(interpolated E at t, node values, deviation at the checks / peak)``."""
    s_lo, width, node_times, check_times = _layout(tau, peclet, panels, degree)
    _, to_coefficients, at_checks = _chebyshev(degree)
    # Nodes and check points in one exact evaluation (one quadrature in the program).
    both = _exact(jnp.concatenate([node_times, check_times], axis=1), tau, peclet)
    values = both[:, : degree + 1]  # (panels, degree + 1), differentiable
    exact_checks = jax.lax.stop_gradient(both[:, degree + 1:])
    coefficients = values @ to_coefficients.T
    fixed = jax.lax.stop_gradient(coefficients)
    at_check_points = fixed @ at_checks.T
    fixed_values = jax.lax.stop_gradient(values)
    peak = jnp.maximum(jnp.max(jnp.abs(fixed_values)), jnp.max(jnp.abs(exact_checks)))
    peak = jnp.where(peak > 0, peak, 1.0)
    ends = jnp.maximum(jnp.abs(fixed_values[0, 0]), jnp.abs(fixed_values[-1, -1]))
    deviation = jnp.maximum(jnp.max(jnp.abs(at_check_points - exact_checks)), ends) / peak
    deviation = jnp.where(jnp.isfinite(deviation), deviation, jnp.inf)
    curve = _interpolate(t, coefficients, s_lo, width, jax.lax.stop_gradient(
        jnp.asarray(tau, float)))
    return curve, deviation


@partial(jax.jit, static_argnames=("panels", "degree", "check"))
def _evaluate(t, tau, peclet, panels: int, degree: int, check: bool):
    curve, deviation = _panel_curve(t, tau, peclet, panels, degree)
    if not check:
        return curve
    return jax.lax.cond(deviation <= CHECK_TOLERANCE, lambda: curve,
                        lambda: _exact(t, tau, peclet))


def _require_layout(panels: int, degree: int) -> None:
    if not isinstance(panels, int) or panels < 1:
        raise ValueError(f"panels must be a positive integer, got {panels!r}")
    if not isinstance(degree, int) or degree < 2:
        raise ValueError(f"degree must be an integer of at least 2, got {degree!r}")


def exit_age_closed_panels(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    panels: int = PANELS,
    degree: int = DEGREE,
    check: bool = True,
) -> jax.Array:
    """Return the closed–closed E(t) from Chebyshev panels of exact values (see the module).

    Same values as :func:`axialmix.analytic.exit_age_closed` to about 1e-13 of the peak for
    Pe from 0.05 to 2000 (checked on every call, see `check`), at a fixed cost of
    ``panels × (2 degree + 1)`` exact evaluations plus a few nanoseconds a point.
    Differentiable in `t`, `tau` and `peclet`; jit- and vmap-able (under ``vmap`` over
    `tau` or `peclet` the check's branch becomes a select: both sides are computed).

    **Arguments:**

    - `t`: times (any unit, any shape, any order); times ``<= 0`` give 0.
    - `tau`: space time ``L / v`` in the unit of `t` (a positive scalar).
    - `peclet`: Peclet number (dimensionless, a positive scalar).
    - `panels`, `degree`: the layout (static).
    - `check`: compare with the exact E between the nodes of every panel and at both ends
      of the support, and evaluate exactly on every point where the interpolant misses by
      more than :data:`CHECK_TOLERANCE` of the peak (static).

    **Returns:**

    ``E(t)`` in 1/(time unit), shape of `t`.
    """
    require_finite("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    _require_layout(panels, degree)
    return _evaluate(jnp.asarray(t, float), tau, peclet, panels, degree, check)


def closed_panel_check(
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    panels: int = PANELS,
    degree: int = DEGREE,
) -> float:
    """The deviation an evaluation of :func:`exit_age_closed_panels` checks itself by.

    **Arguments:**

    - `tau`: space time (time unit, positive); `peclet`: Peclet number (positive).
    - `panels`, `degree`: the layout.

    **Returns:**

    The largest of ``|interpolant - exact E|`` at the points between every panel's nodes and
    of ``|E|`` at both ends of the support, as a share of the peak of E (dimensionless);
    ``inf`` where E is not finite.
    """
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    _require_layout(panels, degree)
    return float(_check(tau, peclet, panels, degree))


@partial(jax.jit, static_argnames=("panels", "degree"))
def _check(tau, peclet, panels: int, degree: int):
    return _panel_curve(jnp.ones(1), tau, peclet, panels, degree)[1]


@partial(jax.jit, static_argnames=("panels", "degree"))
def _deviation(t, tau, peclet, panels: int, degree: int):
    curve, _ = _panel_curve(t, tau, peclet, panels, degree)
    exact = _exact(t, tau, peclet)
    _, _, node_times, _ = _layout(tau, peclet, panels, degree)
    peak = jnp.maximum(jnp.max(jnp.abs(exact)), jnp.max(jnp.abs(_exact(node_times, tau,
                                                                       peclet))))
    return jnp.max(jnp.abs(curve - exact)), peak


def closed_panel_deviation(
    t: ArrayLike,
    tau: ArrayLike,
    peclet: ArrayLike,
    *,
    panels: int = PANELS,
    degree: int = DEGREE,
) -> tuple[float, float]:
    """The interpolant's deviation from the exact E on every given time (an exact evaluation
    of all of them: the check of a fit at its fitted values).

    **Arguments:**

    - `t`: times (any unit, any shape); `tau`: space time in the same unit (positive);
      `peclet`: Peclet number (positive).
    - `panels`, `degree`: the layout.

    **Returns:**

    ``(largest |interpolant - exact E| over t, peak of E)``, both in 1/(time unit); the peak
    is the largest exact E at `t` and at the panels' nodes (so a curve sampled away from its
    peak is still measured against the peak).
    """
    require_finite("t", t)
    require_positive("tau", tau)
    require_positive("peclet", peclet)
    _require_layout(panels, degree)
    largest, peak = _deviation(jnp.asarray(t, float), tau, peclet, panels, degree)
    return float(largest), float(peak)
