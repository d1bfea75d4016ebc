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
  by JAX's persistent compilation cache, and the programs of the built-in models (also
  when wrapped in a measurement, :func:`model_identity`) are kept as :mod:`jax.export` files
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
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import functools
import hashlib
import math
import os
import time as _time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import export as jax_export

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.losses import LOSSES
from fitting.models import MODELS
from fitting.parameters import Layout

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


class Status(enum.IntEnum):
    """Why a fit stopped; the values are the status codes of earlier releases."""

    GRADIENT = 0
    LOSS_CHANGE = 1
    MAX_STEPS = 2
    NO_DECREASE = 3
    NOT_FINITE = 4
    PRECISION_LIMIT = 5
    FLAT = 6
    MISSES_DATA = 7
    SECOND_ORDER = 8
    ON_BOUND = 9
    SLOW = 10

    @property
    def converged(self) -> bool:
        """Whether this stopping rule counts as convergence."""
        return self in CONVERGED

    @property
    def message(self) -> str:
        """The stopping rule in words."""
        return STATUS_MESSAGES[self]


#: Stopping codes of the optimisation loop and their messages.
STATUS_MESSAGES = {
    Status.GRADIENT: "converged: gradient norm below tol",
    Status.LOSS_CHANGE: "converged: relative loss change below ftol",
    Status.MAX_STEPS: "not converged: maximum number of steps reached",
    Status.NO_DECREASE: "not converged: no step found a decrease (line search, or damping "
    "past 1e16)",
    Status.NOT_FINITE: "not converged: the loss is not finite",
    Status.PRECISION_LIMIT: "converged: at the precision limit (no further decrease possible; "
    "Gauss-Newton step below xtol)",
    Status.FLAT: "not converged: a Gauss-Newton step from here is still large (flat loss: the "
    "model curve may miss the data; try other start values or n_starts > 1)",
    Status.MISSES_DATA: "not converged: the model curve misses the data (loss at least 99 % of "
    "that of a zero curve); try other start values or n_starts > 1",
    Status.SECOND_ORDER: "converged: a local minimum where the Gauss-Newton curvature is "
    "singular (the full Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors); a parameter combination is determined only at second "
    "order, see the identifiability report",
    Status.ON_BOUND: "converged: a minimum on the bound of {names} (the loss falls towards it; "
    "the other parameters' Hessian is positive definite and Newton's method puts the minimum "
    "within 0.001 standard errors)",
    Status.SLOW: "not converged: the loss fell by less than 0.1 % over 20 Levenberg-Marquardt "
    "steps (a slow crawl, e.g. along a valley towards a bound); try other start values, "
    "n_starts > 1 or method='lbfgs'",
}
#: Status codes that count as converged.
CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT, Status.SECOND_ORDER,
             Status.ON_BOUND)
#: Status codes that count as converged without the second-order check (profile re-fits).
FIRST_ORDER_CONVERGED = (Status.GRADIENT, Status.LOSS_CHANGE, Status.PRECISION_LIMIT)
#: Newton distance to a local minimum, in standard errors, below which a fit that stopped on
#: a singular Gauss-Newton curvature counts as converged (status 8).
SECOND_ORDER_DISTANCE = 1e-3
RUNNING = -1
#: Scaled loss (1 = a zero model curve) at or above which a fit is reported as missing the data.
PLATEAU = 0.99
#: The optimiser methods (see :class:`Optimiser`).
METHODS = ("auto", "lm", "lbfgs", "adam")
#: Method names in results and reports.
METHOD_NAMES = {"lm": "levenberg-marquardt", "lbfgs": "lbfgs", "adam": "adam"}


class Optimiser(eqx.Module):
    """Settings of the local optimiser, immutable.

    **Arguments:**

    - `method`: ``'auto'`` (default: Levenberg–Marquardt for least squares, L-BFGS for the
      mean absolute error), ``'lm'`` (Levenberg–Marquardt, least squares only), ``'lbfgs'``
      or ``'adam'``.
    - `max_steps`: iteration limit per start; ``None``: 500 for Levenberg–Marquardt and
      L-BFGS, 5000 for Adam.
    - `tol`: gradient-norm tolerance on the scaled loss in transformed coordinates.
    - `ftol`: relative loss change below which the iteration stops.
    - `xtol`: a least-squares fit counts as converged only if one Gauss–Newton step from the
      result would move no transformed coordinate by more than `xtol` (for positive
      parameters: a relative change).
    - `learning_rate`: Adam's step size in transformed coordinates.
    - `memory_size`: L-BFGS history length.
    """

    method: str = eqx.field(default="auto", static=True)
    max_steps: int | None = eqx.field(default=None, static=True)
    tol: float = eqx.field(default=1e-10, static=True)
    ftol: float = eqx.field(default=1e-10, static=True)
    xtol: float = eqx.field(default=1e-6, static=True)
    learning_rate: float = eqx.field(default=0.05, static=True)
    memory_size: int = eqx.field(default=10, static=True)

    def __check_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got "
                             f"{self.method!r}")
        if self.max_steps is not None and not self.max_steps >= 1:
            raise ValueError(f"max_steps must be at least 1, got {self.max_steps}")
        if not (self.tol > 0 and self.xtol > 0 and self.ftol >= 0):
            raise ValueError("tol and xtol must be positive and ftol non-negative")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be positive, got {self.learning_rate}")
        if not self.memory_size >= 1:
            raise ValueError(f"memory_size must be at least 1, got {self.memory_size}")

    @property
    def steps(self) -> int:
        """The iteration limit in force."""
        if self.max_steps is not None:
            return int(self.max_steps)
        return 5000 if self.method == "adam" else 500

    def resolved(self, loss: str) -> str:
        """The method used on `loss`: ``'auto'`` resolved, ``'lm'`` refused off least squares."""
        if self.method == "auto":
            return "lm" if loss == "sse" else "lbfgs"
        if self.method == "lm" and loss != "sse":
            raise ValueError(f"method 'lm' (Levenberg-Marquardt) fits least squares only; use "
                             f"'lbfgs' or 'adam' for loss {loss!r}")
        return self.method


