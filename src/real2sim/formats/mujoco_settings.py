"""MuJoCo's contact and integration settings (:class:`MujocoConfig`), chosen by measurement against the
Drake reference (docs/design-notes/evaluate.md#mujoco-contact-settings): the asset writes them into
``model.xml`` and ``scene.xml``, and the evaluation simulates with them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from real2sim.plumbing.errors import UserInputError

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
CONES = ("pyramidal", "elliptic")


@dataclass(frozen=True)
class MujocoConfig:
    """How MuJoCo simulates the object: one setting for every geom that touches (the object's collision
    geoms, the floor, and in the evaluation the pusher and the ramp's table), so rows compare geometry;
    ``model.xml`` carries the per-geom settings, ``scene.xml`` the world's options as well.
    Each default was picked by ``benchmarks/bench_mujoco_contact.py`` on the bundled objects
    (docs/design-notes/evaluate.md#mujoco-contact-settings)."""

    timestep_s: float = 1e-3
    """MuJoCo's time step, s; the scene's ``time_step_s`` divided by a whole number >= 1 (each scene
    step is that many MuJoCo steps, so the trajectory is sampled where the reference is)."""
    integrator: str = "Euler"
    """MuJoCo's integrator: "Euler" (semi-implicit, MuJoCo's default), "implicitfast", "implicit" or "RK4"
    (implicitfast measured no closer to the reference: the design note)."""
    cone: str = "elliptic"
    """Friction cone: "pyramidal" (MuJoCo's default) or "elliptic" (measured closer to the reference:
    the design note)."""
    condim: int = 3
    """Contact dimensionality: 1 (frictionless), 3 (sliding friction), 4 (+ torsional), 6 (+ rolling);
    Drake has sliding friction only, hence 3."""
    solref_timeconst_s: float = 0.04
    """solref's time constant of the contact's spring-damper, s; > 0, at least two time steps (MuJoCo's
    default is 0.02; 0.04 was measured closer to the reference with a resting object under 1 mm deep,
    softer ones sink deeper: the design note)."""
    solref_dampratio: float = 1.0
    """solref's damping ratio; > 0 (1: critically damped, MuJoCo's default)."""
    solimp: tuple[float, float, float, float, float] = (0.9, 0.95, 0.001, 0.5, 2.0)
    """solimp (dmin, dmax, width m, midpoint, power): the constraint's impedance as the penetration
    grows (MuJoCo's default)."""
    impratio: float = 1.0
    """Ratio of frictional to normal constraint impedance (elliptic cones only); > 0 (MuJoCo's default 1)."""

    def __post_init__(self) -> None:
        if not (isinstance(self.timestep_s, (int, float)) and math.isfinite(self.timestep_s) and self.timestep_s > 0):
            raise UserInputError(f"MuJoCo timestep_s must be a finite number of seconds > 0, got {self.timestep_s}")
        if self.integrator not in INTEGRATORS:
            raise UserInputError(f"unknown MuJoCo integrator {self.integrator!r}; choose from {', '.join(INTEGRATORS)}")
        if self.cone not in CONES:
            raise UserInputError(f"unknown MuJoCo cone {self.cone!r}; choose from {', '.join(CONES)}")
        if self.condim not in (1, 3, 4, 6):
            raise UserInputError(f"MuJoCo condim must be 1, 3, 4 or 6, got {self.condim}")
        for name in ("solref_timeconst_s", "solref_dampratio", "impratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise UserInputError(f"MuJoCo {name} must be a finite number > 0, got {value}")
        if len(self.solimp) != 5 or not all(math.isfinite(v) for v in self.solimp):
            raise UserInputError(f"MuJoCo solimp must be 5 finite numbers, got {self.solimp}")

    def substeps(self, scene_time_step_s: float) -> int:
        """MuJoCo steps per scene step; ValueError when the scene's step is not a whole number of them."""
        k = scene_time_step_s / self.timestep_s
        if abs(k - round(k)) > 1e-6 or round(k) < 1:
            raise ValueError(f"the scene's time step {scene_time_step_s:g} s is not a whole number of MuJoCo "
                             f"steps of {self.timestep_s:g} s")
        return int(round(k))

    @classmethod
    def from_record(cls, record: dict) -> "MujocoConfig":
        """The settings as ``asset_config.json`` records them (its ``"mujoco"`` object; lists for tuples)."""
        known = {f: record[f] for f in cls.__dataclass_fields__ if f in record}
        if "solimp" in known:
            known["solimp"] = tuple(float(v) for v in known["solimp"])
        return cls(**known)
