"""Point-contact stiffness per piece: a body's stiffness shared among the pieces that touch a plane together.

Drake's point contact gives each pair of touching geometries one contact point with the
stiffness of ``drake:point_contact_stiffness``. A body made of one convex piece (CoACD on a
bottle or a can) rests on one point; a union of primitives rests on every piece whose surface
reaches the plane, each with that stiffness, so it is that many times stiffer, and sinks and
rocks differently from the same object in one piece (a can of 10 stacked cylinders rolls on 10
points at once). Dividing the stiffness among the pieces that touch a plane laid on the body's
convex hull, averaged over the hull's faces by area, gives every representation of an object
about the same resting stiffness.

Everything is in the asset frame, metres.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from real2sim.formats.collision import CollisionGeometry
from real2sim.formats.contact import ContactProperties

# A piece touches the plane when its support in that direction is within this of the body's:
# about twice the depth a 0.5 kg object sinks into point contact of 1e4 N/m (0.5 mm).
TOUCH_TOLERANCE_M = 1.0e-3


def touching_pieces(geometry: CollisionGeometry, rep_dir: Path | None = None,
                    tolerance_m: float = TOUCH_TOLERANCE_M) -> float:
    """Mean number of pieces (>= 1) that touch a plane laid on a face of the geometry's convex hull,
    weighted by the face's area: a piece touches when its support (its farthest extent along the face's
    normal) is within ``tolerance_m`` of the whole body's.

    A floor, a ramp or a wall meets a body on its convex hull, and the body comes to rest on the hull's
    large faces (a box on a side, a can on its bottom or its round side), so those directions count by
    their area; a direction picked at random would almost always meet one corner."""
    import trimesh

    from real2sim.geometry.collision_mesh import shape_mesh

    if not geometry.shapes:
        raise ValueError("geometry has no pieces")
    # With 32 segments the tessellated round pieces lie within 0.5 % of their radius inside the true
    # surface (0.16 mm on a 34 mm can): well below the tolerance.
    pieces = [np.asarray(shape_mesh(s, rep_dir, 32).vertices) for s in geometry.shapes]
    hull = trimesh.convex.convex_hull(np.concatenate(pieces))
    normals, areas = hull.face_normals, hull.area_faces
    support = np.stack([(v @ normals.T).max(axis=0) for v in pieces])  # (pieces, faces)
    touching = (support >= support.max(axis=0) - tolerance_m).sum(axis=0)
    return float((touching * areas).sum() / areas.sum())


def representation_contact(contact: ContactProperties, geometry: CollisionGeometry,
                           rep_dir: Path | None = None) -> ContactProperties:
    """``contact`` with its point-contact stiffness divided by :func:`touching_pieces` (N/m per piece)."""
    share = touching_pieces(geometry, rep_dir)
    return dataclasses.replace(contact, point_contact_stiffness_n_per_m=contact.point_contact_stiffness_n_per_m / share)
