"""DEM configurations: material, the two geometries and the run settings (frozen modules, SI).

Coordinates: the vessel axis is LAMMPS's ``z`` (0 at the inlet end), gravity points along
``-y``, the shaft turns about ``+z``. Every length is in m, time in s, speed in rev/min.

* :class:`BladedMixer`: the source's horizontal bladed mixer (MODELS.md §9, its Table 7.4):
  a closed cylinder of radius 0.1 m and length 0.5 m, a rod 0.45 m long on the axis from the
  ``z = 0`` end, and one flat blade 0.1 m wide along the axis at that end. The source's
  spheres of "0.055 m" cannot fit its vessel; 5.5 mm (about 5 % of the volume as solid, a
  bed about a third of the radius deep) is used. The source says the blade is "0.1 m
  across"; a blade of 0.1 m tip to tip would turn above a bed that deep and never touch it,
  so here the blade reaches 0.095 m from the axis on both sides (0.1 m from axis to wall,
  less a 5 mm clearance) and is 0.1 m wide axially.
* :class:`PaddleSection`: a periodic axial section of the continuous blender of MODELS.md
  §1 (blender 1: 0.15 m across) with two pitched paddles on the shaft; the pitch pushes the
  bed along the axis (the drift a feed drives in the blender).

Material (:class:`Material`): Hertz contact from Young's modulus and Poisson ratio
(``hertz/material``), Mindlin tangential friction, Tsuji damping set by the restitution
coefficient; the same values between particles and against walls. The modulus is that of a
soft pharmaceutical granule model (5 MPa: the time step of real moduli, GPa, is 30 times
smaller, and bed flow in slow mixers does not depend on it in this range).
"""

from __future__ import annotations

import math

import equinox as eqx

__all__ = ["BladedMixer", "Material", "PaddleSection", "RunSettings", "rayleigh_time"]


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(float(value)) and float(value) > 0):
        raise ValueError(f"{name} must be positive and finite, got {value}.")


def rayleigh_time(diameter: float, density: float, youngs_modulus: float, poisson: float) -> float:
    """Rayleigh wave time of a sphere, s: ``pi r sqrt(rho / G) / (0.1631 nu + 0.8766)``.

    **Arguments:** `diameter` (m), `density` (kg/m³), `youngs_modulus` (Pa), `poisson` (-);
    ``G = E / (2 (1 + nu))`` is the shear modulus.
    """
    shear = youngs_modulus / (2 * (1 + poisson))
    return math.pi * diameter / 2 * math.sqrt(density / shear) / (0.1631 * poisson + 0.8766)


class Material(eqx.Module):
    """Contact material of the spheres and walls (Hertz–Mindlin with friction, Tsuji damping).

    **Arguments:**

    - `youngs_modulus`: E, Pa (default 5 MPa).
    - `poisson_ratio`: nu (default 0.3).
    - `restitution`: normal coefficient of restitution (default 0.5).
    - `friction`: sliding friction coefficient (default 0.5).
    - `density`: particle density, kg/m³ (default 1500, a pharmaceutical granule).
    """

    youngs_modulus: float = 5.0e6
    poisson_ratio: float = 0.3
    restitution: float = 0.5
    friction: float = 0.5
    density: float = 1500.0

    def __check_init__(self) -> None:
        _positive("youngs_modulus", self.youngs_modulus)
        _positive("density", self.density)
        if not 0 <= self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must be in [0, 0.5), got {self.poisson_ratio}.")
        if not 0 < self.restitution <= 1:
            raise ValueError(f"restitution must be in (0, 1], got {self.restitution}.")
        if not self.friction >= 0:
            raise ValueError(f"friction must not be negative, got {self.friction}.")

    def contact_model(self) -> str:
        """The LAMMPS ``granular`` contact arguments for this material."""
        return (
            f"hertz/material {self.youngs_modulus:.10g} {self.restitution:.10g} "
            f"{self.poisson_ratio:.10g} tangential mindlin NULL 1.0 {self.friction:.10g} "
            "damping tsuji"
        )