class MultiStart(eqx.Module):
    """How many starts a fit makes and how random starts are drawn, immutable.

    **Arguments:**

    - `n_starts`: number of starts, run as one vmapped batch: the start value, then (for
      models with a moment estimate) the moment estimate, then random starts. ``None``
      (default): the model's default (the start value, plus the moment estimate when it
      differs, unless the model says otherwise).
    - `seed`: seed of the random starts.
    - `warmup_steps`: Adam steps applied to each random start before L-BFGS.
    """

    n_starts: int | None = eqx.field(default=None, static=True)
    seed: int = eqx.field(default=0, static=True)
    warmup_steps: int = eqx.field(default=100, static=True)

    def __check_init__(self):
        if self.n_starts is not None and not self.n_starts >= 1:
            raise ValueError(f"n_starts must be at least 1, got {self.n_starts}")
        if not self.warmup_steps >= 0:
            raise ValueError(f"warmup_steps must be non-negative, got {self.warmup_steps}")


@dataclass(frozen=True)
class SolverPlan:
    """The static settings one compiled solver is built for (hashable; see :func:`make_plan`)."""

    loss: str
    method: str
    max_steps: int
    tol: float
    ftol: float
    warmup_steps: int
    learning_rate: float
    memory_size: int
    xtol: float


def make_plan(loss: str, optimiser: Optimiser, multistart: MultiStart) -> SolverPlan:
    """The :class:`SolverPlan` of a loss and settings.

    A single start never warms up, so its solver has no Adam loop; ``method='auto'`` is
    resolved for the loss (:meth:`Optimiser.resolved`).

    **Arguments:** `loss`: a key of :data:`fitting.losses.LOSSES`; `optimiser`, `multistart`:
    the settings.

    **Returns:** the plan.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {sorted(LOSSES)}, got {loss!r}")
    n_starts = multistart.n_starts
    warmup = int(multistart.warmup_steps) if n_starts is None or n_starts > 1 else 0
    return SolverPlan(loss, optimiser.resolved(loss), optimiser.steps, float(optimiser.tol),
                      float(optimiser.ftol), warmup, float(optimiser.learning_rate),
                      int(optimiser.memory_size), float(optimiser.xtol))


def user_cache_folder() -> Path:
    """The package's folder in the user's cache: ``$XDG_CACHE_HOME/axialmix``.

    **Returns:** the path (``~/.cache/axialmix`` without ``XDG_CACHE_HOME``); not created.
    """
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "axialmix"


#: The environment variable that turns the on-disk caches off (``off``).
CACHE_SWITCH = "AXIALMIX_COMPILATION_CACHE"
#: Size bound of the compilation cache (bytes); the least recently used entries go first.
COMPILATION_CACHE_BYTES = 2 * 1024**3
#: Folder of exported programs once :func:`enable_compilation_cache` has run (``None``: off).
_EXPORT_FOLDER: Path | None = None
#: File-name ending of exported programs.
EXPORT_SUFFIX = ".jaxexport"


def enable_compilation_cache(folder: str | Path | None = None, exports: bool = True) -> Path:
    """Keep compiled solvers on disk, so later runs of the same fit skip tracing and compiling.

    **Arguments:**

    - `folder`: the folder of JAX's compilation cache; default ``$JAX_COMPILATION_CACHE_DIR``
      if set, else ``jax`` in :func:`user_cache_folder`.
    - `exports`: also keep the solver programs of the built-in models as :mod:`jax.export`
      files in ``solvers`` in :func:`user_cache_folder`, so a later process loads them instead
      of tracing them (tracing is never cached by JAX itself).

    The environment variable ``AXIALMIX_COMPILATION_CACHE=off`` (or ``0``, ``no``,
    ``false``) turns both off: every run then traces and compiles afresh.

    **Returns:** the compilation-cache folder (left unused when it cannot be created or the
    cache is turned off).
    """
    global _EXPORT_FOLDER
    if os.environ.get(CACHE_SWITCH, "").strip().lower() in ("off", "0", "no", "false"):
        return Path(folder or os.environ.get("JAX_COMPILATION_CACHE_DIR")
                    or user_cache_folder() / "jax")
    if folder is None:
        folder = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if folder is None:
        folder = user_cache_folder() / "jax"
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # no writable cache folder: run without one
        return folder
    jax.config.update("jax_compilation_cache_dir", str(folder))
    # A bounded cache is also a locked one: JAX then reads and writes its entries under a
    # file lock (filelock), so processes sharing the folder (a Dask pool, the test suite's
    # workers, two fits at once) never read an entry another one is still writing; without
    # a bound the entries are written in place, unlocked, and the folder grows for ever.
    jax.config.update("jax_compilation_cache_max_size", COMPILATION_CACHE_BYTES)
    _date_unbounded_entries(folder)
    # Small programs too: a fit's solvers compile in well under the default one second.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _EXPORT_FOLDER = user_cache_folder() / "solvers" if exports else None
    return folder


def _date_unbounded_entries(folder: Path) -> None:
    """Give every entry of a cache folder written without a bound its access-time file.

    A bounded JAX cache ranks its entries by access-time files (``<key>-atime``) that an
    unbounded one does not write; one entry without its file makes every later write fail.
    Entries are dated by their modification time, so they are evicted oldest first.
    """
    try:
        for entry in folder.glob("*-cache"):
            stamp = entry.with_name(entry.name[: -len("cache")] + "atime")
            if not stamp.exists():
                stamp.write_bytes(entry.stat().st_mtime_ns.to_bytes(8, "little"))
    except OSError:  # a folder we cannot write: JAX then reports each failed write itself
        pass


def padded_length(size: int) -> int:
    """The length a curve of `size` samples is padded to: 16, 32, 64, ... (zero weights).

    **Arguments:** `size`: the number of samples.

    **Returns:** the smallest power of two that is at least `size` and 16.
    """
    return max(16, 1 << max(int(size) - 1, 0).bit_length())


def pad_curve(time, observed, weights, length: int):
    """`time`, `observed`, `weights` padded to `length` with zero-weight points, the times
    continuing the last spacing."""
    time = np.asarray(time, dtype=float)
    extra = length - time.shape[-1]
    if extra == 0:
        return time, np.asarray(observed, dtype=float), np.asarray(weights, dtype=float)
    spacing = time[-1] - time[-2] if time.shape[-1] >= 2 else 1.0
    more = time[-1] + spacing * np.arange(1, extra + 1)
    return (np.concatenate([time, more]),
            np.concatenate([np.asarray(observed, dtype=float), np.zeros(extra)]),
            np.concatenate([np.asarray(weights, dtype=float), np.zeros(extra)]))


@functools.lru_cache(maxsize=1)
def _source_fingerprint() -> str:
    """A digest of the installed package (its version, and each source file's path, size and
    modification time) and of the JAX in use: exported programs are valid only for these."""
    digest = hashlib.sha256()
    digest.update(repr((axialmix.__version__, jax.__version__, jax.lib.__version__,
                        jax.default_backend(), jax.config.jax_enable_x64)).encode())
    for root in (Path(axialmix.__file__).parent, Path(__file__).parent):
        for path in sorted(root.rglob("*.py")):
            stat = path.stat()
            digest.update(f"{path.relative_to(root.parent)}:{stat.st_size}:"
                          f"{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()[:16]


def _write_export(path: Path, blob: bytes) -> None:
    """Write an exported program atomically; remove programs of other package versions."""
    folder = path.parent
    folder.mkdir(parents=True, exist_ok=True)
    temporary = folder / f".{path.name}.{os.getpid()}.tmp"
    temporary.write_bytes(bytes(blob))
    os.replace(temporary, path)
    prefix = path.name.split("-", 1)[0]
    for other in folder.glob(f"*{EXPORT_SUFFIX}"):
        if not other.name.startswith(prefix):
            other.unlink(missing_ok=True)


class Program:
    """One pure function of arrays, compiled once per argument shapes.

    With a `key` (programs of built-in models) and exports on (:func:`enable_compilation_cache`)
    the traced program is exported with :mod:`jax.export` to the user's cache folder and run
    from there, so that a later process deserialises it instead of tracing it again; its
    compiled form then comes from JAX's persistent compilation cache.
    """

    def __init__(self, function: Callable, name: str, key: tuple | None):
        self.function = jax.jit(function)
        self.name = name
        self.key = key
        self.executables: dict = {}

    def executable(self, arguments: Sequence[np.ndarray]) -> tuple[Callable, float]:
        """The compiled program for these arguments' shapes, and the seconds it took to get."""
        signature = tuple((a.shape, a.dtype) for a in arguments)
        found = self.executables.get(signature)
        if found is not None:
            return found, 0.0
        began = _time.perf_counter()
        specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in arguments]
        function = self.function
        if self.key is not None and _EXPORT_FOLDER is not None:
            function = self._exported(specs)
        found = self.executables[signature] = function.lower(*specs).compile()
        return found, _time.perf_counter() - began

    def _exported(self, specs) -> Callable:
        shapes = tuple((s.shape, str(s.dtype)) for s in specs)
        digest = hashlib.sha256(repr((self.key, shapes)).encode()).hexdigest()[:24]
        label = "".join(c if c.isalnum() or c in "-_" else "_" for c in self.name)[:40]
        path = _EXPORT_FOLDER / f"{_source_fingerprint()}-{label}-{digest}{EXPORT_SUFFIX}"
        try:
            exported = jax_export.deserialize(bytearray(path.read_bytes()))
            if tuple((a.shape, str(a.dtype)) for a in exported.in_avals) == shapes:
                return jax.jit(exported.call)
        except Exception:  # noqa: BLE001  (missing, unreadable or stale: export it anew)
            pass
        exported = jax_export.export(self.function)(*specs)
        try:
            _write_export(path, exported.serialize())
        except (OSError, ImportError):  # a read-only cache, or no flatbuffers: run unsaved
            pass
        return jax.jit(exported.call)


