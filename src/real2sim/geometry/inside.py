"""Robust inside/outside tests and signed distances for imperfect meshes.

Reconstructed meshes have holes and internal faces, so the sign comes from the
generalized winding number (Jacobson et al. 2013; libigl's fast, Barnes-Hut
approximation), not from face normals: a point is inside where |w| > 0.5. A
small hole changes w only near the hole; a closed internal shell adds a whole
turn (|w| ~ 2, still inside); an open internal sheet shifts w by less than 0.5
away from the sheet. Taking |w| also accepts meshes whose faces all point inward.

Speed: queries go to libigl in z-order (:func:`morton_order`), so that
consecutive queries walk the same tree nodes; the answers are the same in any
order (why: docs/design-notes/asset.md#inside-tests-z-order-and-short-edges).
"""

from __future__ import annotations

import numpy as np
import trimesh

_CHUNK = 250_000  # bounds peak memory of libigl's per-query work on large batches


def _vf(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(mesh.vertices, dtype=np.float64), np.ascontiguousarray(mesh.faces, dtype=np.int64)


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """Permutation (N,) sorting points (N, 3) along a z-order curve over their bounding box."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.empty(0, dtype=np.int64)
    lo = p.min(axis=0)
    span = np.maximum(p.max(axis=0) - lo, 1e-12)
    grid = ((p - lo) / span * ((1 << bits) - 1)).astype(np.uint64)
    code = np.zeros(len(p), dtype=np.uint64)
    for axis in range(3):
        code |= _spread_bits(grid[:, axis]) << np.uint64(axis)
    return np.argsort(code, kind="stable")


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Two zero bits between each of the low 10 bits of x (30-bit Morton codes)."""
    x = x & np.uint64(0x3FF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x30000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x300F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x9249249)
    return x


def _ordered_queries(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    order = morton_order(q)
    return np.ascontiguousarray(q[order]), order


def winding_numbers(mesh: trimesh.Trimesh, points_m: np.ndarray) -> np.ndarray:
    """Generalized winding number of each point (N,) with respect to ``mesh`` (same frame)."""
    import igl

    v, f = _vf(mesh)
    q, order = _ordered_queries(points_m)
    out = np.empty(len(q))
    for start in range(0, len(q), _CHUNK):
        out[order[start : start + _CHUNK]] = igl.fast_winding_number(v, f, q[start : start + _CHUNK])
    return out


def inside_mask(mesh: trimesh.Trimesh, points_m: np.ndarray) -> np.ndarray:
    """Boolean (N,): True where a point lies inside the solid bounded by ``mesh``."""
    return np.abs(winding_numbers(mesh, points_m)) > 0.5


def signed_distance(mesh: trimesh.Trimesh, points_m: np.ndarray) -> np.ndarray:
    """Signed distance (N,) in the mesh's units: negative inside, positive outside.

    Magnitude is the exact distance to the nearest triangle (libigl AABB tree);
    the sign is the winding-number test above, robust to holes and internal faces.
    """
    import igl

    v, f = _vf(mesh)
    q, order = _ordered_queries(points_m)
    unsigned = np.empty(len(q))
    winding = np.empty(len(q))
    for start in range(0, len(q), _CHUNK):
        chunk = q[start : start + _CHUNK]
        d, _, _, _ = igl.signed_distance(chunk, v, f, igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_UNSIGNED)
        unsigned[order[start : start + _CHUNK]] = np.abs(d)
        winding[order[start : start + _CHUNK]] = igl.fast_winding_number(v, f, chunk)
    return np.where(np.abs(winding) > 0.5, -unsigned, unsigned)


def compact_triangles(mesh: trimesh.Trimesh, edges_per_extent: float = 25.0) -> trimesh.Trimesh:
    """The same surface with no edge longer than 1/``edges_per_extent`` of the largest extent.

    libigl's fast winding number slows down badly on long sliver triangles (the
    fan caps of a cylinder, the caps manifold3d makes when it trims;
    why: docs/design-notes/asset.md#inside-tests-z-order-and-short-edges).
    Splitting edges at their midpoints does not move the surface.
    """
    max_edge = float(np.max(mesh.extents)) / edges_per_extent
    if len(mesh.faces) == 0 or max_edge <= 0:
        return mesh
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge, max_iter=12)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
