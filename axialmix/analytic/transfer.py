"""Transfer functions of mixing units, their dead-zone variants and their series (MODELS.md §2, §6).

A unit is a small frozen ``equinox.Module`` holding its parameters (JAX arrays or numbers, so a
unit is a pytree: ``jit``, ``grad`` and ``vmap`` pass through it). Every unit gives

* ``log_transfer(s)``: ``log G(s)`` for complex ``s`` in 1/(time unit), evaluated in an
  overflow-safe form (``G = ∫ E(t) e^{-s t} dt``, ``G(0) = 1``);
* ``rightmost_singularity()``: the real ``sigma <= 0`` such that G is analytic off
  ``(-inf, sigma]``, which is where :mod:`axialmix.analytic._laplace` puts the focus of its
  contours;
* ``mean()`` and ``variance()``: exact moments of E, from the Taylor series of
  ``log G(s) = -mean s + variance s²/2 + O(s³)``.

Times are in any one unit shared by all parameters (``tau``, time constants, 1/rates).
:func:`axialmix.analytic.exit_age`, :func:`~axialmix.analytic.step_response`,
:func:`~axialmix.analytic.ramp_response` and :func:`~axialmix.analytic.inlet_response` invert
any unit.

**Why every singularity is real and non-positive.** The closed–closed ADM transfer function is
even in ``q = sqrt(1 + 4 s tau / Pe)``, hence meromorphic in s, with poles only at the
eigenvalues ``s = -(4 λ_n² + Pe²) / (4 Pe tau) < -Pe / (4 tau)`` (MODELS.md §2); the open–open
one has a branch point at ``s = -Pe / (4 tau)``; tanks have theirs at ``s = -n / tau``. The
dead-zone substitution ``s' = s (1 + β k_d / (s + k_d))`` has

    Im s' = Im s · (1 + β k_d² / |s + k_d|²),
    Re s' = Re s + β k_d (|s|² + k_d Re s) / |s + k_d|²,

so ``s'`` is real only where ``s`` is real (or ``s = -k_d``, an essential singularity), and
``s' >= 0`` for real ``s >= 0``: the singularities of ``G(s')`` are again real and negative.
On ``(-k_d, 0)`` the map ``s -> s'`` increases from ``-inf`` to 0, so the rightmost
singularity is the root there of ``s' = sigma_inner``; all the others (the images of the inner
singularities, accumulating at ``-k_d``, and ``-k_d`` itself) lie to its left. Products of
such functions (units in series) keep the property.
"""

from __future__ import annotations

import abc
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from axialmix._validation import concrete_value, require_finite, require_positive
from axialmix.analytic._complex import log_expm1
from axialmix.analytic.closed import variance_ratio_closed

__all__ = [
    "ClosedClosedADM",
    "ExchangeZone",
    "OpenOpenADM",
    "Series",
    "StirredTank",
    "TanksInSeries",
    "TransferFunction",
]

_LOG_FOUR = math.log(4.0)
_LOG_TWO = math.log(2.0)
# Taylor coefficients of sinh(x)/x and cosh(x) in x²; 10 terms reach 1e-17 for |x²| < 1.
_SINH_RATIO_COEFFICIENTS = tuple(1.0 / math.factorial(2 * n + 1) for n in range(10))
_COSH_COEFFICIENTS = tuple(1.0 / math.factorial(2 * n) for n in range(10))


def _sinh_ratio_and_cosh(x_squared: jax.Array) -> tuple[jax.Array, jax.Array]:
    sinh_ratio = jnp.zeros_like(x_squared)
    cosh = jnp.zeros_like(x_squared)
    for a, b in zip(_SINH_RATIO_COEFFICIENTS[::-1], _COSH_COEFFICIENTS[::-1], strict=True):
        sinh_ratio = sinh_ratio * x_squared + a
        cosh = cosh * x_squared + b
    return sinh_ratio, cosh


def _require_non_negative(name: str, value: ArrayLike) -> None:
    require_finite(name, value)
    array = concrete_value(value)
    if array is not None and (array < 0).any():
        raise ValueError(f"{name} must be zero or positive, got {array.min():g}")


