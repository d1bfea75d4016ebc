"""The particle simulator with scheduled exchange, as the checker of scheduled networks and VRR.

* Move schedules: made from a :class:`axialmix.network.RateSchedule` they keep every hold-up,
  follow the rates to one particle over a run, and a constant schedule is the plain run.
* A four-compartment blender whose exchange ramps up (an impeller speed ramp) solved by
  diffrax agrees with the mean of particle runs on the same schedule within 3 standard errors
  at every reported step, while the same runs reject the network without the ramp. The
  particle process steps in time, the ODE does not: the gap between the ODE and the exact
  expectation of the stepped process is computed and must stay below a third of a standard
  error, so the comparison tests the schedule, not the step length.
* The VRR predicted from the transfer function (held white feeder noise, MODELS.md §8)
  agrees with the VRR of particle runs with fluctuating feeders within the runs' 95 %
  confidence interval, at three settings of the source's fitted rates.

The default versions are small (seconds); ``--studies`` runs the full-size evidence.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from axialmix import particles
from axialmix.line import Unit, spectral_variance_reduction_ratio
from axialmix.network import (
    RateSchedule,
    four_compartment,
    scheduled_amounts,
    scheduled_exit_age,
)
from axialmix.particles import (
    TracerPulse,
    check_move_schedule,
    constant_feed,
    particle_four_compartment,
    scheduled_moves,
    simulate,
)

#: The structure of the four-compartment network (its rates come from the schedules): the
#: network of tests/test_line_network_schedule.py, so a session compiles the solve once.
STRUCTURE = four_compartment(2.125, 2.125, 0.625, 1.0)
RAMP_START, RAMP_END = 1.0, 3.0


def _ramp(network):
    """The network's rates, then from 1 s to 3 s as many extra particles per step moved both
    ways across every connection as its largest move (an impeller speed ramp)."""
    mean_field = network.to_network().continuous()
    rates, outflow = np.asarray(mean_field.rates), np.asarray(mean_field.outflow_rates)
    extra = network.moves.max() / (network.holdups[network.sources] * network.step_seconds)
    return RateSchedule([RAMP_START, RAMP_END], np.stack([rates, rates + extra]),
                        np.stack([outflow, outflow]))


def _stepped_expectation(network, moves, every):
    """The exact expectation of the particle process: ``m_{k+1} = (I + Q_k) m_k`` with
    ``Q_k`` from the moves of step k (MODELS.md §4), recorded every `every` steps."""
    n = network.n_compartments
    amounts, recorded = np.eye(n)[0], [np.eye(n)[0]]
    fractions = moves / network.holdups[network.sources][None, :]
    for k in range(moves.shape[0]):
        flow = fractions[k] * amounts[network.sources]
        change = -network.outflow_fractions() * amounts
        change += np.bincount(network.targets, flow, n) - np.bincount(network.sources, flow, n)
        amounts = amounts + change
        if (k + 1) % every == 0:
            recorded.append(amounts)
    return np.array(recorded)


def _ramp_runs(time_step, runs, tracer, total, horizon=6.0, report=0.25):
    """Tracer fractions per compartment at the reported steps, one row per run."""
    network = particle_four_compartment(particles=total, time_step=time_step)
    schedule = _ramp(network)
    steps = int(round(horizon / time_step))
    every = int(round(report / time_step))
    moves = scheduled_moves(network, schedule, steps)
    feed = constant_feed(network, [1.0, 0.0], steps)
    start = np.column_stack([network.holdups, np.zeros(4, np.int64)])
    fractions = np.array([
        simulate(network, start, steps, seed=seed, feed=feed, moves=moves,
                 tracer=TracerPulse(0, tracer, 1),
                 report_steps=np.arange(0, steps + 1, every)).counts[:, :, 1] / tracer
        for seed in range(runs)
    ])
    times = np.arange(0, steps + 1, every) * time_step
    return network, schedule, times, fractions, _stepped_expectation(network, moves, every)


# ------------------------------------------------------------------ move schedules
def test_scheduled_moves_keep_holdups_and_follow_the_rates_to_one_particle():
    network = particle_four_compartment(particles=10_000, time_step=0.002)
    schedule = _ramp(network)
    steps = 2000
    moves = scheduled_moves(network, schedule, steps)
    check_move_schedule(network, moves, steps)  # balanced, within hold-ups
    midpoints = (np.arange(steps) + 0.5) * network.step_seconds
    rates = np.stack([np.interp(midpoints, [RAMP_START, RAMP_END], np.asarray(schedule.rates)[:, j])
                      for j in range(network.moves.size)], axis=1)
    wanted = rates * network.holdups[network.sources] * network.step_seconds
    drift = np.abs(np.cumsum(moves - wanted, axis=0))
    assert drift.max() <= 1.0 + 1e-9  # running totals exact to one particle
    assert np.array_equal(moves[0], network.moves)
    assert np.array_equal(moves[-1] - network.moves, np.full(8, network.moves.max()))


def test_constant_move_schedule_is_the_plain_run_for_both_engines():
    network = particle_four_compartment(particles=2000, time_step=0.01)
    steps = 300
    feed = particles.feeder_feed(network, [6.55, 12.16], [1.16, 2.46], steps, seed=4)
    start = np.column_stack([network.holdups // 3, network.holdups - network.holdups // 3])
    constant = np.tile(network.moves, (steps, 1))
    for engine in particles.ENGINES:
        plain = simulate(network, start, steps, engine=engine, seed=9, feed=feed,
                         report_every=50)
        scheduled = simulate(network, start, steps, engine=engine, seed=9, feed=feed,
                             report_every=50, moves=constant)
        assert np.array_equal(plain.counts, scheduled.counts)
        assert np.array_equal(plain.outflow, scheduled.outflow)
        assert scheduled.particles_moved() == plain.particles_moved()


def test_move_schedules_that_change_holdups_are_refused():
    network = particle_four_compartment(particles=10_000, time_step=0.002)
    moves = np.tile(network.moves, (5, 1))
    moves[3, 0] += 1  # one more particle C1 -> C2 at step 3 only
    with pytest.raises(ValueError, match="step 3 change the hold-up of compartment C1"):
        check_move_schedule(network, moves, 5)
    rates = np.asarray(network.to_network().continuous().rates)
    outflow = np.asarray(network.to_network().continuous().outflow_rates)
    forward_only = RateSchedule([0.0, 1.0], np.stack([rates, rates * np.r_[2, 1, 1, 1, 1, 1, 1,
                                                                             1]]),
                                np.stack([outflow, outflow]))
    with pytest.raises(ValueError, match="exchange must change by the same number"):
        scheduled_moves(network, forward_only, 1000)
    faster_weir = RateSchedule([0.0], rates[None], 2 * outflow[None])
    with pytest.raises(ValueError, match="outflow rates must stay"):
        scheduled_moves(network, faster_weir, 10)


# ------------------------------------------------------------------ ramped network
def _ramp_check(time_step, runs, tracer, total, compare):
    network, schedule, times, fractions, stepped = _ramp_runs(time_step, runs, tracer, total)
    mean = fractions.mean(axis=0)[1:]
    standard_error = fractions.std(axis=0, ddof=1)[1:] / np.sqrt(runs)
    stepped = stepped[1:]
    ode, unramped = compare(network, schedule, times)
    ode, unramped = ode[1:], unramped[1:]
    columns = slice(None) if ode.shape[1] == 4 else slice(3, 4)
    mean, standard_error, stepped = mean[:, columns], standard_error[:, columns], stepped[:,
                                                                                         columns]
    z = np.abs(mean - ode) / standard_error
    bias = np.abs(stepped - ode) / standard_error
    rejected = np.abs(mean - unramped) / standard_error
    print(f"\nramp, {runs} runs of {tracer} tracer particles, step {time_step} s, "
          f"{z.size} comparisons: max |mean - ODE| = {z.max():.2f} SE, stepped-process "
          f"expectation vs ODE {bias.max():.3f} SE, without the ramp {rejected.max():.1f} SE")
    return z, bias, rejected


def _exit_age_of_the_outlet(network, schedule, times):
    """``m_4 = E / k_out`` with the ramp and without it (the same compiled solve)."""
    k_out = float(schedule.outflow_rates[0, 0])
    before = RateSchedule(schedule.times, np.stack([schedule.rates[0]] * 2),
                          schedule.outflow_rates)
    return tuple(np.asarray(scheduled_exit_age(STRUCTURE, s, times))[:, None] / k_out
                 for s in (schedule, before))


def test_ramped_network_solved_by_diffrax_agrees_with_the_particle_mean():
    z, bias, rejected = _ramp_check(0.002, 40, 1000, 10_000, _exit_age_of_the_outlet)
    assert z.max() < 3.0
    assert bias.max() < 1 / 3
    assert rejected.max() > 3.0


def _amounts(network, schedule, times):
    before = RateSchedule(schedule.times, np.stack([schedule.rates[0]] * 2),
                          schedule.outflow_rates)
    mean_field = network.to_network().continuous()
    return tuple(np.asarray(scheduled_amounts(mean_field, s, np.eye(4)[0], times))
                 for s in (schedule, before))


@pytest.mark.study
def test_ramped_network_agrees_with_the_particle_mean_at_full_size():
    # 200 runs of 10,000 tracer particles among 10**6, steps of 1e-4 s (60,000 per run); all
    # four compartments at 24 reported times.
    z, bias, rejected = _ramp_check(1e-4, 200, 10_000, 1_000_000, _amounts)
    assert z.max() < 3.0
    assert bias.max() < 1 / 3
    assert rejected.max() > 3.0


# ------------------------------------------------------------------ variance reduction
#: (k_f, k_r, k_s) of the source's horizontal, +14° and -14° fits (1/s), with k_out = 1/s,
#: and the time (s) each drawn feeder rate is held.
SETTINGS = [((2.125, 2.125, 0.625), 1.0), ((0.75, 0.75, 1.0), 0.5), ((2.25, 2.25, 0.375), 2.0)]


def _held_noise_vrr(unit, hold, reach):
    """VRR of feeder noise held for `hold` between independent draws, from |G(iω)|²: the
    spectrum of such noise is ``hold sinc²(ω hold / 2)`` (phase averaged). Frequencies up
    to ``reach / hold`` miss ``2 / (pi reach)`` of the input variance."""
    omega = np.linspace(0.0, reach / hold, 100 * int(reach) + 1)
    spectrum = hold * np.sinc(omega * hold / (2 * np.pi)) ** 2
    return float(spectral_variance_reduction_ratio(unit, omega, spectrum))


def _vrr_check(rates, hold, time_step, runs, length, reach, seeds):
    # 10**9 particles: outflow samples of about 10**6 particles a step, whose sampling
    # variance (p(1-p)/n, about 2e-7) is a thousandth of the outlet variance, so the VRR is
    # the blender's damping alone.
    network = particle_four_compartment(*rates, 1.0, particles=10**9, time_step=time_step)
    unit = Unit.network(network.to_network().continuous())
    predicted = _held_noise_vrr(unit, hold, reach)
    hold_steps = int(round(hold / time_step))
    steps = int(round(length / time_step))
    warm_up = int(round(float(unit.mean() + 10 * np.sqrt(unit.variance())) / time_step))
    api = np.rint(0.35 * network.holdups).astype(np.int64)
    start = np.column_stack([api, network.holdups - api])
    series = []
    for run in range(runs):
        feed = particles.feeder_feed(network, [6.55, 12.16], [1.16, 2.46], steps,
                                     hold_steps=hold_steps, seed=seeds + run)
        result = simulate(network, start, steps, seed=seeds + run, feed=feed)
        series.append([feed[warm_up:, 0, 0] / feed[warm_up:, 0].sum(axis=1),
                       result.outflow[warm_up:, 0] / result.outflow[warm_up:].sum(axis=1)])
    # Variances about the mean of all runs (inflow and outflow have the same mean), so a run
    # shorter than the outlet's slow swings is not robbed of them as about its own mean; the
    # VRR of the runs together is sigma²_in / sigma²_out of the pooled variances, with a
    # jackknife interval over runs (the mean of the runs' own ratios is biased upwards:
    # E[1/x] > 1/E[x]).
    series = np.array(series)
    variances = ((series - series.mean(axis=(0, 2), keepdims=True)) ** 2).mean(axis=2)
    pooled = variances[:, 0].mean() / variances[:, 1].mean()
    left_out = np.array([np.delete(variances[:, 0], k).mean() / np.delete(variances[:, 1], k)
                         .mean() for k in range(runs)])
    standard_error = np.sqrt((runs - 1) / runs * np.sum((left_out - left_out.mean()) ** 2))
    half_width = stats.t.ppf(0.975, runs - 1) * standard_error
    print(f"\nk = {rates}, hold {hold} s: VRR particles {pooled:.3f} ± {half_width:.3f}"
          f" (95 %, {runs} runs of {length:g} s), transfer function {predicted:.3f}")
    return pooled, half_width, predicted


def test_vrr_from_the_transfer_function_agrees_with_particle_runs():
    # The source's horizontal fit, feeders held 1 s; 4 runs of 1200 s in steps of 0.05 s.
    # Known small offsets, far inside the interval (about ±15 %): the stepped process's VRR is
    # 0.9 % below the continuous model's at this step, and the variance about the mean of
    # all runs misses about VRR × hold / (runs × length) = 0.3 % of the outlet variance.
    (rates, hold), = SETTINGS[:1]
    mean, half_width, predicted = _vrr_check(rates, hold, 0.05, 4, 1200.0, 500.0, 1000)
    assert abs(mean - predicted) <= half_width


@pytest.mark.study
def test_vrr_agrees_with_particle_runs_at_three_settings_at_full_size():
    # 20 runs of 4000 s in steps of 0.005 s per setting (offsets as above: about 0.1 % from
    # the step, 0.02 % from the windows), with feeder draws of their own for each setting
    # (shared draws would make the three comparisons err together).
    for index, (rates, hold) in enumerate(SETTINGS):
        mean, half_width, predicted = _vrr_check(rates, hold, 0.005, 20, 4000.0, 4000.0,
                                                 1000 * (index + 1))
        assert abs(mean - predicted) <= half_width
