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

from axialmix.analytic._complex import log_expm1

DEFAULT_NODES = 32
OFFSET_EXPONENT = 2.3
TRUNCATION_EXPONENT = 40.0
SADDLE_ITERATIONS = 60
_SADDLE_TOLERANCE = 1e-3
# Taylor coefficients at 0 are taken on a circle of this fraction of the distance to the focus.
_TAYLOR_RADIUS = 0.3
_THRESHOLD_MARGIN = 1.05
# The saddle is searched for in s - focus between these multiples of the rate scale 1/mean.
_BRACKET = 1e-30, 1e30
# Points on each circle of the Laurent/Taylor split, and terms kept of each series: the series
# are used at ratios of at most 2/3, so 96 terms reach 1e-17.
_CIRCLE_POINTS = 192
_SERIES_TERMS = 96
# Radii of the two circles relative to rho = sqrt(β) k_d: on |s + k_d| = r rho the mobile variable
# s' keeps |Re s' - (β - 1) k_d| <= |r - 1/r| sqrt(β) k_d (0.83 sqrt(β) k_d here).
_CIRCLE_RATIO = 1.5
# The split is used when the rest of the singularities are farther than this many rho from -k_d
# and the cluster itself is within rho / this.
_SEPARATION = 3.0
# Largest cost (log of the rounding the split adds, relative to the curve; see
# invert_with_dead_zone) for which the split is used.
_CIRCLE_SIZE = 12.0
# Scaled distance (Gaussian widths) from the mobile parabola to the cluster below which G_N is
# inverted on its own contour.
_CLUSTER_CLEARANCE = 3.0


Function = Callable[[jax.Array], jax.Array]


def _cumulant_slopes(log_transform: Function, s: jax.Array, reach: jax.Array):
    """Return the first two derivatives of ``Re log H`` at real ``s`` (elementwise).

    H is real and analytic near the real axis right of its focus, so with ``K = log H`` and a
    step ``r`` up the imaginary axis, ``Im K(s + i r) / r`` and ``2 Re[K(s) - K(s + i r)] / r²``
    are K' and K'' up to ``O(r²)``; one Richardson step with ``2 r`` makes that ``O(r⁴)``. The
    step is a tenth of ``reach`` (the distance to the focus), inside the disc where K is
    analytic, which gives the 1e-4 relative accuracy the contour geometry needs. This costs
    three evaluations of H in one vectorised call instead of nested differentiation, which
    would multiply the size of the compiled program.
    """
    step = 0.1 * reach
    points = s[..., None] + jnp.array([0.0, 1.0, 2.0]) * 1j * step[..., None]
    values = log_transform(points)
    base, near, far = values[..., 0], values[..., 1], values[..., 2]
    first_near = jnp.imag(near - base) / step
    first_far = jnp.imag(far - base) / (2.0 * step)
    second_near = 2.0 * jnp.real(base - near) / step**2
    second_far = 2.0 * jnp.real(base - far) / (2.0 * step) ** 2
    return (4.0 * first_near - first_far) / 3.0, (4.0 * second_near - second_far) / 3.0


def _saddle(log_transform: Function, focus, rate, theta):
    """Return ``s* - focus`` and ``Phi''(s*)`` for the saddle of ``s theta + log H(s)``.

    ``theta`` is a positive array, ``focus`` an array like it, ``rate`` a scalar. Newton's
    method on ``log(mean(s)) = log(theta)`` in ``x = log(s - focus)`` (nearly linear in x:
    slope -1 near a pole, -1/2 on the dispersion branch), keeping a bracket and bisecting
    whenever a step would leave it, so that plateaus of the tilted mean (slow exchange) cannot
    derail it; it stops when every step is below 1e-3 in x. Points too close to the focus to
    be resolved count as left of the saddle.
    """
    nearest = _BRACKET[0] * rate + 1e-13 * jnp.abs(focus)
    lower = jnp.broadcast_to(jnp.log(nearest), theta.shape)
    upper = jnp.full_like(theta, jnp.log(_BRACKET[1] * rate))
    start = jnp.clip(-jnp.log(theta), lower, upper)
    log_theta = jnp.log(theta)

    def iterate(state):
        count, x, low, high, _, _ = state
        distance = jnp.exp(x)
        first, second = _cumulant_slopes(log_transform, focus + distance, distance)
        valid = (-first > 0) & jnp.isfinite(first) & jnp.isfinite(second)
        mean = jnp.where(valid, -first, 1.0)
        residual = jnp.where(valid, jnp.log(mean) - log_theta, jnp.inf)
        low = jnp.where(residual > 0, x, low)
        high = jnp.where(residual <= 0, x, high)
        slope = -second * distance / mean
        newton = x - residual / jnp.where(slope < 0, slope, -1.0)
        usable = valid & (slope < 0) & (newton > low) & (newton < high) & jnp.isfinite(newton)
        following = jnp.where(usable, newton, 0.5 * (low + high))
        return count + 1, following, low, high, jnp.max(jnp.abs(following - x)), second

    def unfinished(state):
        count, _, _, _, change, _ = state
        return (count < SADDLE_ITERATIONS) & (change > _SADDLE_TOLERANCE)

    initial = (0, start, lower, upper, jnp.inf, jnp.ones_like(theta))
    _, x, _, _, _, second = jax.lax.while_loop(unfinished, iterate, initial)
    # The curvature of the last iterate, which is within 1e-3 in x of the returned point.
    return jnp.exp(x), second


