"""Signed distance to a triangle mesh, with its sign from the generalized winding number.

The magnitude is the exact distance to the nearest triangle (libigl's AABB tree); the sign
comes from the winding number (:mod:`real2sim.geometry.inside`), robust to holes and internal
faces. Used by :mod:`real2sim.collision.sdf_sampling`.

Speed (``sign_method="fast"``, the default). Evaluating the winding number at
every near-surface point costs more than the distances, because
Barnes-Hut is slowest right at the surface. But the nearest-triangle query
already tells on which side of its closest face a point lies, and the segment
from a point to its closest surface point crosses no other face. So we evaluate
the winding number once per face, just in front of the face centroid, and carry
it to every point whose closest face it is (behind the face it is one more).
Off the surface the winding number changes only around *boundary* edges (the
edges where the faces do not cancel: holes, rims of open sheets, stray
triangles); for a closed mesh it is constant between faces. A point falls back
to the exact winding number when the inference is doubtful: its closest point is
on an edge or a vertex rather than inside the face (the offset is not along the
face normal), the face is degenerate, a boundary edge is nearer than twice the
path probe -> closest point -> point, or the inferred winding number is within
``sign_margin`` of the 0.5 threshold. Queries are also issued in Morton
(z-curve) order, which makes libigl's tree walks faster than random order
(docs/design-notes/collision.md#fast-signs).
``sign_method="exact"`` evaluates the winding number at every point;
``tests/collision/test_sdf_sampling.py`` checks that the two agree, including on meshes
with holes, internal sheets and stray triangles.

Limits: like any winding-number test, points right next to a stray open
triangle or sheet get a sign that depends on the side they are on (the winding
number swings by +-0.5 there), and a void pocket bounded by an inward-facing
closed shell counts as outside (ray stabbing would fill it).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from real2sim.geometry.inside import morton_order

_CHUNK = 250_000  # bounds libigl's per-call working memory


def _closest_points(v: np.ndarray, f: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared distance, closest face and closest point of each query (already spatially ordered)."""
    import igl

    tree = igl.AABB()
    tree.init(v, f)
    sq = np.empty(len(q))
    face = np.empty(len(q), dtype=np.int64)
    closest = np.empty((len(q), 3))
    for start in range(0, len(q), _CHUNK):
        s, i, c = tree.squared_distance(v, f, q[start : start + _CHUNK])
        sq[start : start + _CHUNK] = s
        face[start : start + _CHUNK] = i
        closest[start : start + _CHUNK] = c
    return sq, face, closest


def _winding(v: np.ndarray, f: np.ndarray, q: np.ndarray) -> np.ndarray:
    import igl

    out = np.empty(len(q))
    for start in range(0, len(q), _CHUNK):
        out[start : start + _CHUNK] = igl.fast_winding_number(v, f, np.ascontiguousarray(q[start : start + _CHUNK]))
    return out


