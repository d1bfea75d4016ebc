"""Which parameters of a study's curves a global fit shares, gives by factor laws, or fits per
curve (:class:`~fitting.study.global_fit.GlobalModel`), and how a per-curve parameter of the
joint fit is named (``"tau[3]"`` for curve 3).
"""

from __future__ import annotations

import equinox as eqx

from fitting.measurement import FREEABLE, Inlet, measured
from fitting.models import MODELS, Model, get_model
from fitting.study.global_fit.law import FactorLaw, checked_names

#: Inlet signals a global fit supports (every curve gets the same kind).
_INLETS = ("pulse", "step")


class GlobalModel(eqx.Module):
    """Which parameters of a study's curves are shared, given by factor laws, or per curve.

    **Arguments:**

    - `model`: a built-in model name (:data:`fitting.models.MODELS`, e.g. ``"adm"``); each
      curve is fitted as that model in the measurement model
      ``A_i (E ⊗ u)(t - t_d) + b`` (:func:`fitting.measurement.measured`).
    - `laws`: :class:`FactorLaw` s, at most one per parameter of the model.
    - `shared`: parameters with one value for all curves: of the model, or measurement
      parameters (``"amplitude"``, and a freed ``"dead_time"`` or ``"baseline"``).
    - `free`: measurement parameters fitted besides the amplitude (``"dead_time"``,
      ``"baseline"``; fixed at 0 otherwise), per curve unless shared.
    - `inlet`: ``"pulse"`` (default: the curves are pulse responses) or ``"step"``
      (F-curves).

    Every other parameter (and the amplitude) is fitted per curve.
    """

    model: str = eqx.field(static=True)
    laws: tuple[FactorLaw, ...] = eqx.field(default=(), static=True, converter=tuple)
    shared: tuple[str, ...] = eqx.field(default=(), static=True,
                                        converter=lambda s: checked_names(s, "shared"))
    free: tuple[str, ...] = eqx.field(default=(), static=True,
                                      converter=lambda s: checked_names(s, "free"))
    inlet: str = eqx.field(default="pulse", static=True)

    def __check_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; choose from "
                             f"{', '.join(sorted(MODELS))}")
        base = MODELS[self.model].parameter_names
        for law in self.laws:
            if not isinstance(law, FactorLaw):
                raise ValueError(f"laws must be FactorLaw objects, got {type(law).__name__}")
            if law.parameter not in base:
                raise ValueError(f"a factor law gives {law.parameter!r}, which is not a "
                                 f"parameter of model {self.model!r} ({', '.join(base)})")
        given = [law.parameter for law in self.laws]
        if len(set(given)) != len(given):
            raise ValueError("two factor laws give the same parameter")
        unknown = [name for name in self.free if name not in FREEABLE]
        if unknown:
            raise ValueError(f"free: {unknown[0]!r} is not a measurement parameter that can be "
                             f"freed ({', '.join(FREEABLE)})")
        allowed = (*base, "amplitude", *self.free)
        for name in self.shared:
            if name not in allowed:
                raise ValueError(f"shared parameter {name!r} is not a parameter of model "
                                 f"{self.model!r} or a fitted measurement parameter "
                                 f"({', '.join(allowed)})")
            if name in given:
                raise ValueError(f"{name!r} is both shared and given by a factor law")
        if not (self.laws or self.shared):
            raise ValueError("a global fit needs a factor law or a shared parameter; without "
                             "one the curves are independent (fit them with fit_many)")
        if self.inlet not in _INLETS:
            raise ValueError(f"inlet must be one of {', '.join(_INLETS)}, got {self.inlet!r}")

    @property
    def curve_model(self) -> Model:
        """The model one curve is fitted with (the measurement model around :attr:`model`)."""
        inlet = Inlet.pulse() if self.inlet == "pulse" else Inlet.step()
        return measured(self.model, inlet, self.free)

    @property
    def fitted(self) -> tuple[str, ...]:
        """The parameters fitted for a curve: the model's, the amplitude, freed ones."""
        return (*get_model(self.model).parameter_names, "amplitude", *self.free)

    @property
    def per_curve(self) -> tuple[str, ...]:
        """The parameters fitted once per curve."""
        given = {law.parameter for law in self.laws}
        return tuple(n for n in self.fitted if n not in given and n not in self.shared)

    @property
    def factors(self) -> tuple[str, ...]:
        """Every factor column the laws read."""
        return tuple(dict.fromkeys(f for law in self.laws for f in law.factors))

    def law_of(self, name: str) -> FactorLaw | None:
        """The law that gives parameter `name`, or ``None``."""
        return next((law for law in self.laws if law.parameter == name), None)


def curve_name(name: str, index: int) -> str:
    """The joint name of parameter `name` of curve `index` (``"tau[3]"``)."""
    return f"{name}[{index}]"
