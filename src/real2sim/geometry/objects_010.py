"""The bundled bottle, can and mug as 0.1.0 made them: the meshes every published figure and recorded
test value was measured on (64 sections for the bottle and the mug, 72 for the can).

:func:`real2sim.geometry.objects.make_object` returns these by default; the round versions, cut to
a stated chord error, are the evaluation's references (``make_object(name, rolling_sagitta_m=
REFERENCE_SAGITTA_M)``; why: docs/design-notes/asset.md#bundled-objects-tessellation).
"""

from __future__ import annotations

import numpy as np
import trimesh


def _revolve(radius_m: np.ndarray, z_m: np.ndarray, sections: int) -> trimesh.Trimesh:
    """Solid of revolution about z of a profile that starts and ends on the axis."""
    return trimesh.creation.revolve(np.column_stack([radius_m, z_m]), sections=sections)


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(meshes, engine="manifold")


def bottle() -> trimesh.Trimesh:
    """A squeeze bottle like the YCB mustard bottle: an oval body 0.096 x 0.060 m, bulging low,
    tapering to a shoulder, with an off-centre cap; 0.19 m tall, metres, on z = 0."""
    z_body = np.linspace(0.0, 0.160, 40)
    r_body = 0.045 + 0.004 * np.sin(np.pi * z_body / 0.11) - 0.2 * np.clip(z_body - 0.09, 0, None) ** 1.1
    r_body = np.clip(r_body, 0.017, None)
    fillet = np.linspace(0.0, np.pi / 2, 6)[1:]  # a 4 mm fillet: the support face flat but not sharp
    r_fillet = r_body[0] - 0.004 + 0.004 * np.sin(fillet)
    z_fillet = 0.004 - 0.004 * np.cos(fillet)
    radius = np.concatenate([[0.0], r_fillet, r_body[z_body > 0.004], [0.016, 0.0]])
    height = np.concatenate([[0.0], z_fillet, z_body[z_body > 0.004], [0.163, 0.163]])
    body = _revolve(radius, height, sections=64)
    body.apply_scale([1.0, 0.64, 1.0])
    cap = trimesh.creation.cylinder(radius=0.0135, height=0.022, sections=32)
    cap.apply_translation([0.008, 0.0, 0.171])
    nozzle = trimesh.creation.cone(radius=0.007, height=0.008, sections=24)
    nozzle.apply_translation([0.008, 0.0, 0.182])
    mesh = _union([body, cap, nozzle])
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    return mesh


def can() -> trimesh.Trimesh:
    """A soup can: radius 0.034 m, height 0.10 m, rims 1 mm proud at both ends, 72 sections."""
    radius = np.array([0.0, 0.0335, 0.034, 0.034, 0.0335, 0.0])
    height = np.array([0.0, 0.0, 0.002, 0.098, 0.100, 0.100])
    return _revolve(radius, height, sections=72)


def mug() -> trimesh.Trimesh:
    """A mug: outer radius 0.04 m, height 0.095 m, 3 mm wall, 6 mm floor, a ring handle."""
    outer = trimesh.creation.cylinder(radius=0.040, height=0.095, sections=64)
    outer.apply_translation([0, 0, 0.0475])
    cavity = trimesh.creation.cylinder(radius=0.037, height=0.095, sections=64)
    cavity.apply_translation([0, 0, 0.0475 + 0.006])
    cup = trimesh.boolean.difference([outer, cavity], engine="manifold")
    handle = trimesh.creation.torus(major_radius=0.026, minor_radius=0.006, major_sections=48, minor_sections=16)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.048, 0.0, 0.050])
    keep = trimesh.creation.box(extents=[0.06, 0.03, 0.08])  # the part of the ring outside the cavity
    keep.apply_translation([0.068, 0.0, 0.050])
    handle = trimesh.boolean.intersection([handle, keep], engine="manifold")
    return _union([cup, handle])


#: The 0.1.0 mesh of each bundled object that had one, by name.
MESHES_010 = {"bottle": bottle, "can": can, "mug": mug}