def _real(value: ArrayLike) -> jax.Array:
    return jnp.asarray(value, float)


class TransferFunction(eqx.Module):
    """A linear mixing unit given by its transfer function G(s) (abstract base)."""

    @abc.abstractmethod
    def log_transfer(self, s: ArrayLike) -> jax.Array:
        """Return ``log G(s)`` for complex ``s`` in 1/(time unit), elementwise."""

    @abc.abstractmethod
    def rightmost_singularity(self) -> jax.Array:
        """Return the real ``sigma <= 0`` (1/time unit) right of which G is analytic."""

    @abc.abstractmethod
    def mean(self) -> jax.Array:
        """Return the mean residence time (time unit)."""

    @abc.abstractmethod
    def variance(self) -> jax.Array:
        """Return the residence-time variance ((time unit)²)."""

    def surrogate_log_transfer(self, s: ArrayLike, far: ArrayLike) -> jax.Array:
        """Return ``log G(s)``, or where `far` holds the log of a positive surrogate for G
        without its dead-zone cluster (elementwise; only the contour geometry uses it).

        For units without a dead zone both are ``log G``.
        """
        del far
        return self.log_transfer(s)

    def far_log_transfer(self, s: ArrayLike) -> jax.Array:
        """Return the log of the positive surrogate for G without its dead-zone cluster."""
        return self.surrogate_log_transfer(s, True)

    def far_singularity(self) -> jax.Array:
        """Return the rightmost singularity of G outside its dead-zone cluster (1/time unit)."""
        return self.rightmost_singularity()

    def exchange_zones(self) -> tuple[ExchangeZone, ...]:
        """Return the dead-zone units inside this unit (static structure)."""
        return ()

    def transfer(self, s: ArrayLike) -> jax.Array:
        """Return ``G(s)`` for complex ``s`` in 1/(time unit); ``G(0) = 1``.

        **Arguments:**

        - `s`: Laplace variable in 1/(time unit), any shape.

        **Returns:**

        Complex ``G(s)``, same shape as `s`.
        """
        return jnp.exp(self.log_transfer(jnp.asarray(s, complex)))


def _first_closed_eigenvalue(peclet: jax.Array) -> jax.Array:
    """Return ``λ_1`` in (0, π), the root of ``λ = 2 atan(Pe / (2 λ))`` (MODELS.md §2).

    The function ``λ - 2 atan(Pe/(2λ))`` is increasing and concave, so Newton's method from a
    point left of the root rises monotonically to it; ``min(sqrt(Pe), π) / 2`` is such a point
    because the root is below both ``sqrt(Pe)`` and ``π``.
    """
    lam = 0.5 * jnp.minimum(jnp.sqrt(peclet), jnp.pi)

    def newton(_, lam):
        residual = lam - 2.0 * jnp.arctan(peclet / (2.0 * lam))
        slope = 1.0 + 4.0 * peclet / (4.0 * lam**2 + peclet**2)
        return lam - residual / slope

    return jax.lax.fori_loop(0, 30, newton, lam)


