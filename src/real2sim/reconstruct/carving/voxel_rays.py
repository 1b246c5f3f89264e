"""Rays walked through a voxel solid with torch, on any device: the samples of many rays of different
lengths as one flat list, in chunks of bounded size.

Two users: the masks' re-check (``mask_recheck``: does a mask pixel's ray still meet the solid?) and
photo carving's visibility test on a GPU (``carving.views``: does anything of the solid stand between
a camera and a voxel?). On a CPU carving asks Embree instead, on the solid's marching-cubes surface:
there a BVH over a few thousand triangles beats walking every ray; on a GPU the walk is a few
gathers and rebuilding a mesh and a BVH every carving round is what costs.

World frame, metres; solids are bool arrays of a :class:`~real2sim.multiview.voxel_grid.VoxelGrid`'s shape.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

from real2sim.multiview.views import ray_box
from real2sim.multiview.voxel_grid import VoxelGrid


def flat_samples(start: torch.Tensor, count: torch.Tensor, step_m: float, samples_per_chunk: int
                 ) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Per chunk of rays: ``(rays, ray_of, t)``: the indices (R,) of the chunk's rays, the chunk-local
    ray of each sample (S,) and its distance along the ray (S,), ``start[i] + k * step_m`` for
    ``k < count[i]``. A chunk holds whole rays and about ``samples_per_chunk`` samples (more only when
    a single ray has more)."""
    device = start.device
    chunk_of = torch.div(torch.cumsum(count, 0) - 1, samples_per_chunk, rounding_mode="floor")
    for chunk in torch.unique(chunk_of[count > 0]).tolist():
        rays = torch.nonzero((chunk_of == chunk) & (count > 0))[:, 0]
        n = count[rays]
        ray_of = torch.repeat_interleave(torch.arange(len(rays), device=device), n)
        k = torch.arange(len(ray_of), device=device) - torch.repeat_interleave(torch.cumsum(n, 0) - n, n)
        yield rays, ray_of, start[rays][ray_of] + k.to(start.dtype) * step_m


class VoxelIndex:
    """Cell lookups in ``grid`` on ``device``: :meth:`cells` maps points to flat voxel indices and
    whether they fall inside the grid."""

    def __init__(self, grid: VoxelGrid, device: str):
        self.device = device
        self.voxel_m = float(grid.voxel_m)
        shape = np.asarray(grid.shape)
        self.shape = torch.as_tensor(shape, dtype=torch.int64, device=device)
        self.lo_m = np.asarray(grid.origin_m, dtype=float) - 0.5 * grid.voxel_m  # the grid's corner
        self.lo = torch.as_tensor(self.lo_m, dtype=torch.float64, device=device)
        self.strides = torch.as_tensor([shape[1] * shape[2], shape[2], 1], dtype=torch.int64, device=device)

    def tensor(self, a, dtype=torch.float64) -> torch.Tensor:
        if isinstance(a, torch.Tensor):
            return a.to(device=self.device, dtype=dtype)
        return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=self.device)

    def cells(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(flat voxel index (S,), inside the grid (S,)) of ``points`` (S, 3); outside ones get an index
        clamped into the grid."""
        cells = torch.floor((points - self.lo) / self.voxel_m).to(torch.int64)
        inside = ((cells >= 0) & (cells < self.shape)).all(dim=1)
        return (torch.minimum(cells.clamp_min(0), self.shape - 1) * self.strides).sum(dim=1), inside

    def occupied_box(self, solid) -> tuple[torch.Tensor, torch.Tensor]:
        """The corners (lo, hi), metres, of the box around ``solid``'s voxels (an array or a tensor)."""
        if isinstance(solid, torch.Tensor):
            occupied = torch.nonzero(solid).to(torch.float64)
            return (self.lo + occupied.min(dim=0).values * self.voxel_m,
                    self.lo + (occupied.max(dim=0).values + 1) * self.voxel_m)
        occupied = np.argwhere(solid)
        return (self.tensor(self.lo_m + occupied.min(axis=0) * self.voxel_m),
                self.tensor(self.lo_m + (occupied.max(axis=0) + 1) * self.voxel_m))


def segments_clear(solid: np.ndarray, grid: VoxelGrid, origins: np.ndarray, directions: np.ndarray,
                   lengths_m: np.ndarray, device: str = "cpu", samples_per_chunk: int | None = None) -> np.ndarray:
    """(N,) bool: whether the segment ``origins + t * directions``, ``0 <= t <= lengths_m`` (unit
    directions, metres), stays outside ``solid`` (:func:`segments_blocked`, on arrays)."""
    index = VoxelIndex(grid, device)
    blocked = segments_blocked(index.tensor(solid, torch.bool), grid, index.tensor(origins), index.tensor(directions),
                               index.tensor(lengths_m), samples_per_chunk)
    return ~blocked.cpu().numpy()


def segments_blocked(solid: torch.Tensor, grid: VoxelGrid, origins: torch.Tensor, directions: torch.Tensor,
                     lengths_m: torch.Tensor, samples_per_chunk: int | None = None) -> torch.Tensor:
    """(N,) bool tensor: whether the segment ``origins + t * directions``, ``0 <= t <= lengths_m`` (float64
    tensors, unit directions, metres), meets ``solid`` (bool tensor, ``grid.shape``, on their device) --
    where its trilinear interpolation is above 0.5 --, sampled every half voxel back from its end across
    the box around the solid (outside it there is nothing to meet). A segment that starts inside the
    solid is blocked."""
    device = origins.device
    if len(origins) == 0 or not bool(solid.any()):
        return torch.zeros(len(origins), dtype=torch.bool, device=device)
    if samples_per_chunk is None:  # a chunk's temporaries take about 100 bytes a sample
        samples_per_chunk = 1 << 22 if device.type == "cpu" else 1 << 23
    index = VoxelIndex(grid, device)
    o, d, length = origins, directions, lengths_m
    enter, leave = ray_box(o, d, *index.occupied_box(solid))
    step_m = 0.5 * index.voxel_m
    end = torch.minimum(leave, length)
    count = torch.where(end >= enter, torch.floor((end - enter) / step_m).to(torch.int64) + 1, 0)
    # trilinear, as the marching-cubes surface Embree would test against: its level-0.5 surface cuts
    # the voxels' corners where a cube's would stand proud (why: docs/design-notes/reconstruct.md#voxel-rays)
    occupancy = solid.permute(2, 1, 0)[None, None].to(torch.float64).contiguous()  # (1, 1, Z, Y, X)
    to_unit = 2.0 / torch.clamp(index.shape - 1, min=1).to(torch.float64)
    centre_0 = index.lo + 0.5 * index.voxel_m
    blocked = torch.zeros(len(o), dtype=torch.bool, device=device)
    # counted back from the segment's end, so that its last sample is the end itself: a surface just
    # short of it is met whatever the box's entry (why: docs/design-notes/reconstruct.md#voxel-rays)
    start = end - (count - 1).clamp_min(0).to(end.dtype) * step_m
    for rays, ray_of, t in flat_samples(start, count, step_m, samples_per_chunk):
        at = ((o[rays][ray_of] + t[:, None] * d[rays][ray_of] - centre_0) / index.voxel_m) * to_unit - 1.0
        value = torch.nn.functional.grid_sample(occupancy, at.view(1, -1, 1, 1, 3), mode="bilinear",
                                                padding_mode="zeros", align_corners=True).view(-1)
        hits = torch.zeros(len(rays), dtype=torch.int64, device=device)
        blocked[rays] = hits.index_add_(0, ray_of, (value > 0.5).to(torch.int64)) > 0
    return blocked
