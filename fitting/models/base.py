"""The model type: a :class:`~fitting.models.Model` is a named, immutable JAX function
``f(t, params) -> E(t)`` with its parameters' default settings, optional hooks (start values,
equivalent ADM, statements, units, meanings, step and inlet responses), and a user's own
function wrapped as one (:func:`~fitting.models.custom_model`)."""

from __future__ import annotations

import contextlib
import contextvars
import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from fitting.data import Curve
from fitting.parameters import Parameter, Parameters, clip_into_bounds

ModelFunction = Callable[..., object]
#: ``(values, length_m or None, time_unit) -> {key: value}``: the equivalent closed–closed
#: ADM of fitted values, units in the keys (``tau_<unit>``, ``peclet``, ``velocity_m_per_s``,
#: ``dispersion_m2_per_s``, ...; ``None`` where undefined).
EquivalentADM = Callable[[Mapping[str, float], "float | None", str], dict[str, Any]]
#: ``(values, settings) -> [sentence, ...]``: facts about a fit of this model in words.
Statements = Callable[[Mapping[str, float], Mapping[str, Parameter]], list[str]]
#: ``(t, params, inlet_times, inlet_values) -> outlet``: the outlet signal at times ``t`` for
#: an inlet signal linear between its samples, zero before the first and after the last
#: (JAX; ``t`` need not be sorted against the inlet samples).
InletResponse = Callable[..., object]

_TIME_GRID: contextvars.ContextVar[bool | None] = contextvars.ContextVar(
    "fitting_traced_time_grid", default=None)


@contextlib.contextmanager
def traced_on_time_grid(regular: bool | None) -> Iterator[None]:
    """Trace a program of curves inside this block with what their times are: ``True``
    when every curve's times are a regular grid (:func:`axialmix.network.regular_grid`),
    ``False`` when not, ``None``: not said. The built-in network models pass it to
    :func:`axialmix.network.exit_age` (``regular``), so that only the propagation those
    times need is compiled. A program traced here must be kept apart from one traced with
    another value (:class:`fitting.solve.Program` keys its executables by it).

    **Arguments:** `regular`: the value.
    """
    token = _TIME_GRID.set(regular)
    try:
        yield
    finally:
        _TIME_GRID.reset(token)


def traced_time_grid() -> bool | None:
    """What the program being traced says of its times (see :func:`traced_on_time_grid`);
    ``None`` outside one."""
    return _TIME_GRID.get()


def parameter_unit(template: str, time_unit: str, value_unit: str | None = None) -> str:
    """A parameter's unit from its template: ``{t}`` is the curve's time unit, ``{y}`` its
    value unit (``"{t}"`` -> ``"min"``, ``"1/{t}"`` -> ``"1/min"``, ``"1"`` dimensionless,
    ``"{y}*{t}"`` -> ``"g/L*min"``, and ``"particles"`` for counts per time unit).

    **Arguments:** `template`; `time_unit` (``"s"``, ``"min"``, ...); `value_unit` (the data
    column's unit, or ``None`` when the file names none: then ``"signal"``, the unit of the
    file's values).

    **Returns:** the unit as text.
    """
    value_unit = value_unit or "signal"
    per_time = f"/{time_unit}"
    if "{y}*{t}" in template and value_unit.endswith(per_time):
        # A rate times time: "particles/s*s" is "particles".
        template = template.replace("{y}*{t}", value_unit[: -len(per_time)])
    return template.replace("{t}", time_unit).replace("{y}", value_unit)