def _lbfgs(objective: Callable, u0, options: SolverPlan):
    """Minimise `objective` from `u0` with optax L-BFGS + zoom line search in a while_loop."""
    import optax  # only L-BFGS and Adam need it (a fifth of a second to import)

    solver = optax.lbfgs(
        memory_size=options.memory_size,
        linesearch=optax.scale_by_zoom_linesearch(
            max_linesearch_steps=20, initial_guess_strategy="one"
        ),
    )
    value0, grad0 = jax.value_and_grad(objective)(u0)

    def step(carry):
        u, state, value, grad, count, evaluations, _ = carry
        updates, state = solver.update(
            grad, state, u, value=value, grad=grad, value_fn=objective
        )
        candidate = optax.apply_updates(u, updates)
        new_value = optax.tree.get(state, "value")
        new_grad = optax.tree.get(state, "grad")
        evaluations = evaluations + optax.tree.get(state, "num_linesearch_steps")
        finite = jnp.isfinite(new_value) & jnp.all(jnp.isfinite(new_grad))
        decreased = finite & (new_value <= value)
        u_next = jnp.where(decreased, candidate, u)
        value_next = jnp.where(decreased, new_value, value)
        grad_next = jnp.where(decreased, new_grad, grad)
        relative_change = (value - value_next) / jnp.maximum(jnp.abs(value), 1e-300)
        count = count + 1
        status = jnp.select(
            [
                ~jnp.isfinite(value_next),
                jnp.linalg.norm(grad_next) <= options.tol,
                ~decreased,
                relative_change <= options.ftol,
                count >= options.max_steps,
            ],
            [4, 0, 3, 1, 2],
            default=RUNNING,
        )
        return u_next, state, value_next, grad_next, count, evaluations, status

    initial_status = jnp.where(
        ~jnp.isfinite(value0), 4, jnp.where(jnp.linalg.norm(grad0) <= options.tol, 0, RUNNING)
    )
    carry = (u0, solver.init(u0), value0, grad0, jnp.asarray(0), jnp.asarray(1), initial_status)
    u, _, value, grad, count, evaluations, status = jax.lax.while_loop(
        lambda c: c[-1] == RUNNING, step, carry
    )
    return u, value, grad, count, evaluations, status


