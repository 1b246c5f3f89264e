"""The radiance field's training rays: the pool of rays through the views' pixels near the object, and each
ray's stretch inside the field's occupancy (cast with Embree), kept valid while per-view pose corrections
move the rays. World frame, metres; split from :mod:`real2sim.reconstruct.field.train`, which uses them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.reconstruct.field.view_corrections import ViewCorrections
from real2sim.multiview.views import PosedViews, pixel_rays


@dataclass(frozen=True)
class RayPool:
    """Training rays: world origins/directions (R, 3), target colour (R, 3), mask (R,), float32 tensors,
    and the view each comes from (R,), int64."""

    origins: torch.Tensor
    directions: torch.Tensor
    rgb: torch.Tensor
    mask: torch.Tensor
    view: torch.Tensor

    def to(self, device) -> "RayPool":
        return RayPool(*(getattr(self, f).to(device) for f in ("origins", "directions", "rgb", "mask", "view")))


def ray_pool(views: PosedViews, *, mask_dilation_px: int, background_fraction: float,
             rng: np.random.Generator) -> RayPool:
    """Rays through every pixel near the object (dilated masks) plus a sample of the others."""
    k = views.intrinsics
    origins, dirs, rgbs, masks, index = [], [], [], [], []
    disk = np.ones((2 * mask_dilation_px + 1,) * 2, bool)
    for i in range(views.count):
        near = binary_dilation(views.mask[i] > 0.5, disk)
        far = ~near & (rng.random(near.shape) < background_fraction)
        v_px, u_px = np.nonzero(near | far)
        o, d = pixel_rays(k, views.c2w_cv[i], u_px + 0.5, v_px + 0.5)
        origins.append(o)
        dirs.append(d)
        rgbs.append(views.rgb[i, v_px, u_px])
        masks.append(views.mask[i, v_px, u_px])
        index.append(np.full(len(u_px), i))
    cat = lambda xs: torch.from_numpy(np.concatenate(xs).astype(np.float32))
    return RayPool(cat(origins), cat(dirs), cat(rgbs), cat(masks), torch.from_numpy(np.concatenate(index)))


def occupancy_ranges(field: VoxelRadianceField, origins: torch.Tensor, directions: torch.Tensor,
                     grow_voxels: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Per ray, the distances (R,) where it first enters and last leaves the field's occupancy
    grown by ``grow_voxels``.

    Ray-cast (embree) against the occupancy's surface, so rendering marches only that
    stretch of each ray; a ray that misses gets an empty range.
    """
    surface = field.occupancy_rays(grow_voxels)
    origins = origins.detach().cpu().numpy().astype(np.float64)
    dirs = directions.detach().cpu().numpy().astype(np.float64)
    far = 4.0 * float(np.linalg.norm(field.grid.bounds_m[1] - field.grid.bounds_m[0])) + \
        float(np.abs(origins - field.grid.bounds_m.mean(axis=0)).max())
    t_in = surface.first_hit(origins, dirs)
    entered = np.isfinite(t_in)
    t_in = np.where(entered, t_in, 0.0)
    t_back = surface.first_hit(origins + far * dirs, -dirs)  # from beyond the far side, back along the ray
    t_out = np.where(np.isfinite(t_back), far - t_back, 0.0)
    t_out = np.where(entered, np.maximum(t_out, t_in) + field.grid.voxel_m, 0.0)
    t_in = np.where(entered, np.maximum(t_in - field.grid.voxel_m, 0.0), 0.0)
    to = lambda a: torch.from_numpy(a.astype(np.float32)).to(field.device)
    return to(t_in), to(t_out)


class PoolRanges:
    """Each pool ray's stretch inside the field's occupancy, kept valid while pose corrections move the rays.

    With moving rays the occupancy is grown by ``pad_voxels``: a corrected ray's occupied samples lie
    within that of the ray the ranges were cast for until its view's rays have moved by more
    (``moved_m``). Then the batch's rays of such views are cast as they are now; the whole pool is
    cast again when a quarter of the views have moved that far, at most every ``min_interval`` steps
    (a cast of the pool costs seconds, of a batch tens of milliseconds).
    """

    def __init__(self, field: VoxelRadianceField, pool: RayPool, corrections: ViewCorrections | None,
                 pad_voxels: int = 4, min_interval: int = 50):
        self.field, self.pool, self.corrections = field, pool, corrections
        self.moving = corrections is not None and corrections.poses_learning
        self.grow = pad_voxels if self.moving else 1
        self.allowance_m = (self.grow - 1) * field.grid.voxel_m
        self.min_interval = min_interval
        corners = np.stack(np.meshgrid(*field.grid.bounds_m.T, indexing="ij"), axis=-1).reshape(-1, 3)
        self.reach_m = float(np.linalg.norm(corners[None] - pool.origins.cpu().numpy()[::997, None], axis=-1).max())
        self.casts, self.steps = 0, 0
        self._cast()

    def _corrected(self, index: torch.Tensor | None = None):
        origins, directions, view = self.pool.origins, self.pool.directions, self.pool.view
        if index is not None:
            origins, directions, view = origins[index], directions[index], view[index]
        if self.corrections is None or not self.corrections.poses:
            return origins, directions
        with torch.no_grad():
            return self.corrections.rays(view, origins, directions)

    def _cast(self) -> None:
        if self.moving:
            self.since = self.corrections.snapshot()
        self.t_in, self.t_out = occupancy_ranges(self.field, *self._corrected(), grow_voxels=self.grow)
        self.casts, self.last_cast = self.casts + 1, self.steps

    def batch(self, pick: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.steps += 1
        if not self.moving:
            return self.t_in[pick], self.t_out[pick]
        stale = self.corrections.moved_m(*self.since, self.reach_m) > self.allowance_m
        if stale.float().mean() > 0.25 and self.steps - self.last_cast >= self.min_interval:
            self._cast()
            stale[:] = False
        t_in, t_out = self.t_in[pick], self.t_out[pick]
        redo = torch.nonzero(stale[self.pool.view[pick]])[:, 0]
        if len(redo):
            fresh = occupancy_ranges(self.field, *self._corrected(pick[redo]), grow_voxels=self.grow)
            t_in, t_out = t_in.index_put((redo,), fresh[0]), t_out.index_put((redo,), fresh[1])
        return t_in, t_out
