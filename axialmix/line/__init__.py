"""Unit operations and lines: from an RTD to manufacturing decisions (MODELS.md §7, §8).

* **Units and lines.** :class:`Unit` is one unit operation's RTD (closed–closed or open–open
  ADM, tanks in series, either with a dead zone, an ADM followed by a stirred tank, a
  compartment network, a measured curve, or any :class:`UnitModel`);
  it gives E, F, the ramp response ``∫F``, the moments and the transfer function G(s),
  exactly. :class:`Line` puts units in series: transfer functions multiply, means and
  variances add, and E and F come from an exact piecewise-linear convolution on a grid with
  Richardson extrapolation (sixth order).
* **Disturbances.** :class:`Disturbance` (step, pulse, square, ramp, sampled trace) and
  :func:`outlet_response`; :func:`frequency_response` and the variance reduction ratio of
  feeder noise from a spectrum (:func:`spectral_variance_reduction_ratio`), for white noise
  (:func:`white_noise_variance_reduction_ratio`) or from a sampled series
  (:func:`series_variance_reduction_ratio`).
* **Funnel plot.** :func:`funnel`: the largest outlet deviation ``M max_t [F(t) - F(t-d)]``
  for every magnitude and duration, exact and vectorised.
* **Diversion.** :func:`diversion_window` (when to start and stop, how much), and
  :func:`conservative_diversion_window`, which samples a fit's parameter distribution
  (:func:`sample_units`, the hook for fit results) for a window that covers the true one with
  a stated probability. :class:`FittedRTD` is a fit result as plain numbers (model name,
  values, free parameters, covariance): it gives the fitted unit and is the unit factory
  those functions sample.
* **Changing throughput.** :class:`FlowSchedule` and the cumulative-throughput clock
  (:func:`throughput_clock`, :func:`equivalent_time`, :func:`exit_age_changing_throughput`,
  :func:`outlet_response_changing_throughput`); networks with scheduled rates are in
  :mod:`axialmix.network` (:class:`~axialmix.network.RateSchedule`).
* **Plots.** :func:`plot_line`, :func:`plot_response`, :func:`plot_funnel`,
  :func:`plot_diversion` (matplotlib is imported when a plot is drawn).
* **Compiled programs.** The funnel and the diversion run as a few compiled programs (the
  covariance samples in one batched program, run on the CPU as one call per core at once;
  a network's scans propagated along their uniform grids). By default they are compiled
  in this process; a :data:`ProgramRunner` (the command line's keeps them on disk across
  processes) decides how, by their :func:`program_identity`.
"""

from axialmix.line._disturbance import Disturbance, OutletResponse, outlet_response
from axialmix.line._diversion import (
    MAX_EVALUATIONS,
    MAX_FAILED_SHARE,
    ConservativeDiversion,
    DiversionRefused,
    DiversionTooLarge,
    DiversionWindow,
    conservative_diversion_window,
    diversion_window,
    sample_units,
)
from axialmix.line._fitted import UNIT_BUILDERS, FittedRTD
from axialmix.line._frequency import (
    frequency_response,
    series_variance_reduction_ratio,
    spectral_variance_reduction_ratio,
    white_noise_variance_reduction_ratio,
)
from axialmix.line._funnel import FunnelResult, FunnelSettings, funnel
from axialmix.line._line import Line, LineSettings, TabulatedRTD
from axialmix.line._models import (
    CLOSED_CLOSED,
    CLOSED_CLOSED_EXCHANGE,
    CLOSED_CLOSED_TANK,
    EMPIRICAL,
    NETWORK,
    OPEN_OPEN,
    TANKS,
    TANKS_EXCHANGE,
    UnitModel,
    transfer_unit_model,
)
from axialmix.line._plots import (
    funnel_map_durations,
    plot_diversion,
    plot_funnel,
    plot_line,
    plot_response,
)
from axialmix.line._programs import (
    CompiledProgram,
    ProgramRunner,
    compile_program,
    program_identity,
    rtd_moments,
)
from axialmix.line._throughput import (
    FlowSchedule,
    equivalent_time,
    exit_age_changing_throughput,
    outlet_response_changing_throughput,
    throughput_clock,
)
from axialmix.line._unit import Unit

__all__ = [
    "CLOSED_CLOSED",
    "CLOSED_CLOSED_EXCHANGE",
    "CLOSED_CLOSED_TANK",
    "EMPIRICAL",
    "NETWORK",
    "OPEN_OPEN",
    "TANKS",
    "TANKS_EXCHANGE",
    "UNIT_BUILDERS",
    "MAX_EVALUATIONS",
    "MAX_FAILED_SHARE",
    "CompiledProgram",
    "ConservativeDiversion",
    "DiversionRefused",
    "DiversionTooLarge",
    "Disturbance",
    "DiversionWindow",
    "FittedRTD",
    "FlowSchedule",
    "FunnelResult",
    "FunnelSettings",
    "Line",
    "LineSettings",
    "OutletResponse",
    "ProgramRunner",
    "TabulatedRTD",
    "Unit",
    "UnitModel",
    "compile_program",
    "conservative_diversion_window",
    "diversion_window",
    "equivalent_time",
    "exit_age_changing_throughput",
    "frequency_response",
    "funnel",
    "funnel_map_durations",
    "outlet_response",
    "outlet_response_changing_throughput",
    "plot_diversion",
    "plot_funnel",
    "plot_line",
    "plot_response",
    "program_identity",
    "rtd_moments",
    "sample_units",
    "series_variance_reduction_ratio",
    "spectral_variance_reduction_ratio",
    "throughput_clock",
    "transfer_unit_model",
    "white_noise_variance_reduction_ratio",
]