def signed_distance_winding(
    v: np.ndarray, f: np.ndarray, points: np.ndarray, sign_method: str = "fast", sign_margin: float = 0.25,
    before_signs: Callable[[], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (negative inside) and (possibly inferred) winding number of each point, in input order.

    ``sign_method``: "fast" (inferred from the closest face, see the module docstring) or "exact".
    ``before_signs`` is called between the distances and the signs (a progress step).
    """
    order = morton_order(points)
    q = np.ascontiguousarray(points[order])
    sq, face, closest = _closest_points(v, f, q)
    dist = np.sqrt(np.maximum(sq, 0.0))
    if before_signs is not None:
        before_signs()
    if sign_method == "exact":
        winding = _winding(v, f, q)
    else:
        winding = _fast_winding(v, f, q, dist, face, closest, sign_margin)
    signed = np.where(np.abs(winding) > 0.5, -dist, dist)
    out, w_out = np.empty_like(signed), np.empty_like(winding)
    out[order] = signed
    w_out[order] = winding
    return out, w_out


def _fast_winding(
    v: np.ndarray, f: np.ndarray, q: np.ndarray, dist: np.ndarray, face: np.ndarray, closest: np.ndarray, margin: float
) -> np.ndarray:
    """Winding number at ``q`` inferred from the winding number in front of each point's closest face.

    Exact (libigl fast winding number at the point) wherever the inference is
    doubtful; see the module docstring.
    """
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice_area = np.linalg.norm(normal, axis=1)
    ok_face = twice_area > 1e-14
    normal[ok_face] /= twice_area[ok_face, None]

    # Probe each used face just in front of its centroid, 1e-3 of its longest
    # edge away: on the face plane the triangle's own solid angle is ambiguous
    # (+-2 pi), and libigl's winding number loses precision closer than ~1e-5
    # edge (docs/design-notes/collision.md#fast-signs); only another surface within 1e-3 edge of
    # the face (nearly coincident sheets) could lie in between.
    used = np.flatnonzero((np.bincount(face, minlength=len(f)) > 0) & ok_face)
    t_used = tri[used]
    edge = np.sqrt(((t_used - np.roll(t_used, 1, axis=1)) ** 2).sum(axis=2).max(axis=1))
    probe = t_used.mean(axis=1) + normal[used] * (1e-3 * edge)[:, None]
    probe_order = morton_order(probe)
    w_front = np.full(len(f), np.nan)
    w_probe = np.empty(len(used))
    w_probe[probe_order] = _winding(v, f, np.ascontiguousarray(probe[probe_order]))
    w_front[used] = w_probe
    face_edge = np.zeros(len(f))
    face_edge[used] = edge

    offset = q - closest
    along = np.einsum("ij,ij->i", offset, normal[face])
    behind = along < 0
    # Crossing a face against its normal raises the winding number by one.
    inferred = w_front[face] + behind
    doubtful = (
        ~ok_face[face]
        | ~np.isfinite(inferred)
        | (np.abs(along) < 0.5 * dist)  # closest point on an edge/vertex, or the point is on the surface
        | (dist <= 1e-12)
        | (np.abs(np.abs(inferred) - 0.5) < margin)
    )
    # Off a closed surface the winding number is constant between faces; it
    # varies only around boundary edges (holes, rims of open sheets, stray
    # triangles), by the angle they subtend. A point must be far from every
    # boundary edge compared with the path probe -> closest point -> point
    # (at most edge + dist long), so that w cannot drift by the margin on the way.
    boundary = boundary_edges(f)
    if len(boundary):
        check = np.flatnonzero(~doubtful)
        if len(check):
            import igl

            sq_b, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(q[check]), v, boundary)
            near_rim = np.sqrt(sq_b) < 2.0 * (dist[check] + face_edge[face[check]])
            doubtful[check[near_rim]] = True
    winding = inferred
    if doubtful.any():
        winding = inferred.copy()
        winding[doubtful] = _winding(v, f, np.ascontiguousarray(q[doubtful]))
    return winding


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges (E, 2) where the faces do not cancel: the boundary of the mesh as an oriented chain.

    An edge is interior when the faces using it traverse it as often in one
    direction as in the other (two consistently oriented faces, or any balanced
    non-manifold fan). Holes, the rims of open sheets, stray triangles and
    edges between inconsistently oriented faces remain. Empty for a closed mesh,
    whose winding number is then an integer constant between its faces.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return np.empty((0, 2), dtype=np.int64)
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    keep = a != b  # collapsed edges of degenerate faces bound nothing
    a, b = a[keep], b[keep]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    direction = np.where(a < b, 1, -1)
    key = lo * (int(f.max()) + 1) + hi
    unique, inverse = np.unique(key, return_inverse=True)
    net = np.bincount(inverse, weights=direction, minlength=len(unique))
    first = np.zeros(len(unique), dtype=np.int64)
    first[inverse[::-1]] = np.arange(len(inverse))[::-1]
    rim = net != 0
    return np.ascontiguousarray(np.column_stack([lo[first[rim]], hi[first[rim]]]))


__all__ = ["boundary_edges", "signed_distance_winding"]
