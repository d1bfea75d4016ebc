"""Closed–closed axial dispersion model solved with FiPy: the independent cross-check.

The JAX finite-volume solver (:mod:`axialmix.adm`) is checked against this one. It solves the
dimensionless ADM of MODELS.md section 2,

    ∂c/∂θ + ∂c/∂x = (1/Pe) ∂²c/∂x²,   0 < x < 1,   θ = t / tau,

with FiPy's finite volumes on ``n_cells`` uniform cells:

* Danckwerts inlet ``c_in(θ) = c - (1/Pe) ∂c/∂x`` at x = 0 as a flux condition: convection
  and diffusion coefficients are zeroed on the inlet face and the total inflow ``c_in`` enters
  as the divergence of a face vector (the construction of FiPy's
  ``examples/convection/robin.py``).
* Closed outlet ``∂c/∂x = 0`` at x = 1: no diffusive flux; the convective outflow ``c`` leaves
  through the outlet face by an implicit sink on the last cell (FiPy's exterior faces carry no
  flux by default). The outlet concentration, which is ``E(θ)`` for a pulse and ``F(θ)`` for a
  step, is the last cell's value (its zero-gradient extrapolation to the face).
* Interior convection by central differences (second order; free of oscillations for cell
  Peclet numbers ``Pe / n_cells < 2``, which is therefore required).
* Time by FiPy's ``TransientTerm``: backward Euler, first order, with a fixed step; every step
  is solved by ``LinearLUSolver(tolerance=1e-12)`` (FiPy's default iterative tolerance stalls
  in transient runs).
* Pulse input: the unit tracer mass enters through the inlet face during the first time step
  (``c_in = 1/Δθ`` on ``0 < θ <= Δθ``, zero after), so the Danckwerts inlet condition itself
  is exercised and the injected mass is exactly one. Step input: ``c_in = 1`` for ``θ > 0``.

The discretisation error is ``O(Δθ) + O(1/n_cells²)``; backward Euler dominates at practical
settings. FiPy assembles and solves a sparse system each step (several ms per step), so this
module is a reference for tests and benchmarks, not a model for fitting.
"""

import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["exit_age_fipy", "step_response_fipy"]

_MAX_CELL_PECLET = 2.0