def adam_minimise(objective: Callable, u0, options: SolverPlan, max_steps: int):
    """Minimise `objective` with Adam for at most `max_steps`; returns the best point seen."""
    import optax  # only L-BFGS and Adam need it (a fifth of a second to import)

    solver = optax.adam(options.learning_rate)
    value_and_grad = jax.value_and_grad(objective)

    def step(carry):
        u, state, best_u, best_value, best_grad, count, _ = carry
        value, grad = value_and_grad(u)
        improved = jnp.isfinite(value) & (value < best_value)
        best_u = jnp.where(improved, u, best_u)
        best_grad = jnp.where(improved, grad, best_grad)
        best_value = jnp.where(improved, value, best_value)
        safe_grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        updates, state = solver.update(safe_grad, state, u)
        count = count + 1
        status = jnp.select(
            [jnp.linalg.norm(best_grad) <= options.tol, count >= max_steps],
            [0, 2],
            default=RUNNING,
        )
        return optax.apply_updates(u, updates), state, best_u, best_value, best_grad, count, status

    carry = (u0, solver.init(u0), u0, jnp.asarray(jnp.inf), jnp.full_like(u0, jnp.inf),
             jnp.asarray(0), jnp.asarray(RUNNING if max_steps > 0 else 2))
    _, _, u, value, grad, count, status = jax.lax.while_loop(
        lambda c: c[-1] == RUNNING, step, carry
    )
    status = jnp.where(jnp.isfinite(value), status, 4)
    return u, value, grad, count, count, status


def _cholesky_solve(matrix, vector):
    """Solve ``matrix x = vector`` for a small symmetric positive definite `matrix`.

    A Cholesky factorisation and two triangular solves, each a ``fori_loop`` over columns:
    no LAPACK call (whose first use on the CPU imports SciPy), and a traced size that does
    not grow with the dimension. A matrix that is not positive definite gives NaN.
    """
    size = matrix.shape[0]
    index = jnp.arange(size)

    def factor_column(j, lower):
        column = matrix[:, j] - lower @ lower[j]
        pivot = jnp.sqrt(column[j])
        return lower.at[:, j].set(
            jnp.where(index > j, column / pivot, jnp.where(index == j, pivot, 0.0)))

    lower = jax.lax.fori_loop(0, size, factor_column, jnp.zeros_like(matrix))

    def forward(i, partial):
        return partial.at[i].set((vector[i] - lower[i] @ partial) / lower[i, i])

    partial = jax.lax.fori_loop(0, size, forward, jnp.zeros_like(vector))

    def backward(k, solution):
        i = size - 1 - k
        return solution.at[i].set((partial[i] - lower[:, i] @ solution) / lower[i, i])

    return jax.lax.fori_loop(0, size, backward, jnp.zeros_like(vector))


#: Levenberg-Marquardt's damping at the start (relative to the largest diagonal entry of JᵀJ).
_INITIAL_DAMPING = 1e-3
#: Damping past which no step can decrease the loss at float64 precision.
_MAX_DAMPING = 1e16
#: Accepted steps in a row, each changing the loss by less than ``ftol``, after which
#: Levenberg-Marquardt stops even though its steps are longer than ``xtol`` (a loss falling
#: ever more slowly towards a bound or along a flat valley); the post-check then decides.
_STALLED_STEPS = 3
#: Levenberg-Marquardt gives up (status SLOW) when the loss falls by less than _SLOW_FALL of
#: itself over _SLOW_STEPS iterations: a crawl along a curved valley (e.g. towards a rate of
#: zero) that it would follow only in hundreds of steps.
_SLOW_STEPS = 20
_SLOW_FALL = 1e-3
#: Largest change of an unconstrained coordinate in one Levenberg-Marquardt step (a factor
#: e for a positive parameter): a poorly determined parameter (e.g. a Peclet number whose
#: curve barely changes towards zero) does not leap across decades in one Gauss-Newton step
#: onto a plateau of the loss.
_MAX_STEP = 1.0


def lm_initial(u0, empty):
    """Levenberg–Marquardt's loop state before its first iteration (which only evaluates
    at `u0`); `empty`: zeros of the shapes of ``(r, J, aux)``. See :func:`lm_step`."""
    residual0, jacobian0, aux0 = empty
    return (u0, residual0, jacobian0, aux0, jnp.asarray(jnp.inf), jnp.asarray(_INITIAL_DAMPING),
            jnp.asarray(2.0), jnp.asarray(True), jnp.asarray(0), jnp.asarray(0),
            jnp.asarray(0), jnp.asarray(jnp.inf), jnp.asarray(RUNNING))


def lm_step(evaluate: Callable, carry, options: SolverPlan):
    """One Levenberg–Marquardt iteration on the loop state `carry` (see
    :func:`_levenberg_marquardt`); its last entry is the status (``RUNNING`` until a
    stopping rule fires)."""
    (u, residual, jacobian, aux, value, damping, factor, first, count, evaluations, stalled,
     checkpoint, _) = carry
    curvature = jacobian.T @ jacobian
    gradient = jacobian.T @ residual
    size = jnp.maximum(jnp.max(jnp.diag(curvature)), 1e-300)
    move = _cholesky_solve(curvature + damping * size * jnp.eye(gradient.shape[0]),
                           -gradient)
    longest = jnp.max(jnp.abs(move))
    move = move * jnp.where(longest > _MAX_STEP, _MAX_STEP / longest, 1.0)
    trial = jnp.where(first, u, u + move)
    new_residual, new_jacobian, new_aux = evaluate(trial)
    new_value = new_residual @ new_residual
    finite = jnp.isfinite(new_value) & jnp.all(jnp.isfinite(new_jacobian))
    accept = finite & (first | (new_value < value))
    predicted_fall = -(2.0 * gradient @ move + move @ curvature @ move)
    ratio = (value - new_value) / jnp.where(predicted_fall > 0, predicted_fall, jnp.inf)
    damping_next = jnp.where(
        first, _INITIAL_DAMPING,
        jnp.where(accept, damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3),
                  damping * factor))
    factor_next = jnp.where(accept, 2.0, 2.0 * factor)
    relative_change = (value - new_value) / jnp.maximum(jnp.abs(value), 1e-300)
    small_change = accept & ~first & (relative_change <= options.ftol)
    stalled = jnp.where(small_change, stalled + 1, jnp.where(accept, 0, stalled))

    def keep(new, old):
        return jax.tree.map(lambda a, b: jnp.where(accept, a, b), new, old)

    u, residual, jacobian, aux, kept_value = keep(
        (trial, new_residual, new_jacobian, new_aux, new_value),
        (u, residual, jacobian, aux, value))
    count = count + jnp.where(first, 0, 1)
    gradient_norm = jnp.linalg.norm(2.0 * jacobian.T @ residual)
    # Every _SLOW_STEPS iterations: did the loss fall by at least _SLOW_FALL of itself?
    milestone = ~first & (count % _SLOW_STEPS == 0)
    slow = milestone & (checkpoint - kept_value <= _SLOW_FALL * checkpoint)
    checkpoint = jnp.where(first | milestone, kept_value, checkpoint)
    status = jnp.select(
        [
            first & ~finite,
            ~first & (gradient_norm <= options.tol) & (longest <= options.xtol),
            small_change & ((longest <= options.xtol) | (stalled >= _STALLED_STEPS)),
            damping_next > _MAX_DAMPING,
            count >= options.max_steps,
            slow,
        ],
        [4, 0, 1, 3, 2, 10],
        default=RUNNING,
    )
    return (u, residual, jacobian, aux, kept_value, damping_next, factor_next,
            jnp.asarray(False), count, evaluations + 1, stalled, checkpoint, status)


