"""Deprecated aliases: an old public name keeps working for one release and says what to use."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any

__all__ = ["deprecated_alias", "warn_deprecated"]


def warn_deprecated(old: str, new: str) -> None:
    """Issue the one DeprecationWarning of the project for a renamed public name."""
    warnings.warn(
        f"{old} is deprecated and will be removed in the next release; use {new}.",
        DeprecationWarning,
        stacklevel=3,
    )


def deprecated_alias(function: Callable[..., Any], old: str, new: str) -> Callable[..., Any]:
    """Wrap `function` so that calling it under its old name `old` warns to use `new`.

    **Arguments:**

    - `function`: the current implementation (same signature as the old name).
    - `old`, `new`: qualified old and new names, for the message.

    **Returns:** the wrapper; its docstring points to `new`.
    """

    @functools.wraps(function)
    def alias(*args: Any, **kwargs: Any) -> Any:
        warn_deprecated(old, new)
        return function(*args, **kwargs)

    alias.__doc__ = f"Deprecated alias of :func:`{new}` (removed in the next release)."
    alias.__name__ = old.rsplit(".", 1)[-1]
    alias.__qualname__ = alias.__name__
    return alias
