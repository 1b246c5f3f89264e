"""How the object touches: Drake's proximity (contact) properties written into every collision
element (:class:`ContactProperties`), and MuJoCo's contact and integration settings
(:class:`MujocoConfig`) that ``scene.xml`` carries and the MuJoCo evaluation simulates with.

Defaults are documented here once; ``real2sim asset`` can override each Drake one.
The same values are used by the reference and the candidates in evaluation, so
that rows compare geometry, not material. MuJoCo's were chosen by measurement against the
Drake reference (docs/design-notes/evaluate.md#mujoco-contact-settings).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from real2sim.plumbing.errors import UserInputError


#: A representation's Drake model for point contact, beside its model.urdf (ContactProperties.point_model).
POINT_URDF_NAME = "model_point.urdf"

# "hydroelastic" means Drake's hydroelastic_with_fallback (strict hydroelastic refuses rigid-rigid pairs).
CONTACT_MODELS = ("point", "hydroelastic")


@dataclass(frozen=True)
class ContactProperties:
    """Contact material of the object's collision geometry: the Drake proximity properties written into
    every collision element of every model file."""

    hydroelastic: str = "compliant"
    """Hydroelastic type of the shapes: "compliant" (primitives become compliant volume meshes, the
    paper's setting), "rigid", or "none" (point contact only)."""
    hydroelastic_modulus_pa: float = 1.0e7
    """Drake's hydroelastic modulus, Pa, > 0: 1e7 is stiff plastic-like for a hand-sized object and keeps
    penetrations well under a millimetre."""
    point_contact_stiffness_n_per_m: float = 1.0e4
    """Stiffness of point contact, N/m, > 0: 1e4 lets a 0.5 kg object rest about 0.5 mm deep, as compliant
    as the hydroelastic reference; softer than Drake's default, which comes from a 1 mm penetration
    allowance (why: docs/design-notes/asset.md#point-contact-stiffness)."""
    point_stiffness_per_piece: bool = True
    """True: :attr:`point_contact_stiffness_n_per_m` is the body's, and each piece gets it divided by the
    mean number of pieces that touch a plane laid on the hull (:mod:`real2sim.asset.export.point_contact`),
    so every representation rests as stiffly as the object in one piece. False: every piece gets all of
    it, and a union of N pieces resting on all N is N times stiffer
    (why: docs/design-notes/asset.md#point-stiffness-per-piece)."""
    hunt_crossley_dissipation_s_per_m: float = 1.0
    """Hunt-Crossley dissipation of every contact, s/m, >= 0."""
    point_dissipation_s_per_m: float | None = 20.0
    """None, or the Hunt-Crossley dissipation (s/m, >= 0) of the representations' point-contact models:
    each representation then also gets ``model_point.urdf``, the same as ``model.urdf`` but for this
    dissipation, and the evaluation simulates its point-contact rows with it. Point contact presses one
    point per touching piece where the object presses a patch, and a point that chatters on and off the
    floor leaves a one-point model hopping unless it is damped; hydroelastic rows keep
    :attr:`hunt_crossley_dissipation_s_per_m` (why: docs/design-notes/asset.md#point-dissipation)."""
    mu_static: float = 0.5
    """Static Coulomb friction coefficient, >= 0 (Drake combines the two of a pair)."""
    mu_dynamic: float = 0.5
    """Dynamic Coulomb friction coefficient, >= 0 (Drake combines the two of a pair)."""
    resolution_hint_m: float = 0.01
    """Edge length Drake aims for when it meshes curved primitives (spheres, cylinders, ellipsoids,
    capsules) for compliant contact, m, > 0."""
    cylinder_flat_depth_m: float | None = None
    """None, or how far inside its circle each flat of a compliant cylinder's mesh may lie, m, > 0: each
    cylinder then gets its own hint, the smaller of :attr:`resolution_hint_m` and one that keeps its flats
    this shallow. Drake cuts a cylinder's circle into ceil(2 pi r / hint) sections, so at the default hint
    a 34 mm cylinder is a 22-gon with flats 0.35 mm deep, and a body rolling on it rolls on them
    (docs/truth.md)."""

    def __post_init__(self) -> None:
        if self.hydroelastic not in ("compliant", "rigid", "none"):
            raise ValueError("hydroelastic must be 'compliant', 'rigid' or 'none'")
        point = self.point_dissipation_s_per_m
        if point is not None and not (math.isfinite(point) and point >= 0):
            raise ValueError("point_dissipation_s_per_m must be a number of s/m >= 0 or None")
        depth = self.cylinder_flat_depth_m
        if depth is not None and not (math.isfinite(depth) and depth > 0):
            raise ValueError("cylinder_flat_depth_m must be a positive number of metres or None")

    @property
    def point_model(self) -> "ContactProperties | None":
        """The material of the representations' point-contact models (``model_point.urdf``); None when
        they need none (no point dissipation of their own, or the same as the body's)."""
        point = self.point_dissipation_s_per_m
        if point is None or point == self.hunt_crossley_dissipation_s_per_m:
            return None
        return dataclasses.replace(self, hunt_crossley_dissipation_s_per_m=point, point_dissipation_s_per_m=None)

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
