"""Differentiable signed distance functions of primitive shapes (torch).

All functions take query points ``points`` of shape (N, 3) and parameters for P
primitives, and return a (P, N) tensor of signed distances (negative inside), in
the same length unit as the inputs (the fitter works in unit-sphere coordinates).
Every function also accepts ``paired=True``: then the parameters have a leading
dimension equal to N and the result is (N,), the distance of point k to primitive
k (the fitter uses this to differentiate only through each point's closest primitive).

Quaternions are (w, x, y, z), need not be unit (they are normalised here), and
rotate the primitive's own frame into the query frame: a primitive-frame point
``u`` sits at ``centre + R(q) u``.

Exactness: sphere, box (axis-aligned or rotated), cylinder (axis = primitive z)
and capsule (axis = primitive z) are exact Euclidean signed distances. An
ellipsoid has no closed-form distance (it needs the root of a sextic); we use the
bound ``k0 (k0 - 1) / k1`` with ``k0 = |u / a|`` and ``k1 = |u / a^2|`` (Inigo
Quilez's "improved" ellipsoid estimate): it has the correct sign everywhere,
vanishes exactly on the surface, is first-order exact near the surface (where the
fitter's samples are) and costs two norms, so it suits a loss that is dominated
by near-surface samples; far from the surface it is only a bound.

A superquadric (superellipsoid, beyond the paper) has no closed-form distance
either. With semi-axes ``a`` and exponents ``e1`` (along z) and ``e2`` (around z),
its inside-outside function ``G(u) = F(u)^(e1/2)``, ``F = (|x/a1|^(2/e2) +
|y/a2|^(2/e2))^(e2/e1) + |z/a3|^(2/e1)``, is positively homogeneous of degree 1,
so we use the first-order distance ``(G - 1) / |grad G|``: exact in sign, zero
exactly on the surface, first-order exact next to it, and for ``e1 = e2 = 1`` it
is the ellipsoid estimate above term for term. It is evaluated in log space
because ``|x/a|^(2/e)`` overflows float32 for small exponents far from a small
primitive. Exponents in (0, 2] keep the solid convex (it is simulated as a convex
mesh, see :mod:`real2sim.collision.superquadric`); 1 gives an ellipsoid, near 0 a box, and
``e1 -> 0, e2 = 1`` an elliptic cylinder.

The union of primitives is the minimum over primitives (paper eq. 7).

Packed parameter layout per kind (one row per primitive), used by
:func:`primitive_sdf` and the fitter:

===========  ===  ==========================================
kind         D    columns
===========  ===  ==========================================
sphere       4    centre(3), radius
box          6    centre(3), half_extents(3)          (axis-aligned)
rotated_box  10   centre(3), half_extents(3), quat(4)
cylinder     9    centre(3), radius, half_length, quat(4)
ellipsoid    10   centre(3), semi_axes(3), quat(4)
capsule      9    centre(3), radius, half_length, quat(4)
superquadric 12   centre(3), semi_axes(3), e1, e2, quat(4)
===========  ===  ==========================================
"""

from __future__ import annotations

import torch

KINDS: tuple[str, ...] = ("sphere", "box", "rotated_box", "cylinder", "ellipsoid", "capsule", "superquadric")
PARAM_DIM: dict[str, int] = {
    "sphere": 4, "box": 6, "rotated_box": 10, "cylinder": 9, "ellipsoid": 10, "capsule": 9, "superquadric": 12,
}  # fmt: skip
SIZE_DIM: dict[str, int] = {"sphere": 1, "box": 3, "rotated_box": 3, "cylinder": 2, "ellipsoid": 3, "capsule": 2, "superquadric": 3}
# Shape exponents sit between the sizes and the quaternion; only superquadrics have them.
EXPONENT_DIM: dict[str, int] = {k: 2 if k == "superquadric" else 0 for k in KINDS}
HAS_ROTATION: dict[str, bool] = {k: PARAM_DIM[k] - 3 - SIZE_DIM[k] - EXPONENT_DIM[k] == 4 for k in KINDS}
# Superquadric exponents: above 2 the solid is no longer convex. The lower end decides how
# sharp an edge can get (docs/design-notes/collision.md#superquadric-exponent-range).
SUPERQUADRIC_EXPONENT_RANGE: tuple[float, float] = (0.02, 2.0)

# Below this squared length a norm is treated as zero: keeps sqrt's gradient finite
# at the origin (the clamp blocks the gradient there) while changing values by <1e-9.
_TINY_SQ = 1e-18


