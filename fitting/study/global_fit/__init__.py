"""Global fits: parameters shared across the curves of a study, or following a factor law.

A study's curves are fitted jointly: one least-squares problem over the residuals of every
curve, one parameter vector, one covariance. Each model parameter is

* **per curve** (the default): one value for each curve, like a fit of that curve alone;
* **shared** (:attr:`GlobalModel.shared`): one value for all curves; or
* **given by a factor law** (:class:`FactorLaw`): for curve ``i`` with factor values
  ``x_i1, x_i2, ...`` (columns of the study table), ``g(p_i) = c0 + c1 x_i1 + c2 x_i2 + ...``
  with ``g = ln`` (``transform="log"``, for positive parameters such as the Peclet number)
  or ``g`` the identity. The coefficients ``c`` are fitted parameters of the joint problem,
  so they come with standard errors and 95 % intervals from its one covariance.

Every curve keeps its own measurement model (:func:`fitting.measurement.measured`): its
amplitude ``A_i`` (tracer amount over the flow) is always a per-curve parameter (or
shared, if listed), and a freed dead time or baseline is per curve too. Curves keep their
own time grids: each is padded with zero-weight points to a common length, and the model of
all curves is one ``vmap`` over them (no loop over curves in the traced program).

How it is solved (:func:`global_fit`):

1. **First stage.** Each curve is fitted alone (:func:`fitting.fit.fit_many`, one compiled
   solver for all of them). These fits give the starts (per-curve values; the median of a
   shared parameter; the least-squares regression of ``g(p_i)`` on the factors for a
   law's coefficients) and each curve's error model: with ``weights="combined"`` (the
   default) its additive and proportional noise sizes ``a_i`` and ``b_i``, estimated as
   ``axialmix fit`` estimates them; with ``"per-curve"`` its noise level ``s_i``.
2. **Joint fit.** The stacked residuals ``sqrt(w_ij) (A_i (E_i ⊗ u)(t_ij) + b_i - c_ij)``, with
   ``w_ij = 1 / (a_i² + (b_i m_ij)²)`` (``"combined"``, ``m_ij`` the first-stage model curve:
   samples count by their precision within and across curves, as in two-stage generalised least
   squares), ``w_ij = 1 / s_i²`` (``"per-curve"``) or ``w_ij = 1`` (``"equal"``: one noise size for
   the whole study), are minimised by the project's compiled Levenberg–Marquardt solver
   (:func:`fitting.solve.compiled_solver`, the program fits treat as one curve), and the covariance
   is the Gauss–Newton one of :func:`fitting.uncertainty.gauss_newton_uncertainty` over all free
   parameters: ``C = s² (Jᵀ W J)⁻¹``, ``s² = Σ w r² / ν``, intervals ``± t(0.975, ν) · se`` with
   ``ν = N - p`` degrees of freedom (``N`` samples, ``p`` joint parameters), less the number of
   estimated noise sizes minus one (``2 n_curves - 1`` with combined weights, ``n_curves - 1`` with
   per-curve ones: estimated from the same data). Per-curve values that a law gives carry
   delta-method errors (``se(g(p_i)) = sqrt(x_i C_c x_iᵀ)``, intervals back-transformed, so positive
   under ``ln``).

:func:`two_stage_law` is the usual alternative: fit curves one by one, then regress their
fitted values on the factors; its intervals rest on the scatter of ``n_curves`` points
around the law (``n_curves - k - 1`` degrees of freedom) and are wider.

What the intervals assume (measured in ``tests/test_study_global.py``, opt-in study of 200
replicated 18-curve designs):

* **The law holds exactly for every run.** The global fit has no term for run-to-run
  scatter of the parameter around the law; where runs scatter (a process effect the law
  does not hold), its intervals are too short (ln Pe scattering by 0.05 between runs:
  coverage 0.68 to 0.75), while the two-stage regression, whose errors come from that scatter,
  stays right (coverage 0.925 to 0.97). Check the law first (an ANOVA of the one-by-one
  values, or the two-stage residuals) before trusting the global intervals.
* **The curves' weights.** With known weights (one number per curve, ``1 / σ_i²``) the
  intervals hold their 95 % (coverage 0.93 to 0.955; spread of the estimates over their
  standard errors 1.00 to 1.05); with weights estimated from each curve's own fit
  (``"per-curve"``, about 25 samples a curve) that ratio is 1.09 to 1.12 (coverage 0.915
  to 0.94): the estimated weights' own noise is not in the covariance.

The Jacobian of the joint problem is dense (``N`` samples by ``p = k + 1 + m n_curves``
parameters for one law and ``m`` per-curve parameters), so memory and time grow with the
square of the number of curves: a global fit is meant for studies of tens to a few hundred
curves; batch fits of thousands are :func:`fitting.fit.fit_many`'s business.

The parts, one concept a module: :mod:`~fitting.study.global_fit.law` (factor laws),
:mod:`~fitting.study.global_fit.model` (which parameters are shared, given by laws or per
curve), :mod:`~fitting.study.global_fit.joint` (the joint model and its parameter layout),
:mod:`~fitting.study.global_fit.problem` (the joint problem: padded data, weights, starts),
:mod:`~fitting.study.global_fit.estimate` (a law's coefficients, and the two-stage regression),
:mod:`~fitting.study.global_fit.result` (the record, its table and report),
:mod:`~fitting.study.global_fit.propagation` (the uncertainty: covariance, intervals, delta
method) and :mod:`~fitting.study.global_fit.solver` (the fit).
"""

from fitting.study.global_fit.estimate import LawEstimate, two_stage_law
from fitting.study.global_fit.law import LAW_TRANSFORMS, FactorLaw
from fitting.study.global_fit.model import GlobalModel
from fitting.study.global_fit.problem import WEIGHTINGS, GlobalProblem, global_problem
from fitting.study.global_fit.propagation import curve_physical_quantities
from fitting.study.global_fit.result import GlobalFitResult
from fitting.study.global_fit.solver import global_fit

__all__ = [
    "LAW_TRANSFORMS",
    "curve_physical_quantities",
    "WEIGHTINGS",
    "FactorLaw",
    "GlobalFitResult",
    "GlobalModel",
    "GlobalProblem",
    "LawEstimate",
    "global_fit",
    "global_problem",
    "two_stage_law",
]
