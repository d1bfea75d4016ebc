"""Factor laws of a global fit (:class:`~fitting.study.global_fit.FactorLaw`): a model
parameter given by the process factors, ``g(p_i) = c0 + Σ_j c_j x_ij`` with ``g = ln`` or the
identity, its design matrix over the curves and the factor columns it reads.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import axialmix  # noqa: F401  (float64 before any JAX array is made)

#: The transforms a factor law may apply to its parameter.
LAW_TRANSFORMS = ("log", "identity")


def checked_names(value, what: str) -> tuple[str, ...]:
    """`value` (one name or several) as a tuple of names, each non-empty and none twice;
    `what` names them in the one-line ``ValueError``."""
    if isinstance(value, str):
        value = (value,)
    names = tuple(value)
    for name in names:
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"{what} must be non-empty names, got {name!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"{what} lists a name twice: {', '.join(names)}")
    return names


class FactorLaw(eqx.Module):
    """A model parameter given by the process factors, ``g(p_i) = c0 + Σ_j c_j x_ij``.

    **Arguments:**

    - `parameter`: the model parameter the law gives (``"peclet"``, ``"tau"``, ...).
    - `terms`: factor columns of the study table, numeric, each entering linearly; a term
      ``"a:b"`` is the product of columns ``a`` and ``b`` (an interaction).
    - `transform`: ``"log"`` (default: ``ln p_i`` is linear in the factors, so ``p_i`` stays
      positive and a coefficient is a relative change per unit of its factor) or
      ``"identity"`` (``p_i`` itself is linear).

    The law's coefficients are named ``"<parameter>:intercept"`` and
    ``"<parameter>:<term>"`` (:attr:`coefficient_names`).
    """

    parameter: str = eqx.field(static=True)
    terms: tuple[str, ...] = eqx.field(static=True, converter=lambda t: checked_names(t, "terms"))
    transform: str = eqx.field(default="log", static=True)

    def __check_init__(self):
        if not isinstance(self.parameter, str) or not self.parameter.strip():
            raise ValueError(f"a factor law needs a parameter name, got {self.parameter!r}")
        if not self.terms:
            raise ValueError(f"the factor law of {self.parameter!r} has no terms: give at least "
                             "one factor column (a parameter equal for all curves is shared)")
        if self.transform not in LAW_TRANSFORMS:
            raise ValueError(f"transform must be one of {', '.join(LAW_TRANSFORMS)}, got "
                             f"{self.transform!r}")
        for term in self.terms:
            if any(not part.strip() for part in term.split(":")):
                raise ValueError(f"term {term!r}: an interaction names factors as a:b")

    @property
    def coefficient_names(self) -> tuple[str, ...]:
        """The names of the law's coefficients: the intercept, then one per term."""
        return (f"{self.parameter}:intercept",
                *(f"{self.parameter}:{term}" for term in self.terms))

    @property
    def factors(self) -> tuple[str, ...]:
        """The factor columns the law reads, in order of first use."""
        return tuple(dict.fromkeys(part for term in self.terms for part in term.split(":")))

    def describe(self) -> str:
        """The law as a formula, e.g. ``ln peclet = c0 + c1 speed + c2 flow``."""
        left = f"ln {self.parameter}" if self.transform == "log" else self.parameter
        right = " + ".join(["c0", *(f"c{j} {t}" for j, t in enumerate(self.terms, start=1))])
        return f"{left} = {right}"

    def design(self, factors: Mapping[str, np.ndarray]) -> np.ndarray:
        """The design matrix ``[1, x_i1, x_i2, ...]`` of the law over the curves.

        **Arguments:** `factors`: factor columns by name, one number per curve.

        **Returns:** an ``(n_curves, 1 + len(terms))`` array; a one-line ``ValueError`` for a
        missing or non-numeric column.
        """
        columns = []
        for term in self.terms:
            column = None
            for part in term.split(":"):
                values = factor_column(factors, part)
                column = values if column is None else column * values
            columns.append(column)
        count = len(columns[0])
        return np.column_stack([np.ones(count), *columns])

    def apply(self, linear):
        """The parameter from the law's linear predictor (``exp`` for ``"log"``; JAX or NumPy)."""
        return jnp.exp(linear) if self.transform == "log" else linear

    def linear(self, value: np.ndarray) -> np.ndarray:
        """The law's linear predictor from parameter values (``ln`` for ``"log"``; NumPy)."""
        value = np.asarray(value, dtype=float)
        if self.transform == "log":
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(value > 0, np.log(np.where(value > 0, value, 1.0)), np.nan)
        return value


def factor_column(factors: Mapping[str, Any], name: str) -> np.ndarray:
    """Factor column `name` of `factors` as finite numbers, one per curve (a one-line
    ``ValueError`` otherwise)."""
    if name not in factors:
        known = ", ".join(map(repr, factors)) or "none"
        raise ValueError(f"factor {name!r} is not among the study's factor columns ({known})")
    try:
        values = np.asarray(factors[name], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"factor {name!r} is not numeric; a factor law needs numbers") from None
    if values.ndim != 1 or not np.all(np.isfinite(values)):
        raise ValueError(f"factor {name!r} needs one finite number per curve")
    return values
