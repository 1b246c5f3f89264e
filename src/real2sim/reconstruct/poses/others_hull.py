"""The others' hull: the visual hull each view is aligned to when every pose comes from the silhouettes
(:func:`real2sim.reconstruct.poses.silhouette.align_all`), carved by all the other views, and how fine it is.

The views are fitted to it by :mod:`real2sim.reconstruct.poses.view_fit`. World frame, metres.
"""

from __future__ import annotations

import numpy as np

from real2sim.multiview.views import PosedViews

#: Voxels along the longest side of the others' hull the rounds align to (near cameras)
ALL_VOXELS = 96
#: ... and, for cameras too far to be moved along their axes (``FAR_RATIO``), finer where a voxel would span
#: more than this many pixels in a typical view, up to ALL_MAX_VOXELS: the rounds cannot align a view closer
#: than the others' hull is fine. Near cameras keep ALL_VOXELS (why: docs/design-notes/reconstruct.md#others-hull).
ALL_VOXEL_PX = 1.5
ALL_MAX_VOXELS = 160

#: Cameras farther from the object than this many times its size (median view) are not moved along their
#: optical axes by the rounds: through a long lens that move only scales the silhouette a little, and the
#: one-sided fit, which lets a camera come closer to cover its mask at almost no cost, walks them toward the
#: object round after round (why: docs/design-notes/reconstruct.md#others-hull). Nearer cameras see depth by
#: perspective.
FAR_RATIO = 8.0


def others_hull_box(region: tuple[np.ndarray, np.ndarray], table_z_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi, metres) the others' hull is carved in: ``region`` (the one all views agree on) with a
    tenth of its size added on every side, as the others' hull may reach past it, and not below the table."""
    pad = 0.1 * (region[1] - region[0])
    lo, hi = region[0] - pad, region[1] + pad
    if table_z_m is not None:
        lo[2] = max(lo[2], table_z_m)
    return lo, hi


def cameras_far(c2w_cv: np.ndarray, region: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the cameras (N, 4, 4) stand farther from the box ``region`` (lo, hi, metres) than ``FAR_RATIO``
    times its longest side (median camera)."""
    lo, hi = (np.asarray(a, dtype=float) for a in region)
    distance = float(np.median(np.linalg.norm(c2w_cv[:, :3, 3] - 0.5 * (lo + hi), axis=1)))
    return distance >= FAR_RATIO * max(float(np.max(hi - lo)), 1e-9)


def rounds_hull_voxels(views: PosedViews, region: tuple[np.ndarray, np.ndarray], table_z_m: float | None,
                       far: bool | None = None) -> int:
    """Voxels along the longest side of the others' hull the rounds align to, ``region`` being the box all
    views agree on: ``ALL_VOXELS`` for near cameras, :func:`others_hull_voxels` of its box for far ones
    (``far``: that verdict when the caller holds it; None: :func:`cameras_far` of ``region``)."""
    if not (cameras_far(views.c2w_cv, region) if far is None else far):
        return ALL_VOXELS
    return others_hull_voxels(views, *others_hull_box(region, table_z_m))


def others_hull_voxels(views: PosedViews, lo_m: np.ndarray, hi_m: np.ndarray) -> int:
    """Voxels along the longest side of the box [lo, hi] (metres) for the others' hull: ``ALL_VOXELS``, or as
    many as keep a voxel within ``ALL_VOXEL_PX`` pixels in a typical view (at the median camera distance from
    the box's centre), at most ``ALL_MAX_VOXELS``."""
    centre = 0.5 * (np.asarray(lo_m) + np.asarray(hi_m))
    pixel_m = float(np.median(np.linalg.norm(views.c2w_cv[:, :3, 3] - centre, axis=1))) / views.intrinsics.fl_x
    wanted = float(np.max(np.asarray(hi_m) - np.asarray(lo_m))) / (ALL_VOXEL_PX * pixel_m)
    return int(np.clip(np.ceil(wanted), ALL_VOXELS, ALL_MAX_VOXELS))


def leave_one_out_surfaces(views: PosedViews, *, outlier_fraction: float, table_z_m: float | None,
                           voxels: int | None = None, region: tuple[np.ndarray, np.ndarray] | None = None
                           ) -> tuple[list[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Per view, (P_i, 3) centres (metres, world) of the boundary voxels of the visual hull carved by the
    other views: a point is inside when at most ``outlier_fraction`` of the others that see it (at
    least 3) put it outside their masks; and the region all views agree on (:func:`hull.object_region`
    with that tolerance), which the grid covers with a margin."""
    import torch
    from scipy.ndimage import binary_erosion

    from real2sim.multiview.hull import mask_votes, object_region
    from real2sim.multiview.voxel_grid import VoxelGrid

    if region is None:
        region = object_region(views, outlier_fraction=outlier_fraction, table_z_m=table_z_m)
    lo, hi = others_hull_box(region, table_z_m)
    grid = VoxelGrid.covering(lo, hi, voxels or rounds_hull_voxels(views, region, table_z_m), table_z_m)
    centres = grid.centres()
    outside, seen = [], []
    with torch.no_grad():
        for _, _, _, sees, vals in mask_votes(views, centres, 200_000):
            outside.append((sees & (vals < 0.5)).numpy())
            seen.append(sees.numpy())
    outside_v, seen_v = np.concatenate(outside, axis=1), np.concatenate(seen, axis=1)
    outside_n, seen_n = outside_v.sum(axis=0), seen_v.sum(axis=0)
    surfaces = []
    for i in range(views.count):
        others_out, others_seen = outside_n - outside_v[i], seen_n - seen_v[i]
        inside = ((others_seen >= 3) & (others_out <= np.floor(outlier_fraction * others_seen))).reshape(grid.shape)
        surfaces.append(centres[(inside & ~binary_erosion(inside, border_value=0)).ravel()])
    return surfaces, region