def _norm(v: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over the last axis with a finite gradient at zero."""
    return torch.sqrt(torch.clamp((v * v).sum(-1), min=_TINY_SQ))


def _hypot(*parts: torch.Tensor) -> torch.Tensor:
    """sqrt of a sum of squares of same-shaped components, finite gradient at zero.

    Components are kept as separate (P, N) tensors rather than one (P, N, 3) tensor:
    elementwise ops over contiguous (P, N) blocks are several times faster on the CPU
    than reductions over a trailing axis of length 3.
    """
    total = parts[0] * parts[0]
    for p in parts[1:]:
        total = total + p * p
    return torch.sqrt(torch.clamp(total, min=_TINY_SQ))


def quaternion_to_matrix(q_wxyz: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) (w, x, y, z); normalises first."""
    q = q_wxyz / _norm(q_wxyz).unsqueeze(-1)
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return torch.stack(rows, -1).reshape(q.shape[:-1] + (3, 3))


def _local(
    points: torch.Tensor, centre: torch.Tensor, quat: torch.Tensor | None, paired: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Components (u_x, u_y, u_z) of the points in each primitive's frame, u = R^T (x - c):
    each (P, N), or (N,) when paired."""
    if not paired:
        if quat is None:
            return tuple(points[:, j].unsqueeze(0) - centre[:, j].unsqueeze(1) for j in range(3))  # type: ignore[return-value]
        rot = quaternion_to_matrix(quat)  # (P, 3, 3); column j is the primitive's axis j
        offset = (centre.unsqueeze(2) * rot).sum(1)  # (P, 3): c . axis_j
        # u_j = axis_j . x - axis_j . c, one (P, 3) @ (3, N) matmul per component.
        return tuple(torch.addmm(-offset[:, j : j + 1], rot[:, :, j], points.T) for j in range(3))  # type: ignore[return-value]
    d = points - centre
    if quat is None:
        return d[:, 0], d[:, 1], d[:, 2]
    rot = quaternion_to_matrix(quat)  # (N, 3, 3)
    u = (d.unsqueeze(2) * rot).sum(1)
    return u[:, 0], u[:, 1], u[:, 2]


def _per(x: torch.Tensor, paired: bool) -> torch.Tensor:
    """A per-primitive vector (P,) shaped to broadcast against (P, N) components, or (N,) paired."""
    x = x.reshape(-1)
    return x if paired else x.unsqueeze(1)


def _box_local(u: tuple[torch.Tensor, ...], half: torch.Tensor, paired: bool) -> torch.Tensor:
    q = [u[j].abs() - _per(half[:, j], paired) for j in range(3)]
    outside = _hypot(*(torch.clamp(qj, min=0.0) for qj in q))
    inside = torch.clamp(torch.maximum(torch.maximum(q[0], q[1]), q[2]), max=0.0)
    return outside + inside


def sphere_sdf(points: torch.Tensor, centre: torch.Tensor, radius: torch.Tensor, *, paired: bool = False) -> torch.Tensor:
    """Eq. 5: ``|x - c| - r``. centre (P, 3), radius (P,) or (P, 1)."""
    r = radius.reshape(-1)
    if paired:
        return _norm(points - centre) - r
    # |x|^2 - 2 x.c + |c|^2 through a matmul: much cheaper than materialising (P, N, 3).
    sq = torch.addmm((centre * centre).sum(-1, keepdim=True), centre, points.T, alpha=-2.0) + (points * points).sum(-1).unsqueeze(0)
    return torch.sqrt(torch.clamp(sq, min=_TINY_SQ)) - r.unsqueeze(1)


def box_sdf(points: torch.Tensor, centre: torch.Tensor, half_extents: torch.Tensor, *, paired: bool = False) -> torch.Tensor:
    """Exact distance to an axis-aligned box. centre (P, 3), half_extents (P, 3)."""
    return _box_local(_local(points, centre, None, paired), half_extents, paired)


def rotated_box_sdf(
    points: torch.Tensor, centre: torch.Tensor, half_extents: torch.Tensor, quaternion_wxyz: torch.Tensor, *, paired: bool = False
) -> torch.Tensor:
    """Exact distance to a box with edges along the columns of R(q). Sizes are half-extents (P, 3)."""
    return _box_local(_local(points, centre, quaternion_wxyz, paired), half_extents, paired)


def cylinder_sdf(
    points: torch.Tensor,
    centre: torch.Tensor,
    radius: torch.Tensor,
    half_length: torch.Tensor,
    quaternion_wxyz: torch.Tensor,
    *,
    paired: bool = False,
) -> torch.Tensor:
    """Exact distance to a solid capped cylinder whose axis is the primitive z axis."""
    ux, uy, uz = _local(points, centre, quaternion_wxyz, paired)
    q_r = _hypot(ux, uy) - _per(radius, paired)
    q_z = uz.abs() - _per(half_length, paired)
    return _hypot(torch.clamp(q_r, min=0.0), torch.clamp(q_z, min=0.0)) + torch.clamp(torch.maximum(q_r, q_z), max=0.0)


def capsule_sdf(
    points: torch.Tensor,
    centre: torch.Tensor,
    radius: torch.Tensor,
    half_length: torch.Tensor,
    quaternion_wxyz: torch.Tensor,
    *,
    paired: bool = False,
) -> torch.Tensor:
    """Exact distance to a capsule: segment from -h to +h along primitive z, swept by radius r."""
    ux, uy, uz = _local(points, centre, quaternion_wxyz, paired)
    h = _per(half_length, paired)
    beyond = torch.clamp(uz.abs() - h, min=0.0)  # distance along the axis past the segment's end
    return _hypot(ux, uy, beyond) - _per(radius, paired)


def ellipsoid_sdf(
    points: torch.Tensor, centre: torch.Tensor, semi_axes: torch.Tensor, quaternion_wxyz: torch.Tensor, *, paired: bool = False
) -> torch.Tensor:
    """Signed-distance bound ``k0 (k0 - 1) / k1`` of an ellipsoid (see module docstring)."""
    u = _local(points, centre, quaternion_wxyz, paired)
    a = [_per(semi_axes[:, j], paired) for j in range(3)]
    k0 = _hypot(*(u[j] / a[j] for j in range(3)))
    k1 = _hypot(*(u[j] / (a[j] * a[j]) for j in range(3)))
    return k0 * (k0 - 1.0) / k1


def superquadric_sdf(
    points: torch.Tensor,
    centre: torch.Tensor,
    semi_axes: torch.Tensor,
    exponents: torch.Tensor,
    quaternion_wxyz: torch.Tensor,
    *,
    paired: bool = False,
) -> torch.Tensor:
    """First-order signed distance ``(G - 1) / |grad G|`` of a superquadric (module docstring).

    semi_axes (P, 3) along the primitive's x, y, z; exponents (P, 2) = (e1, e2), e1 shaping
    the profile along z and e2 the section around z.
    """
    u = _local(points, centre, quaternion_wxyz, paired)
    e1 = _per(exponents[:, 0], paired)
    e2 = _per(exponents[:, 1], paired)
    log_u = [0.5 * torch.log(torch.clamp(c * c, min=_TINY_SQ)) for c in u]  # log |u_j|
    log_s = [log_u[j] - torch.log(_per(semi_axes[:, j], paired)) for j in range(3)]  # log |u_j / a_j|
    px, py = (2.0 / e2) * log_s[0], (2.0 / e2) * log_s[1]
    pxy = (e2 / e1) * torch.logaddexp(px, py)  # log of the (x, y) term of F
    pz = (2.0 / e1) * log_s[2]
    log_g = 0.5 * e1 * torch.logaddexp(pxy, pz)
    # d log G / d u_j = w_j / u_j with softmax weights w of the terms of F (closed form).
    w_xy = torch.nn.functional.logsigmoid(pxy - pz)
    log_t = (
        w_xy + torch.nn.functional.logsigmoid(px - py) - log_u[0],
        w_xy + torch.nn.functional.logsigmoid(py - px) - log_u[1],
        torch.nn.functional.logsigmoid(pz - pxy) - log_u[2],
    )
    grad_log_g = _hypot(*(torch.exp(t) for t in log_t))  # |grad G| / G
    return -torch.expm1(-log_g) / grad_log_g


def primitive_sdf(kind: str, points: torch.Tensor, packed: torch.Tensor, *, paired: bool = False) -> torch.Tensor:
    """Signed distance for packed parameters (P, D) of one kind (layout in the module docstring)."""
    c = packed[:, 0:3]
    if kind == "sphere":
        return sphere_sdf(points, c, packed[:, 3], paired=paired)
    if kind == "box":
        return box_sdf(points, c, packed[:, 3:6], paired=paired)
    if kind == "rotated_box":
        return rotated_box_sdf(points, c, packed[:, 3:6], packed[:, 6:10], paired=paired)
    if kind == "cylinder":
        return cylinder_sdf(points, c, packed[:, 3], packed[:, 4], packed[:, 5:9], paired=paired)
    if kind == "ellipsoid":
        return ellipsoid_sdf(points, c, packed[:, 3:6], packed[:, 6:10], paired=paired)
    if kind == "capsule":
        return capsule_sdf(points, c, packed[:, 3], packed[:, 4], packed[:, 5:9], paired=paired)
    if kind == "superquadric":
        return superquadric_sdf(points, c, packed[:, 3:6], packed[:, 6:8], packed[:, 8:12], paired=paired)
    raise ValueError(f"unknown primitive kind {kind!r}; known: {', '.join(KINDS)}")


def union_sdf(distances: torch.Tensor) -> torch.Tensor:
    """Eq. 7: signed distance of a union, the minimum over primitives of (P, N) distances -> (N,)."""
    return distances.min(0).values
