"""Drake proximity (contact) properties written into every collision element.

Defaults are documented here once; ``real2sim asset`` can override each one.
The same values are used by the reference and the candidates in evaluation, so
that rows compare geometry, not material.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass


#: A representation's Drake model for point contact, beside its model.urdf (ContactProperties.point_model).
POINT_URDF_NAME = "model_point.urdf"

# "hydroelastic" means Drake's hydroelastic_with_fallback (strict hydroelastic refuses rigid-rigid pairs).
CONTACT_MODELS = ("point", "hydroelastic")


@dataclass(frozen=True)
class ContactProperties:
    """Contact material of the object's collision geometry.

    hydroelastic: "compliant" (primitives become compliant volume meshes, the
        paper's setting), "rigid", or "none" (point contact only).
    hydroelastic_modulus_pa: Drake's hydroelastic modulus, Pa. 1e7 is stiff plastic-like
        for a hand-sized object and keeps penetrations well under a millimetre.
    point_contact_stiffness_n_per_m: stiffness of point contact, N/m. 1e4 lets a
        0.5 kg object rest about 0.5 mm deep, as compliant as the hydroelastic
        reference; Drake's default (from a 1 mm penetration allowance) is stiffer
        and made the bundled bottle bounce on the floor and ramp under point
        contact, tripling its OCAE (docs/benchmarks.md, "Point-contact stiffness").
    point_stiffness_per_piece: True (default): ``point_contact_stiffness_n_per_m`` is the body's, and
        each piece gets it divided by the mean number of pieces that touch a plane laid on the hull
        (:mod:`real2sim.asset.export.point_contact`), so every representation rests as stiffly as the object
        in one piece. False: every piece gets all of it, and a union of N pieces resting on all N is
        N times stiffer. Shared, every multi-piece primitive point row measured moved closer to the
        reference (ten on the bundled bottle and can, e.g. ellipsoids_64 0.0171 -> 0.0139 m OCAE;
        five on a carton and a mug on its side) and CoACD's one- or two-piece hulls stayed as they
        were (docs/benchmarks/point_contact_split20_idle.md, point_contact_split20_shapes.md).
    hunt_crossley_dissipation_s_per_m: Hunt-Crossley dissipation, s/m.
    point_dissipation_s_per_m: None, or the Hunt-Crossley dissipation of the representations'
        point-contact models, s/m: each representation then also gets ``model_point.urdf``, the
        same as ``model.urdf`` but for this dissipation, and the evaluation simulates its
        point-contact rows with it. Point contact presses one point per touching piece where the
        object presses a patch; a point that chatters on and off the floor leaves a one-point
        model hopping unless it is damped. At 20 s/m every point-contact row of Table I moved
        closer to the hydroelastic reference (docs/benchmarks/point_contact.md), while the
        hydroelastic rows got worse with it, so it applies to point contact only.
    mu_static, mu_dynamic: Coulomb friction coefficients (Drake combines pairs).
    resolution_hint_m: edge length Drake aims for when it meshes curved
        primitives (spheres, cylinders, ellipsoids, capsules) for compliant contact.
    cylinder_flat_depth_m: None, or how far inside its circle each flat of a compliant
        cylinder's mesh may lie, m. Drake cuts a cylinder's circle into
        ceil(2 pi r / hint) sections, so at the default hint a 34 mm cylinder is a
        22-gon with flats 0.35 mm deep, and a body rolling on it rolls on them
        (docs/truth.md). When set, each cylinder gets its own hint,
        the smaller of ``resolution_hint_m`` and one that keeps its flats this shallow.
    """

    hydroelastic: str = "compliant"
    hydroelastic_modulus_pa: float = 1.0e7
    point_contact_stiffness_n_per_m: float = 1.0e4
    point_stiffness_per_piece: bool = True
    hunt_crossley_dissipation_s_per_m: float = 1.0
    point_dissipation_s_per_m: float | None = 20.0
    mu_static: float = 0.5
    mu_dynamic: float = 0.5
    resolution_hint_m: float = 0.01
    cylinder_flat_depth_m: float | None = None

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