@dataclass(frozen=True, eq=False)
class Model:
    """A fittable residence-time model: a JAX function of time and a parameter dict.

    **Arguments:**

    - `name`: short name (used in reports and by :func:`get_model`).
    - `parameter_names`: the names ``f`` reads from its parameter dict, in report order.
    - `function`: ``f(t, params) -> E``: ``t`` an array of times (unit T), ``params`` a dict
      of scalar JAX values, returns the exit-age density at ``t`` (unit 1/T). Must be
      jit-, grad- and vmap-able.
    - `defaults`: one :class:`~fitting.parameters.Parameter` per name (start value, bounds).
    - `initial_guess`: optional ``curve -> {name: value}`` start values from the curve's
      moments; used when :func:`~fitting.fit.fit` is given no start values.
    - `description`: one line for reports.
    - `default_starts`: number of starts of a fit by default; ``None``: the start values
      and, when it differs, the moment estimate.
    - `equivalent_adm`: optional hook, see :data:`EquivalentADM`.
    - `statements`: optional hook, see :data:`Statements`.
    - `units`: each parameter's unit as a template for :func:`parameter_unit` (``"{t}"``,
      ``"1/{t}"``, ``"1"``); a parameter without one has an unknown unit.
    - `meanings`: what a parameter means, one sentence, by name (e.g. for ``tau``).
    - `step_response`: optional ``F(t, params)``, the outlet for a unit step inlet at t = 0.
    - `inlet_response`: optional hook, see :data:`InletResponse`.
    - `transfer_unit`: optional ``params -> TransferFunction``, the model as an exact unit of
      :mod:`axialmix.analytic`; with it, fits report fitted values outside the range where
      its inversion is verified (:func:`axialmix.analytic.unverified_parameters`).
    - `long_curve_check`: optional ``(t, params) -> (deviation, peak)`` of a model whose
      `function` evaluates a curve of many points by interpolating exact values (the
      closed–closed ADM, from :data:`axialmix.analytic.panels.LONG_CURVE` points, padding
      included: a fit pads a curve to a power of two): the largest deviation of that
      evaluation from the exact one over the times `t` at `params` (plain numbers), and the
      exact curve's peak (both 1/T; an exact evaluation of every point, seconds for a
      million), whatever the length of `t`.

    **Attribute (not an argument):** ``export_identity``, ``None`` or a tuple of strings
    that determines everything the model's function and hooks compute. A model with one has
    its compiled programs kept between processes (:func:`fitting.solve.model_identity`); the
    package's own constructors set it (:func:`~fitting.models.network_model`: the network
    file's content and the parameter mapping). A model made from another with
    :func:`dataclasses.replace` has none, since its function may differ.
    """

    name: str
    parameter_names: tuple[str, ...]
    function: ModelFunction
    defaults: Mapping[str, Parameter] = field(repr=False)
    initial_guess: Callable[[Curve], dict[str, float]] | None = field(default=None, repr=False)
    description: str = ""
    default_starts: int | None = None
    equivalent_adm: EquivalentADM | None = field(default=None, repr=False)
    statements: Statements | None = field(default=None, repr=False)
    units: Mapping[str, str] = field(default_factory=dict, repr=False)
    meanings: Mapping[str, str] = field(default_factory=dict, repr=False)
    step_response: ModelFunction | None = field(default=None, repr=False)
    inlet_response: InletResponse | None = field(default=None, repr=False)
    transfer_unit: Callable[[Mapping[str, float]], Any] | None = field(default=None,
                                                                        repr=False)
    long_curve_check: Callable[..., tuple[float, float] | None] | None = field(
        default=None, repr=False)
    export_identity: tuple[str, ...] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        names = tuple(self.parameter_names)
        if not names:
            raise ValueError(f"model {self.name!r} has no parameters")
        if len(set(names)) != len(names):
            raise ValueError(f"model {self.name!r} has repeated parameter names: {names}")
        missing = [n for n in names if n not in self.defaults]
        if missing:
            raise ValueError(f"model {self.name!r}: no default for parameter(s) {missing}")
        if self.default_starts is not None and self.default_starts < 1:
            raise ValueError(f"model {self.name!r}: default_starts must be at least 1")
        object.__setattr__(self, "parameter_names", names)
        object.__setattr__(
            self, "defaults", {n: _as_parameter(self.defaults[n], n) for n in names}
        )

    def __call__(self, time, params: Mapping[str, object]):
        """Evaluate the model: exit-age density at `time` for the parameter values `params`."""
        return self.function(time, {n: params[n] for n in self.parameter_names})

    def evaluate(self, time, params: Mapping[str, float]) -> np.ndarray:
        """The model at concrete times and parameter values, as one compiled program.

        Same values as calling the model, but traced and compiled once per model and shape
        (a plot and the start-value check share it) instead of dispatching each operation
        of the model eagerly. Warnings that look at concrete parameter values (such as an
        unverified parameter range) are not raised on this path.

        **Arguments:**

        - `time`: times in the curve's unit, a 1-D array.
        - `params`: a value for every name in :attr:`parameter_names` (plain numbers).

        **Returns:** the model's values at `time` as a float64 NumPy array (1/T for an
        exit-age model).
        """
        values = {n: np.float64(params[n]) for n in self.parameter_names}
        return np.asarray(_compiled_model(self)(np.asarray(time, np.float64), values))

    def parameters(self, curve: Curve | None = None) -> Parameters:
        """A fresh :class:`~fitting.parameters.Parameters` with the defaults.

        With a `curve` and a method-of-moments guess available, the start values are the
        moment estimates (clipped into the bounds).
        """
        params = Parameters({n: self.defaults[n] for n in self.parameter_names})
        if curve is not None and self.initial_guess is not None:
            for name, value in self.initial_guess(curve).items():
                if name in params and np.isfinite(value):
                    params[name] = params[name].replace(
                        value=clip_into_bounds(value, params[name]))
        return params

    def facts(self, values: Mapping[str, float], settings: Mapping[str, Parameter]) -> list[str]:
        """The model's :data:`Statements` about fitted `values` (empty without the hook)."""
        return [] if self.statements is None else list(self.statements(values, settings))

    def unit(self, name: str, time_unit: str, value_unit: str | None = None) -> str:
        """The unit of parameter `name` for a curve in `time_unit` (``""`` when unknown)."""
        template = self.units.get(name)
        return "" if template is None else parameter_unit(template, time_unit, value_unit)


@functools.lru_cache(maxsize=64)
def _compiled_model(model: Model) -> Callable:
    """``jax.jit`` of `model`'s function, kept while the model is among the 64 last used
    (models compare by identity)."""
    return jax.jit(model.function)


def _as_parameter(value: Parameter | float, name: str) -> Parameter:
    if isinstance(value, Parameter):
        return value
    try:
        return Parameter(float(value))
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name!r}: expected a Parameter or a number") from None


def custom_model(
    name: str,
    fn: ModelFunction,
    parameters: Mapping[str, Parameter | float],
    *,
    initial_guess: Callable[[Curve], dict[str, float]] | None = None,
    description: str = "",
) -> Model:
    """Wrap a user's own JAX function as a fittable model.

    **Arguments:**

    - `name`: the model's name.
    - `fn`: ``fn(t, params) -> E``; ``params`` is a dict of scalar JAX values keyed by the
      names of `parameters`. It must be written in ``jax.numpy`` (jit/grad/vmap-able).
    - `parameters`: name -> :class:`~fitting.parameters.Parameter` or start value, in order.
    - `initial_guess`: optional ``curve -> {name: value}`` start values.
    - `description`: one line for reports.

    **Returns:**

    A :class:`Model`.
    """
    if not callable(fn):
        raise ValueError(f"custom model {name!r}: fn must be callable")
    return Model(
        name=name,
        parameter_names=tuple(parameters),
        function=fn,
        defaults={n: _as_parameter(v, n) for n, v in parameters.items()},
        initial_guess=initial_guess,
        description=description or f"user model {name}",
    )