class ClosedClosedADM(TransferFunction):
    """The closed–closed (Danckwerts) axial dispersion model (MODELS.md §2).

    ``G(s) = 4 q e^{Pe(1-q)/2} / [(1+q)² - (1-q)² e^{-q Pe}]`` with
    ``q = sqrt(1 + 4 s tau / Pe)``; mean ``tau``, variance ``tau² (2/Pe - 2/Pe² (1 - e^{-Pe}))``.

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive); the mean residence time.
    - `peclet`: Peclet number ``v L / D_z`` (dimensionless, positive).
    """

    tau: ArrayLike
    peclet: ArrayLike

    def __check_init__(self) -> None:
        require_positive("tau", self.tau)
        require_positive("peclet", self.peclet)

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        peclet = _real(self.peclet)
        z = jnp.asarray(s, complex) * _real(self.tau)
        # G is even in q, an entire function of x² = (q Pe / 2)² = Pe²/4 + Pe z. Near q = 0 the
        # q-form differentiates badly (dq/ds is infinite there although G is smooth), so for
        # |x| < 1 G = 2 e^{Pe/2} / [(1 + q²)(Pe/2) sinh(x)/x + 2 cosh(x)] is summed in x².
        # Elsewhere |q Pe| >= 2 and the overflow-safe q-form needs no expm1.
        x_squared = 0.25 * peclet**2 + peclet * z
        small = jnp.abs(x_squared) < 1.0
        q = jnp.sqrt(1.0 + 4.0 * jnp.where(small, 1.0, z) / peclet)
        exponent = q * peclet
        large = 4.0 + peclet * (1.0 - q) ** 2 * (1.0 - jnp.exp(-exponent)) / exponent
        sinh_ratio, cosh = _sinh_ratio_and_cosh(jnp.where(small, x_squared, 0.0))
        small_denominator = (2.0 + 4.0 * z / peclet) * 0.5 * peclet * sinh_ratio + 2.0 * cosh
        offset = jnp.where(small, _LOG_TWO + 0.5 * peclet, _LOG_FOUR + 0.5 * peclet * (1.0 - q))
        return offset - jnp.log(jnp.where(small, small_denominator, large))

    def rightmost_singularity(self) -> jax.Array:
        peclet = _real(self.peclet)
        lam = _first_closed_eigenvalue(peclet)
        return -(4.0 * lam**2 + peclet**2) / (4.0 * peclet * _real(self.tau))

    def mean(self) -> jax.Array:
        return _real(self.tau) + 0.0 * _real(self.peclet)

    def variance(self) -> jax.Array:
        return _real(self.tau) ** 2 * variance_ratio_closed(self.peclet)


class OpenOpenADM(TransferFunction):
    """The open–open axial dispersion model with flux detection (MODELS.md §2).

    ``G(s) = e^{Pe(1-q)/2} / q`` with ``q = sqrt(1 + 4 s tau / Pe)``, the transform of
    ``sqrt(Pe / (4 pi theta)) e^{-Pe (1-theta)² / (4 theta)} / tau``; mean ``(1 + 2/Pe) tau``,
    variance ``tau² (2/Pe + 8/Pe²)``.

    **Arguments:**

    - `tau`: space time ``L / v`` (time unit, positive); not the mean.
    - `peclet`: Peclet number (dimensionless, positive).
    """

    tau: ArrayLike
    peclet: ArrayLike

    def __check_init__(self) -> None:
        require_positive("tau", self.tau)
        require_positive("peclet", self.peclet)

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        peclet = _real(self.peclet)
        q = jnp.sqrt(1.0 + 4.0 * jnp.asarray(s, complex) * _real(self.tau) / peclet)
        return 0.5 * peclet * (1.0 - q) - jnp.log(q)

    def rightmost_singularity(self) -> jax.Array:
        return -_real(self.peclet) / (4.0 * _real(self.tau))

    def mean(self) -> jax.Array:
        return _real(self.tau) * (1.0 + 2.0 / _real(self.peclet))

    def variance(self) -> jax.Array:
        peclet = _real(self.peclet)
        return _real(self.tau) ** 2 * (2.0 / peclet + 8.0 / peclet**2)


class TanksInSeries(TransferFunction):
    """Equal stirred tanks in series, ``G(s) = (1 + s tau / n)^-n`` (n real, positive).

    **Arguments:**

    - `tau`: total mean residence time of the chain (time unit, positive).
    - `n_tanks`: number of tanks (positive real).
    """

    tau: ArrayLike
    n_tanks: ArrayLike

    def __check_init__(self) -> None:
        require_positive("tau", self.tau)
        require_positive("n_tanks", self.n_tanks)

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        n = _real(self.n_tanks)
        return -n * jnp.log1p(jnp.asarray(s, complex) * _real(self.tau) / n)

    def rightmost_singularity(self) -> jax.Array:
        return -_real(self.n_tanks) / _real(self.tau)

    def mean(self) -> jax.Array:
        return _real(self.tau) + 0.0 * _real(self.n_tanks)

    def variance(self) -> jax.Array:
        return _real(self.tau) ** 2 / _real(self.n_tanks)


