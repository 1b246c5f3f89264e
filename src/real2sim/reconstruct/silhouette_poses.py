"""Poses for the views COLMAP could not refine, from their masks.

`refine-poses` marks a frame it could not register (too few triangulated features: on a
3.5 cm box, the low ring of views sees mostly the box's narrow sides) and leaves the robot's
pose on it, a few millimetres and a degree off. Such a view cuts the visual hull where its mask
and pose disagree, and leaving it out loses the only views from its direction (the box's
Chamfer rose from 0.35 to 0.56 mm without its low ring).

Here each such view's camera is moved, by a small rigid motion in its own frame, until the
visual hull of the refined views, projected into it, covers its mask. The loss is one-sided:
the refined views' hull contains the object, so at the true pose it covers the whole mask and
spills over it where no refined view cut the hull tight (on the box, above its top edges as a
low view sees them); a symmetric silhouette fit centres the mask in that spill and moves the
camera off. Mask pixels the hull leaves uncovered cost fully, hull pixels outside the mask
cost ``SPILL_WEIGHT``. On 8 of the box's 16 unrefined views the true box's points moved from 3.9 px
(the robot's poses) to 0.9 px from where the true cameras see them (refined views: 0.3 px; with a
symmetric loss, 1.7 px).

A view whose mask the moved hull still leaves more than ``1 - min_coverage`` uncovered is left
out: its mask or its pose is wrong in a way a small motion does not explain.

World frame, metres; cameras are camera-to-world with OpenCV axes, as in :mod:`views`.
"""

from __future__ import annotations

import numpy as np

from real2sim.formats.dataset import pose_errors
from real2sim.reconstruct.views import MIN_VIEWS, PosedViews, project

SPILL_WEIGHT = 0.03
BLUR_PX = 1.5
# the search's units: one unit is about the robot's pose noise (a degree, 5 mm)
STEP_DEG, STEP_MM = 1.0, 5.0


def hull_surface_points(views: PosedViews, *, outlier_fraction: float, table_z_m: float,
                        longest_side_voxels: int = 160) -> np.ndarray:
    """(P, 3) centres of the visual hull's boundary voxels (metres, world frame)."""
    from scipy.ndimage import binary_erosion

    from real2sim.reconstruct.hull import VoxelGrid, carve, object_region

    lo, hi = object_region(views, outlier_fraction=outlier_fraction, table_z_m=table_z_m)
    grid = VoxelGrid.covering(lo, hi, longest_side_voxels, table_z_m)
    inside = carve(views, grid, outlier_fraction) >= 0.5
    boundary = inside & ~binary_erosion(inside, border_value=0)
    return grid.centres()[boundary.ravel()]


def splatted_silhouette(views: PosedViews, c2w_cv: np.ndarray, points_m: np.ndarray) -> np.ndarray:
    """(H, W) float silhouette in [0, 1]: each point's projection shared bilinearly among its
    four nearest pixel centres, clipped at 1, so the image moves continuously with the camera."""
    k = views.intrinsics
    h, w = k.height, k.width
    uv, depth = project(k, c2w_cv[None], points_m)
    front = depth[0] > 0
    u = uv[0, front, 0].astype(np.float64) - 0.5  # pixel centres at integers
    v = uv[0, front, 1].astype(np.float64) - 0.5
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    image = np.zeros(h * w)
    for du, dv, weight in ((0, 0, (1 - fu) * (1 - fv)), (1, 0, fu * (1 - fv)), (0, 1, (1 - fu) * fv), (1, 1, fu * fv)):
        uu, vv = u0 + du, v0 + dv
        ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        image += np.bincount(vv[ok] * w + uu[ok], weights=weight[ok], minlength=h * w)
    return np.minimum(image.reshape(h, w), 1.0)


def moved_camera(c2w_cv: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The camera moved by ``step`` = (rotation vector, translation) in its own frame, in units of
    (``STEP_DEG`` degrees, ``STEP_MM`` millimetres)."""
    from scipy.spatial.transform import Rotation

    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_rotvec(np.radians(STEP_DEG * np.asarray(step[:3]))).as_matrix()
    motion[:3, 3] = STEP_MM * 1e-3 * np.asarray(step[3:])
    return c2w_cv @ motion


def align_view(views: PosedViews, index: int, points_m: np.ndarray, *, max_evaluations: int = 300
               ) -> tuple[np.ndarray, float]:
    """View ``index``'s camera moved so ``points_m`` (the refined views' hull) cover its mask, and the
    share of its mask the moved hull covers."""
    from scipy.ndimage import binary_closing, gaussian_filter
    from scipy.optimize import minimize

    mask = views.mask[index].astype(np.float64)
    target = gaussian_filter(mask, BLUR_PX)
    start = views.c2w_cv[index]

    def loss(step: np.ndarray) -> float:
        diff = gaussian_filter(splatted_silhouette(views, moved_camera(start, step), points_m), BLUR_PX) - target
        return float(np.mean(np.minimum(diff, 0.0) ** 2) + SPILL_WEIGHT * np.mean(np.maximum(diff, 0.0) ** 2))

    result = minimize(loss, np.zeros(6), method="Powell",
                      options={"xtol": 1e-2, "ftol": 1e-7, "maxfev": max_evaluations})
    c2w = moved_camera(start, result.x)
    covered = binary_closing(splatted_silhouette(views, c2w, points_m) > 0, np.ones((3, 3), bool))
    coverage = float((mask * covered).sum() / max(mask.sum(), 1e-9))
    return c2w, coverage


def align_unrefined(views: PosedViews, *, outlier_fraction: float, table_z_m: float, min_coverage: float = 0.97,
                    progress=None) -> tuple[PosedViews, dict]:
    """``views`` with its unrefined views' cameras moved onto the refined views' visual hull (those whose
    masks it then still leaves uncovered are left out), and a report (per view: coverage of its mask,
    how far its camera moved, kept or not). ``views`` as it is when fewer than 8 views are refined."""
    is_unrefined = views.is_unrefined
    unrefined, refined = np.nonzero(is_unrefined)[0], np.nonzero(~is_unrefined)[0]
    if not len(unrefined) or len(refined) < MIN_VIEWS:
        return views, {}
    points = hull_surface_points(views.subset(refined), outlier_fraction=outlier_fraction, table_z_m=table_z_m)
    c2w = views.c2w_cv.copy()
    keep = np.ones(views.count, dtype=bool)
    coverage = np.ones(views.count)
    for n, i in enumerate(unrefined):
        if progress:
            progress("poses of unrefined views", n, len(unrefined))
        c2w[i], coverage[i] = align_view(views, i, points)
        keep[i] = coverage[i] >= min_coverage
    turned_deg, moved_mm = pose_errors(c2w[unrefined], views.c2w_cv[unrefined])
    report = {views.names[i]: {"mask_coverage": round(float(coverage[i]), 4), "kept": bool(keep[i]),
                               "moved_mm": round(float(mm), 3), "turned_deg": round(float(deg), 4)}
              for i, deg, mm in zip(unrefined, turned_deg, moved_mm)}
    moved = PosedViews(views.rgb, views.mask, c2w, views.intrinsics, views.names, views.unrefined)
    return moved.subset(np.nonzero(keep)[0]), report
