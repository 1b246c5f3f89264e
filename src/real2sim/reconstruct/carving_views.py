"""Which views see which voxels of a solid, for photo-consistent carving (``photo_carving``): a view
sees a point when nothing of the solid lies on the ray from its camera nearer than the point.

Two tests of that ray (``CarvingConfig.visibility``): Embree on the solid's marching-cubes surface
("mesh"), or the ray walked through the solid's trilinear interpolation with torch ("voxels",
:func:`real2sim.reconstruct.voxel_rays.segments_clear`). "auto" takes the mesh on a CPU, where
Embree's BVH is 4x faster than walking every ray on 2 cores, and the voxels on a GPU, where the walk
is a few gathers and rebuilding a mesh and a BVH every round is what costs (the mug's hull and
carving 28.5 -> 12.3 s on an H200, the same carving). World frame, metres.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from real2sim.reconstruct.hull import VoxelGrid, surface_from_grid
from real2sim.reconstruct.views import PosedViews, project


class Occluder(NamedTuple):
    """What a line of sight is tested against: the solid's surface ``mesh`` (Embree), or the ``solid``
    itself walked on ``device`` (voxel_rays.segments_clear); one of the two is None."""

    mesh: object | None
    solid: np.ndarray | None
    grid: VoxelGrid
    device: str


def visibility_method(method: str, device: str) -> str:
    """``method`` ("mesh", "voxels" or "auto") as it runs on ``device``: "auto" is the mesh on a CPU and
    the voxels elsewhere."""
    if method not in ("mesh", "voxels", "auto"):
        raise ValueError(f"visibility: mesh, voxels or auto, not {method!r}")
    return method if method != "auto" else ("mesh" if device == "cpu" else "voxels")


def occluder(grid: VoxelGrid, solid: np.ndarray, method: str, device: str) -> Occluder:
    """What :func:`observations` tests against: ``method`` "mesh", "voxels" or "auto" (the mesh on a CPU,
    the voxels elsewhere; ``CarvingConfig.visibility``)."""
    if visibility_method(method, device) == "voxels":
        return Occluder(None, solid, grid, device)
    return Occluder(surface_from_grid(solid.astype(np.float32), grid, 0.5, float(grid.bounds_m[0, 2])), None,
                     grid, device)


def in_image(views: PosedViews, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Where projections (``uv`` (..., 2) px, ``depth`` (...) m) lie in front of the camera and inside its
    image with room for a bilinear sample (its right and bottom neighbours too)."""
    height, width = views.mask.shape[1:]
    return (depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < width - 1) & (uv[..., 1] >= 0) & (uv[..., 1] < height - 1)


def observations(views: PosedViews, grid: VoxelGrid, points: np.ndarray, occluder: Occluder,
                 tolerance_voxels: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which views see which of ``points`` (P, 3, metres): nothing of the solid (``occluder``) lies on
    the ray from the camera nearer than the point (less ``tolerance_voxels``). Per
    observation: its view and point indices, the pixel position (N, 2) and the ray's unit direction (N, 3)."""
    uv, depth = project(views.intrinsics, views.c2w_cv, points)  # (V, P, 2), (V, P)
    view_of, point_of = np.nonzero(in_image(views, uv, depth))
    origins = views.c2w_cv[view_of, :3, 3]
    offsets = points[point_of] - origins
    distance = np.linalg.norm(offsets, axis=1)
    directions = offsets / distance[:, None]
    reach = distance - tolerance_voxels * grid.voxel_m
    if occluder.mesh is None:
        from real2sim.reconstruct.voxel_rays import segments_clear

        visible = segments_clear(occluder.solid, grid, origins, directions, reach, occluder.device)
    else:
        hit_at = np.full(len(origins), np.inf)
        hits, rays, _ = occluder.mesh.ray.intersects_location(origins, directions, multiple_hits=False)
        hit_at[rays] = np.einsum("nd,nd->n", hits - origins[rays], directions[rays])
        visible = hit_at >= reach
    view_of, point_of = view_of[visible], point_of[visible]
    return view_of, point_of, uv[view_of, point_of], directions[visible]
