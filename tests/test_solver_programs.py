"""The single-start programs a process shares: a plan without warm-up runs on the program of
the same plan with one (its warm-up skipped at run time), for Levenberg–Marquardt and for the
L-BFGS polish alike, and gives the numbers of a program compiled without the warm-up."""

import collections
import dataclasses

import numpy as np

from axialmix.analytic.closed import exit_age_closed
from fitting.data import Curve
from fitting.fit import prepare
from fitting.models import get_model
from fitting.solve import MultiStartSolver, make_plan, pad_curve, padded_length, single_start
from fitting.solve.programs import Program, export_key, run_program
from fitting.solve.settings import MultiStart, Optimiser
from fitting.solve.single_start import single_start_function, solver_program


def _plan(method: str, warmup: int):
    plan = make_plan("sse", Optimiser(), MultiStart(n_starts=4, warmup_steps=warmup))
    return dataclasses.replace(plan, method=method)


def test_a_plan_without_warm_up_shares_the_program_of_the_plan_with_one(monkeypatch):
    # A registry of its own: programs made by earlier tests of this process do not count.
    monkeypatch.setattr(single_start, "_PROGRAMS", collections.OrderedDict())
    model = get_model("four-compartment")
    t = np.linspace(0.2, 30.0, 40)
    curve = Curve("c", t, 1000.0 * np.exp(-0.3 * t) * (1.0 - np.exp(-t)), time_unit="s")
    layout = prepare(model, curve, None, None, 4, 0).layout
    warm, plain = _plan("lm", 100), _plan("lm", 0)
    with_warm_up = MultiStartSolver(model, layout, warm, "curves")
    without = MultiStartSolver(model, layout, plain, "curves")
    assert without.program is with_warm_up.program
    # The L-BFGS polish of the passes (no warm-up, after the first fit made its own) is the
    # first fit's L-BFGS program.
    first = with_warm_up.lbfgs_program()
    assert without.lbfgs_program() is first
    assert with_warm_up.lbfgs_program() is not with_warm_up.program
    # Nothing to share with: a plan of another method or model gets its own program.
    assert solver_program(model, layout, _plan("lbfgs", 0)) is with_warm_up.lbfgs_program()
    assert solver_program(get_model("adm"), prepare("adm", curve, None, None, 1, 0).layout,
                          _plan("lbfgs", 0)) is not with_warm_up.lbfgs_program()


def test_the_shared_l_bfgs_program_gives_the_numbers_of_one_without_warm_up():
    model = get_model("adm")
    t = np.linspace(0.0, 30.0, 45)
    exact = np.asarray(exit_age_closed(t, 10.0, 15.0))  # the "adm" model: E itself
    noise = 0.01 * exact.max() * np.random.default_rng(5).standard_normal(t.size)
    curve = Curve("c", t, exact + noise, time_unit="s")
    prepared = prepare(model, curve, None, None, 1, 0)
    shared = solver_program(model, prepared.layout, _plan("lbfgs", 100))
    own = Program(single_start_function(model, prepared.layout, _plan("lbfgs", 0)),
                  "lbfgs-own", export_key(model, prepared.layout, _plan("lbfgs", 0)))
    padded = pad_curve(t, curve.value, np.ones(t.size), padded_length(t.size))
    arguments = (prepared.starts[0], np.asarray(False), prepared.base, *padded)
    a = run_program(shared, arguments, [0.0, 0.0])
    b = run_program(own, arguments, [0.0, 0.0])
    assert int(a["steps"]) > 1 and int(a["evaluations"]) == int(b["evaluations"])
    np.testing.assert_allclose(a["free_values"], b["free_values"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(a["scaled_loss"], b["scaled_loss"], rtol=1e-12, atol=0)
    # And the fit is the curve's: tau and Pe near the truth.
    tau, peclet = (float(a["all_values"][prepared.layout.names.index(n)])
                   for n in ("tau", "peclet"))
    assert abs(tau / 10.0 - 1) < 0.01 and abs(peclet / 15.0 - 1) < 0.05
