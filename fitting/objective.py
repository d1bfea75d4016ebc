"""Deprecated: the losses moved to :mod:`fitting.losses` (kept one release)."""

from fitting.losses import LOSSES, mean_absolute_error, residuals, sum_of_squares

__all__ = ["LOSSES", "mean_absolute_error", "residuals", "sum_of_squares"]