class _Parabola:
    """A saddle-point parabola: focus, ``p = s* - focus``, line ``a`` (all per time)."""

    def __init__(self, focus, distance, curvature, theta):
        # A curvature lost to rounding (far tails where the transform is nearly flat) falls
        # back to that of a simple pole at the focus.
        usable = jnp.isfinite(curvature) & (curvature > jnp.finfo(float).tiny)
        curvature = jnp.where(usable, curvature, 1.0 / distance**2)
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
        theta = jax.lax.stop_gradient(theta)
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
    """Return the saddle-point parabola at times ``theta`` (held fixed: geometry only)."""
    theta = jax.lax.stop_gradient(theta)
    focus = jnp.broadcast_to(focus, theta.shape)
    distance, curvature = _saddle(log_fixed, focus, rate, theta)
    return _Parabola(focus, distance, curvature, theta)


def _log_remainder(ell: jax.Array, s: jax.Array, slope, power: int) -> jax.Array:
    """Return ``log[(G - 1)/s]`` (power 1) or ``log[(G - 1 - slope s)/s²]`` (power 2).

    ``G = e^ell`` with ``G(0) = 1`` and ``G'(0) = slope``. At real s the real part is the log
    of the transform of ``1 - F`` (power 1) or of ``∫_t^∞ (1 - F)`` (power 2), both
    non-negative functions.
    """
    if power == 1:
        # log(G - 1): where |G| < 1 (real s > 0) as log(1 - G) - i pi, the lower side of the
        # branch cut, which is where the principal log puts G - 1 just above the real axis;
        # on the real axis itself the principal log may give +pi (by the sign of a zero), and
        # the complex-step slopes of the saddle search saw a jump of 2 pi (a dead zone whose
        # late-form saddle lies right of 0 got a wrong contour and lost every digit).
        inside = jnp.real(ell) < 0
        safe_inside = jnp.where(inside, ell, -1.0)
        safe_outside = jnp.where(inside, 1.0, ell)
        below = jnp.log(-jnp.expm1(safe_inside)) - 1j * jnp.pi
        return jnp.where(inside, below, log_expm1(safe_outside)) - jnp.log(s)
    large = jnp.real(ell) > 0
    safe_large = jnp.where(large, ell, 1.0)
    safe_small = jnp.where(large, -1.0, ell)
    numerator = jnp.where(
        large,
        safe_large + jnp.log(1.0 - (1.0 + slope * s) * jnp.exp(-safe_large)),
        jnp.log(jnp.expm1(safe_small) - slope * s),
    )
    return numerator - 2.0 * jnp.log(s)


def _exp(exponent: jax.Array) -> jax.Array:
    """Return ``e^exponent`` with the real part capped at 700.

    Every form of the integrand is evaluated at every node and the right one selected per
    time; capping keeps the others finite, so that their zero cotangents do not turn into NaN
    (0 × inf) in reverse-mode derivatives. The selected form never comes near the cap.
    """
    return jnp.exp(jnp.minimum(jnp.real(exponent), 700.0) + 1j * jnp.imag(exponent))


def _sum(weights, values):
    return jnp.sum(jnp.real(weights * values), axis=-1)