def _levenberg_marquardt(evaluate: Callable, u0, empty, options: SolverPlan):
    """Minimise ``r(u)·r(u)`` from `u0` by Levenberg–Marquardt in a while_loop.

    `evaluate(u) -> (r, J, aux)`: residuals, their Jacobian in `u` and anything else wanted
    at the final point; `empty`: zeros of the shapes of ``(r, J, aux)``. The step solves
    ``(JᵀJ + λ m I) δ = -Jᵀr`` (``m`` the largest diagonal entry of ``JᵀJ``: Levenberg's
    damping in the unconstrained coordinates, so a poorly determined direction moves like
    gradient descent rather than by a huge Gauss–Newton step), is shortened to at most
    :data:`_MAX_STEP` in every coordinate, and λ follows Nielsen's update. The first
    iteration only evaluates at `u0`, so the program holds the model once.
    Returns ``(u, value, gradient, steps, evaluations, status, aux)``.
    """
    carry = jax.lax.while_loop(lambda c: c[-1] == RUNNING,
                               lambda c: lm_step(evaluate, c, options),
                               lm_initial(u0, empty))
    u, residual, jacobian, aux, value, _, _, _, count, evaluations, _, _, status = carry
    return u, value, 2.0 * jacobian.T @ residual, count, evaluations, status, aux


def _single_start_function(model, layout: Layout, options: SolverPlan) -> Callable:
    """The pure function that fits one curve from one start (see :class:`MultiStartSolver`).

    ``(u0, warm, base, time, observed, weights) -> dict``: `u0` the start in unconstrained
    coordinates, `warm` whether it first takes the Adam warm-up, `base` all parameter values
    (fixed ones used), the curve and its weights (zero weight: a point that does not count,
    whatever the model gives there).
    """
    loss_function = LOSSES[options.loss]

    def predict(free_values, base, time):
        return model(time, layout.all_values(free_values, base))

    def solve(u0, warm, base, time, observed, weights):
        used = weights > 0
        if options.loss == "sse":
            scale = jnp.sum(weights * observed**2)
        else:
            scale = jnp.sum(weights * jnp.abs(observed)) / jnp.sum(weights)
        scale = jnp.where(scale > 0, scale, 1.0)

        def objective(u):
            free_values = layout.physical_from_unconstrained(u)
            residual = jnp.where(used, predict(free_values, base, time) - observed, 0.0)
            return loss_function(residual, weights) / scale

        warm_evaluations = jnp.asarray(0)
        if options.warmup_steps > 0 and options.method != "adam":
            def warm_up(u):
                u_warm, _, _, _, evaluations, _ = adam_minimise(objective, u, options,
                                                        options.warmup_steps)
                return u_warm, evaluations

            u0, warm_evaluations = jax.lax.cond(warm, warm_up,
                                                lambda u: (u, jnp.asarray(0)), u0)
        if options.method == "lm":
            root = jnp.sqrt(weights / scale)

            def evaluate(u):
                free_values = layout.physical_from_unconstrained(u)
                derivative = jax.jvp(layout.physical_from_unconstrained, (u,),
                                     (jnp.ones_like(u),))[1]

                def curve(f):
                    value = predict(f, base, time)
                    return value, value

                jacobian, predicted = jax.jacfwd(curve, has_aux=True)(free_values)
                residual = jnp.where(used, root * (predicted - observed), 0.0)
                scaled = jnp.where(used[:, None], root[:, None] * jacobian * derivative, 0.0)
                return residual, scaled, (predicted, jacobian)

            size, count = time.shape[0], u0.shape[0]
            empty = (jnp.zeros(size), jnp.zeros((size, count)),
                     (jnp.zeros(size), jnp.zeros((size, count))))
            u, value, grad, steps, evaluations, status, (predicted, jacobian) = (
                _levenberg_marquardt(evaluate, u0, empty, options))
            free_values = layout.physical_from_unconstrained(u)
        else:
            if options.method == "adam":
                u, value, grad, steps, evaluations, status = adam_minimise(objective, u0, options,
                                                                   options.max_steps)
            else:
                u, value, grad, steps, evaluations, status = _lbfgs(objective, u0, options)
            free_values = layout.physical_from_unconstrained(u)
            predicted = predict(free_values, base, time)
            jacobian = jax.jacfwd(predict)(free_values, base, time)
        all_from_free = jax.jacfwd(
            lambda f: jnp.stack(list(layout.all_values(f, base).values())))(free_values)
        return {
            "u": u,
            "free_values": free_values,
            "all_values": jnp.stack(list(layout.all_values(free_values, base).values())),
            "predicted": predicted,
            "jacobian": jacobian,
            "derivative": jax.jvp(layout.physical_from_unconstrained, (u,),
                                  (jnp.ones_like(u),))[1],
            "all_from_free": all_from_free,
            "scaled_loss": value,
            "scale": scale,
            "grad_norm": jnp.linalg.norm(grad),
            "steps": steps,
            "evaluations": evaluations + warm_evaluations,
            "status": status,
        }

    return solve


