"""Regenerate the example RTD curves in examples/data/ from seeded "virtual experiments".

Each curve is a tracer experiment run on the stochastic particle simulator
(:mod:`axialmix.particles`, count engine) as a continuous four-compartment blender
(MODELS.md sections 3 and 4) with the source work's fitted fluxes for its five inclinations:

    inclination   k_f     k_r     k_s      (1/s)
    +14°          0.75    0.75    1.0
    +7.5°         0.5     0.5     2.0
    horizontal    2.125   2.125   0.625
    -7.5°         1.5     1.5     0.375
    -14°          2.25    2.25    0.375

Choices (the source leaves them open):

* Time unit: the source's fluxes are read as rates per second, so the source's grid
  ``[0 : 0.125 : 2.5]`` applies to fits of these files directly. The particle process moves
  ``k dt N_i`` particles per step with a step of ``dt = 0.02 s`` (at most 5.5 % of a
  compartment per step), close to the continuous-time network.
* Outflow over the weir ``k_out = 0.8 /s`` (the feed rate divided by the outlet
  compartment's hold-up), the same for all inclinations. Mean residence times are then
  7.3-8.3 s, those of the source's blender 2 at high impeller speed (about 7 s at 300 RPM).
  With ``k_f = k_r`` the drift through the blender comes from the weir alone, and the
  curves of the five inclinations differ little: the fluxes are hard to identify from an RTD.
* 40,000 particles held, a pulse of 8,000 tracer particles into compartment 1 at t = 0.
* Sampling: 15 outflow samples, denser early (0 to 33 s; the one at 0 s is taken as the
  tracer is injected, so it holds only the first 0.2 s of outflow); each sample collects
  the outflow of 0.4 s (20 steps) around its time, and its concentration is the tracer's number
  fraction in it (counting noise comes from the simulation itself).
* Measurement noise: 3 % multiplicative (Gaussian) and an additive Gaussian of 0.2 % of the
  largest sample, clipped at zero (an analyser reports no negative content).

Run ``python examples/make_data.py`` (about a second per curve); the same seeds give the
same files. If :mod:`axialmix.particles` cannot be imported, the curves come instead from the
mean-field RTD of :mod:`axialmix.network` with multinomial counting noise of the same size
(a note says so on the console), so the script keeps working while the simulator changes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import axialmix  # noqa: F401  (float64 for the mean-field fallback)

INCLINATIONS = {
    "incline_plus14": (0.75, 0.75, 1.0),
    "incline_plus7p5": (0.5, 0.5, 2.0),
    "horizontal": (2.125, 2.125, 0.625),
    "incline_minus7p5": (1.5, 1.5, 0.375),
    "incline_minus14": (2.25, 2.25, 0.375),
}
K_OUT = 0.8  # 1/s
TIME_STEP = 0.02  # s
PARTICLES = 40_000
TRACER_PARTICLES = 8_000
SAMPLE_TIMES = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.5, 8.0, 10.0, 12.0, 15.0, 18.0, 22.0, 27.0,
                         33.0])  # s
SAMPLE_WINDOW = 0.4  # s
MULTIPLICATIVE_NOISE = 0.03
ADDITIVE_NOISE = 0.002  # of the largest sample
SEED = 2024


def _window_steps(steps: int) -> list[np.ndarray]:
    """Step indices whose outflow forms each sample (steps k cover (k dt, (k+1) dt])."""
    half = SAMPLE_WINDOW / 2
    step_end = (np.arange(steps) + 1) * TIME_STEP
    return [np.nonzero((step_end > t - half) & (step_end <= t + half))[0] for t in SAMPLE_TIMES]


def simulated_outflow(k_f: float, k_r: float, k_s: float, seed: int) -> np.ndarray:
    """Tracer number fraction in each outflow sample from a particle simulation.

    **Arguments:**

    - `k_f`, `k_r`, `k_s`: the four-compartment rates (1/s).
    - `seed`: seed of the simulation.

    **Returns:** the tracer fraction of each sample at :data:`SAMPLE_TIMES`.
    """
    from axialmix.particles.feed import constant_feed
    from axialmix.particles.presets import particle_four_compartment
    from axialmix.particles.simulate import TracerPulse, simulate

    network = particle_four_compartment(k_f, k_r, k_s, K_OUT, particles=PARTICLES,
                                        time_step=TIME_STEP)
    steps = int(round((SAMPLE_TIMES[-1] + SAMPLE_WINDOW) / TIME_STEP)) + 1
    initial = np.column_stack([network.holdups, np.zeros_like(network.holdups)])
    result = simulate(network, initial, steps, feed=constant_feed(network, [1.0, 0.0], steps),
                      tracer=TracerPulse(step=0, particles=TRACER_PARTICLES, species=1),
                      seed=seed)
    outflow = result.outflow
    return np.array([outflow[w, 1].sum() / outflow[w].sum() for w in _window_steps(steps)])


def mean_field_outflow(k_f: float, k_r: float, k_s: float, seed: int) -> np.ndarray:
    """Fallback: tracer fraction per sample from the mean-field RTD with counting noise.

    The expected tracer count in each sample is ``TRACER_PARTICLES ∫ E dt`` over its window;
    the counts are drawn multinomially, as exiting tracer particles are.
    """
    from axialmix.network import four_compartment_exit_age

    rng = np.random.default_rng(seed)
    steps = int(round((SAMPLE_TIMES[-1] + SAMPLE_WINDOW) / TIME_STEP)) + 1
    mid = (np.arange(steps) + 0.5) * TIME_STEP
    exit_age = np.asarray(four_compartment_exit_age(mid, k_f, k_r, k_s, K_OUT))
    probability = exit_age * TIME_STEP
    counts = rng.multinomial(TRACER_PARTICLES, np.append(probability, 1 - probability.sum()))
    # Outflow per step at steady state: k_out times the outlet hold-up.
    from axialmix.network import four_compartment as network_four_compartment

    holdups = network_four_compartment(k_f, k_r, k_s, K_OUT, total_holdup=PARTICLES).holdups
    per_step = K_OUT * TIME_STEP * holdups[3]
    return np.array([counts[w].sum() / (per_step * w.size) for w in _window_steps(steps)])


def measured(fraction: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Add measurement noise (multiplicative and additive, clipped at zero) to true fractions."""
    noisy = fraction * (1 + MULTIPLICATIVE_NOISE * rng.standard_normal(fraction.size))
    noisy = noisy + ADDITIVE_NOISE * fraction.max() * rng.standard_normal(fraction.size)
    return np.clip(noisy, 0.0, None)