class StirredTank(TransferFunction):
    """One ideally stirred tank, ``G(s) = 1 / (1 + s tau)`` (a detector cell, feed frame, hopper).

    **Arguments:**

    - `tau`: its mean residence time (time unit, positive).
    """

    tau: ArrayLike

    def __check_init__(self) -> None:
        require_positive("tau", self.tau)

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        return -jnp.log1p(jnp.asarray(s, complex) * _real(self.tau))

    def rightmost_singularity(self) -> jax.Array:
        return -1.0 / _real(self.tau)

    def mean(self) -> jax.Array:
        return _real(self.tau)

    def variance(self) -> jax.Array:
        return _real(self.tau) ** 2


class ExchangeZone(TransferFunction):
    """A unit whose flowing material exchanges with a stagnant (dead) zone (MODELS.md §6).

    The mobile phase obeys the unit's own model with ``s`` replaced by
    ``s' = s (1 + β k_d / (s + k_d))``: ``G(s) = G_unit(s')``. The unit's ``tau`` is then the
    mobile space time. From ``s' = (1 + β) s - β s² / k_d + O(s³)`` and the unit's moments
    ``m, v``: mean ``(1 + β) m``, variance ``(1 + β)² v + 2 β m / k_d``.

    **Arguments:**

    - `unit`: the mobile-phase model (any :class:`TransferFunction`).
    - `capacity_ratio`: ``β``, immobile to mobile hold-up (dimensionless, zero or positive).
    - `exchange_rate`: ``k_d``, first-order exchange rate (1/time unit, positive); a tracer
      particle stays in the dead zone for an exponential time of mean ``1 / k_d``.
    """

    unit: TransferFunction
    capacity_ratio: ArrayLike
    exchange_rate: ArrayLike

    def __check_init__(self) -> None:
        if not isinstance(self.unit, TransferFunction):
            raise ValueError(f"unit must be a TransferFunction, got {type(self.unit).__name__}")
        if self.unit.exchange_zones():
            raise ValueError("the unit of an ExchangeZone must not have a dead zone itself")
        _require_non_negative("capacity_ratio", self.capacity_ratio)
        require_positive("exchange_rate", self.exchange_rate)

    def exchange_zones(self) -> tuple[ExchangeZone, ...]:
        return (self,)

    def substituted(self, s: ArrayLike) -> jax.Array:
        """Return the mobile-phase Laplace variable ``s' = s (1 + β k_d / (s + k_d))``.

        **Arguments:**

        - `s`: Laplace variable in 1/(time unit), complex, any shape.

        **Returns:**

        ``s'`` in 1/(time unit), same shape.
        """
        s = jnp.asarray(s, complex)
        rate = _real(self.exchange_rate)
        return s + _real(self.capacity_ratio) * rate * s / (s + rate)

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        return self.unit.log_transfer(self.substituted(s))

    def surrogate_log_transfer(self, s: ArrayLike, far: ArrayLike) -> jax.Array:
        # Away from s = -k_d, s' is close to s + β k_d: the far surrogate is the mobile curve
        # damped by e^{-β k_d t}. One evaluation of the unit at the selected argument.
        s = jnp.asarray(s, complex)
        beta_rate = _real(self.capacity_ratio) * _real(self.exchange_rate)
        return self.unit.log_transfer(jnp.where(far, s + beta_rate, self.substituted(s)))

    def far_singularity(self) -> jax.Array:
        beta_rate = _real(self.capacity_ratio) * _real(self.exchange_rate)
        return self.unit.rightmost_singularity() - beta_rate

    def near_log_transfer(self):
        """Return ``s -> log`` of a positive surrogate for G near its dead-zone cluster.

        With ``w = s + k_d`` and ``z_0 = (β - 1) k_d``, ``s' = z_0 + w - β k_d² / w``; dropping
        ``w`` gives ``G_unit(z_0 - β k_d² / w) - G_unit(z_0)``, the transform of
        ``e^{-k_d t} Σ_n (β k_d²)^n M_n t^{n-1} / (n! (n-1)!)`` with positive ``M_n``. Only the
        contour geometry uses it.

        **Returns:**

        A function of complex ``s`` (1/time unit), elementwise.
        """
        rate = _real(self.exchange_rate)
        beta = _real(self.capacity_ratio)
        start = jnp.asarray((beta - 1.0) * rate, complex)
        at_start = self.unit.log_transfer(start)

        def near(s):
            shifted = start - beta * rate**2 / (jnp.asarray(s, complex) + rate)
            return at_start + log_expm1(self.unit.log_transfer(shifted) - at_start)

        return near

    def near_singularity(self) -> jax.Array:
        """Return the rightmost singularity of G and of its near surrogate (1/time unit)."""
        rate = _real(self.exchange_rate)
        beta = _real(self.capacity_ratio)
        surrogate = -rate + beta * rate**2 / (
            (beta - 1.0) * rate - self.unit.rightmost_singularity()
        )
        return jnp.maximum(surrogate, self.rightmost_singularity())

    def rightmost_singularity(self) -> jax.Array:
        inner = self.unit.rightmost_singularity()
        beta = _real(self.capacity_ratio)
        rate = _real(self.exchange_rate)
        # Root in (-k_d, 0) of s² + s (k_d (1 + β) - sigma) - sigma k_d = 0, in the form that
        # does not cancel when k_d is small.
        linear = rate * (1.0 + beta) - inner
        product = -inner * rate
        root = -2.0 * product / (linear + jnp.sqrt(linear**2 - 4.0 * product))
        # Without a dead zone the substitution is the identity and -k_d is no singularity.
        return jnp.where(beta > 0, root, inner)

    def mean(self) -> jax.Array:
        return (1.0 + _real(self.capacity_ratio)) * self.unit.mean()

    def variance(self) -> jax.Array:
        beta = _real(self.capacity_ratio)
        return (1.0 + beta) ** 2 * self.unit.variance() + 2.0 * beta * self.unit.mean() / _real(
            self.exchange_rate
        )


