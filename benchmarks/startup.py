"""Time to a first result: the command line against ``import jax`` and scipy's ``curve_fit``.

Each row is a fresh Python process, timed end to end (wall clock), in this order:

* ``python -c "import jax"``: the unit of the ratios (starting Python and importing JAX);
* ``axialmix --help``;
* ``axialmix fit examples/data/horizontal.csv --model adm``: first run after installation (an
  empty cache folder: ``XDG_CACHE_HOME`` points to a new temporary folder), then a second
  run with the same cache folder;
* the same curve with ``--model four-compartment --fix k_out=0.8``: first and second run;
* the peer: ``scipy.optimize.curve_fit`` of the closed–closed axial dispersion model on the
  same raw curve, ``c(t) = A E(t)`` as ``axialmix fit`` models it by default (amplitude
  fitted, no dead time or baseline), ``E`` written here in NumPy as the Bromwich integral of
  its transfer function (:data:`PEER_MODEL`, independent of JAX and of axialmix; the
  eigenvalue series is no use here: its terms cancel to nothing at high Pe), started from
  the moment estimates. Before anything is timed the peer's E is checked against
  :func:`axialmix.analytic.closed.exit_age_closed` on the curve's times over the tau and Pe
  its fit may visit; above 1e-8 of the peak the benchmark stops.

The table gives seconds, the ratio to ``import jax`` and the targets: ADM second run ≤ 3×,
first run ≤ 8×, four-compartment second run ≤ 5×, ``axialmix --help`` ≤ 1 s. The fitted
tau and Pe of the ADM fit and of ``curve_fit`` are printed too (the same optimum when the
fit command's error model is ``absolute``; its default may weight the points).

    python benchmarks/startup.py [--repeat N]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CURVE = ROOT / "examples" / "data" / "horizontal.csv"

#: The peer's model: the closed-closed E in NumPy (independent of JAX and of axialmix), used by
#: this benchmark's peer and by the peers of benchmarks/study.py.
PEER_MODEL = r'''
import numpy as np

def exit_age(t, tau, peclet, nodes=32):
    # E(t) of the closed-closed ADM as the Bromwich integral of its transfer function
    # G(s) = 4 q e^{Pe(1-q)/2} / ((1+q)^2 - (1-q)^2 e^{-q Pe}),  q = sqrt(1 + 4 s tau / Pe)
    # (MODELS.md section 2). With theta = t / tau and s = Pe (q^2 - 1) / 4, the exponent
    # s theta + Pe (1-q)/2 = (Pe theta / 4) (q - 1/theta)^2 - Pe (1-theta)^2 / (4 theta) is a
    # Gaussian about its saddle q = 1/theta, and the poles of G lie on the imaginary q axis:
    # the line Re q = 1/theta + sqrt(9.2 / (Pe theta)) is integrated by the trapezoidal rule
    # out to where the Gaussian is e^-40. No term grows like e^{Pe/2}, unlike the eigenvalue
    # series, whose alternating terms cancel to nothing in double precision at high Pe.
    theta = np.asarray(t, dtype=float) / tau
    out = np.zeros(theta.shape)
    # Below this theta, Pe (1 - theta)^2 / (4 theta) > 1000: E underflows to 0.
    k = 4000.0
    live = theta > 2 * peclet / ((2 * peclet + k) + np.sqrt(k * (4 * peclet + k)))
    th = theta[live][:, None]
    pe_th = peclet * th
    offset = np.sqrt(9.2 / pe_th)
    step = np.sqrt(160.0 / pe_th) / nodes
    y = np.arange(nodes + 1) * step
    q = 1.0 / th + offset + 1j * y
    exponent = 0.25 * pe_th * (offset + 1j * y) ** 2 - peclet * (1.0 - th) ** 2 / (4.0 * th)
    z = -q * peclet  # Re z < 0: (1+q)^2 - (1-q)^2 e^z = q (4 + Pe (1-q)^2 (e^z - 1) / z)
    denominator = 4.0 + peclet * (1.0 - q) ** 2 * (np.expm1(z) / z)
    integrand = (np.exp(exponent) * 2.0 * peclet * q / denominator).real
    weights = np.ones(nodes + 1)
    weights[0] = 0.5
    out[live] = step[:, 0] / np.pi * (integrand @ weights)
    return out / tau
'''

#: The peer, run as its own process: the NumPy model above + curve_fit.
PEER = PEER_MODEL + r'''
import sys
from scipy.optimize import curve_fit

data = np.loadtxt(sys.argv[1], delimiter=",", comments="#", skiprows=2)
t, y = data[:, 0], data[:, 1]
density = np.clip(y, 0, None)
area = np.trapezoid(density, t)
mean = np.trapezoid(t * density, t) / area
variance = np.trapezoid((t - mean) ** 2 * density, t) / area
# Moment start for Pe: the closed-closed relation sigma^2/tau^2 = 2/Pe - 2/Pe^2 (1 - e^-Pe).
ratio = variance / mean**2
peclet = 2.0
for _ in range(100):
    peclet = 2 / ratio * (1 - (1 - np.exp(-peclet)) / peclet)
def measured(t, tau, peclet, amplitude):
    # The raw values as axialmix fit reads them: c(t) = A E(t) (no dead time, no baseline).
    return amplitude * exit_age(t, tau, peclet)

(tau, pe, _), _ = curve_fit(measured, t, y, p0=[mean, peclet, area],
                            bounds=([1e-9, 1e-9, 0.0], np.inf))
print(f"{tau:.6g} {pe:.6g}")
'''

#: (label, target ratio to import jax or None, absolute target in seconds or None).
TARGETS = {
    "help": (None, 1.0),
    "adm first": (8.0, None),
    "adm second": (3.0, None),
    "four-compartment second": (5.0, None),
}


#: Largest admitted |E_peer - E_exact| over the peak of E_exact on a curve's sample times.
PEER_TOLERANCE = 1e-8


def peer_model() -> Callable[..., np.ndarray]:
    """The peer's NumPy ``exit_age(t, tau, peclet)`` (1/time unit) of :data:`PEER_MODEL`."""
    namespace: dict = {}
    exec(PEER_MODEL, namespace)
    return namespace["exit_age"]


