"""A fitted RTD with its parameter covariance, from plain numbers: the hook for fit results.

:class:`FittedRTD` holds a model name of :data:`UNIT_BUILDERS`, the fitted value of every
parameter, which of them were free and the covariance of the free ones. It gives the unit at
the fitted values and, called with a vector of free values, the unit there (fixed parameters
held), so it can be handed as the ``unit_factory`` of :func:`sample_units` and
:func:`conservative_diversion_window` together with :attr:`FittedRTD.free_values` and
:attr:`FittedRTD.covariance`. It reads plain dicts and arrays, so any fitting code (the
``fitting`` package's results or JSON records, or another program's) can use it without
:mod:`axialmix` knowing that code.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from axialmix._validation import require_finite
from axialmix.line._unit import Unit, is_concrete
from axialmix.network import FOUR_COMPARTMENT_CONNECTIONS, FOUR_COMPARTMENT_RATES
from axialmix.network import four_compartment as _four_compartment_network

__all__ = ["UNIT_BUILDERS", "FittedRTD"]


def _four_compartment(p: Mapping[str, Array], time_unit: str, name: str) -> Unit:
    # The structure of a network with all rates 1; the rates of `p` in its connection order
    # (FOUR_COMPARTMENT_CONNECTIONS, which the preset keeps).
    network = _four_compartment_network(1.0, 1.0, 1.0, 1.0)
    rates = [p[rate] for _, _, rate in FOUR_COMPARTMENT_CONNECTIONS]
    # Concrete rates (a fitted unit) are gathered in NumPy, traced ones (samples) stacked.
    stack = np.asarray if is_concrete(p) else jnp.stack
    return Unit.network(network, stack(rates), stack([p["k_out"]]),
                        name=name or "four_compartment", time_unit=time_unit)


Builder = Callable[[Mapping[str, Array], str, str], Unit]


def _closed_closed(p, time_unit, name):
    return Unit.closed_closed(p["tau"], p["peclet"], time_unit=time_unit, name=name)


def _open_open(p, time_unit, name):
    return Unit.open_open(p["tau"], p["peclet"], time_unit=time_unit, name=name)


def _tanks(p, time_unit, name):
    return Unit.tanks(p["tau"], p["n_tanks"], time_unit=time_unit, name=name)


def _closed_closed_exchange(p, time_unit, name):
    return Unit.closed_closed_exchange(p["tau"], p["peclet"], p["beta"], p["k_d"],
                                       time_unit=time_unit, name=name)


def _tanks_exchange(p, time_unit, name):
    return Unit.tanks_exchange(p["tau"], p["n_tanks"], p["beta"], p["k_d"],
                               time_unit=time_unit, name=name)


def _closed_closed_tank(p, time_unit, name):
    return Unit.closed_closed_tank(p["tau"], p["peclet"], p["tau_tank"], time_unit=time_unit,
                                   name=name)


UNIT_BUILDERS: dict[str, tuple[tuple[str, ...], Builder]] = {
    "closed_closed": (("tau", "peclet"), _closed_closed),
    "open_open": (("tau", "peclet"), _open_open),
    "tanks": (("tau", "n_tanks"), _tanks),
    "closed_closed_exchange": (("tau", "peclet", "beta", "k_d"), _closed_closed_exchange),
    "tanks_exchange": (("tau", "n_tanks", "beta", "k_d"), _tanks_exchange),
    "closed_closed_tank": (("tau", "peclet", "tau_tank"), _closed_closed_tank),
    "four_compartment": (FOUR_COMPARTMENT_RATES, _four_compartment),
}
"""Model name -> (parameter names, ``builder(parameters, time_unit, name) -> Unit``)."""


class FittedRTD(eqx.Module):
    """A fitted unit: its model, values, free parameters and their covariance (a JAX pytree).

    Calling it with a vector of free values gives the :class:`Unit` there, with the fixed
    parameters at their values; it is traceable, so it serves as the ``unit_factory`` of
    :func:`sample_units` and :func:`conservative_diversion_window`.

    **Arguments:**

    - `model`: a name of :data:`UNIT_BUILDERS`.
    - `values`: value of every parameter of the model, ``(p_all,)`` in the model's order.
    - `free`: names of the free (fitted) parameters, in the order of `covariance`.
    - `covariance`: their covariance ``(len(free), len(free))``, in the parameters' units.
    - `time_unit`: unit of time of the parameters.
    - `name`: label of the unit.
    """

    model: str = eqx.field(static=True)
    values: Array
    free: tuple[str, ...] = eqx.field(static=True)
    covariance: Array
    time_unit: str = eqx.field(static=True, default="s")
    name: str = eqx.field(static=True, default="")

    def __check_init__(self) -> None:
        if self.model not in UNIT_BUILDERS:
            raise ValueError(
                f"unknown unit model {self.model!r}; choose one of {', '.join(UNIT_BUILDERS)}."
            )
        names = UNIT_BUILDERS[self.model][0]
        if jnp.shape(self.values) != (len(names),):
            raise ValueError(
                f"values must hold the {len(names)} parameters {', '.join(names)}, "
                f"got shape {jnp.shape(self.values)}."
            )
        unknown = [name for name in self.free if name not in names]
        if unknown:
            raise ValueError(
                f"free parameter(s) {', '.join(unknown)} are not parameters of the "
                f"{self.model} model ({', '.join(names)})."
            )
        if len(set(self.free)) != len(self.free):
            raise ValueError("each free parameter may be named only once.")
        size = len(self.free)
        if jnp.shape(self.covariance) != (size, size):
            raise ValueError(
                f"covariance must have shape ({size}, {size}) for the free parameters, "
                f"got {jnp.shape(self.covariance)}."
            )
        require_finite("values", self.values)
        require_finite("covariance", self.covariance)

    @classmethod
    def from_parameters(
        cls,
        model: str,
        values: Mapping[str, float],
        *,
        free: Sequence[str] = (),
        covariance: ArrayLike | None = None,
        time_unit: str = "s",
        name: str = "",
    ) -> FittedRTD:
        """A fitted unit from a dict of values and the covariance of the free ones.

        **Arguments:**

        - `model`: a name of :data:`UNIT_BUILDERS`.
        - `values`: ``{parameter: value}`` for every parameter of the model (others, such
          as a measurement model's amplitude, are ignored).
        - `free`: the parameters `covariance` is about, in its order.
        - `covariance`: ``(len(free), len(free))``; zeros when None.
        - `time_unit`, `name`: unit of time and label.

        **Returns:**

        A :class:`FittedRTD`.
        """
        if model not in UNIT_BUILDERS:
            raise ValueError(
                f"unknown unit model {model!r}; choose one of {', '.join(UNIT_BUILDERS)}."
            )
        names = UNIT_BUILDERS[model][0]
        missing = [n for n in names if n not in values]
        if missing:
            raise ValueError(f"the {model} model needs a value of {', '.join(missing)}.")
        vector = np.asarray([float(values[n]) for n in names], float)
        free = tuple(free)
        if covariance is None:
            covariance = np.zeros((len(free), len(free)))
        covariance = np.asarray(covariance, dtype=float)
        if covariance.shape == (len(free), len(free)) and len(free) and not np.allclose(
            covariance, covariance.T, rtol=1e-8, atol=0.0
        ):
            raise ValueError("covariance must be symmetric.")
        return cls(model, vector, free, covariance, time_unit, name)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Every parameter of the model, in the order of :attr:`values`."""
        return UNIT_BUILDERS[self.model][0]

    @property
    def free_values(self) -> Array:
        """The fitted values of the free parameters, in the order of :attr:`free`."""
        names = self.parameter_names
        index = [names.index(n) for n in self.free]
        if is_concrete(self.values):
            return np.asarray(self.values, float)[index]
        return jnp.stack([self.values[i] for i in index]) if self.free else jnp.zeros(0)

    @property
    def standard_errors(self) -> Array:
        """Standard errors of the free parameters (square roots of the covariance diagonal)."""
        if is_concrete(self.covariance):
            return np.sqrt(np.clip(np.diagonal(np.asarray(self.covariance, float)), 0.0, None))
        return jnp.sqrt(jnp.clip(jnp.diagonal(self.covariance), 0.0, None))

    def __call__(self, free_values: ArrayLike) -> Unit:
        """The unit with the free parameters at `free_values` and the fixed ones at their values.

        **Arguments:**

        - `free_values`: ``(len(free),)`` values (traceable).

        **Returns:**

        A :class:`Unit`.
        """
        names = self.parameter_names
        if is_concrete(free_values, self.values):  # a unit at given values: NumPy, no program
            free_values = np.atleast_1d(np.asarray(free_values, float))
            values = np.asarray(self.values, float)
        else:
            free_values = jnp.atleast_1d(jnp.asarray(free_values, float))
            values = self.values
        parameters = {n: values[i] for i, n in enumerate(names)}
        for k, n in enumerate(self.free):
            parameters[n] = free_values[k]
        return UNIT_BUILDERS[self.model][1](parameters, self.time_unit, self.name)

    def unit(self) -> Unit:
        """The unit at the fitted values."""
        return self(self.free_values)