class BladedMixer(eqx.Module):
    """The source's horizontal bladed mixer (MODELS.md §9, Table 7.4; see the module text).

    **Arguments:**

    - `radius`, `length`: vessel, m (0.1, 0.5).
    - `shaft_radius`, `shaft_length`: the rod on the axis from ``z = 0``, m (0.01, 0.45).
    - `blade_tip_radius`: the blade reaches this far from the axis on both sides, m (0.095).
    - `blade_width`: axial width of the blade at the ``z = 0`` end, m (0.1).
    - `blade_thickness`: thickness of the plate, m (0.01).
    - `particles`: spheres of each species (colour), ``(red, blue)`` (5,000 + 5,000);
      species 0 starts in ``z < length / 2``, species 1 in the other half.
    - `diameter`: sphere diameter, m (5.5 mm, see the module text).
    - `rpm`: impeller speed, rev/min (60).
    - `material`: the contact :class:`Material`.
    """

    radius: float = 0.1
    length: float = 0.5
    shaft_radius: float = 0.01
    shaft_length: float = 0.45
    blade_tip_radius: float = 0.095
    blade_width: float = 0.1
    blade_thickness: float = 0.01
    particles: tuple[int, ...] = (5000, 5000)
    diameter: float = 0.0055
    rpm: float = 60.0
    material: Material = Material()

    def __check_init__(self) -> None:
        for name in ("radius", "length", "shaft_radius", "shaft_length", "blade_tip_radius",
                     "blade_width", "blade_thickness", "diameter", "rpm"):
            _positive(name, getattr(self, name))
        if not self.shaft_radius < self.blade_tip_radius < self.radius:
            raise ValueError("the blade tip must lie between the shaft and the vessel wall.")
        if self.shaft_length > self.length or self.blade_width > self.length:
            raise ValueError("the shaft and the blade must fit in the vessel length.")
        _check_particles(self.particles)

    @property
    def periodic(self) -> bool:
        """Whether the axial direction is periodic (no: closed ends)."""
        return False

    @property
    def revolution_time(self) -> float:
        """Time of one impeller revolution, s."""
        return 60.0 / self.rpm

    def truncated(self, length: float, particles: tuple[int, ...]) -> BladedMixer:
        """The same mixer cut at ``z = length`` by a flat end wall (the DEM part of a hybrid)."""
        return eqx.tree_at(
            lambda m: (m.length, m.shaft_length, m.particles),
            self,
            (float(length), min(self.shaft_length, float(length)), tuple(particles)),
        )

    def impeller_regions(self) -> list[str]:
        """LAMMPS region commands of the rotating impeller (each ``side out``), named ``imp*``."""
        rot = "rotate v_theta 0 0 0 0 0 1 units box"
        t = self.blade_thickness / 2
        return [
            f"region imp1 cylinder z 0 0 {self.shaft_radius:.10g} 0 {self.shaft_length:.10g} "
            f"side out {rot}",
            f"region imp2 block {-self.blade_tip_radius:.10g} {self.blade_tip_radius:.10g} "
            f"{-t:.10g} {t:.10g} 0 {self.blade_width:.10g} side out {rot}",
        ]

    def vessel_region(self) -> str:
        """LAMMPS region command of the vessel interior (``side in``), named ``vessel``."""
        return (f"region vessel cylinder z 0 0 {self.radius:.10g} 0 {self.length:.10g} side in "
                "units box")

    def fill_height(self) -> float:
        """Particles are placed below ``y`` = this value at the start, m (clear of the blade)."""
        return -(self.blade_thickness / 2 + self.diameter)