def check_peer_model(model, cases, label: str = "peer model check") -> float:
    """Compare the peer's E with axialmix's exact E on every case; refuse to go on if off.

    **Arguments:**

    - `model`: the peer's ``exit_age(t, tau, peclet)``.
    - `cases`: ``(t, tau, peclet)`` triples (times and tau in one time unit, Pe
      dimensionless), or ``(t, tau, peclet, exact)`` with the exact E at `t` already known.
    - `label`: the start of the printed line.

    **Returns:** the worst ``max |E_peer - E_exact| / max E_exact`` over the cases
    (dimensionless), printed as one line; exits (status 1) above :data:`PEER_TOLERANCE`.
    """
    from axialmix.analytic.closed import exit_age_closed

    worst, count = 0.0, 0
    for case in cases:
        t, tau, peclet = case[:3]
        exact = np.asarray(case[3] if len(case) > 3 else exit_age_closed(t, tau, peclet))
        error = np.max(np.abs(model(t, tau, peclet) - exact)) / np.max(exact)
        worst = max(worst, float(error)) if np.isfinite(error) else np.inf
        count += 1
    verdict = "ok" if worst <= PEER_TOLERANCE else "FAILED: the peers are not timed"
    print(f"{label}: {count} curves, worst |E_peer - E_exact| / peak = {worst:.2e} "
          f"(limit {PEER_TOLERANCE:g}) {verdict}", flush=True)
    if worst > PEER_TOLERANCE:
        raise SystemExit(1)
    return worst


def check_startup_peer() -> float:
    """The peer's model on the benchmark curve's times, at its moment estimate of tau times
    0.5, 1 and 2 and at Pe from 0.1 to 1000 (what its fit may visit), against the exact E."""
    t, y = np.loadtxt(CURVE, delimiter=",", comments="#", skiprows=2)[:, :2].T
    density = np.clip(y, 0, None)
    mean = np.trapezoid(t * density, t) / np.trapezoid(density, t)
    cases = [(t, mean * factor, peclet) for factor in (0.5, 1.0, 2.0)
             for peclet in np.geomspace(0.1, 1000.0, 13)]
    return check_peer_model(peer_model(), cases,
                            f"peer model check ({CURVE.name}, tau and Pe swept)")


