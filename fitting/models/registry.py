"""The built-in models by name: ``MODELS`` and :func:`~fitting.models.get_model`."""

from __future__ import annotations

from fitting.models.adm import adm_closed, adm_closed_fv, adm_open, tanks
from fitting.models.base import Model
from fitting.models.exchange import adm_exchange, adm_tank, tanks_exchange
from fitting.models.network import four_compartment

MODELS: dict[str, Model] = {
    "adm": adm_closed,
    "adm-fv": adm_closed_fv,
    "adm-open": adm_open,
    "tanks": tanks,
    "four-compartment": four_compartment,
    "adm-exchange": adm_exchange,
    "tanks-exchange": tanks_exchange,
    "adm-tank": adm_tank,
}


def get_model(model: str | Model) -> Model:
    """The built-in model called `model` (see :data:`MODELS`), or `model` itself.

    **Arguments:**

    - `model`: a name (``'adm'``, ``'adm-fv'``, ``'adm-open'``, ``'tanks'``,
      ``'four-compartment'``, ``'adm-exchange'``, ``'tanks-exchange'``, ``'adm-tank'``) or a
      :class:`Model`.

    **Returns:**

    The :class:`Model`.
    """
    if isinstance(model, Model):
        return model
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown model {model!r}; choose one of {', '.join(MODELS)}"
        ) from None