def _late_form_switch(log_fixed: Function, singularity, power: int):
    """Return the log of H(0), its slope, the mean, the time after which the late form of
    ``H/s**power`` is used, and whether H is sharp enough to need it (H need not be normalised).

    The moments come from the Taylor coefficients at 0, by the trapezoidal rule for the Cauchy
    integral on ``|s| = 0.3 |sigma|`` (16 points, aliasing ``0.3^13``). The late form's saddle
    is left of 0 once t exceeds the tilted mean at 0 of ``1 - F``, ``E[T²] / (2 E[T])``
    (power 1), or of its integral, ``E[T³] / (3 E[T²])`` (power 2); the threshold has a 5 %
    margin. On the narrow parabola of the early form, ``e^{s t} G(s)`` meets values of G far
    left of 0 (``G ~ e^{Pe/2}`` near ``-Pe/4`` for the ADM); ``log G(sigma/2) > 8`` marks
    curves sharp enough (nearly a delay) for that to matter; smooth ones keep the early form.
    One vectorised evaluation of H serves both.
    """
    points = 16
    radius = _TAYLOR_RADIUS * jnp.abs(singularity)
    circle = radius * jnp.exp(2j * jnp.pi * jnp.arange(points) / points)
    values = log_fixed(jnp.concatenate([circle, jnp.reshape(0.5 * singularity, (1,))]))
    coefficients = jnp.real(jnp.fft.fft(values[:points]) / points)
    log_at_zero = coefficients[0]
    slope = coefficients[1] / radius
    variance = 2.0 * coefficients[2] / radius**2
    skew = -6.0 * coefficients[3] / radius**3
    mean = -slope
    moment2 = variance + mean**2
    moment3 = skew + 3.0 * mean * variance + mean**3
    tilted = moment2 / (2.0 * mean) if power == 1 else moment3 / (3.0 * moment2)
    threshold = _THRESHOLD_MARGIN * jnp.maximum(mean, tilted)
    sharp = jnp.real(values[points]) > 8.0
    return log_at_zero, slope, mean, threshold, sharp


def _per_point(flag: jax.Array, like: jax.Array) -> jax.Array:
    """Return a per-time flag shaped to broadcast against ``like`` (extra trailing axes)."""
    return flag.reshape(flag.shape + (1,) * (like.ndim - flag.ndim))


def invert_single(
    log_transfer: Function,
    log_fixed: Function,
    singularity,
    mean,
    theta,
    power: int,
    nodes: int,
):
    """Return the inverse transform of ``G / s**power`` at positive times ``theta``.

    One saddle-point parabola per time, with the step and ramp treatment described above.
    ``log_transfer`` is ``log G`` and ``mean`` its mean (live parameters), ``log_fixed`` the
    same function with its parameters held fixed and ``singularity`` its rightmost
    singularity (both place the contour).
    """
    if power == 0:
        parabola = _parabola(log_fixed, singularity, 1.0 / jax.lax.stop_gradient(mean), theta)
        s, weights = parabola.nodes(nodes)
        return _sum(weights, _exp(s * theta[..., None] + log_transfer(s)))
    _, _, fixed_mean, threshold, sharp = _late_form_switch(log_fixed, singularity, power)
    late = (theta >= threshold) & sharp

    def geometry(s):
        ell = log_fixed(s)
        early_form = ell - power * jnp.log(s)
        late_form = _log_remainder(ell, s, -fixed_mean, power)
        return jnp.where(_per_point(late, s), late_form, early_form)

    parabola = _parabola(geometry, jnp.where(late, singularity, 0.0), 1.0 / fixed_mean, theta)
    parabola.move_clear_of(late, 0.0, theta)
    s, weights = parabola.nodes(nodes)
    ell = log_transfer(s)
    late_form = _log_remainder(ell, s, -mean, power)
    exponent = s * theta[..., None] + jnp.where(
        late[..., None], late_form, ell - power * jnp.log(s)
    )
    residue = 1.0 if power == 1 else theta - mean
    return _sum(weights, _exp(exponent)) + jnp.where(late, residue, 0.0)