class Series(TransferFunction):
    """Units in series: the product of their transfer functions (MODELS.md §6).

    Means and variances add. Example: ``Series(ClosedClosedADM(40.0, 8.0), StirredTank(3.0))``
    is a blender followed by a detector cell.

    **Arguments:**

    - `*units`: one or more :class:`TransferFunction` (their order does not matter).
    """

    units: tuple[TransferFunction, ...]

    def __init__(self, *units: TransferFunction):
        self.units = tuple(units)

    def __check_init__(self) -> None:
        if not self.units:
            raise ValueError("Series needs at least one unit")
        for unit in self.units:
            if not isinstance(unit, TransferFunction):
                raise ValueError(
                    f"every unit of a Series must be a TransferFunction, got {type(unit).__name__}"
                )
        if len(self.exchange_zones()) > 1:
            raise ValueError("a Series may hold at most one ExchangeZone")

    def log_transfer(self, s: ArrayLike) -> jax.Array:
        s = jnp.asarray(s, complex)
        return sum(unit.log_transfer(s) for unit in self.units)

    def surrogate_log_transfer(self, s: ArrayLike, far: ArrayLike) -> jax.Array:
        s = jnp.asarray(s, complex)
        return sum(unit.surrogate_log_transfer(s, far) for unit in self.units)

    def far_singularity(self) -> jax.Array:
        return functools.reduce(jnp.maximum, (u.far_singularity() for u in self.units))

    def exchange_zones(self) -> tuple[ExchangeZone, ...]:
        return sum((unit.exchange_zones() for unit in self.units), ())

    def rightmost_singularity(self) -> jax.Array:
        return functools.reduce(jnp.maximum, (u.rightmost_singularity() for u in self.units))

    def mean(self) -> jax.Array:
        return sum(unit.mean() for unit in self.units)

    def variance(self) -> jax.Array:
        return sum(unit.variance() for unit in self.units)
