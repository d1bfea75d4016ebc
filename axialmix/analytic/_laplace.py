"""Bromwich inversion on saddle-point parabolas, for transfer functions with real singularities.

Every transfer function of :mod:`axialmix.analytic.transfer` is analytic off a ray
``(-inf, sigma]`` of the real axis (see there why). For such a function the Bromwich integral

    f(t) = (1 / 2 pi i) ∫ e^{s t} H(s) ds,     H = G, G/s or G/s²  (E, F or the ramp response)

may run along any parabola with its focus at ``sigma`` opening to the left,
``s = sigma + p q²`` with ``q = a + i y`` (a vertical line in ``q``; for the closed–closed ADM
with focus ``-Pe/4`` this is the line of :mod:`._contour`). Seen from the ``y`` variable, every
singularity left of the focus sits at distance exactly ``a`` from the real axis, so the
trapezoidal rule in ``y`` converges exponentially.

**Saddle point.** The parabola is chosen per time from the saddle of ``Phi(s) = s t + log H(s)``
on the real axis (Daniels 1954): ``Phi'(s*) = 0``, i.e. ``t`` is the mean of the exponentially
tilted density ``f(t) e^{-s t} / H(s)``. For the transform of a non-negative function that mean
falls from infinity at the focus to zero as ``s -> inf``, so the saddle exists and is unique;
it is found by Newton's method in ``x = log(s - sigma)``, safeguarded by bisection. With
``p = s* - sigma`` the saddle is at ``q = 1`` and the integrand near it is the Gaussian
``exp(-S² y²)``, ``S² = 2 p² Phi''(s*)``. The line is moved right by ``sqrt(L)`` scaled units
(``a = 1 + sqrt(L)/S``, a factor ``e^L`` of round-off, as in :mod:`._contour`) and cut where the
slower of that Gaussian and the far-field decay ``e^{-t p y²}`` of ``e^{s t}`` reaches
``e^{-T}``. Near the saddle ``|e^{Phi}|`` is about ``f(t) sqrt(2 pi Phi'')``, so rounding is
relative to ``f(t)`` itself: curves that are exponentially small (early times at high Pe)
come out with relative accuracy. This is the parabolic contour of Weideman and Trefethen
(2007, Math. Comp. 76, 1341) with its parameters set by the saddle point, which the near-delay
behaviour at high Pe requires.

**Steps and ramps.** ``G/s`` and ``G/s²`` have a pole at 0 right of every singularity of G.
Before the mean, the focus is put there. After it, where ``F`` is close to 1, the parabola with
its focus at 0 would be far narrower than the natural contour of G and pass where ``|G|`` is
huge (``|G| ~ e^{Pe/2}`` near ``s = -Pe/4``); there the polynomial part is taken out,
``G/s = 1/s + (G - 1)/s`` and ``G/s² = (1 - m s)/s² + (G - 1 + m s)/s²`` (m the mean), whose
inverses are ``1`` and ``t - m``, and the remainder, analytic at 0, is inverted on the natural
contour of G (its geometry from the saddle of the non-negative survival ``1 - F`` or its
integral). The vertex is kept half a Gaussian width away from 0, where the remainder loses
digits to cancellation.

**Dead zones (two scales).** A slow exchange zone adds a cluster of singularities at
``s ≈ -k_d``, an essential singularity with poles accumulating at it, far right of the mobile
unit's own (at ``-Pe/(4 tau)`` and beyond). No single parabola resolves both scales. When the
cluster is well separated, G is split exactly, ``G = G_F + G_N``, by its Laurent expansion about
``c = -k_d``: ``G_N = Σ_{n>=1} a_n (s - c)^{-n}`` holds the cluster, ``G_F = G - G_N`` is analytic
there (Cauchy). The coefficients come from G on the circle ``|s - c| = rho/2`` (``rho =
sqrt(β) k_d``), and ``G_F`` near the cluster from its Taylor series on ``|s - c| = 2 rho``; on
these circles ``s'`` stays in the strip ``|Re s' - (β - 1) k_d| <= 1.5 sqrt(β) k_d``, where G
is tame. ``G_F`` is inverted on a parabola of the mobile scale (focus at the mobile unit's
singularity shifted by ``-β k_d``), ``G_N`` on one of the exchange scale, each placed by the
saddle of a non-negative surrogate (``G_unit(s + β k_d)`` and
``G_unit(z_0 - β k_d²/(s + k_d)) - G_unit(z_0)``, see :class:`~.transfer.ExchangeZone`). While
the mobile parabola passes well right of the cluster (early times), G itself is inverted on it.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

DEFAULT_NODES = 32
OFFSET_EXPONENT = 2.3
TRUNCATION_EXPONENT = 40.0
SADDLE_ITERATIONS = 40
# The saddle is searched for in s - focus between these multiples of the rate scale 1/mean.
_BRACKET = 1e-30, 1e30
# Points on each circle of the Laurent/Taylor split, and terms kept of each series: on the
# circles the series are used at ratios of at most 1/2, so 64 terms reach 5e-20.
_CIRCLE_POINTS = 128
_SERIES_TERMS = 64
# The split is used when the rest of the singularities are farther than this many rho from -k_d
# and the cluster itself is within rho / this.
_SEPARATION = 6.0
# Scaled distance (Gaussian widths) from the mobile parabola to the cluster below which G_N is
# inverted on its own contour.
_CLUSTER_CLEARANCE = 3.0


Function = Callable[[jax.Array], jax.Array]


def _cumulant_slopes(log_transform: Function, s: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Return the first two derivatives of ``Re log H`` at real ``s`` (elementwise)."""

    def cumulant(real_s):
        return jnp.real(log_transform(real_s.astype(complex)))

    def slope(real_s):
        return jax.jvp(cumulant, (real_s,), (jnp.ones_like(real_s),))[1]

    return jax.jvp(slope, (s,), (jnp.ones_like(s),))


