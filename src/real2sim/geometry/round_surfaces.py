"""Surfaces of revolution cut into flats no deeper than a stated chord error, and that error measured back on a mesh.

A bundled object's round parts are surfaces of revolution: a profile curve in the half-plane
(radius from the axis, coordinate along the axis), swept about the axis. Its mesh has flats in two
directions: around the axis (the polygon of ``sections`` sides, :func:`ring_sections`) and along the
profile (the polyline through the curve, :func:`simplify_profile`). Where both directions are curved
(a torus, a fillet, a bottle's bulge), each gets half the bound, since the two depths add at a flat's
centre; a straight profile (cylinder, cone, flat cap) gives the whole bound to the rings.

:func:`chord_error_m` measures the result: the largest distance, over points of every face whose
vertices lie on one of the object's true surfaces, from the face to that surface.

All lengths in metres; profiles are ``(N, 2)`` arrays of (radius, axial coordinate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from real2sim.geometry.tessellation import sections_for

DENSE_PER_M = 1e5
"""Points of a true profile per metre of its length: at 10 um spacing a dense polyline's own chord
error on a 4 mm radius (the smallest here) is 3e-9 m, three orders below the bounds used."""


@dataclass(frozen=True)
class Revolved:
    """One true surface of an object: a profile revolved about an axis, then stretched."""

    axis_origin_m: tuple[float, float, float]
    """A point on the axis, object frame, m (after any stretch: the stretch is about this point)."""
    axis_direction: tuple[float, float, float]
    """Direction of the axis, object frame, unit length."""
    profile_m: np.ndarray
    """The true profile, densely sampled: (N, 2) of (radius from the axis, coordinate along it), m."""
    stretch: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Scale per object axis applied about :attr:`axis_origin_m` after revolving; each in (0, 1], so
    a distance measured before the stretch bounds the one after it (an oval body from a round one)."""


def ring_sections(radius_m: float, chord_m: float) -> int:
    """Sections of a circle of ``radius_m`` whose flats lie at most ``chord_m`` inside it (a multiple of 8)."""
    return sections_for(radius_m, chord_m)


def dense_curve(points: np.ndarray) -> np.ndarray:
    """A polyline ``points`` (N, 2) resampled every 10 um along each segment (corners kept)."""
    points = np.asarray(points, dtype=float)
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) * DENSE_PER_M)))
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a + t * (b - a))
    return np.concatenate(out)


def arc(centre: tuple[float, float], radius_m: float, start_rad: float, stop_rad: float) -> np.ndarray:
    """A circular arc in the profile half-plane sampled every 10 um, (N, 2)."""
    n = max(8, int(np.ceil(abs(stop_rad - start_rad) * radius_m * DENSE_PER_M)))
    t = np.linspace(start_rad, stop_rad, n + 1)
    return np.column_stack([centre[0] + radius_m * np.cos(t), centre[1] + radius_m * np.sin(t)])


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points ``p`` (N, 2) to segments a-b (N, 2 each)."""
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def _corners(dense: np.ndarray) -> np.ndarray:
    """Indices of a dense polyline's ends and of its corners: turns of more than 0.05 rad between
    10 um steps (a 1 mm radius turns 0.01 rad per step; the corners of these profiles, 6 degrees and more)."""
    step = np.diff(dense, axis=0)
    heading = np.arctan2(step[:, 1], step[:, 0])
    turn = np.abs((np.diff(heading) + np.pi) % (2 * np.pi) - np.pi)
    return np.unique(np.concatenate([[0], 1 + np.flatnonzero(turn > 0.05), [len(dense) - 1]]))


PROFILE_SAGITTA_FACTOR = 10.0
"""How much deeper a flat along a profile may lie than one around the axis of revolution: a body
rolling on its side rolls across the flats around its axis, which the ramp's orientation error
feels, while the flats along its profile lie along the contact line; 10x keeps the bottle's
reference mesh near 12k faces rather than 48k, whose Drake reference simulation took 20x longer
(why: docs/design-notes/asset.md#bundled-objects-tessellation)."""


def simplify_profile(dense: np.ndarray, chord_m: float) -> np.ndarray:
    """A greedy subset of a dense profile ``dense`` (N, 2) whose chords stay within ``chord_m`` of
    every dense point they skip; its ends and corners are kept, so flat faces stay flat."""
    dense = np.asarray(dense, dtype=float)
    corners = _corners(dense)
    keep = [0]
    for start, stop in zip(corners[:-1], corners[1:]):
        keep += [start + k for k in _simplify_run(dense[start:stop + 1], chord_m)[1:]]
    return dense[keep]


def _simplify_run(dense: np.ndarray, chord_m: float) -> list[int]:
    """Greedy chord simplification of one smooth run: indices kept, ends included."""
    keep, i, n = [0], 0, len(dense)

    def fits(j: int) -> bool:
        inner = dense[i + 1:j]
        if len(inner) == 0:
            return True
        a = np.broadcast_to(dense[i], inner.shape)
        b = np.broadcast_to(dense[j], inner.shape)
        return bool(_segment_distance(inner, a, b).max() <= chord_m)

    while i < n - 1:
        step = 1
        while i + 2 * step < n and fits(i + 2 * step):
            step *= 2
        lo, hi = i + step, min(n - 1, i + 2 * step)  # lo fits; find the last fitting index in (lo, hi]
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if fits(mid):
                lo = mid
            else:
                hi = mid - 1
        keep.append(lo)
        i = lo
    return keep


def revolve(profile_m: np.ndarray, sections: int) -> trimesh.Trimesh:
    """The solid of revolution about z of a profile (N, 2) that starts and ends on the axis, or is
    closed (first point = last): rings of ``sections`` vertices, one vertex where it meets the axis,
    outward faces. Written here since trimesh's drops the sliver fan of a short last step to the axis."""
    profile = np.array(profile_m, dtype=float)
    closed = bool(np.allclose(profile[0], profile[-1]))
    if closed:
        profile = profile[:-1]
    profile[np.abs(profile[:, 0]) < 1e-12, 0] = 0.0  # an arc's end on the axis (cos(pi/2) != 0)
    angle = 2 * np.pi * np.arange(sections) / sections
    vertices, rings = [], []
    for r, z in profile:
        start = sum(len(v) for v in vertices)
        if r == 0.0:
            vertices.append(np.array([[0.0, 0.0, z]]))
            rings.append(np.full(sections, start))
        else:
            vertices.append(np.column_stack([r * np.cos(angle), r * np.sin(angle), np.full(sections, z)]))
            rings.append(start + np.arange(sections))
    faces = []
    pairs = list(zip(rings[:-1], rings[1:])) + ([(rings[-1], rings[0])] if closed else [])
    for a, b in pairs:
        a1, b1 = np.roll(a, -1), np.roll(b, -1)
        for tri in (np.column_stack([a, a1, b1]), np.column_stack([a, b1, b])):
            faces.append(tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])])
    mesh = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _to_surface_frame(points: np.ndarray, surface: Revolved) -> np.ndarray:
    """Points (N, 3) -> (radius, axial) (N, 2) in ``surface``'s half-plane, stretch undone."""
    origin = np.asarray(surface.axis_origin_m, dtype=float)
    p = (points - origin) / np.asarray(surface.stretch, dtype=float)
    axis = np.asarray(surface.axis_direction, dtype=float)
    axis = axis / np.linalg.norm(axis)
    along = p @ axis
    return np.column_stack([np.linalg.norm(p - along[:, None] * axis, axis=1), along])


