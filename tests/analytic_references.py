"""Independent references for the dead-zone, series and sampled-inlet models of axialmix.analytic.

None of these uses the saddle-point inversion under test:

* :func:`exchange_exit_age_subordinated` — the compound-Poisson (subordination) form of the
  closed–closed ADM with a dead zone, in the time domain: a tracer spends mobile time U with
  the plain closed–closed density, and meanwhile makes Poisson(β k_d U) visits of Exp(k_d)
  length to the dead zone, so

      E(t) = e^{-β k U} E_0(t) + ∫_0^t E_0(u) e^{-β k u - k (t-u)} β k² u g(2 k sqrt(β u (t-u))) du,

  ``g(z) = 2 I_1(z) / z``; E_0 is the plain closed–closed density of
  :mod:`axialmix.analytic._contour` (a different contour, itself checked against the
  eigenfunction series), the integral composite Gauss–Legendre.
* :func:`exchange_step_response_subordinated` — the same for F, with the dead-zone time's
  distribution ``e^{-β k u} (1 + Σ_n (β k u)^n / n! P(n, k y))``.
* :class:`ChebyshevADM` — method of lines: Chebyshev collocation of the closed–closed ADM with
  an immobile-zone ODE at every node (and an optional stirred tank after the outlet), solved by
  scipy's matrix exponential: ``E(t) = C e^{A t} b``, ``F(t) = 1 + C A^{-1} e^{A t} b``.
* :func:`tanks_exchange_network` — n stirred tanks, each exchanging with its own stagnant
  tank: a 2n-compartment network whose exit age, step and ramp responses and response to a
  piecewise-linear inlet are exact matrix exponentials (scipy).
"""

from __future__ import annotations

import numpy as np
from scipy import special
from scipy.linalg import expm, solve

from axialmix.analytic._contour import closed_closed_curves

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(20)