def _saddle(log_transform: Function, focus, rate, theta):
    """Return ``s* - focus`` and ``Phi''(s*)`` for the saddle of ``s theta + log H(s)``.

    ``theta`` is a positive array, ``focus`` a scalar or an array like it, ``rate`` a scalar.
    Newton's method on ``log(mean(s)) = log(theta)`` in ``x = log(s - focus)`` (nearly linear
    in x: slope -1 near a pole, -1/2 on the dispersion branch), keeping a bracket and bisecting
    whenever a step would leave it, so that plateaus of the tilted mean (slow exchange) cannot
    derail it. Points too close to the focus to be resolved count as left of the saddle.
    """
    nearest = _BRACKET[0] * rate + 1e-13 * jnp.abs(focus)
    lower = jnp.broadcast_to(jnp.log(nearest), theta.shape)
    upper = jnp.full_like(theta, jnp.log(_BRACKET[1] * rate))
    start = jnp.clip(-jnp.log(theta), lower, upper)
    log_theta = jnp.log(theta)

    def iterate(_, state):
        x, low, high = state
        distance = jnp.exp(x)
        first, second = _cumulant_slopes(log_transform, focus + distance)
        valid = (-first > 0) & jnp.isfinite(first) & jnp.isfinite(second)
        mean = jnp.where(valid, -first, 1.0)
        residual = jnp.where(valid, jnp.log(mean) - log_theta, jnp.inf)
        low = jnp.where(residual > 0, x, low)
        high = jnp.where(residual <= 0, x, high)
        slope = -second * distance / mean
        newton = x - residual / jnp.where(slope < 0, slope, -1.0)
        usable = valid & (slope < 0) & (newton > low) & (newton < high) & jnp.isfinite(newton)
        return jnp.where(usable, newton, 0.5 * (low + high)), low, high

    x, _, _ = jax.lax.fori_loop(0, SADDLE_ITERATIONS, iterate, (start, lower, upper))
    distance = jnp.exp(x)
    _, second = _cumulant_slopes(log_transform, focus + distance)
    return distance, jnp.maximum(second, jnp.finfo(float).tiny)