def model_identity(model) -> tuple | None:
    """What identifies a model's function in another process, or ``None``.

    A built-in model (:data:`fitting.models.MODELS`) by its name; a model that declares an
    ``export_identity`` (a tuple of strings and bytes) by that; a built-in model wrapped in a
    measurement (a model with ``base``, ``inlet`` — with a ``key`` — and ``free``, such as
    ``fitting.measurement.MeasuredModel``) by its class, the base's identity, the inlet and
    the free measurement parameters. Other models (a user's function) have none: their
    programs are traced in each process, never exported.

    **Arguments:** `model`: a :class:`~fitting.models.Model`.

    **Returns:** a tuple, or ``None``.
    """
    declared = getattr(model, "export_identity", None)
    if declared is not None:
        return ("declared", tuple(declared))
    if MODELS.get(getattr(model, "name", None)) is model:
        return ("built-in", model.name)
    base, inlet = getattr(model, "base", None), getattr(model, "inlet", None)
    if base is not None and hasattr(inlet, "key"):
        inner = model_identity(base)
        if inner is not None:
            return (type(model).__qualname__, inner, inlet.key,
                    tuple(getattr(model, "free", ())))
    return None


#: Solver programs of this process by (model, layout, plan), most recently used last.
_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
#: Solver programs kept at most (each holds its compiled executables).
_MAX_PROGRAMS = 64


def _solver_program(model, layout: Layout, options: SolverPlan) -> Program:
    """The single-start program of a model, layout and plan, shared within the process.

    A plan without warm-up runs on the program of the same plan with a warm-up when this
    process has one (the warm-up is skipped at run time, ``warm`` false), so the one-start
    refits after a multi-start fit (relative or combined errors, profiles) compile and load
    nothing new.
    """
    key = (model, layout, options)
    program = _PROGRAMS.get(key)
    if program is None and options.warmup_steps == 0:
        program = next((found for (m, lay, plan), found in reversed(_PROGRAMS.items())
                        if m is model and lay == layout
                        and dataclasses.replace(plan, warmup_steps=0) == options), None)
    if program is None:
        program = Program(_single_start_function(model, layout, options),
                           f"solve-{model.name}", export_key(model, layout, options))
        _PROGRAMS[key] = program
        while len(_PROGRAMS) > _MAX_PROGRAMS:
            _PROGRAMS.popitem(last=False)
    else:
        _PROGRAMS.move_to_end(next(k for k, v in _PROGRAMS.items() if v is program))
    return program


def export_key(model, *parts) -> tuple | None:
    """The key of a model's program for :mod:`jax.export` (see :func:`model_identity`)."""
    identity = model_identity(model)
    return None if identity is None else (identity, *map(repr, parts))


def _run(program: Program, arguments: tuple, times: list[float]) -> dict:
    """Run `program` on `arguments` as NumPy outputs; add run and compile seconds to `times`."""
    executable, seconds = program.executable(arguments)
    began = _time.perf_counter()
    out = jax.device_get(executable(*arguments))
    times[0] += _time.perf_counter() - began
    times[1] += seconds
    return out


#: Newton iterations (full Hessian) at most, where Levenberg–Marquardt stops on a singular
#: Gauss–Newton curvature.
_NEWTON_STEPS = 10


def _inside(layout: Layout, free_values: np.ndarray) -> bool:
    """Whether free parameter values lie strictly inside their bounds."""
    for j, kind in enumerate(layout.kinds):
        if kind in ("lower", "both") and not free_values[j] > layout.lower[j]:
            return False
        if kind in ("upper", "both") and not free_values[j] < layout.upper[j]:
            return False
    return True


