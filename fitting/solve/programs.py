"""Compiled programs and their caches across processes: a ``Program`` compiled once per
argument shapes, JAX's persistent compilation cache
(:func:`~fitting.solve.enable_compilation_cache`), and the :mod:`jax.export` files of the
built-in models' programs, keyed by :func:`~fitting.solve.model_identity` and
``export_key``."""

from __future__ import annotations

import functools
import hashlib
import os
import threading
import time as _time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import numpy as np
from jax import export as jax_export

import axialmix  # float64 before any JAX array is made; its version keys the exports
from axialmix.network import regular_grid
from fitting.models import MODELS
from fitting.models.base import traced_on_time_grid


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


@functools.lru_cache(maxsize=1)
def _source_fingerprint() -> str:
    """A digest of the installed package (its version, and each source file's path, size and
    modification time) and of the JAX in use: exported programs are valid only for these.
    The sources are those of :mod:`axialmix` and of the whole :mod:`fitting` package (this
    module's grandparent folder), each path relative to the folder above them."""
    digest = hashlib.sha256()
    digest.update(repr((axialmix.__version__, jax.__version__, jax.lib.__version__,
                        jax.default_backend(), jax.config.jax_enable_x64)).encode())
    for root in (Path(axialmix.__file__).parent, Path(__file__).parents[1]):
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

    With `times` (the position of the argument that holds the curves' times, one row per
    curve), each program is traced knowing whether those times are all regular grids
    (:func:`axialmix.network.regular_grid`, said through
    :func:`fitting.models.base.traced_on_time_grid`): a built-in compartment network then
    compiles only the propagation its times need, not both. The two programs are kept, and
    exported, apart. Only programs with a `key` (the models this package defines) are told:
    a user's function may hold jitted code of its own, whose trace JAX keeps without it.
    """

    def __init__(self, function: Callable, name: str, key: tuple | None,
                 times: int | None = None):
        self.name = name
        self.key = key
        self.times = times if key is not None else None
        self.executables: dict = {}
        self._compiling = threading.Lock()
        # The function to trace by what its times are said to be (None: not said).
        self._traced: dict[bool | None, Callable] = {None: jax.jit(function)}
        if self.times is not None:
            for regular in (False, True):
                def on_grid(*arguments, regular=regular):
                    with traced_on_time_grid(regular):
                        return function(*arguments)

                self._traced[regular] = jax.jit(on_grid)

    def executable(self, arguments: Sequence[np.ndarray]) -> tuple[Callable, float]:
        """The compiled program for these arguments' shapes (and, with `times`, whether
        their times are regular grids), and the seconds it took to get (thread-safe: threads
        asking for the same program at once compile it once)."""
        grid = None if self.times is None else regular_grid(arguments[self.times])
        signature = (grid, *((a.shape, a.dtype) for a in arguments))
        found = self.executables.get(signature)
        if found is not None:
            return found, 0.0
        with self._compiling:
            found = self.executables.get(signature)
            if found is not None:
                return found, 0.0
            began = _time.perf_counter()
            specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in arguments]
            function = self._traced[grid]
            if self.key is not None and _EXPORT_FOLDER is not None:
                function = self._exported(function, specs, grid)
            found = self.executables[signature] = function.lower(*specs).compile()
            return found, _time.perf_counter() - began

    def _exported(self, function: Callable, specs, grid: bool | None) -> Callable:
        shapes = tuple((s.shape, str(s.dtype)) for s in specs)
        identity = (self.key, shapes) if grid is None else (
            self.key, shapes, "regular times" if grid else "irregular times")
        digest = hashlib.sha256(repr(identity).encode()).hexdigest()[:24]
        label = "".join(c if c.isalnum() or c in "-_" else "_" for c in self.name)[:40]
        path = _EXPORT_FOLDER / f"{_source_fingerprint()}-{label}-{digest}{EXPORT_SUFFIX}"
        try:
            exported = jax_export.deserialize(bytearray(path.read_bytes()))
            if tuple((a.shape, str(a.dtype)) for a in exported.in_avals) == shapes:
                return jax.jit(exported.call)
        except Exception:  # noqa: BLE001  (missing, unreadable or stale: export it anew)
            pass
        exported = jax_export.export(function)(*specs)
        try:
            _write_export(path, exported.serialize())
        except (OSError, ImportError):  # a read-only cache, or no flatbuffers: run unsaved
            pass
        return jax.jit(exported.call)


def model_identity(model) -> tuple | None:
    """What identifies a model's function in another process, or ``None``.

    A built-in model (:data:`fitting.models.MODELS`) by its name; a model that declares an
    ``export_identity`` (a tuple of strings and bytes; a network file's model, by the file's
    content and parameter mapping) by that; a built-in model wrapped in a
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


def export_key(model, *parts) -> tuple | None:
    """The key of a model's program for :mod:`jax.export` (see :func:`model_identity`)."""
    identity = model_identity(model)
    return None if identity is None else (identity, *map(repr, parts))


def run_program(program: Program, arguments: tuple, times: list[float]) -> dict:
    """Run `program` on `arguments` as NumPy outputs; add run and compile seconds to `times`."""
    executable, seconds = program.executable(arguments)
    began = _time.perf_counter()
    out = jax.device_get(executable(*arguments))
    times[0] += _time.perf_counter() - began
    times[1] += seconds
    return out
