"""Bromwich inversion of the closed–closed transfer function on a vertical line in q.

With time in units of tau, ``q = sqrt(1 + 4 s / Pe)`` and ``s = Pe (q² - 1) / 4``, the
exponent of the Bromwich integrand ``s theta + Pe (1 - q) / 2`` is the quadratic
``phi(q) = (Pe theta / 4) (q - 1/theta)² - Pe (1 - theta)² / (4 theta)`` with its saddle at
``q = 1/theta``. The transfer function (MODELS.md section 2) is even in q and its poles lie on
the imaginary q axis, so the Bromwich line can be any vertical line ``Re q = a > 0``. On
``q = 1/theta + delta + i y`` the integrand is a Gaussian in y times a factor that is analytic
in a strip of half-width ``a``: the trapezoidal rule converges exponentially. Scaling y by
``sqrt(Pe theta) / 2`` makes the rule the same for every Pe and theta, so one fixed number of
nodes serves all of them:

* ``delta = sqrt(4 L / (Pe theta))`` (the line sits ``sqrt(L)`` scaled units right of the
  saddle; it costs a factor ``e^L`` of round-off and keeps the line at least ``sqrt(L)``
  scaled units from every pole),
* the integral is truncated at ``y = sqrt(4 T / (Pe theta))``, where the Gaussian is
  ``e^-T``.

With ``T = 40`` and 24 nodes the step is 0.26 scaled units; the discretisation error
``~exp(-2 pi sqrt(L) / step)`` (about 2e-16) is below round-off. Measured against 48 nodes
over Pe from 1e-3 to 1e5 and theta from 1e-4 to 20: E to 2.4e-15 of its peak, F to 4e-16,
E's Jacobian to 1.4e-12 of each column's largest entry, as 32 nodes; 20 nodes reach 7e-14
and 16 nodes 3e-11.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc

OFFSET_EXPONENT = 2.3
TRUNCATION_EXPONENT = 40.0
DEFAULT_NODES = 24
#: Points per block of a long evaluation (see :func:`closed_closed_curves`): about 50 MB of
#: quadrature arrays per block.
BLOCK = 4096
#: Most points evaluated at once. Up to here a gradient keeps at most about 0.25 GB of
#: quadrature arrays; beyond, blocks bound it, at the price of recomputing each block in the
#: backward pass (a gradient costs about 1.5 times the CPU time).
AT_ONCE = 16 * BLOCK
# Below this exponent, exp(-Pe (1-theta)² / (4 theta)) and E, F underflow in double precision.
_UNDERFLOW_EXPONENT = 1000.0


def exprel(z: jax.Array) -> jax.Array:
    """Return (e^z - 1) / z, equal to 1 at z = 0, for complex z."""
    nonzero = z != 0
    z_safe = jnp.where(nonzero, z, 1.0)
    return jnp.where(nonzero, jnp.expm1(z_safe) / z_safe, 1.0)


def _earliest_nonzero_theta(peclet: jax.Array) -> jax.Array:
    """Return theta below which Pe (1 - theta)² / (4 theta) exceeds the underflow exponent."""
    k = 4.0 * _UNDERFLOW_EXPONENT
    return 2.0 * peclet / ((2.0 * peclet + k) + jnp.sqrt(k * (4.0 * peclet + k)))


def _geometry(theta: jax.Array, peclet: jax.Array, nodes: int):
    """The quadrature line of each theta (a trailing axis of ``nodes + 1`` points), held fixed
    under differentiation: ``(theta, Pe, q, weights, offset, step)``, theta and Pe with that
    axis, and the trapezoidal weights (the step over pi included) of the integral of the real
    part."""
    theta = theta[..., None]
    peclet = jnp.asarray(peclet)[..., None]
    pe_theta = peclet * theta
    # The line geometry is held fixed under differentiation: the integral is the same on every
    # admissible line, so derivatives are the (equally convergent) integrals of derivatives.
    offset = jax.lax.stop_gradient(jnp.sqrt(4.0 * OFFSET_EXPONENT / pe_theta))
    height = jax.lax.stop_gradient(jnp.sqrt(4.0 * TRUNCATION_EXPONENT / pe_theta))
    step = height / nodes
    line = jax.lax.stop_gradient(1.0 / theta + offset)
    q = line + 1j * jnp.arange(nodes + 1) * step
    weights = jnp.ones(nodes + 1).at[0].set(0.5) * step / jnp.pi
    return theta, peclet, q, weights, offset, step


def _phi(theta: jax.Array, peclet: jax.Array, q: jax.Array) -> jax.Array:
    """The exponent ``phi = (Pe theta / 4) (q - 1/theta)² - Pe (1 - theta)² / (4 theta)``
    of the integrand at fixed q (linear in Pe; its theta derivative is ``s = Pe (q² - 1) / 4``)."""
    return 0.25 * peclet * theta * (q - 1.0 / theta) ** 2 - peclet * (1.0 - theta) ** 2 / (
        4.0 * theta)


def _powers(angle: jax.Array, count: int) -> jax.Array:
    """``exp(-i k angle)`` for ``k = 0 … count - 1`` on a trailing axis, by products of the
    binary powers of ``exp(-i angle)`` (no transcendental function per node)."""
    bits = max(1, (count - 1).bit_length())
    k = np.arange(count)
    base = jnp.exp(-1j * angle)
    out = jnp.ones(angle.shape + (count,), complex)
    for b in range(bits):
        out = out * jnp.where(jnp.asarray((k >> b) & 1, bool), base[..., None], 1.0)
        base = base * base
    return out


@partial(jax.custom_jvp, nondiff_argnums=(2,))
def _factors(theta: jax.Array, peclet: jax.Array, nodes: int):
    """``(e^phi, e^{-q Pe} - 1, e^{-q Pe})`` on the line of every theta (trailing axis of
    nodes).

    On the line, ``phi_k = L - T k²/n² + 2 i sqrt(L T) k/n - Pe (1 - theta)² / (4 theta)``
    (L, T the offset and truncation exponents, n the nodes): ``e^phi`` is one real
    exponential a point times a fixed complex array. ``e^{-q Pe} = e^{-Pe Re q} w^k`` with
    ``w = e^{-i Pe dy}``, whose powers are products; ``e^{-q Pe} - 1`` is formed from
    ``expm1`` and the half-angle powers so that it keeps its digits where ``|q Pe|`` is small.
    The same numbers as the complex exponentials to round-off (E and its two slopes on 40
    points: 46 µs against 90 µs with the exponentials, measured on one CPU core); the
    derivatives (a custom JVP, at fixed q) are those of the exponentials, to every order.
    """
    theta_n, peclet_n, q, _, _, step = _geometry(theta, peclet, nodes)
    k = np.arange(nodes + 1)
    fixed = np.exp(-TRUNCATION_EXPONENT * (k / nodes) ** 2
                   + 2j * math.sqrt(OFFSET_EXPONENT * TRUNCATION_EXPONENT) * k / nodes)
    level = OFFSET_EXPONENT - peclet_n * (1.0 - theta_n) ** 2 / (4.0 * theta_n)
    growth = jnp.exp(level) * fixed
    half = _powers(0.5 * peclet * step[..., 0], nodes + 1)
    sine, cosine = -half.imag, half.real
    rotated_change = -2.0 * sine**2 - 2j * sine * cosine  # e^{-i Pe y} - 1
    decay_change = jnp.expm1(-peclet_n * q.real)  # e^{-Pe Re q} - 1 (real)
    change = decay_change * (1.0 + rotated_change) + rotated_change
    # e^{-q Pe} itself, to its own relative precision where it is tiny (large Pe).
    decay = jnp.exp(-peclet_n * q.real) * half * half
    return growth, change, decay


@_factors.defjvp
def _factors_jvp(nodes, primals, tangents):
    theta, peclet = primals
    theta_dot, peclet_dot = tangents
    growth, change, decay = _factors(theta, peclet, nodes)
    theta_n, peclet_n, q, *_ = _geometry(theta, peclet, nodes)
    phi = _phi(theta_n, peclet_n, q)
    slope = 0.25 * peclet_n * (q * q - 1.0)
    growth_dot = growth * (slope * theta_dot[..., None] + phi / peclet_n * peclet_dot[..., None])
    decay_dot = -q * decay * peclet_dot[..., None]
    return (growth, change, decay), (growth_dot, decay_dot, decay_dot)


def _line_integrals(theta: jax.Array, peclet: jax.Array, nodes: int):
    """Return E(theta) and F(theta) for theta above the underflow limit (elementwise)."""
    growth, change, _ = _factors(theta, peclet, nodes)
    theta, peclet, q, weights, _, _ = _geometry(theta, peclet, nodes)
    # Overflow-safe denominator: (1+q)² - (1-q)² e^{-q Pe} = q (4 + Pe (1-q)² exprel(-q Pe)).
    relative_growth = change / (-q * peclet)
    denominator = 4.0 + peclet * (1.0 - q) ** 2 * relative_growth
    exit_age_integrand = growth * 2.0 * peclet * q / denominator
    # F: the pole of G/s at q = 1 is removed by subtracting e^phi / (q - 1), whose line integral
    # is erfc(sqrt(Pe/theta) (1 - theta) / 2) / 2; what remains is analytic there.
    step_integrand = (
        growth * (4.0 + (1.0 - q**2) * peclet * relative_growth) / ((1.0 + q) * denominator)
    )
    exit_age = jnp.sum(weights * exit_age_integrand.real, axis=-1)
    theta = theta[..., 0]
    peclet = peclet[..., 0]
    plug_flow = 0.5 * erfc(0.5 * jnp.sqrt(peclet / theta) * (1.0 - theta))
    step_response = plug_flow + jnp.sum(weights * step_integrand.real, axis=-1)
    return exit_age, step_response


def _exit_age_slopes(theta: jax.Array, peclet: jax.Array, nodes: int):
    """Return E(theta) and its derivatives in theta and Pe above the underflow limit.

    On the (fixed) line the exit-age integrand is ``f = 2 Pe q e^phi / D`` with
    ``phi = s theta + Pe (1 - q) / 2``, ``s = Pe (q² - 1) / 4`` and
    ``D = 4 + (1 - q)² (1 - e^{-q Pe}) / q`` (the denominator of :func:`_line_integrals`,
    ``Pe exprel(-q Pe) = (1 - e^{-q Pe}) / q``); at fixed q, ``df/dtheta = s f`` and
    ``df/dPe = f ((1 + phi) / Pe - (1 - q)² e^{-q Pe} / D)`` (phi is linear in Pe), so the two
    derivatives are two more sums over the same nodes: no tangent is carried through the
    complex arithmetic.
    """
    growth, change, decay = _factors(theta, peclet, nodes)
    theta, peclet, q, weights, _, _ = _geometry(theta, peclet, nodes)
    phi = _phi(theta, peclet, q)
    squared = (1.0 - q) ** 2
    # 1 / (4 - (1 - q)² change / q) = q / d with d = 4 q - (1 - q)² change, as q conj(d) / |d|²
    # (one real division; |d| stays far from overflow on every line).
    denominator = 4.0 * q - squared * change
    reciprocal = q * jnp.conj(denominator) / (denominator.real**2 + denominator.imag**2)
    integrand = growth * (2.0 * peclet) * q * reciprocal
    by_theta = integrand * (0.25 * peclet * (q * q - 1.0))
    by_peclet = integrand * ((1.0 + phi) / peclet - squared * decay * reciprocal)
    return tuple(jnp.sum(weights * part.real, axis=-1)
                 for part in (integrand, by_theta, by_peclet))


def _exit_age_parts(theta: jax.Array, peclet: jax.Array, nodes: int):
    """E, dE/dtheta and dE/dPe at equally shaped theta and Pe, zero below the underflow
    limit; in blocks of :data:`BLOCK` beyond :data:`AT_ONCE` points."""
    size = theta.size

    def parts(theta, peclet):
        nonzero = theta > _earliest_nonzero_theta(peclet)
        theta_safe = jnp.where(nonzero, theta, 1.0)
        return tuple(jnp.where(nonzero, part, 0.0)
                     for part in _exit_age_slopes(theta_safe, peclet, nodes))

    if size <= AT_ONCE:
        return parts(theta, peclet)
    blocks = -(-size // BLOCK)
    padding = blocks * BLOCK - size
    flat_theta = jnp.pad(theta.reshape(-1), (0, padding), constant_values=1.0)
    flat_peclet = jnp.pad(peclet.reshape(-1), (0, padding), mode="edge")
    results = jax.lax.map(jax.checkpoint(lambda pair: parts(*pair)),
                          (flat_theta.reshape(blocks, BLOCK),
                           flat_peclet.reshape(blocks, BLOCK)))
    return tuple(r.reshape(-1)[:size].reshape(theta.shape) for r in results)


@partial(jax.custom_jvp, nondiff_argnums=(2,))
def _exit_age(theta: jax.Array, peclet: jax.Array, nodes: int) -> jax.Array:
    return _exit_age_parts(theta, peclet, nodes)[0]


@_exit_age.defjvp
def _exit_age_jvp(nodes, primals, tangents):
    theta, peclet = primals
    theta_dot, peclet_dot = tangents
    value, by_theta, by_peclet = _exit_age_parts(theta, peclet, nodes)
    return value, by_theta * theta_dot + by_peclet * peclet_dot


@partial(jax.jit, static_argnames="nodes")
def closed_closed_exit_age(theta: jax.Array, peclet: jax.Array,
                           nodes: int = DEFAULT_NODES) -> jax.Array:
    """Return the closed–closed E(theta) (dimensionless time), zero for theta <= 0.

    The same quadrature as the E of :func:`closed_closed_curves`, with its derivatives in
    theta and Pe summed on the same nodes (a custom JVP): a Jacobian costs about one more
    evaluation, not one per direction, and gradients keep three arrays of the points' size
    instead of the quadrature's. Higher derivatives differentiate those sums.
    """
    theta, peclet = jnp.broadcast_arrays(jnp.asarray(theta, float), jnp.asarray(peclet, float))
    return _exit_age(theta, peclet, nodes)


def _curves(theta: jax.Array, peclet: jax.Array, nodes: int) -> tuple[jax.Array, jax.Array]:
    """E and F at equally shaped theta and Pe, zero below the underflow limit."""
    nonzero = theta > _earliest_nonzero_theta(peclet)
    theta_safe = jnp.where(nonzero, theta, 1.0)
    exit_age, step_response = _line_integrals(theta_safe, peclet, nodes)
    return jnp.where(nonzero, exit_age, 0.0), jnp.where(nonzero, step_response, 0.0)


@partial(jax.jit, static_argnames="nodes")
def closed_closed_curves(
    theta: jax.Array, peclet: jax.Array, nodes: int = DEFAULT_NODES
) -> tuple[jax.Array, jax.Array]:
    """Return the closed–closed E(theta) and F(theta) (dimensionless time), zero for theta <= 0.

    The quadrature holds about twenty ``(points, nodes + 1)`` complex arrays, which reverse-mode
    differentiation keeps: 0.5 GB each for a million points. More than :data:`AT_ONCE` points
    are therefore evaluated in blocks of :data:`BLOCK` (``lax.map``), each block
    rematerialised in the backward pass (``jax.checkpoint``), so memory stays that of one
    block plus the results, at any number of points, with the same values.
    """
    theta, peclet = jnp.broadcast_arrays(jnp.asarray(theta, float), jnp.asarray(peclet, float))
    size = theta.size
    if size <= AT_ONCE:
        return _curves(theta, peclet, nodes)
    blocks = -(-size // BLOCK)
    padding = blocks * BLOCK - size
    # Padded with theta = 1 (inside the valid range), cut off again below.
    flat_theta = jnp.pad(theta.reshape(-1), (0, padding), constant_values=1.0)
    flat_peclet = jnp.pad(peclet.reshape(-1), (0, padding), mode="edge")

    @jax.checkpoint
    def block(pair):
        return _curves(pair[0], pair[1], nodes)

    exit_age, step_response = jax.lax.map(
        block, (flat_theta.reshape(blocks, BLOCK), flat_peclet.reshape(blocks, BLOCK))
    )
    return (exit_age.reshape(-1)[:size].reshape(theta.shape),
            step_response.reshape(-1)[:size].reshape(theta.shape))