class MultiStartSolver:
    """A multi-start solver: the compiled single-start program run over starts and curves.

    Each start on each curve is one call of one compiled program (no ``vmap``); the start
    with the lowest finite loss wins, and its Gauss–Newton step (least squares) is checked
    in NumPy. Where Levenberg–Marquardt stops at a point that check does not accept (a flat
    loss, or a minimum held only by the second-order term ``Σ r ∇²r`` that Gauss–Newton
    ignores, as on the four-compartment mirror line), Newton's method with the full Hessian
    (the program of :func:`compiled_curvature`, which the second-order check needs there
    anyway) continues from it while the Hessian is positive definite, and
    Levenberg–Marquardt runs once more from its end. Where Levenberg–Marquardt crawls (status
    SLOW, or out of steps) along a curved valley, L-BFGS, which learns the curvature along
    it, redoes that start (a second program, compiled only then) and the better of the two
    is kept. Their evaluations are counted too.
    Build it with :func:`compiled_solver`, run it with :func:`run_solver`.

    **Arguments:** `model`, `layout`, `options` (a :class:`SolverPlan`), and `batch`:
    ``'curves'`` (each row of the arguments is a curve with its own data) or ``'bases'`` (each
    row is a set of fixed-parameter values on one curve, for profiles).
    """

    def __init__(self, model, layout: Layout, options: SolverPlan, batch: str):
        if batch not in ("curves", "bases"):
            raise ValueError(f"batch must be 'curves' or 'bases', got {batch!r}")
        self.model, self.layout, self.options, self.batch = model, layout, options, batch
        self.program = _solver_program(model, layout, options)
        self._lbfgs: Program | None = None

    def __call__(self, starts, warm, base, time, observed, weights) -> tuple[dict, float, float]:
        """Run every start on every row; returns the outputs (a leading axis per row), the run
        time and the compile (or load) time in seconds."""
        starts = np.asarray(starts, dtype=float)
        warm = np.asarray(warm, dtype=bool)
        base = np.asarray(base, dtype=float)
        shared = self.batch == "bases"
        times = [0.0, 0.0]
        outputs = []
        for i in range(starts.shape[0]):
            data = [np.asarray(a if shared else a[i], dtype=float)
                    for a in (time, observed, weights)]
            size = data[0].shape[0]
            padded = pad_curve(*data, padded_length(size))
            per_start = [_run(self.program, (starts[i, s], np.asarray(warm[s]), base[i],
                                              *padded), times)
                         for s in range(starts.shape[1])]
            values = np.array([float(o["scaled_loss"]) for o in per_start])
            best = int(np.argmin(np.where(np.isfinite(values), values, np.inf)))
            out = per_start[best]
            status, newton_step = self._check(out, *padded)
            evaluations = int(np.sum([o["evaluations"] for o in per_start]))
            steps = int(out["steps"])
            polished = None
            if self.options.method == "lm" and status == Status.FLAT:
                polished = self._newton_polish(out, base[i], padded, times)
            elif self.options.method == "lm" and status in (Status.SLOW, Status.MAX_STEPS):
                polished = _run(self.lbfgs_program(), (starts[i, best], np.asarray(warm[best]),
                                                       base[i], *padded), times)
            if polished is not None:
                evaluations += int(polished["evaluations"])
                steps += int(polished["steps"])
                if float(polished["scaled_loss"]) <= values[best]:
                    out, values[best] = polished, float(polished["scaled_loss"])
                    status, newton_step = self._check(out, *padded)
            # A model curve that explains (almost) nothing of the data sits on a plateau of
            # the loss where every stopping rule can fire; never call that converged.
            if values[best] >= PLATEAU:
                status = Status.MISSES_DATA
            outputs.append({
                "free_values": out["free_values"],
                "all_values": out["all_values"],
                "predicted": out["predicted"][:size],
                "jacobian": out["jacobian"][:size],
                "all_from_free": out["all_from_free"],
                "scaled_loss": np.asarray(values[best]),
                "start_losses": values * float(out["scale"]),
                # Where each start ended (free values; the polished best start's end for it).
                "start_values": np.stack([out["free_values"] if s == best else
                                          o["free_values"] for s, o in enumerate(per_start)]),
                "grad_norm": out["grad_norm"],
                "steps": np.asarray(steps),
                "evaluations": np.asarray(evaluations),
                "status": np.asarray(int(status)),
                "newton_step": np.asarray(newton_step),
            })
        run_time, compile_time = times
        return ({k: np.stack([o[k] for o in outputs]) for k in outputs[0]}, run_time,
                compile_time)

    def lbfgs_program(self) -> Program:
        """The L-BFGS program that redoes a start where Levenberg–Marquardt crawled (built once)."""
        if self._lbfgs is None:
            options = dataclasses.replace(self.options, method="lbfgs")
            self._lbfgs = Program(_single_start_function(self.model, self.layout, options),
                                   f"lbfgs-{self.model.name}",
                                   export_key(self.model, self.layout, options))
        return self._lbfgs

    def _newton_polish(self, out: dict, base, padded, times: list[float]) -> dict | None:
        """Newton's method with the full Hessian from `out`'s end, then Levenberg–Marquardt
        again from there (for its outputs); ``None`` where the Hessian is not positive
        definite at the start. Its evaluations and steps include the Newton iterations."""
        layout = self.layout
        program = _curvature_program(self.model, layout)
        free = np.asarray(out["free_values"], dtype=float)
        value, gradient, hessian = _run(program, (free, base, *padded), times)
        evaluations = iterations = 1
        while iterations <= _NEWTON_STEPS:
            if not (np.isfinite(value) and np.all(np.isfinite(gradient))
                    and np.all(np.isfinite(hessian))):
                break
            hessian = 0.5 * (hessian + hessian.T)
            eigenvalues = np.linalg.eigvalsh(hessian)
            if eigenvalues[0] <= 1e-12 * max(eigenvalues[-1], 1e-300):
                if iterations == 1:
                    return None
                break
            step = -np.linalg.solve(hessian, gradient)
            if -float(gradient @ step) <= 1e-15 * value:  # at the precision of the loss
                break
            for _ in range(30):  # halve into the bounds and onto a decrease
                candidate = free + step
                if _inside(layout, candidate):
                    new = _run(program, (candidate, base, *padded), times)
                    evaluations += 1
                    if new[0] <= value:
                        break
                step = 0.5 * step
            else:
                break
            free, (value, gradient, hessian) = candidate, new
            iterations += 1
        u = layout.unconstrained_from_physical(free)
        again = _run(self.program, (u, np.asarray(False), base, *padded), times)
        again["evaluations"] = int(again["evaluations"]) + evaluations
        again["steps"] = int(again["steps"]) + iterations
        return again

    def _check(self, out: dict, time, observed, weights) -> tuple[Status, float]:
        """The status after the Gauss–Newton check (least squares), and that step's length."""
        status = Status(int(out["status"]))
        if self.options.loss != "sse":
            return status, math.nan
        # Distance to the optimum, estimated by one Gauss-Newton step in the transformed
        # coordinates (minimum-norm step: unidentifiable directions do not count).
        used = weights > 0
        root = np.sqrt(weights)
        design = np.where(used[:, None], root[:, None] * out["jacobian"] * out["derivative"], 0.0)
        residual = np.where(used, root * (out["predicted"] - observed), 0.0)
        newton_step = math.nan
        if np.all(np.isfinite(design)) and np.all(np.isfinite(residual)):
            step = np.linalg.lstsq(design, -residual, rcond=1e-10)[0]
            newton_step = float(np.max(np.abs(step)))
        if status in (Status.GRADIENT, Status.LOSS_CHANGE, Status.NO_DECREASE):
            if newton_step <= self.options.xtol:
                if status == Status.NO_DECREASE:
                    status = Status.PRECISION_LIMIT
            else:
                status = Status.FLAT
        return status, newton_step


@functools.lru_cache(maxsize=64)
def compiled_solver(model, layout: Layout, options: SolverPlan, batch: str) -> MultiStartSolver:
    """The multi-start solver of one model, layout and option set (see :class:`MultiStartSolver`).

    **Arguments:** the model, its :class:`~fitting.parameters.Layout`, the
    :class:`SolverPlan`, and `batch` (``'curves'`` or ``'bases'``).

    **Returns:** the solver, kept for later fits of the same kind.
    """
    return MultiStartSolver(model, layout, options, batch)


def run_solver(solver: Callable, *arguments) -> tuple[dict, float, float]:
    """Run a solver from :func:`compiled_solver`.

    **Arguments:** the solver, then starts ``(rows, starts, free)``, warm-up flags
    ``(starts,)``, base values ``(rows, parameters)``, and times, observed values and weights
    (``(rows, samples)`` for ``'curves'``, ``(samples,)`` for ``'bases'``).

    **Returns:** ``(outputs, run time, compile time)``, times in seconds.
    """
    return solver(*arguments)