class _Parabola:
    """A saddle-point parabola: focus, ``p = s* - focus``, line ``a`` (all per time)."""

    def __init__(self, focus, distance, curvature, theta):
        self.focus = focus
        self.distance = distance
        self.saddle = focus + distance
        self.width = 1.0 / jnp.sqrt(curvature)  # Gaussian width in s, 1/time unit
        self.gaussian = 2.0 * distance**2 * curvature  # S², in y units
        self.far_field = theta * distance
        self.line = 1.0 + jnp.sqrt(OFFSET_EXPONENT / self.gaussian)

    def vertex(self):
        return self.focus + self.distance * self.line**2

    def move_vertex(self, where, target):
        """Put the vertex at ``target`` (right of the focus) wherever ``where`` holds."""
        line = jnp.sqrt(jnp.maximum(target - self.focus, 0.0) / self.distance)
        self.line = jnp.where(where, line, self.line)

    def move_clear_of(self, where, point, theta):
        """Move the vertex left, where ``where`` holds, away from a removed pole at ``point``.

        The integrand is analytic at ``point`` but as large there as the curve itself, which
        is exponentially larger than on the contour; the trapezoidal error is that size times
        ``exp(-2 pi d / h)``, d the distance in y. The vertex goes to at least three Gaussian
        widths and ``T / t`` left of ``point``, but never more than ``e^5`` costlier than the
        saddle nor so close to the focus that ``a < sqrt(1/2)``.
        """
        wanted = jnp.minimum(
            self.vertex(),
            jnp.minimum(point - 3.0 * self.width, point - TRUNCATION_EXPONENT / theta),
        )
        affordable = jnp.maximum(
            self.saddle - jnp.sqrt(10.0) * self.width, self.focus + 0.5 * self.distance
        )
        self.move_vertex(where, jnp.maximum(wanted, affordable))

    def clearance(self, point):
        """Gaussian widths between the line and a singularity at ``point`` left of the vertex."""
        inside = jnp.sqrt(jnp.maximum(point - self.focus, 0.0) / self.distance)
        return (self.line - inside) * jnp.sqrt(self.gaussian)

    def nodes(self, nodes: int):
        """Return the nodes ``s`` and the weights of ``Re Σ weight e^{s t} H(s)``."""
        height = jnp.sqrt(TRUNCATION_EXPONENT / jnp.minimum(self.gaussian, self.far_field))
        step = height / nodes
        y = step[..., None] * jnp.arange(nodes + 1)
        q = self.line[..., None] + 1j * y
        s = self.focus[..., None] + self.distance[..., None] * q**2
        trapezoid = jnp.ones(nodes + 1).at[0].set(0.5)
        weights = (step / jnp.pi)[..., None] * trapezoid * 2.0 * self.distance[..., None] * q
        return s, weights


def _parabola(log_fixed: Function, focus, rate, theta) -> _Parabola:
    focus = jnp.broadcast_to(focus, theta.shape)
    distance, curvature = _saddle(log_fixed, focus, rate, theta)
    return _Parabola(focus, distance, curvature, theta)


def _log_expm1(ell: jax.Array) -> jax.Array:
    """Return ``log(e^ell - 1)`` for complex ell without overflow (any branch of the log)."""
    large = jnp.real(ell) > 0
    safe_large = jnp.where(large, ell, 1.0)
    safe_small = jnp.where(large, -1.0, ell)
    return jnp.where(
        large,
        safe_large + jnp.log(-jnp.expm1(-safe_large)),
        jnp.log(jnp.expm1(safe_small)),
    )


