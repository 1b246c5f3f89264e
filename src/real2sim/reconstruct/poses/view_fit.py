"""One view's camera moved onto a visual hull until the hull, projected into it, covers its mask: the fit
under both ways of finding poses from silhouettes (:mod:`real2sim.reconstruct.poses.silhouette`).

The camera moves by a small rigid motion in its own frame. The loss is one-sided: a hull carved by other
views contains the object, so at the true pose it covers the whole mask and spills over it where no view
cut the hull tight (on a box, above its top edges as a low view sees them); a symmetric silhouette fit
centres the mask in that spill and moves the camera off. Mask pixels the hull leaves uncovered cost
fully, hull pixels outside the mask cost ``SPILL_WEIGHT`` (why: docs/design-notes/reconstruct.md#unrefined-views).

World frame, metres; cameras are camera-to-world with OpenCV axes, as in :mod:`real2sim.multiview.views`.
"""

from __future__ import annotations

import numpy as np

from real2sim.multiview.views import PosedViews, project

#: The cost of a hull pixel outside the mask, against 1 for a mask pixel the hull leaves uncovered.
SPILL_WEIGHT = 0.03
#: Both silhouettes are blurred by a Gaussian of this sigma (pixels) before they are compared.
BLUR_PX = 1.5
# the search's units: one unit is about the robot's pose noise (a degree, 5 mm)
STEP_DEG, STEP_MM = 1.0, 5.0


def hull_surface_points(views: PosedViews, *, outlier_fraction: float, table_z_m: float,
                        longest_side_voxels: int = 160, device: str = "cpu") -> np.ndarray:
    """(P, 3) centres of the visual hull's boundary voxels (metres, world frame), the hull scored on ``device``."""
    from scipy.ndimage import binary_erosion

    from real2sim.multiview.hull import carve, object_region
    from real2sim.multiview.voxel_grid import VoxelGrid

    lo, hi = object_region(views, outlier_fraction=outlier_fraction, table_z_m=table_z_m, device=device)
    grid = VoxelGrid.covering(lo, hi, longest_side_voxels, table_z_m)
    inside = carve(views, grid, outlier_fraction, device=device) >= 0.5
    boundary = inside & ~binary_erosion(inside, border_value=0)
    return grid.centres()[boundary.ravel()]


def splatted_silhouette(views: PosedViews, c2w_cv: np.ndarray, points_m: np.ndarray,
                        window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """(H, W) float silhouette in [0, 1]: each point's projection shared bilinearly among its
    four nearest pixel centres, clipped at 1, so the image moves continuously with the camera.
    ``window``: (u0, v0, u1, v1) px, only that part of the image (shape (v1 - v0, u1 - u0))."""
    k = views.intrinsics
    u_off, v_off, u_end, v_end = window if window is not None else (0, 0, k.width, k.height)
    h, w = v_end - v_off, u_end - u_off
    uv, depth = project(k, c2w_cv[None], points_m)
    front = depth[0] > 0
    u = uv[0, front, 0].astype(np.float64) - 0.5 - u_off  # pixel centres at integers
    v = uv[0, front, 1].astype(np.float64) - 0.5 - v_off
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


def align_view(views: PosedViews, index: int, points_m: np.ndarray, *, max_evaluations: int = 300,
               along_axis: bool = True, spill_weight: float = SPILL_WEIGHT) -> tuple[np.ndarray, float]:
    """View ``index``'s camera moved so ``points_m`` (the refined views' hull) cover its mask, and the
    share of its mask the moved hull covers. ``along_axis`` False: the camera is not moved along its
    optical axis (see :data:`real2sim.reconstruct.poses.others_hull.FAR_RATIO`)."""
    from scipy.ndimage import binary_closing, gaussian_filter
    from scipy.optimize import minimize

    start = views.c2w_cv[index]
    window = _fit_window(views, index, start, points_m)
    u0, v0, u1, v1 = window
    mask = views.mask[index, v0:v1, u0:u1].astype(np.float64)
    target = gaussian_filter(mask, BLUR_PX)
    scale = mask.size / float(views.mask[index].size)  # the loss stays a mean over the whole image

    free = 6 if along_axis else 5  # the step's last component is the move along the optical axis

    def full(step: np.ndarray) -> np.ndarray:
        return np.concatenate([step, np.zeros(6 - free)])

    def loss(step: np.ndarray) -> float:
        diff = gaussian_filter(splatted_silhouette(views, moved_camera(start, full(step)), points_m, window),
                               BLUR_PX) - target
        return scale * float(np.mean(np.minimum(diff, 0.0) ** 2) + spill_weight * np.mean(np.maximum(diff, 0.0) ** 2))

    result = minimize(loss, np.zeros(free), method="Powell",
                      options={"xtol": 1e-2, "ftol": 1e-7, "maxfev": max_evaluations})
    c2w = moved_camera(start, full(result.x))
    covered = binary_closing(splatted_silhouette(views, c2w, points_m) > 0, np.ones((3, 3), bool))
    whole = views.mask[index]
    coverage = float((whole * covered).sum() / max(whole.sum(), 1e-9))
    return c2w, coverage


def _fit_window(views: PosedViews, index: int, c2w_cv: np.ndarray, points_m: np.ndarray) -> tuple[int, int, int, int]:
    """(u0, v0, u1, v1) px: the part of view ``index`` that holds its mask and ``points_m`` as the camera
    sees them now, with room for the fit to move them (half their size, at least 16 px): the loss is
    the same there as over the whole image, and a small object's fit costs its own size, not the image's."""
    k = views.intrinsics
    ys, xs = np.nonzero(views.mask[index] >= 0.5)
    uv, depth = project(k, c2w_cv[None], points_m)
    uv = uv[0, depth[0] > 0]
    us = np.concatenate([xs + 0.5, uv[:, 0]])
    vs = np.concatenate([ys + 0.5, uv[:, 1]])
    if not len(us):
        return 0, 0, k.width, k.height
    pad = max(16.0, 0.5 * max(us.max() - us.min(), vs.max() - vs.min()))
    return (int(np.clip(np.floor(us.min() - pad), 0, k.width)), int(np.clip(np.floor(vs.min() - pad), 0, k.height)),
            int(np.clip(np.ceil(us.max() + pad), 0, k.width)), int(np.clip(np.ceil(vs.max() + pad), 0, k.height)))
