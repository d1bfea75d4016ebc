"""One progress display for long runs (simulations, grid searches, fits of many curves).

A thin wrapper around :mod:`tqdm` writing to standard error, so every sub-command shows
progress the same way; it is silent when disabled or when standard error is not a terminal
unless forced.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = ["iterate", "progress_bar"]


def progress_bar(
    iterable: Iterable[Any] | None = None,
    *,
    total: int | None = None,
    description: str = "",
    unit: str = "it",
    enabled: bool | None = None,
) -> Any:
    """A progress bar on standard error (a :class:`tqdm.tqdm` instance).

    **Arguments:**

    - `iterable`: items to iterate over, or ``None`` to call ``update(n)`` by hand.
    - `total`: number of items (or of units of work) when `iterable` has no length.
    - `description`: a short label shown before the bar.
    - `unit`: what one item is ("curve", "step", ...).
    - `enabled`: show the bar; ``None`` (default) shows it when standard error is a terminal.

    **Returns:** the bar; use it as an iterator or context manager, and call ``close()``.
    """
    from tqdm.auto import tqdm

    disable = (not sys.stderr.isatty()) if enabled is None else (not enabled)
    return tqdm(
        iterable,
        total=total,
        desc=description or None,
        unit=unit,
        file=sys.stderr,
        disable=disable,
        leave=False,
        dynamic_ncols=True,
    )


def iterate(items: Iterable[Any], **options: Any) -> Iterator[Any]:
    """Iterate over `items` with a :func:`progress_bar` (same keyword options)."""
    bar = progress_bar(items, **options)
    try:
        yield from bar
    finally:
        bar.close()
