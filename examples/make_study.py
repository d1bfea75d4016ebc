"""Regenerate the example study in examples/study/: a speed x flow design of tracer curves.

A design of experiments on a continuous blender, as RTD campaigns are run: three impeller
speeds (100, 200, 300 rpm) times three feed rates (20, 30, 40 kg/h), each run twice, 18
tracer curves in one long-format table (``speed_flow.csv``: run id, time, concentration, and
the factors on every row). The curves are exact closed–closed axial dispersion curves
(:func:`axialmix.analytic.exit_age_closed`, MODELS.md section 2) with parameters from known
factor laws, sampled and measured as a real analyser would:

* hold-up 0.5 kg (so ``tau = 3600 * 0.5 / flow`` s: 90, 60 and 45 s) times a run-to-run
  factor of 1 +/- 2 % (log-normal);
* ``ln Pe = 1.2 + 0.004 speed + 0.02 flow`` (Pe from 8 to 33): the law the global fit
  should give back (``axialmix global-fit ... --law "log(peclet)=speed+flow"``);
* 25 samples from 0 to 3 tau, the first at 0; concentration ``c = A E(t)`` in g/L with the
  tracer amount over the flow ``A`` = 50 g/L*s times 1 +/- 5 %;
* noise: additive 0.5 % of the peak and 2 % proportional (Gaussian), not clipped (the fit
  keeps values slightly below zero).

Run ``python examples/make_study.py``; seeded, so the same file comes out.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from axialmix.analytic import exit_age_closed

SPEEDS = (100.0, 200.0, 300.0)  # rpm
FLOWS = (20.0, 30.0, 40.0)  # kg/h
REPLICATES = 2
HOLD_UP = 0.5  # kg
LAW = (1.2, 0.004, 0.02)  # ln Pe = c0 + c1 speed + c2 flow
SAMPLES = 25


def main() -> Path:
    rng = np.random.default_rng(20261130)
    rows = ["run,t [s],c [g/L],speed,flow"]
    number = 0
    for speed, flow, _ in itertools.product(SPEEDS, FLOWS, range(REPLICATES)):
        number += 1
        tau = 3600.0 * HOLD_UP / flow * float(np.exp(rng.normal(0.0, 0.02)))
        peclet = float(np.exp(LAW[0] + LAW[1] * speed + LAW[2] * flow))
        amplitude = 50.0 * float(np.exp(rng.normal(0.0, 0.05)))
        time = np.linspace(0.0, 3.0 * tau, SAMPLES)
        clean = amplitude * np.asarray(exit_age_closed(time, tau, peclet))
        noisy = clean + rng.normal(0.0, 0.005 * clean.max(), time.size) \
            + rng.normal(0.0, 0.02, time.size) * clean
        run = f"run{number:02d}"
        rows += [f"{run},{t:.4f},{c:.6g},{speed:g},{flow:g}" for t, c in zip(time, noisy,
                                                                             strict=True)]
    path = Path(__file__).resolve().parent / "study" / "speed_flow.csv"
    path.parent.mkdir(exist_ok=True)
    path.write_text("\n".join(rows) + "\n")
    return path


if __name__ == "__main__":
    print(f"wrote {main()}")