def _command_line() -> list[str]:
    """The installed ``axialmix`` script beside this interpreter (not a version manager's shim,
    which would add its own start-up), else the module."""
    beside = Path(sys.executable).parent / "axialmix"
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("axialmix")
    return [found] if found else [sys.executable, "-m", "fitting.cli"]


def _timed(command: list[str], environment: dict[str, str]) -> tuple[float, str]:
    began = time.perf_counter()
    done = subprocess.run(command, env=environment, capture_output=True, text=True, cwd=ROOT)
    seconds = time.perf_counter() - began
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr}")
    return seconds, done.stdout


def run_once() -> tuple[list[tuple[str, float]], dict[str, tuple[float, float]]]:
    """One pass of every row, in fresh processes; returns the timings and fitted values."""
    axialmix = _command_line()
    rows: list[tuple[str, float]] = []
    fitted: dict[str, tuple[float, float]] = {}
    with tempfile.TemporaryDirectory(prefix="axialmix-startup-") as folder:
        folder = Path(folder)
        environment = {k: v for k, v in os.environ.items()
                       if k not in ("JAX_COMPILATION_CACHE_DIR", "JAX_LOG_COMPILES")}
        environment["XDG_CACHE_HOME"] = str(folder / "cache")  # empty: as after installation
        rows.append(("import jax", _timed([sys.executable, "-c", "import jax"], environment)[0]))
        rows.append(("help", _timed([*axialmix, "--help"], environment)[0]))
        adm = [*axialmix, "fit", str(CURVE), "--model", "adm"]
        four = [*axialmix, "fit", str(CURVE), "--model", "four-compartment", "--fix", "k_out=0.8"]
        for name, command in (("adm", adm), ("four-compartment", four)):
            for run in ("first", "second"):
                out = folder / f"{name}-{run}"
                rows.append((f"{name} {run}", _timed([*command, "--out", str(out)],
                                                     environment)[0]))
            record = json.loads((out / f"{CURVE.stem}.json").read_text())
            values = record["parameters"]
            if name == "adm":
                errors = record.get("error_model", {}).get("kind", "absolute")
                fitted[f"axialmix fit (adm, {errors} errors)"] = (
                    values["tau"]["value"], values["peclet"]["value"])
        seconds, printed = _timed([sys.executable, "-c", PEER, str(CURVE)], environment)
        rows.append(("scipy curve_fit (peer)", seconds))
        fitted["scipy curve_fit (unweighted)"] = tuple(float(x) for x in printed.split())
    return rows, fitted


def table(rows: list[tuple[str, float]]) -> str:
    """The timings as a text table with ratios to ``import jax`` and the targets."""
    unit = dict(rows)["import jax"]
    lines = [f"{'run':<28}{'seconds':>9}{'x import jax':>14}  target",
             "-" * 70]
    for label, seconds in rows:
        ratio, absolute = TARGETS.get(label, (None, None))
        target = ""
        if ratio is not None:
            target = f"<= {ratio:g}x: {'met' if seconds <= ratio * unit else 'NOT met'}"
        elif absolute is not None:
            target = f"<= {absolute:g} s: {'met' if seconds <= absolute else 'NOT met'}"
        lines.append(f"{label:<28}{seconds:>9.2f}{seconds / unit:>13.1f}x  {target}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="passes (default 1)")
    args = parser.parse_args()
    check_startup_peer()  # before anything is timed; JAX's import here precedes every timing
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    print(f"{os.cpu_count()} CPUs; load average before: "
          f"{' '.join(f'{x:.2f}' for x in load) if load else 'unknown'}")
    for repetition in range(args.repeat):
        rows, fitted = run_once()
        print(f"\npass {repetition + 1} of {args.repeat}")
        print(table(rows))
        for label, (tau, peclet) in fitted.items():
            print(f"  {label}: tau = {tau:.6g}, Pe = {peclet:.6g}")


if __name__ == "__main__":
    main()
