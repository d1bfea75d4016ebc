"""The optimiser core: compiled single-start solvers in pure JAX, their settings and status.

* The loss (:mod:`fitting.losses`) is divided by its value for a zero model (``Σ w y²`` for
  least squares) so that it is of order one whatever the units; ``tol`` is a bound on the
  gradient norm of this scaled loss in the unconstrained coordinates ``u``
  (:class:`fitting.parameters.Layout`).
* ``method='auto'`` (default): Levenberg–Marquardt for least squares, L-BFGS for the mean
  absolute error. ``'lm'``: Levenberg–Marquardt (least squares only) with Levenberg's
  damping in the unconstrained coordinates, steps of at most 1 in each of them, and
  Nielsen's damping update; each iteration evaluates the residuals and
  their Jacobian once (one model evaluation with forward-mode tangents), the damped normal
  equations are solved by a Cholesky factorisation written in JAX (no LAPACK call, so the
  compiled program needs nothing from SciPy). ``'lbfgs'``: :func:`optax.lbfgs` with its zoom
  line search (strong Wolfe conditions), the value and gradient at the accepted point read
  from the line search's state. ``'adam'``: :func:`optax.adam` at a fixed learning rate
  (rough, many cheap steps).
* One compiled program solves ONE start on ONE curve: a :func:`jax.lax.while_loop` inside
  :func:`jax.jit`, without ``vmap`` (a batched loop runs every lane until the slowest has
  converged, and tracing a vmapped loop costs seconds). Starts, curves and profile points
  are looped over in Python, each call reusing the compiled program. Curves are padded with
  zero-weight points to a length of 16, 32, 64, ... samples, so curves of different
  lengths share programs. Programs are kept per model, parameter layout, settings and
  padded length.
* Across processes (after :func:`enable_compilation_cache`): the compiled programs are kept
  by JAX's persistent compilation cache, and the programs of the built-in models and of
  network files (:func:`~fitting.models.network_model`: by the file's content and parameter
  mapping; also when wrapped in a measurement, :func:`model_identity`) are kept as
  :mod:`jax.export` files
  in the user's cache folder, keyed by the package version
  and source, the JAX version, the model, layout, settings and shapes, so a later run loads
  them instead of tracing them again.
* Starts (:func:`start_points`): the start value, the method-of-moments estimate, then random
  starts (seeded), each random start first moved ``warmup_steps`` Adam steps, then polished
  by the local method; the lowest loss wins.
* Stopping: gradient norm below ``tol`` (converged), relative loss change below ``ftol``
  (converged: no further decrease possible at this precision) — for Levenberg–Marquardt
  each only with a step below ``xtol`` in every coordinate, as its post-check asks, or
  after three such changes in a row —, no step that decreases the loss (the
  line search, or Levenberg–Marquardt's damping growing past 1e16), a non-finite loss,
  ``max_steps`` iterations, or (Levenberg–Marquardt) a loss falling by less than 0.1 % over
  20 iterations (status SLOW) — not converged; see :class:`Status`. Where
  Levenberg–Marquardt's best start is not accepted, :class:`MultiStartSolver` continues
  with Newton's method on the full Hessian (a singular Gauss–Newton curvature) or redoes
  the start with L-BFGS (a slow crawl along a curved valley).
* Checking (least squares): a stopped fit counts as converged only if one Gauss–Newton step
  from it is below ``xtol`` (computed in NumPy from the returned Jacobian). Where the
  Gauss–Newton curvature ``JᵀJ`` is singular (a direction the model curve does not change
  along to first order, e.g. the mirror line of the four-compartment model), that step is
  meaningless; the full Hessian then decides (:func:`second_order_distance`).

The package's modules, each importing only those before it: :mod:`~fitting.solve.status`
(stopping codes), :mod:`~fitting.solve.settings` (settings and plans),
:mod:`~fitting.solve.padding` (padded lengths), :mod:`~fitting.solve.programs` (compiled
programs and their on-disk caches), :mod:`~fitting.solve.first_order` (L-BFGS and Adam),
:mod:`~fitting.solve.levenberg_marquardt`, :mod:`~fitting.solve.single_start` (the program
of one start), :mod:`~fitting.solve.second_order` (the full Hessian: Newton's polish and the
second-order check) and :mod:`~fitting.solve.multistart` (starts and the multi-start solver).
This face re-exports their public names.
"""

# Public names outside the documented API (``__all__``), some of them imported by other
# fitting modules, are re-exported by a redundant alias.
from fitting.solve.first_order import adam_minimise as adam_minimise
from fitting.solve.levenberg_marquardt import lm_initial as lm_initial
from fitting.solve.levenberg_marquardt import lm_step as lm_step
from fitting.solve.levenberg_marquardt import weighted_evaluation as weighted_evaluation
from fitting.solve.levenberg_marquardt import weighted_residuals as weighted_residuals
from fitting.solve.multistart import (
    MultiStartSolver,
    compiled_solver,
    run_solver,
    start_points,
)
from fitting.solve.padding import pad_curve as pad_curve
from fitting.solve.padding import padded_length
from fitting.solve.programs import CACHE_SWITCH as CACHE_SWITCH
from fitting.solve.programs import COMPILATION_CACHE_BYTES as COMPILATION_CACHE_BYTES
from fitting.solve.programs import (
    EXPORT_SUFFIX,
    enable_compilation_cache,
    model_identity,
    user_cache_folder,
)
from fitting.solve.programs import Program as Program
from fitting.solve.programs import export_key as export_key
from fitting.solve.second_order import compiled_curvature, second_order_distance
from fitting.solve.settings import (
    METHOD_NAMES,
    METHODS,
    MultiStart,
    Optimiser,
    SolverPlan,
    make_plan,
)
from fitting.solve.status import (
    CONVERGED,
    FIRST_ORDER_CONVERGED,
    SECOND_ORDER_DISTANCE,
    STATUS_MESSAGES,
    Status,
)
from fitting.solve.status import PLATEAU as PLATEAU
from fitting.solve.status import RUNNING as RUNNING

__all__ = [
    "CONVERGED",
    "FIRST_ORDER_CONVERGED",
    "SECOND_ORDER_DISTANCE",
    "STATUS_MESSAGES",
    "EXPORT_SUFFIX",
    "METHODS",
    "METHOD_NAMES",
    "MultiStart",
    "MultiStartSolver",
    "Optimiser",
    "SolverPlan",
    "Status",
    "compiled_curvature",
    "compiled_solver",
    "enable_compilation_cache",
    "make_plan",
    "model_identity",
    "padded_length",
    "run_solver",
    "second_order_distance",
    "start_points",
    "user_cache_folder",
]