def _profile_distance(points_2d: np.ndarray, profile: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Distance of half-plane points (N, 2) to the dense profile polyline, exact to its spacing."""
    _, idx = tree.query(points_2d, k=2)
    best = np.full(len(points_2d), np.inf)
    last = len(profile) - 1
    for column in idx.T:  # the segments on either side of the two nearest dense points
        for a, b in ((np.maximum(column - 1, 0), column), (column, np.minimum(column + 1, last))):
            best = np.minimum(best, _segment_distance(points_2d, profile[a], profile[b]))
    return best


def _surface_normal(points: np.ndarray, surface: Revolved, profile: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Unit normals (N, 3), up to sign, of ``surface`` (stretch undone) at its points nearest ``points`` (N, 3)."""
    origin = np.asarray(surface.axis_origin_m, dtype=float)
    axis = np.asarray(surface.axis_direction, dtype=float)
    axis = axis / np.linalg.norm(axis)
    p = (points - origin) / np.asarray(surface.stretch, dtype=float)
    radial = p - (p @ axis)[:, None] * axis
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-300)
    _, i = tree.query(_to_surface_frame(points, surface))
    tangent = profile[np.minimum(i + 1, len(profile) - 1)] - profile[np.maximum(i - 1, 0)]
    n2 = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-300)
    return n2[:, :1] * radial + n2[:, 1:] * axis


# Barycentric points where a flat's depth below a curved surface is largest: its corners, edge
# midpoints (a ring edge's sagitta), centroid (a quad's diagonal midpoint lies on an edge) and between.
_BARY = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [.5, .5, 0], [0, .5, .5], [.5, 0, .5], [1 / 3, 1 / 3, 1 / 3],
                  [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])


def chord_error_m(mesh: trimesh.Trimesh, surfaces: tuple[Revolved, ...], on_surface_m: float = 1e-8
                  ) -> tuple[float, int]:
    """(largest distance of a flat from its true surface, m; number of faces measured).

    A face is measured against a surface when all three of its vertices lie within
    ``on_surface_m`` of it and it faces the way the surface does there (within 0.2 rad): faces on
    planes, and the slivers that span a boolean seam from one curve of it to another, are not;
    the distance is taken at ten points of the face (corners, edge midpoints, centroid, between)."""
    worst, measured = 0.0, np.zeros(len(mesh.faces), dtype=bool)
    for surface in surfaces:
        profile = np.asarray(surface.profile_m, dtype=float)
        tree = cKDTree(profile)
        vertex_d = _profile_distance(_to_surface_frame(mesh.vertices, surface), profile, tree)
        on = (vertex_d <= on_surface_m)[mesh.faces].all(axis=1) & ~measured
        if on.any():
            normal = mesh.face_normals[on] * np.asarray(surface.stretch, dtype=float)  # normals map by the inverse
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            facing = np.abs(np.einsum("ij,ij->i", normal,
                                      _surface_normal(mesh.triangles_center[on], surface, profile, tree)))
            on[np.flatnonzero(on)[facing < np.cos(0.2)]] = False
        if not on.any():
            continue
        corners = mesh.vertices[mesh.faces[on]]  # (F, 3, 3)
        points = np.einsum("kj,fjd->fkd", _BARY, corners).reshape(-1, 3)
        d = _profile_distance(_to_surface_frame(points, surface), profile, tree)
        worst = max(worst, float(d.max()))
        measured |= on
    return worst, int(measured.sum())
