"""Which views see which voxels of a solid, for photo-consistent carving
(:mod:`real2sim.reconstruct.carving.photo`): a view sees a point when nothing of the solid lies on the
ray from its camera nearer than the point.

Two tests of that ray (``CarvingConfig.visibility``): Embree on the solid's marching-cubes surface
("mesh"), or the ray walked through the solid's trilinear interpolation with torch ("voxels",
:func:`real2sim.reconstruct.carving.voxel_rays.segments_blocked`). "auto" takes the mesh on a CPU, where
Embree's BVH beats walking every ray, and the voxels on a GPU, where the walk is a few gathers and
rebuilding a mesh and a BVH every round is what costs (docs/design-notes/reconstruct.md#carving-visibility).
The sightings are torch tensors on the carving's device. World frame, metres.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.multiview.rays import SurfaceRays
from real2sim.multiview.voxel_grid import VoxelGrid, surface_from_grid
from real2sim.multiview.views import PosedViews, project_torch


class Occluder(NamedTuple):
    """What a line of sight is tested against: the solid's surface (``surface``, its Embree scene), or the
    ``solid`` itself (a bool tensor) walked on ``device`` (voxel_rays.segments_blocked); one of the two is
    None."""

    surface: SurfaceRays | None
    solid: torch.Tensor | None
    grid: VoxelGrid
    device: str


class Cameras(NamedTuple):
    """The views' cameras on a device: world-to-camera (V, 4, 4) float32, centres (V, 3) float64 (metres),
    the shared intrinsics and the image size."""

    w2c: torch.Tensor
    centres_m: torch.Tensor
    intrinsics: CameraIntrinsics
    height: int
    width: int

    @property
    def count(self) -> int:
        return len(self.w2c)


def cameras_on(views: PosedViews, device: str) -> Cameras:
    """``views``' cameras as tensors on ``device``."""
    height, width = views.mask.shape[1:]
    return Cameras(torch.from_numpy(np.linalg.inv(views.c2w_cv)).float().to(device),
                   torch.as_tensor(views.c2w_cv[:, :3, 3], dtype=torch.float64, device=device),
                   views.intrinsics, int(height), int(width))


def visibility_method(method: str, device: str) -> str:
    """``method`` ("mesh", "voxels" or "auto") as it runs on ``device``: "auto" is the mesh on a CPU and
    the voxels elsewhere."""
    if method not in ("mesh", "voxels", "auto"):
        raise ValueError(f"visibility: mesh, voxels or auto, not {method!r}")
    return method if method != "auto" else ("mesh" if str(device) == "cpu" else "voxels")


def occluder(grid: VoxelGrid, solid, method: str, device: str) -> Occluder:
    """What :func:`sightings` tests against: ``method`` "mesh", "voxels" or "auto" (the mesh on a CPU,
    the voxels elsewhere; ``CarvingConfig.visibility``). ``solid``: bool, ``grid.shape``, an array or a tensor."""
    if visibility_method(method, device) == "voxels":
        return Occluder(None, torch.as_tensor(solid, device=device), grid, device)
    solid = solid.cpu().numpy() if isinstance(solid, torch.Tensor) else np.asarray(solid)
    surface = surface_from_grid(solid.astype(np.float32), grid, 0.5, float(grid.bounds_m[0, 2]))
    return Occluder(SurfaceRays(surface), None, grid, device)


def in_image(cameras: Cameras, uv: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Where projections (``uv`` (..., 2) px, ``depth`` (...) m) lie in front of the camera and inside its
    image with room for a bilinear sample (its right and bottom neighbours too)."""
    return ((depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < cameras.width - 1) & (uv[..., 1] >= 0)
            & (uv[..., 1] < cameras.height - 1))


def sightings(cameras: Cameras, grid: VoxelGrid, points_m: torch.Tensor, occluder: Occluder,
              tolerance_voxels: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Which views see which of ``points_m`` (P, 3, float64 tensor, metres): nothing of the solid
    (``occluder``) lies on the ray from the camera nearer than the point (less ``tolerance_voxels``). Per
    sighting: its view and point indices, the pixel position (N, 2, float32) and the ray's unit direction
    (N, 3); tensors on the points' device."""
    u, v, depth = project_torch(cameras.intrinsics, cameras.w2c, points_m.float())  # (V, P) each
    uv = torch.stack([u, v], dim=-1)
    view_of, point_of = torch.nonzero(in_image(cameras, uv, depth), as_tuple=True)
    origins = cameras.centres_m[view_of]
    offsets = points_m[point_of] - origins
    distance = torch.linalg.vector_norm(offsets, dim=1)
    directions = offsets / distance[:, None]
    reach = distance - tolerance_voxels * grid.voxel_m
    if occluder.surface is None:
        from real2sim.reconstruct.carving.voxel_rays import segments_blocked

        visible = ~segments_blocked(occluder.solid, grid, origins, directions, reach)
    else:
        hit_at = occluder.surface.first_hit(origins.cpu().numpy(), directions.cpu().numpy())
        visible = torch.as_tensor(hit_at, device=points_m.device) >= reach
    view_of, point_of = view_of[visible], point_of[visible]
    return view_of, point_of, uv[view_of, point_of], directions[visible]


def observations(views: PosedViews, grid: VoxelGrid, points: np.ndarray, occluder: Occluder,
                 tolerance_voxels: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`sightings` of ``points`` (P, 3, metres) by ``views``, as arrays."""
    device = occluder.device
    found = sightings(cameras_on(views, device), grid, torch.as_tensor(points, dtype=torch.float64, device=device),
                      occluder, tolerance_voxels)
    return tuple(a.cpu().numpy() for a in found)