def _check_arguments(t: ArrayLike, tau: float, peclet: float, n_cells: int, dt: float | None):
    """Validate the arguments shared by the public solvers; return the times as an array."""
    time = np.asarray(t, dtype=float)
    if time.ndim != 1 or time.size == 0:
        raise ValueError(f"t must be a non-empty one-dimensional array, got shape {time.shape}")
    if not np.all(np.isfinite(time)):
        raise ValueError("t contains NaN or infinite values")
    if np.any(time < 0):
        raise ValueError("t must be non-negative (the pulse or step starts at t = 0)")
    for name, value in (("tau", tau), ("peclet", peclet)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    if int(n_cells) != n_cells or n_cells < 2:
        raise ValueError(f"n_cells must be an integer of at least 2, got {n_cells!r}")
    if peclet / n_cells >= _MAX_CELL_PECLET:
        raise ValueError(
            f"n_cells must exceed peclet / 2 = {peclet / 2:g} for central differencing "
            f"(cell Peclet number {peclet / n_cells:.3g} >= 2 oscillates), got {n_cells}"
        )
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number, got {dt!r}")
    return time


def _outlet_history(
    peclet: float, n_cells: int, dtheta: float, n_steps: int, pulse: bool
) -> np.ndarray:
    """Outlet concentration at θ = k Δθ, k = 0..n_steps, for a unit pulse or a unit step."""
    try:
        import fipy as fp  # only here: the cross-check is the one user of FiPy
    except ImportError as error:
        raise ImportError(
            "axialmix.reference needs FiPy: pip install 'axialmix[reference]'."
        ) from error

    mesh = fp.Grid1D(nx=int(n_cells), dx=1.0 / n_cells)
    concentration = fp.CellVariable(mesh=mesh, value=0.0, hasOld=True)
    inlet_face, outlet_face = mesh.facesLeft, mesh.facesRight

    velocity = fp.FaceVariable(mesh=mesh, rank=1, value=1.0)
    velocity.setValue(0.0, where=inlet_face)
    dispersion = fp.FaceVariable(mesh=mesh, value=1.0 / peclet)
    dispersion.setValue(0.0, where=inlet_face)

    inlet_concentration = fp.Variable(value=0.0)
    # Face normals point out of the domain, so (g n).divergence is an inflow g per unit area.
    inflow = (inlet_concentration * inlet_face * mesh.faceNormals).divergence
    outflow = fp.ImplicitSourceTerm(coeff=(outlet_face * mesh.faceNormals).divergence)
    equation = (
        fp.TransientTerm() + fp.CentralDifferenceConvectionTerm(coeff=velocity) + outflow
        == fp.DiffusionTerm(coeff=dispersion) + inflow
    )
    solver = fp.LinearLUSolver(tolerance=1e-12)

    outlet = np.zeros(n_steps + 1)
    for step in range(n_steps):
        if pulse:
            inlet_concentration.setValue(1.0 / dtheta if step == 0 else 0.0)
        else:
            inlet_concentration.setValue(1.0)
        concentration.updateOld()
        equation.solve(var=concentration, dt=dtheta, solver=solver)
        outlet[step + 1] = concentration.value[-1]
    return outlet


def _solve_on_times(
    t: ArrayLike,
    tau: float,
    peclet: float,
    n_cells: int | None,
    dt: float | None,
    pulse: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Run FiPy up to max(t) and return the requested times and the outlet values there."""
    if n_cells is None and np.isfinite(peclet) and peclet > 0:
        n_cells = max(200, math.ceil(peclet))
    time = _check_arguments(t, tau, peclet, n_cells, dt)
    dtheta = (dt if dt is not None else tau / 200.0) / tau
    n_steps = max(1, math.ceil(time.max() / tau / dtheta - 1e-9))
    outlet = _outlet_history(float(peclet), int(n_cells), dtheta, n_steps, pulse)
    theta_grid = dtheta * np.arange(n_steps + 1)
    return time, np.interp(time / tau, theta_grid, outlet)


def exit_age_fipy(
    t: ArrayLike,
    tau: float,
    peclet: float,
    *,
    n_cells: int | None = None,
    dt: float | None = None,
) -> np.ndarray:
    """Return the closed–closed ADM exit-age density E(t) computed with FiPy.

    The outlet concentration is computed on the time steps ``k * dt`` and interpolated
    linearly to `t`; at ``t = 0`` it is 0. Discretisation and input as in the module
    docstring (backward Euler, central differences, unit mass through the Danckwerts inlet
    during the first step).

    **Arguments:**

    - `t`: times at which to report E, shape ``(times,)``, non-negative; any unit (say s).
    - `tau`: space time ``L / v``, positive, same unit as `t`.
    - `peclet`: Peclet number ``v L / D_z``, positive, dimensionless.
    - `n_cells`: number of finite-volume cells; must exceed ``peclet / 2``; default
      ``max(200, ceil(peclet))`` (cell Peclet number at most one).
    - `dt`: time step in the unit of `t`; default ``tau / 200``.

    **Returns:**

    ``E(t)``, shape ``(times,)``, in 1/(unit of `t`).
    """
    _, outlet = _solve_on_times(t, tau, peclet, n_cells, dt, pulse=True)
    return outlet / tau


def step_response_fipy(
    t: ArrayLike,
    tau: float,
    peclet: float,
    *,
    n_cells: int | None = None,
    dt: float | None = None,
) -> np.ndarray:
    """Return the closed–closed ADM step response F(t) computed with FiPy.

    A unit inlet concentration is switched on at ``t = 0``; the outlet concentration on the
    steps ``k * dt`` is interpolated linearly to `t`.

    **Arguments:**

    - `t`: times at which to report F, shape ``(times,)``, non-negative; any unit (say s).
    - `tau`: space time ``L / v``, positive, same unit as `t`.
    - `peclet`: Peclet number ``v L / D_z``, positive, dimensionless.
    - `n_cells`: number of finite-volume cells; must exceed ``peclet / 2``; default
      ``max(200, ceil(peclet))`` (cell Peclet number at most one).
    - `dt`: time step in the unit of `t`; default ``tau / 200``.

    **Returns:**

    ``F(t)``, shape ``(times,)``, dimensionless.
    """
    _, outlet = _solve_on_times(t, tau, peclet, n_cells, dt, pulse=False)
    return outlet