class _Cluster:
    """The exact split ``G = G_F + G_N`` about a dead-zone cluster at ``center``.

    ``G_N(s) = Σ_{n>=1} a_n (s - c)^{-n}`` (the principal part, analytic outside the cluster)
    comes from G on the circle of radius ``rho / r``, ``G_F = G - G_N`` near the cluster from
    its Taylor series on the circle of radius ``r rho`` (r = :data:`_CIRCLE_RATIO`). Each
    series is used only where its ratio is at most ``1/r``.
    """

    def __init__(self, center, radius):
        self.center = center
        self.radius = radius
        circle = jnp.exp(2j * jnp.pi * jnp.arange(_CIRCLE_POINTS) / _CIRCLE_POINTS)
        self.points = jnp.concatenate(
            [center + radius / _CIRCLE_RATIO * circle, center + radius * _CIRCLE_RATIO * circle]
        )

    def expand(self, log_values):
        """Take ``log G`` at :attr:`points` and form the two series' coefficients.

        Coefficients of ``u^n``, ``u = (rho/r) / (s - c)``, n = 1..K, and of ``v^n``,
        ``v = (s - c) / (r rho)``, n = 0..K-1.
        """
        inner, outer = jnp.split(_exp(log_values), 2)
        self.principal = jnp.fft.ifft(inner)[1 : _SERIES_TERMS + 1]
        self.regular = jnp.fft.fft(outer)[:_SERIES_TERMS] / _CIRCLE_POINTS

    def _series(self, s):
        """Return whether s is outside, the principal part there, the regular part inside, and
        their derivatives in s (for the Taylor polynomial at 0)."""
        offset = s - self.center
        outside = jnp.abs(offset) >= self.radius
        safe_offset = jnp.where(outside, offset, 1.0)
        u = jnp.where(outside, self.radius / _CIRCLE_RATIO / safe_offset, 0.0)
        v = jnp.where(outside, 0.0, offset / (_CIRCLE_RATIO * self.radius))
        powers = jnp.arange(1, _SERIES_TERMS + 1)
        principal = u * jnp.polyval(self.principal[::-1], u)
        principal_slope = -jnp.polyval((powers * self.principal)[::-1], u) * u / safe_offset
        regular = jnp.polyval(self.regular[::-1], v)
        regular_slope = jnp.polyval((powers[:-1] * self.regular[1:])[::-1], v) / (
            _CIRCLE_RATIO * self.radius
        )
        return outside, principal, principal_slope, regular, regular_slope

    def scaled_parts(self, s, exponent_without_g, ell):
        """Return ``e^X G_N(s)`` and ``e^X G_F(s)``, ``X = exponent_without_g``, ``G = e^ell``."""
        outside, principal, _, regular, _ = self._series(s)
        scale = _exp(exponent_without_g)
        full = _exp(exponent_without_g + ell)
        near = jnp.where(outside, scale * principal, full - scale * regular)
        far = jnp.where(outside, full - scale * principal, scale * regular)
        return near, far

    def far_at_zero(self, mean):
        """Return ``G_F(0)`` and ``G_F'(0)``, given ``G(0) = 1`` and ``G'(0) = -mean``."""
        outside, principal, principal_slope, regular, regular_slope = self._series(
            jnp.zeros((), complex)
        )
        value = jnp.where(outside, 1.0 - principal, regular)
        slope = jnp.where(outside, -mean - principal_slope, regular_slope)
        return jnp.real(value), jnp.real(slope)