def _log_remainder(ell: jax.Array, s: jax.Array, slope, power: int) -> jax.Array:
    """Return ``log[(G - 1)/s]`` (power 1) or ``log[(G - 1 - slope s)/s²]`` (power 2).

    ``G = e^ell`` with ``G(0) = 1`` and ``G'(0) = slope``. At real s the real part is the log
    of the transform of ``1 - F`` (power 1) or of ``∫_t^∞ (1 - F)`` (power 2), both
    non-negative functions.
    """
    if power == 1:
        return _log_expm1(ell) - jnp.log(s)
    large = jnp.real(ell) > 0
    safe_large = jnp.where(large, ell, 1.0)
    safe_small = jnp.where(large, -1.0, ell)
    numerator = jnp.where(
        large,
        safe_large + jnp.log(1.0 - (1.0 + slope * s) * jnp.exp(-safe_large)),
        jnp.log(jnp.expm1(safe_small) - slope * s),
    )
    return numerator - 2.0 * jnp.log(s)


def _sum(weights, values):
    return jnp.sum(jnp.real(weights * values), axis=-1)


def _derivatives_at_zero(log_fixed: Function, order: int) -> list[jax.Array]:
    """Return ``d^j log H / ds^j`` at ``s = 0`` for ``j = 0..order`` (real)."""

    def real_log(x):
        return jnp.real(log_fixed(x.astype(complex)))

    values = []
    function = real_log
    for _ in range(order + 1):
        values.append(function(jnp.zeros(())))
        function = (lambda f: lambda x: jax.jvp(f, (x,), (jnp.ones_like(x),))[1])(function)
    return values


def _late_threshold(log_fixed: Function, power: int):
    """Return the mean and the time after which the late form of G/s**power is used.

    The late form's saddle is left of 0 once t exceeds the tilted mean at 0 of ``1 - F``,
    ``E[T²] / (2 E[T])`` (power 1), or of its integral, ``E[T³] / (3 E[T²])`` (power 2).
    """
    _, slope, second, third = _derivatives_at_zero(log_fixed, 3)
    mean, variance, skew = -slope, second, -third
    moment2 = variance + mean**2
    moment3 = skew + 3.0 * mean * variance + mean**3
    tilted = moment2 / (2.0 * mean) if power == 1 else moment3 / (3.0 * moment2)
    return mean, jnp.maximum(mean, tilted)


def _is_sharp(log_fixed: Function, singularity) -> jax.Array:
    """Return whether G grows enough left of 0 for the early form to lose digits late.

    On the narrow parabola of the early form, ``e^{s t} G(s)`` meets values of G far left of 0
    (``G ~ e^{Pe/2}`` near ``-Pe/4`` for the ADM); ``log G(sigma/2) > 8`` marks curves that
    are sharp enough (nearly a delay) for this to matter. Smooth curves keep the early form,
    whose parabola has no removed pole near it.
    """
    return jnp.real(log_fixed(jnp.asarray(0.5 * singularity, complex))) > 8.0


def invert_single(
    log_transfer: Function,
    log_fixed: Function,
    singularity,
    theta,
    power: int,
    nodes: int,
):
    """Return the inverse transform of ``G / s**power`` at positive times ``theta``.

    One saddle-point parabola per time, with the step and ramp treatment described above.
    ``log_transfer`` is ``log G`` (live parameters), ``log_fixed`` the same with its
    parameters held fixed (contour geometry), ``singularity`` the rightmost singularity of G
    (fixed).
    """
    mean, threshold = _late_threshold(log_fixed, max(power, 1))
    rate = 1.0 / mean
    if power == 0:
        parabola = _parabola(log_fixed, singularity, rate, theta)
        s, weights = parabola.nodes(nodes)
        return _sum(weights, jnp.exp(s * theta[..., None] + log_transfer(s)))
    late = (theta >= threshold) & _is_sharp(log_fixed, singularity)

    def geometry(s):
        ell = log_fixed(s)
        early_form = ell - power * jnp.log(s)
        return jnp.where(late, _log_remainder(ell, s, -mean, power), early_form)

    parabola = _parabola(geometry, jnp.where(late, singularity, 0.0), rate, theta)
    parabola.move_clear_of(late, 0.0, theta)
    s, weights = parabola.nodes(nodes)
    ell = log_transfer(s)
    live_slope = _derivatives_at_zero(log_transfer, 1)[1]
    late_form = _log_remainder(ell, s, live_slope, power)
    exponent = s * theta[..., None] + jnp.where(late[..., None], late_form, ell - power * jnp.log(s))
    residue = 1.0 if power == 1 else theta + live_slope
    return _sum(weights, jnp.exp(exponent)) + jnp.where(late, residue, 0.0)


