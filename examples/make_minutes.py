"""Regenerate examples/data/minutes/blender_minutes.csv: a tracer curve sampled in minutes.

A closed–closed axial dispersion blender (MODELS.md section 2) of length 0.5 m with
``tau = 2.4 min`` and ``Pe = 15`` (so ``v = 0.5 m / 144 s = 3.47 mm/s`` and
``D_z = v L / Pe = 1.16e-4 m²/s``), an ideal pulse of tracer giving an outlet signal
``c = A E(t)`` with ``A = 3.0 g·min/L``, sampled every 0.25 min from 0 to 10 min, with 2 %
multiplicative and 0.005 g/L additive Gaussian noise (clipped at zero), seeded. The header
``t [min]`` tells ``axialmix fit`` that the times are in minutes and ``c [g/L]`` the unit
of the signal.

Run ``python examples/make_minutes.py``; the same seed gives the same file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from axialmix import analytic

TAU_MIN, PECLET, AMPLITUDE = 2.4, 15.0, 3.0
SEED = 20240515
PATH = Path(__file__).resolve().parent / "data" / "minutes" / "blender_minutes.csv"


def main() -> None:
    rng = np.random.default_rng(SEED)
    t = np.arange(0.0, 10.0 + 1e-9, 0.25)
    clean = AMPLITUDE * np.asarray(analytic.exit_age_closed(t, TAU_MIN, PECLET))
    noisy = clean * (1 + 0.02 * rng.standard_normal(t.size)) + 0.005 * rng.standard_normal(t.size)
    noisy = np.clip(noisy, 0.0, None)
    PATH.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# closed-closed ADM, tau = {TAU_MIN} min, Pe = {PECLET:g}, L = 0.5 m; "
             "made by examples/make_minutes.py", "t [min],c [g/L]"]
    lines += [f"{ti:.2f},{ci:.5f}" for ti, ci in zip(t, noisy, strict=True)]
    PATH.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