def invert_with_dead_zone(
    log_transfer: Function,
    surrogate_fixed,
    near_fixed: Function,
    singularity,
    far_singularity,
    near_singularity,
    center,
    radius,
    mean,
    theta,
    power: int,
    nodes: int,
):
    """Return the inverse transform of ``G / s**power`` for a unit with a dead-zone cluster.

    ``surrogate_fixed(s, far)`` is ``log G`` with its parameters held fixed, or where ``far``
    holds the positive surrogate without the cluster (focus ``far_singularity``);
    ``near_fixed`` is the positive surrogate of the cluster (focus ``near_singularity``);
    ``center`` (``-k_d``) and ``radius`` (``sqrt(β) k_d``) locate the cluster. All but
    ``log_transfer`` and ``mean`` are held fixed. When the cluster is not well separated from
    the rest (fast exchange, or no dead zone), or G is large on the split's circles, G is
    inverted whole on the contour of :func:`invert_single` (the same program, with the
    cluster's contour masked out).
    """
    safe_radius = jnp.where(radius > 0, radius, 1.0)
    cluster = _Cluster(center, safe_radius)
    fixed_mean = jax.lax.stop_gradient(mean)
    # The split's coefficients carry rounding of the size of G on its circles, e^{circle_size}
    # (s' near (β-1) k_d ± 0.83 sqrt(β) k_d, where G ~ e^{|s'| tau}); beyond a cost of e^12
    # the single contour is taken. In E that error is multiplied by |e^{s t}| near the
    # cluster, at most e^{(c + r rho) t} (c + r rho < 0 for a small dead zone), and the split
    # is used from about the mean on: so the cost is circle_size - |c + r rho| mean. The step
    # and ramp forms also take G_F(0) from the principal part, whose error e^{s t} does not
    # damp: their cost is circle_size.
    circle_size = jnp.max(jnp.real(surrogate_fixed(cluster.points, False)))
    damping = jnp.minimum(center + _CIRCLE_RATIO * safe_radius, 0.0) * fixed_mean
    split_cost = circle_size + (damping if power == 0 else 0.0)
    separated = (
        (radius > 0)
        & (far_singularity < center - _SEPARATION * safe_radius)
        & (near_singularity - center < safe_radius / _SEPARATION)
        & (split_cost < _CIRCLE_SIZE)
    )
    focus = jnp.where(separated, far_singularity, singularity)
    column = theta[..., None]
    near_rate = 1.0 / jnp.abs(center)

    def split_here(parabola):
        """Where the mobile parabola does not pass well right of the cluster."""
        passes_right = (parabola.vertex() > near_singularity) & (
            parabola.clearance(near_singularity) >= _CLUSTER_CLEARANCE
        )
        return separated & ~passes_right

    def evaluate(*node_sets):
        """log G (live) at the circles and at every node set, in one vectorised call."""
        flat = [nodes_.reshape(-1) for nodes_ in node_sets]
        values = log_transfer(jnp.concatenate([cluster.points, *flat]))
        cluster.expand(values[: cluster.points.size])
        out, start = [], cluster.points.size
        for nodes_ in node_sets:
            out.append(values[start : start + nodes_.size].reshape(nodes_.shape))
            start += nodes_.size
        return out

    if power == 0:
        far = _parabola(lambda x: surrogate_fixed(x, separated), focus, 1.0 / fixed_mean, theta)
        split = split_here(far)
        far.move_clear_of(split, center, theta)
        near = _parabola(near_fixed, jnp.where(separated, near_singularity, 0.0), near_rate, theta)
        far_s, far_weights = far.nodes(nodes)
        near_s, near_weights = near.nodes(nodes)
        far_ell, near_ell = evaluate(far_s, near_s)
        _, far_part = cluster.scaled_parts(far_s, far_s * column, far_ell)
        whole = _exp(far_s * column + far_ell)
        far_value = _sum(far_weights, jnp.where(split[..., None], far_part, whole))
        near_part, _ = cluster.scaled_parts(near_s, near_s * column, near_ell)
        return far_value + jnp.where(split, _sum(near_weights, near_part), 0.0)

    # Steps and ramps: before the mobile mean, G/s**power on one contour with its focus at 0
    # (the cluster is left of it); after it, the removed-pole form, split or not.
    mobile_log0, mobile_slope, mobile_mean, threshold, sharp = _late_form_switch(
        lambda x: surrogate_fixed(x, separated), focus, power
    )
    late = (theta >= threshold) & sharp

    def geometry(x):
        late_here = _per_point(late, x)
        ell = surrogate_fixed(x, late_here & separated)
        late_form = _log_remainder(ell - mobile_log0, x, mobile_slope, power)
        return jnp.where(late_here, late_form, ell - power * jnp.log(x))

    far = _parabola(geometry, jnp.where(late, focus, 0.0), 1.0 / mobile_mean, theta)
    far.move_clear_of(late, 0.0, theta)
    split = late & split_here(far)
    far.move_clear_of(split, center, theta)
    near = _parabola(
        lambda x: near_fixed(x) - power * jnp.log(x), jnp.zeros_like(theta), near_rate, theta
    )
    far_s, far_weights = far.nodes(nodes)
    near_s, near_weights = near.nodes(nodes)
    far_ell, near_ell = evaluate(far_s, near_s)
    early_value = _exp(far_s * column + far_ell - power * jnp.log(far_s))
    whole_late = _exp(far_s * column + _log_remainder(far_ell, far_s, -mean, power))
    far_at_zero, far_slope_at_zero = cluster.far_at_zero(mean)
    _, far_part = cluster.scaled_parts(far_s, far_s * column, far_ell)
    polynomial = far_at_zero + (far_slope_at_zero * far_s if power == 2 else 0.0)
    split_late = (far_part - _exp(far_s * column) * polynomial) / far_s**power
    integrand = jnp.where(
        late[..., None], jnp.where(split[..., None], split_late, whole_late), early_value
    )
    value = _sum(far_weights, integrand)
    whole_residue = 1.0 if power == 1 else theta - mean
    split_residue = far_at_zero if power == 1 else far_at_zero * theta + far_slope_at_zero
    residue = jnp.where(split, split_residue, whole_residue)
    near_part, _ = cluster.scaled_parts(near_s, near_s * column, near_ell)
    near_value = _sum(near_weights, near_part / near_s**power)
    return value + jnp.where(late, residue + jnp.where(split, near_value, 0.0), 0.0)