class _Cluster:
    """The exact split ``G = G_F + G_N`` about a dead-zone cluster at ``center``.

    ``G_N(s) = Σ_{n>=1} a_n (s - c)^{-n}`` (the principal part, analytic outside the cluster)
    from G on the circle of radius ``rho/2``; ``G_F = G - G_N`` near the cluster from its Taylor
    series on the circle of radius ``2 rho``. Each series is used only where its ratio is at
    most 1/2, so :data:`_SERIES_TERMS` terms reach ``2^-64``.
    """

    def __init__(self, log_transfer: Function, center, radius):
        self.center = center
        self.radius = radius
        angles = 2.0 * jnp.pi * jnp.arange(_CIRCLE_POINTS) / _CIRCLE_POINTS
        circle = jnp.exp(1j * angles)
        inner = jnp.exp(log_transfer(center + 0.5 * radius * circle))
        outer = jnp.exp(log_transfer(center + 2.0 * radius * circle))
        # Coefficients of u^n, u = (rho/2) / (s - c), n = 1..K, and of v^n, v = (s - c)/(2 rho).
        self.principal = jnp.fft.ifft(inner)[1 : _SERIES_TERMS + 1]
        self.regular = jnp.fft.fft(outer)[:_SERIES_TERMS] / _CIRCLE_POINTS

    def scaled_parts(self, s, exponent_without_g, ell):
        """Return ``e^X G_N(s)`` and ``e^X G_F(s)`` with ``X = exponent_without_g``, ``G = e^ell``."""
        offset = s - self.center
        outside = jnp.abs(offset) >= self.radius
        u = jnp.where(outside, 0.5 * self.radius / jnp.where(outside, offset, 1.0), 0.0)
        v = jnp.where(outside, 0.0, offset / (2.0 * self.radius))
        principal = u * jnp.polyval(self.principal[::-1], u)
        regular = jnp.polyval(self.regular[::-1], v)
        scale = jnp.exp(exponent_without_g)
        full = jnp.exp(exponent_without_g + ell)
        near = jnp.where(outside, scale * principal, full - scale * regular)
        far = jnp.where(outside, full - scale * principal, scale * regular)
        return near, far


def invert_with_dead_zone(
    log_transfer: Function,
    log_fixed: Function,
    far_fixed: Function,
    near_fixed: Function,
    singularity,
    far_singularity,
    near_singularity,
    center,
    radius,
    theta,
    power: int,
    nodes: int,
):
    """Return the inverse transform of ``G / s**power`` for a unit with a dead-zone cluster.

    ``far_fixed`` and ``near_fixed`` are the positive surrogates that place the two contours,
    ``far_singularity`` and ``near_singularity`` their foci, ``center`` (``-k_d``) and
    ``radius`` (``sqrt(β) k_d``) the cluster; all but ``log_transfer`` are held fixed. When the
    cluster is not well separated from the rest (fast exchange, or no dead zone) the single
    contour of :func:`invert_single` is used.
    """
    separated = (
        (radius > 0)
        & (far_singularity < center - _SEPARATION * radius)
        & (near_singularity - center < radius / _SEPARATION)
    )

    def single(_):
        return invert_single(log_transfer, log_fixed, singularity, theta, power, nodes)

    def split(_):
        safe_radius = jnp.where(separated, radius, 1.0)
        return _invert_split(
            log_transfer,
            log_fixed,
            far_fixed,
            near_fixed,
            far_singularity,
            near_singularity,
            center,
            safe_radius,
            theta,
            power,
            nodes,
        )

    return jax.lax.cond(separated, split, single, None)