def _panels(edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    edges = np.unique(edges)
    a, b = edges[:-1], edges[1:]
    nodes = (0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * _GAUSS_X).ravel()
    weights = (0.5 * (b - a)[:, None] * _GAUSS_W).ravel()
    return nodes, weights


def _mobile_nodes(theta: float, peclet: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes on [0, theta] that resolve the plain closed–closed density."""
    width = min(1.0, 4.0 / np.sqrt(peclet))
    peak = np.clip(1.0 + width * np.linspace(-6.0, 6.0, 241), 0.0, theta)
    return _panels(np.concatenate([np.linspace(0.0, theta, 401), peak]))


def _plain_exit_age(u: np.ndarray, peclet: float) -> np.ndarray:
    # Padded to a multiple of 4096 points (with theta = 1) so that few programs are compiled.
    size = u.size
    padded = np.pad(np.asarray(u, float), (0, -size % 4096), constant_values=1.0)
    return np.asarray(closed_closed_curves(padded, peclet)[0])[:size]


def _dead_zone_kernel(u, remaining, beta, kappa):
    """``e^{-β k u - k y} β k² u g(2 k sqrt(β u y))`` with ``g(z) = 2 I_1(z)/z``."""
    z = 2.0 * kappa * np.sqrt(beta * u * remaining)
    safe = np.where(z > 1e-8, z, 1.0)
    log_g = np.where(z > 1e-8, np.log(2.0 * special.ive(1, safe) / safe) + safe, 0.0)
    return np.exp(-beta * kappa * u - kappa * remaining + log_g) * beta * kappa**2 * u


def exchange_exit_age_subordinated(theta, peclet, beta, kappa) -> np.ndarray:
    """Closed–closed ADM with a dead zone, tau = 1: E(theta) by subordination (see module)."""
    values = []
    for t in np.atleast_1d(np.asarray(theta, float)):
        u, w = _mobile_nodes(t, peclet)
        integral = np.sum(w * _plain_exit_age(u, peclet) * _dead_zone_kernel(u, t - u, beta, kappa))
        atom = np.exp(-beta * kappa * t) * _plain_exit_age(np.array([t]), peclet)[0]
        values.append(integral + atom)
    return np.array(values)


def exchange_step_response_subordinated(theta, peclet, beta, kappa) -> np.ndarray:
    """Closed–closed ADM with a dead zone, tau = 1: F(theta) by subordination.

    ``F(t) = ∫_0^t E_0(u) P(Y_u <= t - u) du`` with the dead-zone time ``Y_u``: an atom
    ``e^{-β k u}`` at 0 and, given n visits, a Gamma(n, k) time.
    """
    values = []
    for t in np.atleast_1d(np.asarray(theta, float)):
        u, w = _mobile_nodes(t, peclet)
        mean_visits = beta * kappa * u
        count = int(np.ceil(mean_visits.max() + 12.0 * np.sqrt(mean_visits.max()) + 30.0))
        n = np.arange(1, count + 1)[:, None]
        log_poisson = (
            -mean_visits + n * np.log(np.maximum(mean_visits, 1e-300)) - special.gammaln(n + 1)
        )
        held = np.sum(np.exp(log_poisson) * special.gammainc(n, kappa * (t - u)), axis=0)
        values.append(np.sum(w * _plain_exit_age(u, peclet) * (np.exp(-mean_visits) + held)))
    return np.array(values)


def _chebyshev(points: int):
    """Chebyshev points on [0, 1] (x_0 = 0) and the first-derivative matrix (Trefethen)."""
    x = np.cos(np.pi * np.arange(points + 1) / points)
    c = np.hstack([2.0, np.ones(points - 1), 2.0]) * (-1.0) ** np.arange(points + 1)
    dx = x[:, None] - x[None, :]
    d = np.outer(c, 1.0 / c) / (dx + np.eye(points + 1))
    d -= np.diag(d.sum(axis=1))
    return (1.0 - x) / 2.0, -2.0 * d


class ChebyshevADM:
    """Method-of-lines closed–closed ADM (tau = 1) with an immobile zone at every node.

    ``c_t = -c_x + c_xx / Pe - β k (c - c_im)``, ``(c_im)_t = k (c - c_im)``, Danckwerts
    conditions ``c - c_x / Pe = c_in`` at x = 0 and ``c_x = 0`` at x = 1, collocated at
    Chebyshev points; the boundary values are eliminated, so ``E(t) = C e^{A t} b``. With
    `tank`, the outlet feeds a stirred tank of that mean residence time.
    """

    def __init__(self, peclet, beta=0.0, kappa=1.0, points=60, tank=None):
        x, d = _chebyshev(points)
        operator = -d + d @ d / peclet
        inner = np.arange(1, points)
        boundary = [0, points]
        rows = np.array(
            [[1.0 - d[0, 0] / peclet, -d[0, points] / peclet], [d[points, 0], d[points, points]]]
        )
        from_inner = np.linalg.solve(rows, np.vstack([d[0, inner] / peclet, -d[points, inner]]))
        from_inlet = np.linalg.solve(rows, np.array([1.0, 0.0]))
        mobile = operator[np.ix_(inner, inner)] + operator[np.ix_(inner, boundary)] @ from_inner
        m = points - 1
        a = np.zeros((2 * m, 2 * m))
        a[:m, :m] = mobile - beta * kappa * np.eye(m)
        a[:m, m:] = beta * kappa * np.eye(m)
        a[m:, :m] = kappa * np.eye(m)
        a[m:, m:] = -kappa * np.eye(m)
        b = np.concatenate([operator[np.ix_(inner, boundary)] @ from_inlet, np.zeros(m)])
        c = np.concatenate([from_inner[1], np.zeros(m)])
        if tank is not None:
            a = np.block([[a, np.zeros((2 * m, 1))], [c[None, :] / tank, -np.ones((1, 1)) / tank]])
            b = np.concatenate([b, [from_inlet[1] / tank]])
            c = np.zeros(2 * m + 1)
            c[-1] = 1.0
        self.matrix, self.input, self.output = a, b, c
        self._inverse_input = solve(a, b)

    def on_grid(self, step: float, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Return E and F at ``step, 2 step, ..., count step``: powers of ``e^{A step}``."""
        propagator = expm(self.matrix * step)
        state, held = self.input.copy(), self._inverse_input.copy()
        exit_age, cumulative = [], []
        for _ in range(count):
            state = propagator @ state
            held = propagator @ held
            exit_age.append(self.output @ state)
            cumulative.append(1.0 + self.output @ held)
        return np.array(exit_age), np.array(cumulative)


def tanks_exchange_network(n_tanks: int, tau: float, beta: float, rate: float):
    """Generator, feed vector and outflow vector of n tanks with dead zones (2n compartments).

    States ``(M_1..M_n, I_1..I_n)``: mobile tank i receives ``(n/tau) M_{i-1}``, loses
    ``(n/tau + β k) M_i`` and gains ``k I_i``; stagnant tank i gains ``β k M_i`` and loses
    ``k I_i``. The outflow rate is ``(n/tau) M_n``.
    """
    flow = n_tanks / tau
    a = np.zeros((2 * n_tanks, 2 * n_tanks))
    for i in range(n_tanks):
        a[i, i] = -flow - beta * rate
        if i > 0:
            a[i, i - 1] = flow
        a[i, n_tanks + i] = rate
        a[n_tanks + i, i] = beta * rate
        a[n_tanks + i, n_tanks + i] = -rate
    feed = np.zeros(2 * n_tanks)
    feed[0] = 1.0
    outflow = np.zeros(2 * n_tanks)
    outflow[n_tanks - 1] = flow
    return a, feed, outflow


def network_responses(a, feed, outflow, t):
    """Exit age, step and ramp responses of a linear network at times t (scipy expm)."""
    n = a.shape[0]
    # Augmented exponential: d/dt (m, F, R) with inputs delta -> E, step -> F, ramp -> R.
    block = np.zeros((n + 2, n + 2))
    block[:n, :n] = a
    block[:n, n] = feed
    block[n, n + 1] = 1.0
    exit_age, step, ramp = [], [], []
    for time in t:
        full = expm(block * time)
        exit_age.append(outflow @ expm(a * time) @ feed)
        step.append(outflow @ full[:n, n])
        ramp.append(outflow @ full[:n, n + 1])
    return np.array(exit_age), np.array(step), np.array(ramp)


def network_inlet_response(a, feed, outflow, inlet_times, inlet_signal, t, hold=False):
    """Outflow of a network for a piecewise-linear inlet (zero before its first sample).

    After the last sample the inlet is zero (default) or keeps its last value (`hold`).
    Exact: the state is carried across each inlet interval with the augmented exponential of
    ``[[A, feed, 0], [0, 0, 1], [0, 0, 0]]`` and to each output time from the interval that
    holds it.
    """
    n = a.shape[0]
    block = np.zeros((n + 2, n + 2))
    block[:n, :n] = a
    block[:n, n] = feed
    block[n, n + 1] = 1.0
    knots = np.asarray(inlet_times, float)
    values = np.asarray(inlet_signal, float)
    slopes = np.diff(values) / np.diff(knots)
    out = []
    for time in t:
        state = np.zeros(n)
        if time > knots[0]:
            for j in range(len(knots)):
                start = knots[j]
                if start >= time:
                    break
                end = knots[j + 1] if j + 1 < len(knots) else np.inf
                stop = min(end, time)
                if j + 1 < len(knots):
                    level, slope = values[j], slopes[j]
                else:
                    level, slope = (values[-1] if hold else 0.0), 0.0
                full = expm(block * (stop - start))
                state = full[:n, :n] @ state + full[:n, n] * level + full[:n, n + 1] * slope
        out.append(outflow @ state)
    return np.array(out)