def start_points(
    layout: Layout, start: np.ndarray, anchor: np.ndarray | None, n_starts: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Start points in unconstrained coordinates, and which of them get the Adam warm-up.

    Row 0 is `start`; with `anchor` (the method-of-moments estimate) and ``n_starts >= 2``,
    row 1 is the anchor; the remaining rows are random: log-uniform within a factor of 10 of
    the anchor (or start) for one-sided bounds, uniform inside two-sided bounds (log-uniform
    when positive and wider than a factor 100), normal around it without bounds.
    """
    rng = np.random.default_rng(seed)
    u_start = layout.unconstrained_from_physical(start)
    starts = np.tile(u_start, (n_starts, 1))
    first_random = 1
    centre = u_start
    if anchor is not None and n_starts >= 2:
        centre = layout.unconstrained_from_physical(anchor)
        starts[1] = centre
        first_random = 2
    count = n_starts - first_random
    spread = math.log(10.0)
    for j, kind in enumerate(layout.kinds):
        if count <= 0:
            break
        if kind in ("lower", "upper"):
            starts[first_random:, j] = centre[j] + rng.uniform(-spread, spread, count)
        elif kind == "both":
            low, high = layout.lower[j], layout.upper[j]
            fraction = rng.uniform(0.02, 0.98, count)
            if low > 0 and high / low > 100:
                values = np.exp(np.log(low) + fraction * (np.log(high) - np.log(low)))
            else:
                values = low + fraction * (high - low)
            starts[first_random:, j] = np.log((values - low) / (high - values))
        else:
            starts[first_random:, j] = centre[j] + rng.normal(0.0, 1.0, count)
    warm = np.arange(n_starts) >= first_random
    return starts, warm


@functools.lru_cache(maxsize=64)
def _curvature_program(model, layout: Layout) -> Program:
    """The program of ``(value, gradient, Hessian)`` of ``Σ w r²`` in the free parameters
    (zero weights: points that do not count), the model held once."""

    def sse(free_values, base, time, observed, weights):
        values = layout.all_values(free_values, base)
        residual = jnp.where(weights > 0, model(time, values) - observed, 0.0)
        return jnp.sum(weights * residual**2)

    def gradient_and_value(*arguments):
        value, gradient = jax.value_and_grad(sse)(*arguments)
        return gradient, (value, gradient)

    def curvature(*arguments):
        hessian, (value, gradient) = jax.jacfwd(gradient_and_value, has_aux=True)(*arguments)
        return value, gradient, hessian

    return Program(curvature, f"curvature-{model.name}", export_key(model, layout))


@functools.lru_cache(maxsize=64)
def compiled_curvature(model, layout: Layout) -> Callable:
    """``(value, gradient, Hessian)`` of ``Σ w r²`` in the free parameters, compiled.

    **Arguments:** the model and its layout.

    **Returns:** a function of ``(free_values, base, time, observed, weights)`` returning NumPy
    arrays (the curve padded like the solver's, with zero weights).
    """

    program = _curvature_program(model, layout)

    def run(free_values, base, time, observed, weights):
        size = np.asarray(time).shape[0]
        arguments = (np.asarray(free_values, dtype=float), np.asarray(base, dtype=float),
                     *pad_curve(time, observed, weights, padded_length(size)))
        executable, _ = program.executable(arguments)
        return jax.device_get(executable(*arguments))

    return run


def second_order_distance(model, layout: Layout, free_values, base, time, observed, weights,
                          sse: float, dof: float) -> tuple[float, tuple[str, ...]]:
    """Newton's distance to the nearest minimum in standard errors, and the bounds it lies on.

    Near a minimum ``SSE(p) ≈ SSE* + ½ (p - p*)ᵀ H (p - p*)``, so Newton's method predicts
    ``SSE - SSE* = ½ gᵀ H⁻¹ g``; divided by ``s² = SSE / dof`` this is the squared distance
    to the minimum in the metric of the standard errors (exact for a linear model). A
    parameter whose gradient pushes it onto a bound it (nearly) sits on — Newton's step in
    that parameter alone (``|g_j| / H_jj``) reaches the bound, and the loss falls by less
    than ``SECOND_ORDER_DISTANCE² s²`` when it goes there — is taken as on that bound: it
    adds that fall, and the others are checked on their own.

    **Arguments:** the model and layout of a fit, the free values at its end, the base
    (fixed) values, the data (`time`, `observed`, `weights`), its ``Σ w r²`` and degrees of
    freedom.

    **Returns:** ``(distance, names on a bound)``; ``(inf, ())`` when the free parameters'
    Hessian is not positive definite.
    """
    _, gradient, hessian = compiled_curvature(model, layout)(free_values, base, time,
                                                             observed, weights)
    gradient, hessian = np.asarray(gradient), np.asarray(hessian)
    values = np.asarray(free_values, dtype=float)
    if not (np.all(np.isfinite(gradient)) and np.all(np.isfinite(hessian))):
        return math.inf, ()
    variance = sse / dof
    small = SECOND_ORDER_DISTANCE**2 * variance
    on_bound, fall = [], 0.0
    for j, kind in enumerate(layout.kinds):
        if kind in ("lower", "both") and gradient[j] > 0:
            reach = values[j] - layout.lower[j]
        elif kind in ("upper", "both") and gradient[j] < 0:
            reach = layout.upper[j] - values[j]
        else:
            continue
        gain = abs(gradient[j]) * reach
        if gain <= small and abs(gradient[j]) >= hessian[j, j] * reach:
            on_bound.append(j)
            fall += gain
    inside = [j for j in range(values.size) if j not in on_bound]
    if inside:
        block = hessian[np.ix_(inside, inside)]
        block = 0.5 * (block + block.T)
        eigenvalues = np.linalg.eigvalsh(block)
        if eigenvalues[0] <= 1e-12 * max(eigenvalues[-1], 1e-300):
            return math.inf, ()
        fall += 0.5 * float(gradient[inside] @ np.linalg.solve(block, gradient[inside]))
    return math.sqrt(max(fall, 0.0) / variance), tuple(layout.free[j] for j in on_bound)
