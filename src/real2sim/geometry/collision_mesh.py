"""Collision geometry as triangle meshes and as an inside test, in the asset frame (metres).

* :func:`shape_mesh` turns one :class:`~real2sim.formats.collision.CollisionShape` into a
  closed triangle mesh posed in the asset frame (primitives are tessellated;
  ``convex``/``mesh`` pieces are loaded from the representation folder).
* :func:`union_mesh` is the boolean union of all pieces (manifold3d, one batch
  union), i.e. the surface that bounds the solid the simulator sees. Overlapping
  primitives leave no internal faces, which matters for Chamfer distances.
* :func:`inside_collision` tells which points lie inside any piece, exactly for
  primitives (closed-form tests, no tessellation error), by half-spaces for
  convex pieces and by winding numbers for non-convex mesh pieces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.rotations import quaternion_to_matrix

# Tessellation of round primitives (manifold3d's geodesic sphere and extruded
# circle): with 64 segments the facets lie within 0.12 % of the radius of the
# true surface (0.04 mm on a 3.4 cm can) and enclose 0.56 % (sphere) and 0.16 %
# (cylinder) less volume. Inside tests do not use the tessellation at all.
ROUND_SEGMENTS = 64


def shape_pose(shape: CollisionShape) -> np.ndarray:
    """4x4 transform from the shape frame to the asset frame."""
    pose = np.eye(4)
    pose[:3, :3] = quaternion_to_matrix(shape.quaternion_wxyz)
    pose[:3, 3] = shape.position_m
    return pose


def load_piece_mesh(path: Path) -> trimesh.Trimesh:
    """A convex/mesh piece file as one merged triangle mesh (vertices welded across UV seams)."""
    loaded = trimesh.load(Path(path), force="mesh", process=True)
    mesh = trimesh.Trimesh(vertices=np.asarray(loaded.vertices), faces=np.asarray(loaded.faces), process=True)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return mesh


def _piece_path(shape: CollisionShape, rep_dir: Path | None) -> Path:
    if rep_dir is None:
        raise ValueError(f"a {shape.kind} shape needs rep_dir to find {shape.mesh_file!r}")
    return Path(rep_dir) / str(shape.mesh_file)


def _primitive_manifold(shape: CollisionShape, segments: int = ROUND_SEGMENTS):
    """manifold3d.Manifold of a primitive in its own shape frame."""
    import manifold3d

    M, size = manifold3d.Manifold, shape.size_m
    if shape.kind == "sphere":
        return M.sphere(size[0], segments)
    if shape.kind == "ellipsoid":
        return M.sphere(1.0, segments).scale(tuple(size))
    if shape.kind == "box":
        return M.cube(tuple(size), True)
    if shape.kind == "cylinder":
        return M.cylinder(size[1], size[0], size[0], segments, True)
    if shape.kind == "capsule":
        half = 0.5 * size[1]
        ends = [M.sphere(size[0], segments).translate((0.0, 0.0, z)) for z in (-half, half)]
        return M.batch_hull(ends)
    raise ValueError(f"{shape.kind} is not a primitive")


def _pose_3x4(shape: CollisionShape) -> list[list[float]]:
    return shape_pose(shape)[:3, :4].tolist()


def shape_manifold(shape: CollisionShape, rep_dir: Path | None = None, round_segments: int = ROUND_SEGMENTS):
    """manifold3d.Manifold of one shape, posed in the asset frame; ValueError for a non-manifold mesh piece."""
    if shape.kind == "convex":
        import manifold3d

        # Drake simulates a Convex shape as the convex hull of the file's vertices
        solid = manifold3d.Manifold.hull_points(np.asarray(load_piece_mesh(_piece_path(shape, rep_dir)).vertices))
    elif shape.kind == "mesh":
        solid = to_manifold(load_piece_mesh(_piece_path(shape, rep_dir)))
    else:
        solid = _primitive_manifold(shape, round_segments)
    return solid.transform(_pose_3x4(shape))


def shape_mesh(shape: CollisionShape, rep_dir: Path | None = None, round_segments: int = ROUND_SEGMENTS) -> trimesh.Trimesh:
    """Closed triangle mesh of one collision shape, posed in the asset frame (metres).

    ``convex`` pieces are the convex hull of the vertices of ``rep_dir /
    shape.mesh_file`` (as Drake treats them); ``mesh`` pieces are that file as it
    is (it need not be closed).
    """
    if shape.kind == "convex":
        return from_manifold(shape_manifold(shape, rep_dir))
    if shape.kind == "mesh":
        mesh = load_piece_mesh(_piece_path(shape, rep_dir))
        mesh.apply_transform(shape_pose(shape))
        return mesh
    return from_manifold(shape_manifold(shape, rep_dir, round_segments))


def to_manifold(mesh: trimesh.Trimesh):
    """manifold3d.Manifold of a closed, oriented mesh (float64); raises ValueError if it is not one."""
    import manifold3d

    m = manifold3d.Manifold(
        manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
            tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64),
        )
    )
    if m.status() != manifold3d.Error.NoError:
        raise ValueError(f"mesh is not a closed oriented 2-manifold ({m.status()})")
    return m


def from_manifold(manifold) -> trimesh.Trimesh:
    """trimesh.Trimesh of a manifold3d.Manifold (float64 positions)."""
    out = manifold.to_mesh64()
    vertices = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(out.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def _union(solids: list, loose: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    import manifold3d

    parts = []
    if solids:
        parts.append(from_manifold(manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)))
    parts.extend(loose)
    if not parts:
        return trimesh.Trimesh()
    return parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)


def union_of_meshes(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean union of closed meshes (one manifold3d batch union).

    Pieces that are not closed 2-manifolds (e.g. a raw reconstruction used as the
    ``mesh`` baseline) cannot enter a boolean; they are appended unchanged to the
    union of the others, which keeps winding-number inside tests correct.
    """
    solids, loose = [], []
    for m in meshes:
        try:
            solids.append(to_manifold(m))
        except ValueError:
            loose.append(m)
    return _union(solids, loose)


