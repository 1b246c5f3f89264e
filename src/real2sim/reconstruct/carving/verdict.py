"""Photo carving's verdict on each tested voxel (:mod:`real2sim.reconstruct.carving.photo`): how much the
colours of the views that see it disagree (and their hues), how many views see it through the carved space
or from outside, the image contrast around it, and the disagreement a deeper surface would show. Torch, on
the carving's device; world frame, metres; RGB in [0, 1].
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from real2sim.reconstruct.carving.config import CarvingConfig
from real2sim.reconstruct.carving.views import Cameras, Occluder, in_image, sightings
from real2sim.multiview.views import bilinear, project_torch
from real2sim.multiview.voxel_grid import VoxelGrid


class CarvingScene(NamedTuple):
    """What a carving round looks at, on the carving's device: the views' ``cameras``, their ``images``
    (V, H, W, 3 float32 tensor, blurred and exposure-corrected), the ``grid`` and its origin (3,) float64."""

    cameras: Cameras
    images: torch.Tensor
    grid: VoxelGrid
    origin_m: torch.Tensor

    def points(self, idx: torch.Tensor) -> torch.Tensor:
        """The centres (P, 3, float64, metres) of voxels ``idx`` (P, 3)."""
        return self.origin_m + idx.to(torch.float64) * self.grid.voxel_m


class Verdict(NamedTuple):
    """Per tested voxel (tensors): its views' colour ``spread`` and ``hue_spread`` (see :func:`voxel_verdicts`), how
    many views see it (``seen``), how many of those reach it through the carved space (``through``)
    and from outside (``outside``), the median image ``contrast`` around its projections in
    the views that see it (NaN when none does, or when no contrast map was given), and the spread
    those views would see of a surface deeper along their line of sight (``behind``,
    :func:`_spread_behind`; None when not asked for)."""

    spread: torch.Tensor
    hue_spread: torch.Tensor
    seen: torch.Tensor
    through: torch.Tensor
    outside: torch.Tensor
    contrast: torch.Tensor
    behind: torch.Tensor | None = None


def voxel_verdicts(scene: CarvingScene, idx: torch.Tensor, sight: Occluder, carved: torch.Tensor,
                   config: CarvingConfig, contrast: torch.Tensor | None = None, behind_m: float = 0.0) -> Verdict:
    """The verdict on each voxel of ``idx`` (P, 3): the ``spread_quantile`` of its views' colour
    distances from their median, the same for their hues, and the counts of :class:`Verdict`."""
    grid, views = scene.grid, scene.cameras.count
    points = scene.points(idx)
    count = len(points)
    view_of, point_of, pixel_uv, directions = sightings(scene.cameras, grid, points, sight,
                                                        config.visibility_tolerance_voxels)
    # a view reaches the voxel through carved space when the ray is in it just before the voxel
    before = points[point_of] - 1.5 * grid.voxel_m * directions
    cell = torch.round((before - scene.origin_m) / grid.voxel_m).to(torch.int64).clamp_min(0)
    cell = torch.minimum(cell, torch.as_tensor(grid.shape, device=cell.device) - 1)
    through = carved[cell[:, 0], cell[:, 1], cell[:, 2]]
    through_count = torch.bincount(point_of, weights=through.to(torch.float64), minlength=count)
    outside_count = torch.bincount(point_of, weights=(~through).to(torch.float64), minlength=count)
    colours = bilinear(scene.images, view_of, pixel_uv)
    # hue: colour over brightness, damped for dark pixels whose ratios are noise
    hues = 3.0 * colours / (colours.sum(dim=1, keepdim=True) + config.hue_floor)
    seen = torch.bincount(point_of, minlength=count)
    some = seen > 0
    spreads = [torch.nan_to_num(_colour_spread(values, view_of, point_of, count, views, quantile))
               for values, quantile in ((colours, config.spread_quantile), (hues, config.hue_quantile))]
    median_contrast = torch.full((count,), torch.nan, dtype=torch.float64, device=points.device)
    if contrast is not None:
        height, width = contrast.shape[1:]
        u = pixel_uv[:, 0].to(torch.int64).clamp(0, width - 1)
        v = pixel_uv[:, 1].to(torch.int64).clamp(0, height - 1)
        per_view = torch.full((count, views), torch.nan, dtype=torch.float32, device=points.device)
        per_view[point_of, view_of] = contrast[view_of, v, u]
        median_contrast[some] = row_nanquantile(per_view[some], 0.5)
    behind = None
    if behind_m > 0:
        behind = _spread_behind(scene, points, view_of, point_of, directions, behind_m, config)
    return Verdict(spreads[0], spreads[1], seen, through_count, outside_count, median_contrast, behind)


def _spread_behind(scene: CarvingScene, points: torch.Tensor, view_of: torch.Tensor, point_of: torch.Tensor,
                   directions: torch.Tensor, behind_m: float, config: CarvingConfig) -> torch.Tensor:
    """Per point: the colour spread its views would see were the surface ``behind_m`` farther along their
    mean line of sight (the same views, the same quantile as :func:`verdict`; NaN where fewer than two of
    them see that point inside their image). Where it is no larger than the spread at the point itself,
    the views cannot tell this depth from a deeper one."""
    mean_dir = torch.zeros_like(points).index_add_(0, point_of, directions)
    mean_dir /= torch.clamp(torch.linalg.vector_norm(mean_dir, dim=1, keepdim=True), min=1e-12)
    deeper = points + behind_m * mean_dir
    u, v, depth = project_torch(scene.cameras.intrinsics, scene.cameras.w2c, deeper.float())  # (V, P) each
    uv = torch.stack([u[view_of, point_of], v[view_of, point_of]], dim=-1)
    inside = in_image(scene.cameras, uv, depth[view_of, point_of])
    return _colour_spread(bilinear(scene.images, view_of[inside], uv[inside]), view_of[inside], point_of[inside],
                          len(points), scene.cameras.count, config.spread_quantile, min_views=2)


def _colour_spread(values: torch.Tensor, view_of: torch.Tensor, point_of: torch.Tensor, points: int, views: int,
                   quantile: float, min_views: int = 1) -> torch.Tensor:
    """Per point: the ``quantile`` of its observations' distances from their per-channel median
    (``values`` (N, 3), one row per observation); NaN where fewer than ``min_views`` observe it."""
    device = values.device
    per_point = torch.full((points, views, 3), torch.nan, dtype=torch.float32, device=device)
    per_point[point_of, view_of] = values.to(torch.float32)
    spread = torch.full((points,), torch.nan, dtype=torch.float64, device=device)
    some = torch.bincount(point_of, minlength=points) >= min_views
    rows = per_point[some]  # (S, V, 3): the per-channel median over views, by rows of (S * 3, V)
    median = row_nanquantile(rows.transpose(1, 2).reshape(-1, views), 0.5).reshape(-1, 3)
    spread[some] = row_nanquantile(torch.linalg.vector_norm(rows - median[:, None], dim=2), quantile)
    return spread


def row_nanquantile(values: torch.Tensor, quantile: float) -> torch.Tensor:
    """``np.nanquantile(values, quantile, axis=1)`` (linear interpolation) for rows (P, V) with at
    least one number each, as a float64 tensor. numpy's own runs a Python function per row when there
    are NaNs (why: docs/design-notes/reconstruct.md#carving-speed)."""
    ordered = torch.sort(values, dim=1).values  # NaNs last
    count = (~torch.isnan(values)).sum(dim=1)
    position = quantile * (count - 1).to(torch.float64)
    below = torch.floor(position).to(torch.int64)
    above = torch.minimum(below + 1, count - 1)
    low = ordered.gather(1, below[:, None])[:, 0]
    high = ordered.gather(1, above[:, None])[:, 0]
    return low + (high - low) * (position - below)