def write_curve(path: Path, concentration: np.ndarray, note: str) -> None:
    """Write one curve as ``time_s,concentration`` with a comment line on its origin."""
    lines = [f"# {note}", "time_s,concentration"]
    lines += [f"{t:g},{c:.6g}" for t, c in zip(SAMPLE_TIMES, concentration, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    """Regenerate every example curve; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "data")
    parser.add_argument("--mean-field", action="store_true",
                        help="use the mean-field network with counting noise, not particles")
    args = parser.parse_args(argv)
    use_particles = not args.mean_field
    if use_particles:
        try:
            import axialmix.particles.simulate  # noqa: F401
        except ImportError:
            print("axialmix.particles is not available: using the mean-field network with "
                  "multinomial counting noise", file=sys.stderr)
            use_particles = False
    args.out.mkdir(parents=True, exist_ok=True)
    for index, (name, (k_f, k_r, k_s)) in enumerate(INCLINATIONS.items()):
        seed = SEED + index
        source = simulated_outflow if use_particles else mean_field_outflow
        fraction = source(k_f, k_r, k_s, seed)
        concentration = measured(fraction, np.random.default_rng([seed, 7]))
        how = "particle simulation" if use_particles else "mean-field network + counting noise"
        note = (f"virtual experiment ({how}, seed {seed}): four-compartment k_f={k_f:g} "
                f"k_r={k_r:g} k_s={k_s:g} k_out={K_OUT:g} 1/s; tracer number fraction")
        write_curve(args.out / f"{name}.csv", concentration, note)
        print(f"{name}: {len(SAMPLE_TIMES)} samples, peak fraction {concentration.max():.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
