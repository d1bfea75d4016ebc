"""Deprecated: reading residence-time curves moved to :mod:`fitting.data` (kept one release)."""

from fitting.data import (  # noqa: F401
    TAIL_FRACTION,
    Curve,
    DataError,
    DataWarning,
    read_many,
    read_rtd_csv,
)

__all__ = ["Curve", "DataError", "DataWarning", "read_many", "read_rtd_csv"]
