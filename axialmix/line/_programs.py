"""How the line's compiled programs are run: in this process, or through a caller's cache.

The funnel plot and the diversion each run a few pure functions of arrays as compiled
programs (the scan of the nominal window, the covariance samples in one batched program, the
grid of durations). By default they are compiled in this process (``equinox.filter_jit``).
A caller that keeps compiled programs across processes (the command line exports them to the
user's cache) passes a :data:`ProgramRunner`: it is called with the program's name, the
function and its arguments, and returns the compiled program (a
:class:`CompiledProgram`, called with the same arguments).

:func:`program_identity` says what identifies such a call in another process: the names of
the built-in unit models and of every static value in the arguments (strings, numbers,
tuples, compartment networks), the pytree structure, but not the array values (the caller
adds their shapes). A call whose static values cannot be named stably (a user's own
:class:`~axialmix.line.UnitModel`, a function) has no identity: its program is compiled in
each process and never stored.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from typing import Any, Protocol

import equinox as eqx
import jax
import numpy as np

from axialmix.line._models import (
    CLOSED_CLOSED,
    CLOSED_CLOSED_EXCHANGE,
    CLOSED_CLOSED_TANK,
    EMPIRICAL,
    NETWORK,
    OPEN_OPEN,
    TANKS,
    TANKS_EXCHANGE,
    UnitModel,
)
from axialmix.network import CompartmentNetwork

__all__ = ["CompiledProgram", "ProgramRunner", "compile_program", "program_identity",
           "rtd_moments", "run_program"]


class CompiledProgram(Protocol):
    """A compiled program: called with the arguments it was compiled for (the same
    structure and shapes) it returns what its function returns."""

    def __call__(self, *arguments) -> Any: ...

    def temporary_bytes(self) -> int:
        """Bytes of temporary memory the program needs while it runs (0 when unknown)."""
        ...


#: ``runner(name, function, arguments) -> CompiledProgram``: compiles a pure function of its
#: arguments' arrays (its other values static) as one program.
ProgramRunner = Callable[[str, Callable, tuple], CompiledProgram]

#: The built-in unit models, named across processes by their names.
_BUILT_IN = {id(model): model.name for model in (
    CLOSED_CLOSED, OPEN_OPEN, TANKS, CLOSED_CLOSED_EXCHANGE, TANKS_EXCHANGE,
    CLOSED_CLOSED_TANK, NETWORK, EMPIRICAL)}

class _InProcess:
    """A program compiled in this process (``equinox.filter_jit``, lowered and compiled
    once per structure, static values and shapes)."""

    def __init__(self, function: Callable, arguments: tuple):
        self.compiled = eqx.filter_jit(function).lower(*arguments).compile()

    def __call__(self, *arguments):
        return self.compiled(*arguments)

    def temporary_bytes(self) -> int:
        analysis = self.compiled.compiled.memory_analysis()
        return int(getattr(analysis, "temp_size_in_bytes", 0) or 0) if analysis else 0


#: Programs compiled in this process, by function, structure, static values and shapes.
_COMPILED: dict = {}
#: Programs kept at most (each holds its executable).
_MAX_COMPILED = 32


def _in_process_key(function: Callable, arguments: tuple) -> tuple:
    leaves, structure = jax.tree_util.tree_flatten(arguments)
    return (function, structure, tuple(
        (np.shape(leaf), str(leaf.dtype)) if eqx.is_array(leaf) else ("static", leaf)
        for leaf in leaves))


def compile_program(runner: ProgramRunner | None, name: str, function: Callable,
                    arguments: tuple) -> CompiledProgram:
    """`function` compiled for `arguments`: by `runner`, or in this process.

    **Arguments:**

    - `runner`: a :data:`ProgramRunner`, or None (``equinox.filter_jit`` in this process,
      each program compiled once).
    - `name`: the program's name (for the runner's files and messages).
    - `function`: a module-level pure function; arrays in `arguments` are traced, every
      other value is static. It returns arrays (a tuple or dict of them).
    - `arguments`: its arguments (pytrees).

    **Returns:** the :class:`CompiledProgram`.
    """
    if runner is not None:
        return runner(name, function, arguments)
    key = _in_process_key(function, arguments)
    found = _COMPILED.get(key)
    if found is None:
        if len(_COMPILED) >= _MAX_COMPILED:
            _COMPILED.clear()
        found = _COMPILED[key] = _InProcess(function, arguments)
    return found


_JITTED: dict[Callable, Callable] = {}


def run_program(runner: ProgramRunner | None, name: str, function: Callable, *arguments):
    """``function(*arguments)`` as one compiled program: through `runner` (see
    :func:`compile_program`), or ``equinox.filter_jit`` in this process when `runner` is None
    or an argument is traced (the call is inside a JAX transformation: ``grad``, ``vmap``)."""
    if runner is None or any(isinstance(leaf, jax.core.Tracer)
                             for leaf in jax.tree_util.tree_leaves(arguments)):
        jitted = _JITTED.get(function)
        if jitted is None:
            jitted = _JITTED[function] = eqx.filter_jit(function)
        return jitted(*arguments)
    return runner(name, function, arguments)(*arguments)


class _Unstable(Exception):
    """A static value without a name that holds across processes."""


def _stable(value: Any) -> str:
    if value is None or isinstance(value, bool | int | float | str | complex):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, tuple | list):
        return f"{type(value).__name__}(" + ",".join(_stable(v) for v in value) + ")"
    if isinstance(value, dict):
        return "dict(" + ",".join(f"{_stable(k)}={_stable(v)}" for k, v in sorted(
            value.items(), key=lambda item: repr(item[0]))) + ")"
    if isinstance(value, UnitModel):
        if id(value) not in _BUILT_IN:
            raise _Unstable(value.name)
        return f"UnitModel:{_BUILT_IN[id(value)]}"
    if isinstance(value, CompartmentNetwork):
        return "CompartmentNetwork:" + json.dumps(value.to_dict(), sort_keys=True)
    if isinstance(value, np.ndarray | np.generic):
        array = np.asarray(value)
        digest = hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()
        return f"ndarray:{array.dtype}:{array.shape}:{digest}"
    if type(value).__name__.strip("_") == "Missing" and type(value).__module__.startswith(
            "equinox"):
        return "Missing"  # equinox's marker of a field without a value
    raise _Unstable(type(value).__qualname__)


def _stable_structure(treedef) -> str:
    node = treedef.node_data()
    if node is None:
        return "*"
    kind, data = node
    children = ",".join(_stable_structure(child) for child in treedef.children())
    return f"{kind.__module__}.{kind.__qualname__}[{_stable(data)}]({children})"


def program_identity(function: Callable, arguments: tuple) -> tuple[str, ...] | None:
    """What identifies ``function(*arguments)`` as a program in another process, or None.

    **Arguments:**

    - `function`: the module-level function (named by its module and qualified name).
    - `arguments`: its arguments.

    **Returns:**

    ``(function, structure, static values)`` as strings: the pytree structure of the
    arguments (array positions marked, arrays' shapes left to the caller) and every
    non-array value, named stably; None when some value has no stable name (see the module
    notes).
    """
    dynamic, static = eqx.partition(arguments, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(static)
    try:
        return (f"{function.__module__}.{function.__qualname__}",
                _stable_structure(jax.tree_util.tree_structure(dynamic)),
                _stable_structure(treedef), _stable(leaves))
    except _Unstable:
        return None


def _moments_program(rtd):
    return rtd.mean(), rtd.variance()


def rtd_moments(rtd, *, programs: ProgramRunner | None = None) -> tuple[float, float]:
    """The mean residence time and the variance of a unit or table, as one program (a
    network's moments are a few linear solves: evaluated one operation at a time each would
    be compiled apart).

    **Arguments:**

    - `rtd`: a :class:`~axialmix.line.Unit` or :class:`~axialmix.line.TabulatedRTD`.
    - `programs`: how the program is run (see :func:`compile_program`).

    **Returns:** ``(mean, variance)`` (time unit, time unit squared) as floats.
    """
    mean, variance = run_program(programs, "moments", _moments_program, rtd)
    return float(mean), float(variance)
