"""The silhouettes' re-check of a carved solid: a ray through a mask pixel that met the visual hull
must still meet the solid, since the mask says something is on it.

Photo-consistent carving (:mod:`real2sim.reconstruct.carving.photo`) removes voxels whose views
disagree in colour. Views also disagree where the poses are a few millimetres off, and there carving
eats the object's outside from the top down (docs/design-notes/reconstruct.md#mask-recheck).
The masks catch that: the rays through it no longer meet anything. They say only *that* something
is on such a ray, not where, so what is put back is chosen by how the carving went wrong
(:func:`put_back_for_masks`).

World frame, metres; solids are bool arrays of a :class:`~real2sim.multiview.voxel_grid.VoxelGrid`'s
shape. The rays are walked with torch on ``device``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy.ndimage import binary_dilation, binary_erosion

from real2sim.multiview.views import ray_box
from real2sim.multiview.voxel_grid import VoxelGrid, closed_off, voxel_footprint_px
from real2sim.multiview.views import PosedViews, pixel_rays
from real2sim.reconstruct.carving.voxel_rays import VoxelIndex, flat_samples


def put_back_for_masks(views: PosedViews, grid: VoxelGrid, original: np.ndarray, solid: np.ndarray, *,
                       band_voxels: int, max_rounds: int, void_gap_voxels: int,
                       device: str = "cpu") -> np.ndarray:
    """The carved voxels (of ``original & ~solid``) to put back so that every mask ray that met
    ``original`` meets the solid again.

    Where carving went wrong (poses a few millimetres off) it ate the object's outside, and the rays
    through it are deep in what it removed; where it opened a true concavity, the rays it emptied
    graze a rim it lowered by a few voxels (a thin-walled bin), and putting back every carved voxel
    on them lays a lid across the opening at the rim's height. So, round by round, each emptied ray
    gets back only the carved voxels within ``band_voxels`` of the solid (the rim grows back up to
    meet it); a ray that stays further than that from anything, or is still empty after
    ``max_rounds``, gets back every carved voxel on it.

    Growing back only a skin leaves the space behind it carved; carving reached that space only
    through the skin, which the masks have now put back, so what the skin closes off (no way out to
    the grid's sides or top wider than ``2 * void_gap_voxels``: one mask ray per voxel footprint
    leaves gaps that no ray checks) is filled too, unless it was closed off before the put-back;
    filled last, after the whole rays have closed a skin the rounds left unfinished: filled before
    them, its inside would stay hollow (why: docs/design-notes/reconstruct.md#mask-recheck)."""
    cube = np.ones((3, 3, 3), bool)
    now, deep, emptied = solid.copy(), True, None
    rays = _mask_rays(views, grid)
    for _ in range(max_rounds):
        near = binary_dilation(now, cube, iterations=band_voxels) & original & ~now
        # the solid only grows: each round walks just the rays the round before found empty
        put, deep_rays, emptied = _mask_ray_check(views, grid, original, now, device, within=near, only=emptied,
                                                  rays=rays)
        now |= put
        deep = deep_rays > 0
        if not deep or not put.any():
            break
    if deep:
        now |= _mask_ray_check(views, grid, original, now, device, only=emptied, rays=rays).voxels
    if (now != solid).any():
        now |= closed_off(~now, void_gap_voxels) & original & ~closed_off(~solid, void_gap_voxels)
    return now & ~solid


def emptied_rays(views: PosedViews, grid: VoxelGrid, original: np.ndarray, solid: np.ndarray,
                 device: str = "cpu", samples_per_chunk: int = 1 << 21) -> np.ndarray:
    """The carved voxels (``original & ~solid``) on rays through mask pixels that meet ``original``
    but no longer meet ``solid``: the silhouette says something is on each such ray.
    See :func:`_mask_ray_check`."""
    return _mask_ray_check(views, grid, original, solid, device, samples_per_chunk).voxels


class _RayCheck(NamedTuple):
    """What :func:`_mask_ray_check` found: the carved ``voxels`` to put back (bool, grid shape); how
    many emptied rays meet none of them (``unmet_rays``, 0 without ``within``); and per view, which
    of its rays that cross the object's box were emptied (bool tensors, in the order the rays are
    made), to pass back as ``only``."""

    voxels: np.ndarray
    unmet_rays: int
    emptied: list


def _mask_rays(views: PosedViews, grid: VoxelGrid) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per view, the (origins, directions) of the rays :func:`_mask_ray_check` walks: one per mask pixel,
    at most one per voxel footprint, none within a footprint of the mask's edge."""
    footprint_px = voxel_footprint_px(views, grid)
    stride = max(1, int(footprint_px))
    margin = np.ones((2 * int(np.ceil(footprint_px)) + 1,) * 2, bool)
    rays = []
    for i in range(views.count):
        v_px, u_px = np.nonzero(binary_erosion(views.mask[i] >= 0.5, margin)[::stride, ::stride])
        rays.append(pixel_rays(views.intrinsics, views.c2w_cv[i], u_px * stride + 0.5, v_px * stride + 0.5))
    return rays


def _mask_ray_check(views: PosedViews, grid: VoxelGrid, original: np.ndarray, solid: np.ndarray,
                    device: str = "cpu", samples_per_chunk: int = 1 << 21,
                    within: np.ndarray | None = None, only: list | None = None,
                    rays: list | None = None) -> _RayCheck:
    """The carved voxels (``original & ~solid``, and in ``within`` where given) on rays through mask
    pixels that meet ``original`` but no longer meet ``solid``, and how many such rays meet none of
    those voxels (0 when ``within`` is None). ``only``: walk just these rays (a previous call's
    ``emptied``): a ray that meets the solid, or misses ``original``, does so for any larger solid.

    One ray per mask pixel, at most one per voxel footprint (a finer stride only repeats rays),
    sampled every half voxel from where it enters the grid's box. Pixels within a voxel footprint of the
    mask's edge cast none: their rays graze the object, and on voxels they may miss a thin rim
    that the true object has (on a bowl they put back specks of the lid carving removed).

    Each ray is walked only across the box around ``original`` (outside it nothing can change a
    verdict), as one flat list of samples for all rays of a view rather than a padded (rays, steps)
    array: the same samples, several times faster (on ``device``). ``rays``: :func:`_mask_rays` of
    ``views`` and ``grid``, made once for many calls, so that the masks are not eroded again on each
    (why: docs/design-notes/reconstruct.md#carving-speed)."""
    carved = original & ~solid
    if within is not None:
        carved = carved & within
    if not (original & ~solid).any():
        return _RayCheck(np.zeros(original.shape, bool), 0, [None] * views.count)
    index = VoxelIndex(grid, device)
    step_m = 0.5 * grid.voxel_m
    last_step = int(np.ceil(np.linalg.norm(np.asarray(grid.shape)) * 2))
    box_t = index.occupied_box(original)
    original_f, solid_f, carved_f = (index.tensor(a.ravel(), torch.bool) for a in (original, solid, carved))
    restore_f, unmet, emptied_by_view = torch.zeros_like(original_f), 0, []
    grid_lo, grid_hi = index.lo, index.lo + index.shape * grid.voxel_m
    for i, view_rays in enumerate(rays if rays is not None else _mask_rays(views, grid)):
        o, d = (index.tensor(a) for a in view_rays)
        near, far = ray_box(o, d, grid_lo, grid_hi)
        enter, leave = ray_box(o, d, *box_t)
        # the step numbers k (t = near + k * step) whose samples can fall in the box, a step to spare each side
        first = torch.clamp(torch.floor((enter - near) / step_m) - 1, 0, last_step).to(torch.int64)
        last = torch.clamp(torch.ceil((leave - near) / step_m) + 1, 0, last_step).to(torch.int64)
        count = last - first + 1
        crosses = leave > enter
        o, d, near, far, first, count = (a[crosses] for a in (o, d, near, far, first, count))
        emptied_here = torch.zeros(len(o), dtype=torch.bool, device=device)
        emptied_by_view.append(emptied_here)
        walked = torch.arange(len(o), device=device)
        if only is not None:
            walked = walked if only[i] is None else walked[only[i]]
            o, d, near, far, first, count = (a[walked] for a in (o, d, near, far, first, count))
        for r, ray, t in flat_samples(near + first.to(near.dtype) * step_m, count, step_m, samples_per_chunk):
            cells, in_grid = index.cells(o[r][ray] + t[:, None] * d[r][ray])
            inside = (t <= far[r][ray]) & in_grid

            def meets(occupancy):
                hits = torch.zeros(len(r), dtype=torch.int64, device=device)
                return hits.index_add_(0, ray, (occupancy[cells] & inside).to(torch.int64)) > 0

            emptied = meets(original_f) & ~meets(solid_f)
            emptied_here[walked[r]] = emptied
            restore_f[cells[emptied[ray] & carved_f[cells] & inside]] = True
            if within is not None:
                unmet += int((emptied & ~meets(carved_f)).sum())
    return _RayCheck(restore_f.cpu().numpy().reshape(original.shape), unmet, emptied_by_view)