def union_mesh(geometry: CollisionGeometry, rep_dir: Path | None = None, round_segments: int = ROUND_SEGMENTS) -> trimesh.Trimesh:
    """Outer surface of the union of all pieces of ``geometry``, in the asset frame (metres).

    One manifold3d batch union of all pieces; a ``mesh`` piece that is not a
    closed 2-manifold is appended as it is (see :func:`union_of_meshes`).
    ``round_segments`` trades the tessellation of round primitives for speed
    (why: docs/design-notes/asset.md#union-tessellation-and-speed).
    """
    solids, loose = [], []
    for shape in geometry.shapes:
        try:
            solids.append(shape_manifold(shape, rep_dir, round_segments))
        except ValueError:
            if shape.kind != "mesh":
                raise
            loose.append(shape_mesh(shape, rep_dir))
    return _union(solids, loose)


def _bounding_radius(shape: CollisionShape, piece: trimesh.Trimesh | None) -> float:
    s = shape.size_m
    if shape.kind == "sphere":
        return s[0]
    if shape.kind == "ellipsoid":
        return max(s)
    if shape.kind == "box":
        return 0.5 * float(np.linalg.norm(s))
    if shape.kind == "cylinder":
        return float(np.hypot(s[0], 0.5 * s[1]))
    if shape.kind == "capsule":
        return s[0] + 0.5 * s[1]
    return float(np.linalg.norm(piece.vertices, axis=1).max())  # piece in its shape frame


def _inside_shape_frame(shape: CollisionShape, p: np.ndarray, piece: trimesh.Trimesh | None) -> np.ndarray:
    """Inside test for points ``p`` (K, 3) already expressed in the shape frame."""
    s = shape.size_m
    if shape.kind == "sphere":
        return (p**2).sum(axis=1) <= s[0] ** 2
    if shape.kind == "ellipsoid":
        return ((p / np.asarray(s)) ** 2).sum(axis=1) <= 1.0
    if shape.kind == "box":
        return np.all(np.abs(p) <= 0.5 * np.asarray(s), axis=1)
    if shape.kind == "cylinder":
        return ((p[:, :2] ** 2).sum(axis=1) <= s[0] ** 2) & (np.abs(p[:, 2]) <= 0.5 * s[1])
    if shape.kind == "capsule":
        z = np.clip(p[:, 2], -0.5 * s[1], 0.5 * s[1])
        return (p[:, 0] ** 2 + p[:, 1] ** 2 + (p[:, 2] - z) ** 2) <= s[0] ** 2
    if shape.kind == "convex":
        from scipy.spatial import ConvexHull

        eq = ConvexHull(piece.vertices).equations  # outward normals n, offsets d: n.x + d <= 0 inside
        return np.all(p @ eq[:, :3].T + eq[:, 3] <= 1e-12, axis=1)
    from real2sim.geometry.inside import inside_mask

    return inside_mask(piece, p)


def inside_collision(geometry: CollisionGeometry, rep_dir: Path | None, points_m: np.ndarray) -> np.ndarray:
    """Boolean (N,): True where a point (asset frame, metres) lies inside any piece of ``geometry``.

    Each piece only tests the points within its bounding sphere (a k-d tree query),
    so hundreds of small primitives against a million points stay cheap.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    inside = np.zeros(len(points), dtype=bool)
    if len(points) == 0 or not geometry.shapes:
        return inside
    tree = cKDTree(points)
    for shape in geometry.shapes:
        piece = None
        if shape.kind in ("convex", "mesh"):
            piece = load_piece_mesh(_piece_path(shape, rep_dir))  # in its shape frame
        candidates = np.asarray(tree.query_ball_point(shape.position_m, _bounding_radius(shape, piece) * (1 + 1e-9)), dtype=np.int64)
        candidates = candidates[~inside[candidates]]
        if len(candidates) == 0:
            continue
        rotation = quaternion_to_matrix(shape.quaternion_wxyz)
        local = (points[candidates] - np.asarray(shape.position_m)) @ rotation  # R^T (p - t), row-wise
        inside[candidates[_inside_shape_frame(shape, local, piece)]] = True
    return inside
