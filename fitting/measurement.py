"""The measurement model around every residence-time model (MODELS.md section 6).

A tracer experiment does not observe E itself but

    c(t) = A · (E ⊗ u)(t − t_d) + b

with ``A`` the tracer amount over the flow (unknown in practice: injected amount and detector
gain are rarely known well), ``u`` the inlet signal normalised to unit area, ``t_d`` a dead
time of sampling lines and detectors, and ``b`` a baseline. :func:`measured` wraps any
:class:`~fitting.models.Model` in this measurement model; the result is again a
:class:`~fitting.models.Model` (a :class:`MeasuredModel`), with the parameters
``amplitude``, ``dead_time`` and ``baseline`` after the model's own, so every layer above
(the solver, the uncertainty, profiles, ``fit_many``, the ``--fix``/``--tie`` vocabulary)
treats them like any other parameter.

* **A is always estimated, jointly with the other parameters**, as a positive parameter
  (fitted in ``ln A``, a coordinate without scale), started at the area of the samples above
  the start baseline (the plateau of an F-curve): a start only, never a normalisation.
  A enters linearly, so it could be eliminated at every step (variable projection, Golub and
  Pereyra 1973); keeping it a parameter instead lets one compiled solver, the joint
  Gauss–Newton covariance over A, b, t_d and the model parameters, profiles and batched fits
  work unchanged, and for a least-squares fit the two give the same optimum and the same
  linearised covariance of the model parameters. The data are never divided by their own
  area: that biases E whenever sampling is sparse or the tail is cut.
* **t_d and b are fixed at 0 by default** and freed with ``free=("dead_time", "baseline")``
  (or a :class:`~fitting.parameters.Parameter` with ``vary=True``). A free dead time starts
  at 1 % of the curve's mean time, a free baseline at the median of the lowest tenth of the
  samples: start values that also give the optimiser their scale.
* **u**, the :class:`Inlet`: an ideal pulse (default; then the model is ``A E(t − t_d) + b``),
  an ideal step (F-curves, ``A F(t − t_d) + b``), or a measured signal, taken as linear
  between its samples, zero before the first and after the last, and convolved exactly with
  the model's own :attr:`~fitting.models.Model.inlet_response` (exact models: sums of exact
  step and ramp responses; networks: matrix exponentials; finite volumes: its own step and
  ramp curves).

E is shown normalised by the fitted A: :func:`observed_response` gives ``(c − b) / A``.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)
from axialmix.analytic import unverified_parameters
from fitting.data import Curve
from fitting.models import Model, get_model
from fitting.models.moments import trapezoid
from fitting.parameters import Parameter

__all__ = [
    "INLET_KINDS",
    "MEASUREMENT_PARAMETERS",
    "Inlet",
    "MeasuredModel",
    "base_values",
    "measured",
    "observed_response",
]

#: The measurement parameters, in the order they follow the model's own.
MEASUREMENT_PARAMETERS = ("amplitude", "dead_time", "baseline")
#: Measurement parameters that are fixed at 0 unless freed.
FREEABLE = ("dead_time", "baseline")
#: The kinds of inlet signal.
INLET_KINDS = ("pulse", "step", "sampled")
#: Start of a free dead time, as a fraction of the curve's mean time (gives its scale too).
DEAD_TIME_START = 0.01
#: Share of the samples (the lowest) whose median starts a free baseline.
BASELINE_SHARE = 0.1
#: Models kept by :func:`measured`, so that repeated calls share compiled solvers.
_CACHE_SIZE = 32
_CACHE: OrderedDict = OrderedDict()


@dataclass(frozen=True, eq=False)
class Inlet:
    """The inlet signal u of a tracer experiment, immutable: a pulse, a step or a measured one.

    Build one with :meth:`pulse`, :meth:`step`, :meth:`sampled` or :meth:`from_curve`.

    **Arguments:**

    - `kind`: ``"pulse"`` (an ideal pulse at t = 0), ``"step"`` (an ideal step at t = 0) or
      ``"sampled"`` (a measured signal).
    - `times`: sample times of a measured signal, strictly increasing, in the outlet curve's
      time unit (``None`` otherwise).
    - `values`: the measured signal at `times`, normalised to unit area (1/time unit) for
      the piecewise-linear interpolant, zero before the first sample and after the last.
    - `name`: a label (the file name of a measured signal).
    """

    kind: str = "pulse"
    times: np.ndarray | None = None
    values: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in INLET_KINDS:
            raise ValueError(f"inlet kind must be one of {', '.join(INLET_KINDS)}, got "
                             f"{self.kind!r}")
        if self.kind != "sampled":
            if self.times is not None or self.values is not None:
                raise ValueError(f"an ideal {self.kind} inlet has no samples")
            return
        if self.times is None or self.values is None:
            raise ValueError("a sampled inlet needs times and values")
        times = np.array(self.times, dtype=float)
        values = np.array(self.values, dtype=float)
        if times.ndim != 1 or values.shape != times.shape or times.size < 2:
            raise ValueError(f"a sampled inlet needs 1-D times and values of equal length, at "
                             f"least two; got shapes {times.shape} and {values.shape}")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
            raise ValueError("the inlet samples must be finite")
        if not np.all(np.diff(times) > 0):
            raise ValueError("the inlet sample times must be strictly increasing")
        area = float(np.trapezoid(values, times))
        if not area > 0:
            raise ValueError(f"the inlet signal has no positive area (area {area:.3g})")
        values = values / area
        times.flags.writeable = False
        values.flags.writeable = False
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)

    @classmethod
    def pulse(cls) -> Inlet:
        """An ideal pulse at t = 0: the outlet is the exit-age density E itself."""
        return cls("pulse")

    @classmethod
    def step(cls) -> Inlet:
        """An ideal step at t = 0 (an F-curve): the outlet is the step response F."""
        return cls("step")

    @classmethod
    def sampled(cls, times: Sequence[float], values: Sequence[float], name: str = "") -> Inlet:
        """A measured inlet signal: linear between samples, zero outside them.

        **Arguments:**

        - `times`: sample times (the outlet curve's time unit), strictly increasing.
        - `values`: the signal at `times`, any unit (normalised here to unit area).
        - `name`: a label.

        **Returns:** an :class:`Inlet`; a one-line ``ValueError`` for bad samples.
        """
        return cls("sampled", np.asarray(times, float), np.asarray(values, float), name)

    @classmethod
    def from_curve(cls, curve: Curve) -> Inlet:
        """A measured inlet signal from a curve read by :func:`fitting.data.read_inlet_csv`."""
        return cls.sampled(curve.time, curve.value, curve.name)

    @property
    def key(self) -> tuple:
        """A hashable identity of the signal (kind and samples)."""
        if self.kind != "sampled":
            return (self.kind,)
        return (self.kind, self.times.tobytes(), self.values.tobytes())

    def moments(self) -> tuple[float, float]:
        """Mean time and variance of the (normalised) signal; ``(0, 0)`` for an ideal pulse.

        For a sampled signal: the trapezoid moments of its samples (time unit and its square).
        """
        if self.kind != "sampled":
            return 0.0, 0.0
        mean = float(np.trapezoid(self.times * self.values, self.times))
        variance = float(np.trapezoid((self.times - mean) ** 2 * self.values, self.times))
        return mean, max(variance, 0.0)

    def describe(self) -> str:
        """The inlet in words, for reports."""
        if self.kind == "pulse":
            return "an ideal pulse at t = 0"
        if self.kind == "step":
            return "an ideal step at t = 0 (F-curve)"
        label = f" {self.name!r}" if self.name else ""
        return (f"the measured inlet{label} ({self.times.size} samples, "
                f"t = {self.times[0]:g} to {self.times[-1]:g})")


@dataclass(frozen=True, eq=False)
class MeasuredModel(Model):
    """A :class:`~fitting.models.Model` wrapped in the measurement model (see the module).

    Its parameters are those of `base` followed by :data:`MEASUREMENT_PARAMETERS`.

    **Arguments (besides those of a Model):**

    - `base`: the residence-time model.
    - `inlet`: the :class:`Inlet`.
    - `free`: the measurement parameters free by default (of ``dead_time``, ``baseline``).
    """

    base: Model | None = None
    inlet: Inlet | None = None
    free: tuple[str, ...] = ()


def _response_function(base: Model, inlet: Inlet):
    """``(t, params) -> (E ⊗ u)(t)`` of the base model for the inlet (JAX)."""
    if inlet.kind == "pulse":
        return base.function
    if inlet.kind == "step":
        if base.step_response is None:
            raise ValueError(f"model {base.name!r} has no step response; it cannot be fitted "
                             "to an F-curve (step inlet)")
        return base.step_response
    if base.inlet_response is None:
        raise ValueError(f"model {base.name!r} has no response to a sampled inlet signal; fit "
                         "it with an ideal pulse or step inlet")
    inlet_times = jnp.asarray(inlet.times)
    inlet_values = jnp.asarray(inlet.values)

    def response(t, p):
        return base.inlet_response(t, p, inlet_times, inlet_values)

    return response


def _statements(base: Model, inlet: Inlet):
    """The base model's statements, and a warning when the fitted values lie outside the
    range where its exact solution is verified (the curve is computed inside compiled code,
    where :class:`axialmix.analytic.AccuracyWarning` cannot look at the values)."""
    if base.transfer_unit is None:
        return base.statements

    def statements(values, settings) -> list[str]:
        said = [] if base.statements is None else list(base.statements(values, settings))
        try:
            unit = base.transfer_unit({n: float(values[n]) for n in base.parameter_names})
            problems = unverified_parameters(unit, cumulative=inlet.kind == "step")
        except (ValueError, TypeError):  # values the unit refuses: the fit says so elsewhere
            return said
        if problems:
            said.append("The fitted values are outside the range where this model's exact "
                        f"solution has been verified ({'; '.join(problems)}): its curve, and "
                        "so this fit, may be inaccurate.")
        return said

    return statements


def _lowest_median(values: np.ndarray) -> float:
    count = max(3, int(math.ceil(BASELINE_SHARE * values.size)))
    return float(np.median(np.sort(values)[:count]))


def _initial_guess(base: Model, inlet: Inlet, free: tuple[str, ...]):
    """Start values from a raw curve: the model's moment guess on the curve with the
    baseline and the inlet's moments taken out, the amplitude from the curve's area."""

    def guess(curve: Curve) -> dict[str, float]:
        time = np.asarray(curve.time, float)
        value = np.asarray(curve.value, float)
        peak = float(np.max(np.abs(value))) or 1.0
        baseline = 0.0
        if "baseline" in free:
            baseline = _lowest_median(value)
            if abs(baseline) < 1e-3 * peak:
                baseline = 1e-3 * peak  # a start away from 0 gives the optimiser its scale
        signal = value - baseline
        step = time[1:] - time[:-1]
        if inlet.kind == "step":
            # The derivative of an F-curve is the density whose moments start the model.
            density = np.clip(np.gradient(signal, time), 0.0, None)
            amplitude = float(np.max(signal))
        else:
            density = np.clip(signal, 0.0, None)
            amplitude = float(trapezoid(density, step))
        start: dict[str, float] = {}
        if amplitude > 0 and np.any(density > 0):
            area = float(trapezoid(density, step))
            mean = float(trapezoid(time * density, step)) / area
            variance = float(trapezoid((time - mean) ** 2 * density, step)) / area
            inlet_mean, inlet_variance = inlet.moments()
            dead_time = DEAD_TIME_START * mean if "dead_time" in free else 0.0
            # Cumulants add under convolution: take the inlet's mean and variance (and the
            # start dead time) out, mapping the curve affinely onto the model's moments.
            target_mean = mean - inlet_mean - dead_time
            target_variance = max(variance - inlet_variance, 0.05 * variance)
            if target_mean > 0 and variance > 0 and base.initial_guess is not None:
                stretch = math.sqrt(target_variance / variance)
                proxy = Curve(name=curve.name, time=target_mean + (time - mean) * stretch,
                              value=density, time_unit=curve.time_unit)
                start.update(base.initial_guess(proxy))
            start["amplitude"] = amplitude
            if "dead_time" in free:
                start["dead_time"] = dead_time
        if "baseline" in free:
            start["baseline"] = baseline
        return start

    return guess


def _units(base: Model, inlet: Inlet) -> dict[str, str]:
    units = dict(base.units)
    units.update(amplitude="{y}" if inlet.kind == "step" else "{y}*{t}", dead_time="{t}",
                 baseline="{y}")
    return units


def _meanings(base: Model, inlet: Inlet) -> dict[str, str]:
    meanings = dict(base.meanings)
    if inlet.kind == "step":
        amplitude = "the amplitude A is the height of the step response (inlet step height)"
    else:
        amplitude = ("the amplitude A is the tracer amount over the flow, the area under the "
                     "whole outlet curve above its baseline")
    meanings.update(amplitude=amplitude,
                    dead_time="the dead time t_d delays the whole curve (sampling line, "
                    "detector)",
                    baseline="the baseline b is a constant signal under the curve")
    return meanings


def measured(model: Model | str, inlet: Inlet | None = None,
             free: Sequence[str] = ()) -> MeasuredModel:
    """Wrap a residence-time model in the measurement model ``c = A (E ⊗ u)(t − t_d) + b``.

    The same arguments give the same model object, so repeated fits share compiled solvers.

    **Arguments:**

    - `model`: a :class:`~fitting.models.Model` or a built-in name (``'adm'``, ...).
    - `inlet`: the :class:`Inlet` (default: an ideal pulse).
    - `free`: measurement parameters fitted by default besides the amplitude: any of
      ``'dead_time'``, ``'baseline'`` (both fixed at 0 otherwise).

    **Returns:** a :class:`MeasuredModel` with the parameters of `model` then ``amplitude``
    (A, in signal unit × time unit; signal unit for a step), ``dead_time`` (time unit) and
    ``baseline`` (signal unit).
    """
    base = get_model(model)
    if isinstance(base, MeasuredModel):
        raise ValueError(f"model {base.name!r} already includes the measurement model")
    inlet = Inlet.pulse() if inlet is None else inlet
    if not isinstance(inlet, Inlet):
        raise ValueError(f"inlet must be an Inlet, got {type(inlet).__name__}")
    free = tuple(dict.fromkeys(free))
    unknown = [name for name in free if name not in FREEABLE]
    if unknown:
        raise ValueError(f"free: unknown measurement parameter(s) {unknown}; choose from "
                         f"{', '.join(FREEABLE)} (the amplitude is always fitted)")
    clash = [n for n in MEASUREMENT_PARAMETERS if n in base.parameter_names]
    if clash:
        raise ValueError(f"model {base.name!r} already has parameter(s) {clash}")
    key = (base, inlet.key, tuple(sorted(free)))
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    response = _response_function(base, inlet)
    base_names = base.parameter_names

    def function(t, p):
        shape = response(t - p["dead_time"], {n: p[n] for n in base_names})
        return p["amplitude"] * shape + p["baseline"]

    defaults: dict[str, Parameter] = dict(base.defaults)
    defaults["amplitude"] = Parameter(1.0, min=0.0)
    defaults["dead_time"] = Parameter(0.0, vary="dead_time" in free)
    defaults["baseline"] = Parameter(0.0, vary="baseline" in free)
    wrapped = MeasuredModel(
        name=base.name,
        parameter_names=base_names + MEASUREMENT_PARAMETERS,
        function=function,
        defaults=defaults,
        initial_guess=_initial_guess(base, inlet, tuple(free)),
        description=f"{base.description}; measured as A (E * u)(t - t_d) + b with u "
        f"{inlet.describe()}",
        default_starts=base.default_starts,
        equivalent_adm=base.equivalent_adm,
        statements=_statements(base, inlet),
        units=_units(base, inlet),
        meanings=_meanings(base, inlet),
        base=base,
        inlet=inlet,
        free=tuple(free),
    )
    _CACHE[key] = wrapped
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return wrapped


def observed_response(model: Model, values: Mapping[str, float],
                      curve: Curve) -> tuple[np.ndarray, str]:
    """The data normalised by the fitted amplitude: ``(c − b) / A``, and what it shows.

    **Arguments:**

    - `model`: the fitted model (a :class:`MeasuredModel`, or a bare model: the data are
      then returned as they are).
    - `values`: fitted parameter values.
    - `curve`: the fitted curve.

    **Returns:** ``(values, label)``: ``E`` (1/time unit) for a pulse inlet, ``F`` for a step,
    ``E ⊗ u`` for a measured inlet, or the data themselves for a bare model.
    """
    data = np.asarray(curve.value, float)
    if not isinstance(model, MeasuredModel):
        return data, "E" if curve.normalised else "data"
    amplitude = float(values["amplitude"])
    normalised = (data - float(values["baseline"])) / amplitude if amplitude else data * math.nan
    label = {"pulse": "E", "step": "F", "sampled": "E * u"}[model.inlet.kind]
    return normalised, label


def base_values(model: Model, values: Mapping[str, float]) -> dict[str, float]:
    """The values of the residence-time model's own parameters (without A, t_d, b)."""
    names = model.base.parameter_names if isinstance(model, MeasuredModel) else \
        model.parameter_names
    return {name: values[name] for name in names}
