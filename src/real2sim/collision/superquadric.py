"""Superquadrics as convex meshes: the form in which a simulator receives them.

Drake (and URDF) has no superquadric shape, so a fitted superquadric is written as
a ``convex`` collision piece: a polytope whose vertices lie on the superquadric's
surface (``<drake:declare_convex/>``; Drake simulates the hull of the vertices).

Frames and units: everything is in the superquadric's own frame (centre at the
origin, semi-axes along x, y, z), in whatever length unit the semi-axes are given.
Exponents ``(e1, e2)`` follow :mod:`real2sim.collision.primitive_sdf`: e1 shapes the profile
along z, e2 the section around z; both in (0, 2], where the solid is convex.

Vertex placement: a superquadric is the spherical product of two superellipses (its
section around z, exponent e2, and its profile along z, exponent e1); each curve is
sampled at evenly spaced angles of its normal (points bunch at the edges of box-like
shapes) or of the ray from the centre, and the product grid plus the two poles are
the vertices; of the splits between the two curves and the two samplings, the one
whose polytope holds the most volume is kept. An inscribed
polytope holds less volume than the solid
(docs/design-notes/collision.md#superquadric-polytopes), so the hull is scaled about
the centre until its volume equals the
superquadric's closed-form volume: the simulated solid then neither shrinks nor
grows on average.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import trimesh

DEFAULT_VERTICES = 128


def _validate(semi_axes, exponents) -> tuple[np.ndarray, float, float]:
    a = np.asarray(semi_axes, dtype=np.float64).reshape(3)
    e1, e2 = (float(v) for v in np.asarray(exponents, dtype=np.float64).reshape(2))
    if not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ValueError(f"superquadric semi-axes must be positive, got {a.tolist()}")
    if not (0.0 < e1 <= 2.0 and 0.0 < e2 <= 2.0):
        raise ValueError(f"superquadric exponents must lie in (0, 2] to be convex, got {(e1, e2)}")
    return a, e1, e2


def inside_outside(points: np.ndarray, semi_axes, exponents) -> np.ndarray:
    """G(p) (N,): < 1 inside, 1 on the surface, > 1 outside; positively homogeneous of degree 1."""
    a, e1, e2 = _validate(semi_axes, exponents)
    p = np.abs(np.asarray(points, dtype=np.float64).reshape(-1, 3)) / a
    with np.errstate(divide="ignore"):
        log_p = np.log(p)  # -inf at 0 is fine: it contributes exp(-inf) = 0 below
    pxy = (e2 / e1) * np.logaddexp((2 / e2) * log_p[:, 0], (2 / e2) * log_p[:, 1])
    return np.exp(0.5 * e1 * np.logaddexp(pxy, (2 / e1) * log_p[:, 2]))


def volume(semi_axes, exponents) -> float:
    """Closed-form volume ``2 a1 a2 a3 e1 e2 B(e1/2 + 1, e1) B(e2/2, e2/2)`` (Jaklic et al. 2000)."""
    a, e1, e2 = _validate(semi_axes, exponents)

    def beta(x: float, y: float) -> float:
        return math.exp(math.lgamma(x) + math.lgamma(y) - math.lgamma(x + y))

    return float(2.0 * np.prod(a) * e1 * e2 * beta(e1 / 2 + 1, e1) * beta(e2 / 2, e2 / 2))


def _superellipse(count: int, exponent: float, start: float, stop: float, by_normal: bool) -> np.ndarray:
    """Points (count, 2) on the unit superellipse ``|u|^p + |v|^p = 1`` (p = 2 / exponent) at
    evenly spaced angles from ``start`` to ``stop`` (radians, inclusive) of their outward normal
    (``by_normal``) or of the ray from the centre.

    Even steps of the normal put the points where the curve turns: bunched at the corners of
    a near-square, so that the inscribed polygon loses little area there; even ray steps suit
    curves that turn evenly. The point with normal angle phi is ``(sgn c |c|^t, sgn s |s|^t)``
    with ``t = 1 / (p - 1)``, pushed onto the curve; near the diamond (p -> 1) t is capped,
    which only shifts where the points sit on the true curve.
    """
    p = 2.0 / exponent
    t = 1.0 / (max(p, 1.05) - 1.0) if by_normal else 1.0
    phi = np.linspace(start, stop, count)
    c, s = np.cos(phi), np.sin(phi)
    c[np.abs(c) < 1e-12] = 0.0
    s[np.abs(s) < 1e-12] = 0.0
    pts = np.stack((np.sign(c) * np.abs(c) ** t, np.sign(s) * np.abs(s) ** t), 1)
    with np.errstate(divide="ignore"):
        log_norm = np.logaddexp(*(p * np.log(np.abs(pts.T)))) / p
    return pts / np.exp(log_norm)[:, None]


def _grids(num_vertices: int) -> list[tuple[int, int]]:
    """Candidate (points around the section, rings along the profile without the poles) that
    fill at most ``num_vertices``: from few rings (flat ends, round section) to many."""
    out = []
    for rings in range(1, 16):
        around = (num_vertices - 2) // rings // 4 * 4
        if around >= 8:
            out.append((around, rings))
    return out


def _hull(points: np.ndarray) -> trimesh.Trimesh:
    import manifold3d

    from real2sim.geometry.collision_mesh import from_manifold

    # manifold3d's hull stays closed and consistently oriented even when many points are
    # (nearly) coplanar, as on the faces of box- and diamond-like superquadrics.
    return from_manifold(manifold3d.Manifold.hull_points(np.ascontiguousarray(points, dtype=np.float64)))


def superquadric_hull(semi_axes, exponents, num_vertices: int = DEFAULT_VERTICES) -> trimesh.Trimesh:
    """Closed convex triangle mesh of the superquadric (own frame) with at most ``num_vertices``
    vertices and the superquadric's volume (module docstring)."""
    a, e1, e2 = _validate(semi_axes, exponents)
    if num_vertices < 50:
        raise ValueError(f"a superquadric hull needs at least 50 vertices, got {num_vertices}")
    best = None
    # Keep the sampling whose polytope holds the most volume, i.e. misses the least of the solid.
    for (around, rings), by_normal in itertools.product(_grids(num_vertices), (True, False)):
        section = _superellipse(around + 1, e2, 0.0, 2 * math.pi, by_normal)[:-1]  # (around, 2)
        profile = _superellipse(rings + 2, e1, -math.pi / 2, math.pi / 2, by_normal)[1:-1]  # (r, z), no poles
        # Spherical product of the two curves: (a1 r s_x, a2 r s_y, a3 z).
        ring = profile[:, None, 0:1] * section[None, :, :]
        z = np.broadcast_to(profile[:, None, 1:2], ring.shape[:2] + (1,))
        body = np.concatenate((ring, z), 2).reshape(-1, 3)
        hull = _hull(np.concatenate((body, [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])) * a)
        if best is None or hull.volume > best.volume:
            best = hull
    hull = best
    hull.apply_scale((volume(a, (e1, e2)) / hull.volume) ** (1.0 / 3.0))
    return hull
