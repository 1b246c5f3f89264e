"""Geometric fidelity of a collision representation against the reference mesh (asset frame, metres).

* **IoU** (volumetric intersection over union): points drawn uniformly in the
  union of the two bounding boxes; the reference's inside test is the winding
  number (:func:`real2sim.geometry.inside.inside_mask`), the collision geometry's is exact
  per piece (:func:`real2sim.geometry.collision_mesh.inside_collision`). Of the ``n``
  points that fall in the union of the two solids, the number in the
  intersection is Binomial(n, IoU), so the estimate's standard error is
  ``sqrt(IoU (1 - IoU) / n) <= 0.5 / sqrt(n)``. For a 95 % half-width of 0.005
  (IoU +- 0.5 percentage points) whatever the IoU, ``1.96 * 0.5 / sqrt(n) <= 0.005``
  gives ``n >= (1.96 / (2 * 0.005))^2 = 38,416`` points in the union. The union's
  share of the box is unknown in advance, so points are drawn in batches until
  that many have landed in the union. The half-width actually achieved
  (``1.96 sqrt(IoU (1 - IoU) / n)``, at least ``3 / n``) is returned as ``iou_ci95``.
* **Chamfer distance**: surface points sampled (area-uniform) on the reference
  and on the union mesh of the collision geometry (:func:`union_mesh`: the outer
  surface only, no faces buried inside overlapping pieces); the distance from
  each point to the *other surface* (exact point-to-triangle, libigl), averaged
  per direction; ``chamfer_mm`` is the mean of the two directions, in mm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.collision import CollisionGeometry

Z_95 = 1.959963984540054
IOU_HALF_WIDTH = 0.005
IOU_POINTS_IN_UNION = int(np.ceil((Z_95 / (2 * IOU_HALF_WIDTH)) ** 2))  # 38,415 (~38,416 with z = 1.96)
_BATCH = 100_000
_MAX_IOU_SAMPLES = 5_000_000  # a union filling < 0.8 % of its bounding box stops here, with a wider interval


def surface_distance_m(points_m: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """Exact distance (N,) from each point to the nearest triangle of ``mesh`` (libigl), same units."""
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points_m, dtype=np.float64),
        np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(mesh.faces, dtype=np.int64),
    )
    return np.sqrt(np.maximum(d2, 0.0))


def _sample_surface(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """Area-uniform points on a triangle mesh (seeded)."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    face = rng.choice(len(tri), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def chamfer_distance_mm(mesh_a: trimesh.Trimesh, mesh_b: trimesh.Trimesh, *, num_samples: int = 20_000, seed: int = 0) -> float:
    """Symmetric Chamfer distance (mm) between two surfaces in metres: mean of the two mean point-to-surface distances."""
    rng = np.random.default_rng(seed)
    a_to_b = surface_distance_m(_sample_surface(mesh_a, num_samples, rng), mesh_b).mean()
    b_to_a = surface_distance_m(_sample_surface(mesh_b, num_samples, rng), mesh_a).mean()
    return float(500.0 * (a_to_b + b_to_a))


def volumetric_iou(
    reference_mesh: trimesh.Trimesh,
    geometry: CollisionGeometry,
    rep_dir: Path | None,
    *,
    bounds_m: np.ndarray,
    seed: int = 0,
    num_samples: int | None = None,
) -> tuple[float, int, float]:
    """IoU, the number of box samples drawn, and the 95 % half-width; see the module docstring."""
    from real2sim.geometry.collision_mesh import inside_collision
    from real2sim.geometry.inside import inside_mask

    from real2sim.geometry.inside import compact_triangles

    reference_mesh = compact_triangles(reference_mesh)  # same surface, faster winding numbers
    rng = np.random.default_rng(seed)
    lo, hi = bounds_m
    drawn = in_union = in_both = 0
    target = num_samples if num_samples is not None else _MAX_IOU_SAMPLES
    while drawn < target:
        n = min(_BATCH, target - drawn)
        pts = lo + rng.random((n, 3)) * (hi - lo)
        ref = inside_mask(reference_mesh, pts)
        col = inside_collision(geometry, rep_dir, pts)
        drawn += n
        in_union += int(np.count_nonzero(ref | col))
        in_both += int(np.count_nonzero(ref & col))
        if num_samples is None and in_union >= IOU_POINTS_IN_UNION:
            break
    if in_union == 0:
        return 0.0, drawn, float("nan")
    iou = in_both / in_union
    # normal approximation; at IoU ~ 0 or 1 it collapses to 0, so floor it with the
    # "rule of three" (95 % bound on a proportion with no events in n trials: 3 / n)
    return iou, drawn, float(max(Z_95 * np.sqrt(iou * (1 - iou) / in_union), 3.0 / in_union))


def measure_fidelity(
    reference_mesh: trimesh.Trimesh,
    geometry: CollisionGeometry,
    rep_dir: Path | None,
    *,
    seed: int = 0,
    iou_samples: int | None = None,
    chamfer_samples: int = 20_000,
) -> dict:
    """How well ``geometry`` reproduces ``reference_mesh`` (both in the asset frame, metres).

    Returns ``{"iou", "chamfer_mm", "num_pieces", "iou_samples", "iou_ci95"}``:
    volumetric IoU in [0, 1]; symmetric Chamfer distance in mm; the number of
    collision pieces; the box samples drawn for the IoU (``iou_samples`` fixes it,
    default adaptive for +-0.005 at 95 %); and the 95 % half-width of the IoU.
    """
    from real2sim.geometry.collision_mesh import union_mesh

    union = union_mesh(geometry, rep_dir)
    if len(union.faces) == 0:
        raise ValueError("collision geometry has no pieces")
    lo = np.minimum(reference_mesh.bounds[0], union.bounds[0])
    hi = np.maximum(reference_mesh.bounds[1], union.bounds[1])
    iou, drawn, ci = volumetric_iou(reference_mesh, geometry, rep_dir, bounds_m=np.stack([lo, hi]), seed=seed, num_samples=iou_samples)
    chamfer = chamfer_distance_mm(reference_mesh, union, num_samples=chamfer_samples, seed=seed + 1)
    return {"iou": float(iou), "chamfer_mm": chamfer, "num_pieces": len(geometry.shapes), "iou_samples": int(drawn), "iou_ci95": ci}