class PaddleSection(eqx.Module):
    """A periodic axial section of a continuous paddle blender (MODELS.md §1, blender 1).

    **Arguments:**

    - `radius`: vessel radius, m (0.075: blender 1 is 0.15 m across).
    - `length`: axial period of the section, m (0.12).
    - `shaft_radius`: m (0.01).
    - `paddle_tip_radius`: paddles reach this far from the axis, m (0.07).
    - `paddle_width`: axial extent of a paddle, m (0.03).
    - `paddle_thickness`: plate thickness, m (0.005).
    - `pitch`: angle of the paddle face to the axis, degrees (45); it drives the bed towards
      ``-z``. Two paddles, opposite each other, at mid-section.
    - `particles`: spheres of each species (3,000 of one species by default).
    - `diameter`: m (5 mm).
    - `rpm`: rev/min (60).
    - `material`: the contact :class:`Material`.
    """

    radius: float = 0.075
    length: float = 0.12
    shaft_radius: float = 0.01
    paddle_tip_radius: float = 0.07
    paddle_width: float = 0.03
    paddle_thickness: float = 0.005
    pitch: float = 45.0
    particles: tuple[int, ...] = (3000,)
    diameter: float = 0.005
    rpm: float = 60.0
    material: Material = Material()

    def __check_init__(self) -> None:
        for name in ("radius", "length", "shaft_radius", "paddle_tip_radius", "paddle_width",
                     "paddle_thickness", "diameter", "rpm"):
            _positive(name, getattr(self, name))
        if not self.shaft_radius < self.paddle_tip_radius < self.radius:
            raise ValueError("the paddle tip must lie between the shaft and the vessel wall.")
        if not 0 < self.pitch < 90:
            raise ValueError(f"pitch must be between 0 and 90 degrees, got {self.pitch}.")
        if self.paddle_width >= self.length:
            raise ValueError("the paddles must be shorter than the section.")
        _check_particles(self.particles)

    @property
    def periodic(self) -> bool:
        """Whether the axial direction is periodic (yes)."""
        return True

    @property
    def revolution_time(self) -> float:
        """Time of one impeller revolution, s."""
        return 60.0 / self.rpm

    def impeller_regions(self) -> list[str]:
        """LAMMPS region commands of the shaft and the two pitched paddles (``side out``)."""
        rot = "rotate v_theta 0 0 0 0 0 1 units box"
        t = self.paddle_thickness / 2
        z0 = (self.length - self.paddle_width) / 2
        z1 = z0 + self.paddle_width
        # A prism tilts y as z grows (yz): the face of the +x paddle, moving towards +y,
        # faces (0, 1, -1) for a 45 degree pitch and pushes the bed towards -z; the -x
        # paddle moves towards -y and has the opposite tilt.
        tilt = self.paddle_width / math.tan(math.radians(self.pitch))
        half = tilt / 2
        tip = self.paddle_tip_radius
        s = self.shaft_radius * 0.5
        return [
            f"region imp1 cylinder z 0 0 {self.shaft_radius:.10g} INF INF side out {rot}",
            f"region imp2 prism {s:.10g} {tip:.10g} {-t - half:.10g} {t - half:.10g} {z0:.10g} "
            f"{z1:.10g} 0 0 {tilt:.10g} side out {rot}",
            f"region imp3 prism {-tip:.10g} {-s:.10g} {-t + half:.10g} {t + half:.10g} {z0:.10g} "
            f"{z1:.10g} 0 0 {-tilt:.10g} side out {rot}",
        ]

    def vessel_region(self) -> str:
        """LAMMPS region command of the vessel interior (``side in``), named ``vessel``."""
        return f"region vessel cylinder z 0 0 {self.radius:.10g} INF INF side in units box"

    def fill_height(self) -> float:
        """Particles are placed below ``y`` = this value at the start, m (clear of the paddles)."""
        tilt = self.paddle_width / math.tan(math.radians(self.pitch))
        return -(tilt / 2 + self.paddle_thickness / 2 + self.diameter)


def _check_particles(particles: tuple[int, ...]) -> None:
    if not particles or any(int(n) != n or n < 0 for n in particles) or sum(particles) == 0:
        raise ValueError(
            f"particles must be whole non-negative counts per species, got {particles}."
        )


class RunSettings(eqx.Module):
    """How long a DEM run lasts and how it is recorded.

    **Arguments:**

    - `duration`: simulated time recorded after settling, s.
    - `record_interval`: time between recorded frames, s (rounded to whole time steps).
    - `settle_time`: time the bed settles under gravity with the impeller at rest, s.
    - `time_step_fraction`: the time step as a fraction of the Rayleigh time of the spheres
      (default 0.2; 0.1–0.3 is the usual range for Hertz–Mindlin contacts).
    - `seed`: seed of the random placement, 1 to 900,000,000.
    """

    duration: float = 10.0
    record_interval: float = 0.05
    settle_time: float = 0.5
    time_step_fraction: float = 0.2
    seed: int = 12345

    def __check_init__(self) -> None:
        _positive("duration", self.duration)
        _positive("record_interval", self.record_interval)
        if not (math.isfinite(self.settle_time) and self.settle_time >= 0):
            raise ValueError(f"settle_time must not be negative, got {self.settle_time}.")
        if not 0 < self.time_step_fraction <= 0.5:
            raise ValueError(
                f"time_step_fraction must be in (0, 0.5], got {self.time_step_fraction}."
            )
        if int(self.seed) != self.seed or not 1 <= self.seed <= 900_000_000:
            raise ValueError(f"seed must be a whole number from 1 to 900000000, got {self.seed}.")
