"""Ellipsoids and capsules as convex polytopes, and the lowest point of a collision geometry.

Simulators other than Drake and MuJoCo read only URDF's box, cylinder, sphere and mesh
(PyBullet refuses ``drake:ellipsoid`` and ``drake:capsule`` outright), and USD's physics
schema has no ellipsoid. Such shapes are handed over as convex mesh pieces, written here:

* a polytope whose vertices lie on the shape (rings of latitude on each hemisphere,
  ``AROUND`` vertices per ring), **without pole vertices**: the ring nearest each pole
  is a flat polygon perpendicular to the shape's axis. An upright ellipsoid or capsule
  then rests on that facet, upright, as the smooth shape does; a pole vertex would make
  it balance on a point and rock onto one of the facets around it
  (why: docs/design-notes/asset.md#round-pieces-without-poles).
* scaled about its centre until its volume equals the smooth shape's closed-form volume,
  as :mod:`real2sim.collision.superquadric` does for superquadrics: the inscribed polytope
  would otherwise be a few percent smaller than the fitted shape.

Frames and units: metres, the shape's own frame (centre at the origin, the capsule's axis
and the ellipsoid's third semi-axis along z), the frames of :mod:`real2sim.formats.collision`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.collision import CollisionGeometry, CollisionShape

#: Vertices per ring of latitude and rings per hemisphere: 24 x 2 x 6 = 288 vertices per piece.
AROUND = 24
RINGS_PER_HEMISPHERE = 6


def _hemisphere_rings(around: int, rings: int) -> np.ndarray:
    """Unit-sphere points (rings, around, 3) on the upper hemisphere: the first ring on the equator,
    rings evenly spaced in latitude, the last half a spacing below the pole (the flat cap)."""
    latitude = np.arange(rings) * (0.5 * math.pi / (rings - 0.5))
    azimuth = 2.0 * math.pi * np.arange(around) / around
    cos_lat, sin_lat = np.cos(latitude)[:, None], np.sin(latitude)[:, None]
    return np.stack(np.broadcast_arrays(cos_lat * np.cos(azimuth), cos_lat * np.sin(azimuth), sin_lat), axis=-1)


def _scaled_to_volume(points_m: np.ndarray, volume_m3: float) -> trimesh.Trimesh:
    hull = trimesh.Trimesh(points_m).convex_hull
    hull.apply_scale((volume_m3 / hull.volume) ** (1.0 / 3.0))
    return hull


def ellipsoid_polytope(semi_axes_m, around: int = AROUND, rings: int = RINGS_PER_HEMISPHERE) -> trimesh.Trimesh:
    """Convex polytope of the ellipsoid with semi-axes (a, b, c) m along x, y, z, of its volume."""
    a = np.asarray(semi_axes_m, dtype=float).reshape(3)
    upper = _hemisphere_rings(around, rings).reshape(-1, 3)
    unit = np.concatenate((upper, upper * (1.0, 1.0, -1.0)))
    return _scaled_to_volume(unit * a, 4.0 / 3.0 * math.pi * float(np.prod(a)))


def capsule_polytope(radius_m: float, length_m: float, around: int = AROUND,
                     rings: int = RINGS_PER_HEMISPHERE) -> trimesh.Trimesh:
    """Convex polytope of the capsule (radius, length of the cylindrical part; axis z), of its volume."""
    r, half = float(radius_m), 0.5 * float(length_m)
    upper = _hemisphere_rings(around, rings).reshape(-1, 3) * r
    points = np.concatenate((upper + (0.0, 0.0, half), upper * (1.0, 1.0, -1.0) - (0.0, 0.0, half)))
    return _scaled_to_volume(points, math.pi * r * r * (2.0 * half) + 4.0 / 3.0 * math.pi * r**3)


def round_polytope(shape: CollisionShape) -> trimesh.Trimesh:
    """The polytope of an ellipsoid or capsule shape, in the shape's frame (metres)."""
    if shape.kind == "ellipsoid":
        return ellipsoid_polytope(shape.size_m)
    if shape.kind == "capsule":
        return capsule_polytope(*shape.size_m)
    raise ValueError(f"{shape.kind} is not an ellipsoid or a capsule")


def lowest_point_z_m(geometry: CollisionGeometry, rep_dir: Path) -> float:
    """Lowest z (m, asset frame) of a collision geometry: each shape's support point along -z
    (mesh pieces from their files in ``rep_dir``). Where a floor under the asset goes."""
    low = math.inf
    for s in geometry.shapes:
        rotation, centre = s.rotation, np.asarray(s.position_m, dtype=float)
        if s.kind in ("convex", "mesh"):
            vertices = trimesh.load(Path(rep_dir) / s.mesh_file, process=False, force="mesh").vertices
            z = float((vertices @ rotation.T)[:, 2].min() + centre[2])
        elif s.kind == "sphere":
            z = centre[2] - s.size_m[0]
        elif s.kind == "box":
            z = centre[2] - float(np.abs(rotation[2]) @ (0.5 * np.asarray(s.size_m)))
        elif s.kind == "ellipsoid":
            z = centre[2] - float(np.sqrt(((rotation[2] * np.asarray(s.size_m)) ** 2).sum()))
        else:  # cylinder, capsule: axis along the shape's z
            r, length = s.size_m
            cos_axis = abs(rotation[2, 2])
            rim = r if s.kind == "capsule" else r * math.sqrt(max(0.0, 1.0 - cos_axis**2))
            z = centre[2] - cos_axis * 0.5 * length - rim
        low = min(low, float(z))
    return low
