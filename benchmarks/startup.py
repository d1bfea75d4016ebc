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
  fitted, no dead time or baseline), ``E`` written here in NumPy from its exact eigenvalue
  series (independent of JAX and of axialmix), started from the moment estimates.

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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CURVE = ROOT / "examples" / "data" / "horizontal.csv"

#: The peer, run as its own process: NumPy closed-closed ADM (eigenvalue series) + curve_fit.
PEER = r'''
import sys
import numpy as np
from scipy.optimize import curve_fit

def eigenvalues(peclet, count):
    # Roots of (4 l^2 - Pe^2) sin l = 4 l Pe cos l, the n-th one solving
    # l - 2 atan(Pe / (2 l)) = (n - 1) pi (monotone, one root in ((n-1) pi, n pi)).
    shift = np.arange(count) * np.pi
    low, high = np.maximum(shift, 1e-300), shift + np.pi
    root = 0.5 * (low + high)
    for _ in range(60):  # Newton, kept inside the bracket by bisection
        f = root - 2 * np.arctan(peclet / (2 * root)) - shift
        low, high = np.where(f < 0, root, low), np.where(f < 0, high, root)
        step = root - f / (1 + peclet / (root**2 + peclet**2 / 4))
        inside = (step > low) & (step < high)
        root = np.where(inside, step, 0.5 * (low + high))
    return root

def exit_age(t, tau, peclet, count=400):
    # E(t) = (8/tau) e^{Pe/2} sum (-1)^{n+1} l^2 / (4 l^2 + Pe^2 + 4 Pe)
    #        exp(-(4 l^2 + Pe^2) theta / (4 Pe)),  theta = t / tau (MODELS.md section 2).
    theta = np.asarray(t, dtype=float)[:, None] / tau
    lam = eigenvalues(peclet, count)[None, :]
    sign = np.where(np.arange(count) % 2 == 0, 1.0, -1.0)[None, :]
    exponent = peclet / 2 - (4 * lam**2 + peclet**2) * theta / (4 * peclet)
    terms = sign * lam**2 / (4 * lam**2 + peclet**2 + 4 * peclet) * np.exp(exponent)
    value = 8 / tau * terms.sum(axis=1)
    return np.where(theta[:, 0] > 0, value, 0.0)

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