def _invert_split(
    log_transfer,
    log_fixed,
    far_fixed,
    near_fixed,
    far_singularity,
    near_singularity,
    center,
    radius,
    theta,
    power,
    nodes,
):
    cluster = _Cluster(log_transfer, center, radius)
    far_log0, far_slope = _derivatives_at_zero(far_fixed, 1)
    far_mean, threshold = _late_threshold(far_fixed, max(power, 1))
    column = theta[..., None]
    near_rate = 1.0 / jnp.abs(center)
    if power == 0:
        far = _parabola(far_fixed, far_singularity, 1.0 / far_mean, theta)
        enclosed = (far.vertex() > near_singularity) & (
            far.clearance(near_singularity) >= _CLUSTER_CLEARANCE
        )
        far.move_clear_of(~enclosed, center, theta)
        s, weights = far.nodes(nodes)
        ell = log_transfer(s)
        _, far_part = cluster.scaled_parts(s, s * column, ell)
        whole = jnp.exp(s * column + ell)
        far_value = _sum(weights, jnp.where(enclosed[..., None], whole, far_part))
        near = _parabola(near_fixed, near_singularity, near_rate, theta)
        s, weights = near.nodes(nodes)
        near_part, _ = cluster.scaled_parts(s, s * column, log_transfer(s))
        return far_value + jnp.where(enclosed, 0.0, _sum(weights, near_part))

    late = (theta >= threshold) & _is_sharp(far_fixed, far_singularity)

    def geometry(s):
        early_form = log_fixed(s) - power * jnp.log(s)
        late_form = _log_remainder(far_fixed(s) - far_log0, s, far_slope, power)
        return jnp.where(late, late_form, early_form)

    far = _parabola(geometry, jnp.where(late, far_singularity, 0.0), 1.0 / far_mean, theta)
    far.move_clear_of(late, 0.0, theta)
    enclosed = (far.vertex() > near_singularity) & (
        far.clearance(near_singularity) >= _CLUSTER_CLEARANCE
    )
    far.move_clear_of(late & ~enclosed, center, theta)
    s, weights = far.nodes(nodes)
    ell = log_transfer(s)
    log_s = jnp.log(s)
    early_value = jnp.exp(s * column + ell - power * log_s)
    live_slope = _derivatives_at_zero(log_transfer, 1)[1]
    whole_late = jnp.exp(s * column + _log_remainder(ell, s, live_slope, power))

    def far_transfer(x):
        zero = jnp.zeros_like(x)
        return cluster.scaled_parts(x, zero, log_transfer(x))[1]

    zero = jnp.zeros((), complex)
    far_at_zero, far_slope_at_zero = jax.jvp(far_transfer, (zero,), (jnp.ones((), complex),))
    _, far_part = cluster.scaled_parts(s, s * column, ell)
    polynomial = far_at_zero + (far_slope_at_zero * s if power == 2 else 0.0)
    split_late = (far_part - jnp.exp(s * column) * polynomial) / s**power
    integrand = jnp.where(
        late[..., None], jnp.where(enclosed[..., None], whole_late, split_late), early_value
    )
    value = _sum(weights, integrand)
    whole_residue = 1.0 if power == 1 else theta + live_slope
    split_residue = jnp.real(far_at_zero if power == 1 else far_at_zero * theta + far_slope_at_zero)
    residue = jnp.where(enclosed, whole_residue, split_residue)
    near = _parabola(
        lambda x: near_fixed(x) - power * jnp.log(x), jnp.zeros_like(theta), near_rate, theta
    )
    s, weights = near.nodes(nodes)
    near_part, _ = cluster.scaled_parts(s, s * column, log_transfer(s))
    near_value = _sum(weights, near_part / s**power)
    return value + jnp.where(late, residue + jnp.where(enclosed, 0.0, near_value), 0.0)
