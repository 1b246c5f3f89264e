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

import warnings

import numpy as np

from real2sim.formats.dataset import pose_errors
from real2sim.plumbing.errors import UserInputError
from real2sim.reconstruct.poses.others_hull import cameras_far, leave_one_out_surfaces, rounds_hull_voxels
from real2sim.multiview.views import MIN_VIEWS, PosedViews, project, undistorted_normalized

SPILL_WEIGHT = 0.03
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


def align_unrefined(views: PosedViews, *, outlier_fraction: float, table_z_m: float, min_coverage: float = 0.97,
                    progress=None, device: str = "cpu") -> tuple[PosedViews, dict]:
    """``views`` with its unrefined views' cameras moved onto the refined views' visual hull (those whose
    masks it then still leaves uncovered are left out), and a report (per view: coverage of its mask,
    how far its camera moved, kept or not). ``views`` as it is when fewer than 8 views are refined. ``device``:
    where the refined views' hull is scored (on a GPU's host it was 4.5 of the 5 s this took for one view)."""
    is_unrefined = views.is_unrefined
    unrefined, refined = np.nonzero(is_unrefined)[0], np.nonzero(~is_unrefined)[0]
    if not len(unrefined) or len(refined) < MIN_VIEWS:
        return views, {}
    points = hull_surface_points(views.subset(refined), outlier_fraction=outlier_fraction, table_z_m=table_z_m,
                                 device=device)
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


# --- every view off: silhouette coherence ------------------------------------------------------------
#
# When refine-poses could not refine the capture at all (COLMAP registered too few frames, or its model
# was refused), every pose is the robot's, a few millimetres and a degree off, and there is no set of
# good views to align the others to. The views are then aligned to each other: each view's camera is
# moved (:func:`align_view`) onto the visual hull of all the *other* views, carved with a tolerance
# (``ALL_OUTLIER_FRACTION`` of the views may disagree about a point), and the round is repeated. This is
# the silhouette coherence of Hernandez, Schmitt and Cipolla (2007): at the true poses every mask is
# exactly covered by the projection of the others' hull. The views can agree with each other in any
# frame: a motion of the whole rig (turn, shift, growth about the object) leaves every silhouette the
# same, and the one-sided fit onto a hull that noisy poses have eroded pulls every camera a little
# closer (a growth of -5 % in the first round on a 60-view can). That common motion is taken out after
# each round, so the world frame stays the robot's, with its table at z = 0.

ALL_OUTLIER_FRACTION = 0.15
#: The spill's weight when every view is aligned to the others (``SPILL_WEIGHT`` is for views aligned to a hull
#: of refined views, which contains the object). A view the image border cuts may show one side edge of the
#: object only, and its roll then shows only in how that edge leans: at 0.03 the fit rolled such views until
#: the hull covered a few more mask pixels for hundreds spilled (a second capture of the long-lens bottle: one
#: view 5.5 degrees rolled, 11 px off, the bottle's lower body carved 1-1.5 mm thin, Chamfer 1.52 mm; at 0.1,
#: 0.73 mm). Cut views moved by the robot's noise onto a true hull: worst pixel p90 12.6 -> 3.5 px
#: (tests/reconstruct/test_cut_off_alignment.py).
ALL_SPILL_WEIGHT = 0.1
ALL_ROUNDS = 3
#: Fewer views than this are left as given: the others' hull is then too loose to align a view to
#: (8 views of a can at 64x48 px turned by 3.6 degrees in the first round, three times their noise).
ALL_MIN_VIEWS = 24


def remove_rig_motion(given_c2w: np.ndarray, moved_c2w: np.ndarray, pivot_m: np.ndarray
                      ) -> tuple[np.ndarray, dict]:
    """``moved_c2w`` (N, 4, 4, OpenCV axes) less the motion of the whole rig that best explains how they
    moved from ``given_c2w`` (:func:`view_corrections.rig_motion`: a turn w about ``pivot_m``, a shift t
    and a growth s about it), taken out exactly. Returns the poses and the motion taken out (degrees,
    millimetres, growth as a fraction)."""
    import torch
    from scipy.spatial.transform import Rotation

    from real2sim.reconstruct.field.view_corrections import rig_motion

    arm = given_c2w[:, :3, 3] - pivot_m
    distance_m = float(np.median(np.linalg.norm(arm, axis=1)))
    turn = Rotation.from_matrix(moved_c2w[:, :3, :3] @ np.swapaxes(given_c2w[:, :3, :3], 1, 2)).as_rotvec()
    move = moved_c2w[:, :3, 3] - given_c2w[:, :3, 3]
    w, shift, growth, _ = (t.numpy() for t in rig_motion(torch.from_numpy(turn), torch.from_numpy(move),
                                                          torch.from_numpy(arm), distance_m))
    growth = float(growth)
    rot = Rotation.from_rotvec(w).as_matrix()
    out = moved_c2w.copy()
    out[:, :3, :3] = rot.T @ moved_c2w[:, :3, :3]
    out[:, :3, 3] = pivot_m + ((moved_c2w[:, :3, 3] - pivot_m - shift) @ rot) / (1.0 + growth)
    return out, {"turn_deg": round(float(np.degrees(np.linalg.norm(w))), 4),
                 "shift_mm": round(float(1000.0 * np.linalg.norm(shift)), 3), "growth": round(growth, 5)}


# --- every view off by many pixels: a common point first ---------------------------------------------
#
# Through a long lens a degree of rotation moves the object's image by tens of pixels (29 px at fx = 1650 px),
# a quarter of its size: the others' hull that a view is fitted to is then eroded to a sliver (IoU 0.085 on
# the can), and the fit pulls every camera toward the object (a growth of -23 % taken out in the first round).
# Before the rounds, each view is turned about its own centre, the least turn, so that one common point
# projects onto the centre of its mask. The point is where the views' mask-centre rays meet in least squares
# (the pose noise's rotation dominates it, so turning is the correction it asks for); an axis of a mask that
# touches the image border has no centre and is neither used nor corrected. A mask's centre is the middle of
# its extent (0.2 and 99.8 % quantiles): on a body of revolution seen from a level ring it is exactly the
# projection of a point on the axis; in general it is not, by a few pixels (2.5 px median on the can seen
# from a hemisphere at 256x192 with its true poses), which is why it is only used where the views disagree
# by more than ``CENTRE_MIN_OFFSET`` of the object's size, and the rounds refine what it leaves.

#: The views are turned onto a common point when their mask centres miss it by more than this share of the
#: object's size in the image (median view): 0.16 on the long-lens can at 5 mm / 1 deg, 0.066 on the 60-view
#: can at 256x192.
CENTRE_MIN_OFFSET = 0.10


def mask_centres(views: PosedViews, quantile: float = 0.002) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per view: (N, 2) the middle of its mask's extent (u, v; pixel centres at + 0.5), (N, 2) whether that
    axis is whole (the mask clear of the image border on both sides), (N,) the mask's size (sqrt of its
    area, px; 0 for an empty mask, whose axes are not whole)."""
    n, h, w = views.mask.shape
    centres, whole, size = np.zeros((n, 2)), np.zeros((n, 2), dtype=bool), np.zeros(n)
    for i in range(n):
        ys, xs = np.nonzero(views.mask[i] >= 0.5)
        if len(xs) < 16:
            continue
        for axis, (coord, extent) in enumerate(((xs, w), (ys, h))):
            lo, hi = np.quantile(coord, [quantile, 1.0 - quantile])
            centres[i, axis] = 0.5 * (lo + hi) + 0.5
            whole[i, axis] = coord.min() >= 1 and coord.max() <= extent - 2
        size[i] = np.sqrt(len(xs))
    return centres, whole, size


def common_point(views: PosedViews, centres: np.ndarray, whole: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) world point (metres) nearest, in least squares with Huber weights, to the planes through each
    camera and its mask centre's image line on each whole axis, and (N, 2) each view's miss (px) on its
    whole axes (0 on the others)."""
    k = views.intrinsics
    x, y = undistorted_normalized(k, centres[:, 0], centres[:, 1])  # the centre's line, in the camera's x / z, y / z
    normals, origins = [], []
    for i in range(views.count):
        rot, centre = views.c2w_cv[i, :3, :3], views.c2w_cv[i, :3, 3]
        for axis in np.nonzero(whole[i])[0]:
            n_cam = np.array([1.0, 0.0, -x[i]]) if axis == 0 else np.array([0.0, 1.0, -y[i]])
            normal = rot @ n_cam
            normals.append(normal / np.linalg.norm(normal))
            origins.append(centre)
    if len(normals) < 3:
        raise UserInputError("too few views show their whole mask to find where they look")
    normals, origins = np.asarray(normals), np.asarray(origins)
    weights = np.ones(len(normals))
    for _ in range(4):
        a = np.einsum("k,ki,kj->ij", weights, normals, normals)
        b = np.einsum("k,ki,kj,kj->i", weights, normals, normals, origins)
        point = np.linalg.lstsq(a, b, rcond=None)[0]
        distance = np.abs(np.einsum("ki,ki->k", normals, point - origins))
        scale = 1.4826 * np.median(distance) + 1e-12
        weights = 1.0 / np.maximum(1.0, distance / (2.0 * scale))
    uv, _ = project(k, views.c2w_cv, point[None])
    miss = np.where(whole, uv[:, 0] - centres, 0.0)
    return point, miss


def turned_onto(views: PosedViews, point_m: np.ndarray, centres: np.ndarray, whole: np.ndarray) -> np.ndarray:
    """(N, 4, 4) the cameras of ``views`` each turned about its own centre, the least turn, so ``point_m``
    projects onto its mask's centre on its whole axes (and stays where it is on the others)."""
    from scipy.spatial.transform import Rotation

    k = views.intrinsics
    uv, _ = project(k, views.c2w_cv, point_m[None])
    target = np.where(whole, centres, uv[:, 0])
    out = views.c2w_cv.copy()

    def rays(pixels: np.ndarray) -> np.ndarray:  # (N, 2) px -> (N, 3) unit directions, camera frame
        x, y = undistorted_normalized(k, pixels[:, 0], pixels[:, 1])
        d = np.stack([x, y, np.ones_like(x)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    seen_all, wanted_all = rays(uv[:, 0]), rays(target)  # where the point is seen, where it should be
    for i in range(views.count):
        seen, wanted = seen_all[i], wanted_all[i]
        axis = np.cross(wanted, seen)
        sin = np.linalg.norm(axis)
        if sin < 1e-12:
            continue
        # the camera's axes turned by the rotation taking `wanted` onto `seen`: the point then lies along `wanted`
        turn = Rotation.from_rotvec(axis / sin * np.arctan2(sin, float(wanted @ seen))).as_matrix()
        out[i, :3, :3] = views.c2w_cv[i, :3, :3] @ turn
    return out


def centre_views(views: PosedViews) -> tuple[np.ndarray, dict]:
    """(N, 4, 4) the cameras turned onto the views' common point when they miss it by more than
    ``CENTRE_MIN_OFFSET`` of the object's size (else as they are), and a report."""
    centres, whole, size = mask_centres(views)
    point, miss = common_point(views, centres, whole)
    offset = float(np.median(np.linalg.norm(miss, axis=1)))
    size_px = float(np.median(size[size > 0])) if (size > 0).any() else 0.0
    report = {"point_m": [round(float(x), 5) for x in point], "median_miss_px": round(offset, 2),
              "object_size_px": round(size_px, 1), "views_with_whole_mask": int(whole.all(axis=1).sum())}
    if size_px <= 0 or offset <= CENTRE_MIN_OFFSET * size_px:
        return views.c2w_cv.copy(), {**report, "turned": False}
    return turned_onto(views, point, centres, whole), {**report, "turned": True}


def align_all(views: PosedViews, *, table_z_m: float | None, rounds: int = ALL_ROUNDS,
              outlier_fraction: float = ALL_OUTLIER_FRACTION, max_evaluations: int = 300,
              progress=None) -> tuple[PosedViews, dict]:
    """``views`` with every camera moved so the views' silhouettes agree (see the comment above), and a
    report: per round the rig motion taken out and the median move; per view its coverage and move.
    Views whose masks the others' hull still leaves more than 5 % uncovered keep their move but are
    listed (``poorly_covered``): a mask that is wrong, or a pose a small motion does not explain.
    Cameras too far to be moved along their axes are then turned so the object stands among them where its
    sizes say (:func:`real2sim.reconstruct.poses.size_placement.placed_by_size`)."""
    from dataclasses import replace

    from real2sim.multiview.hull import object_region

    if views.count < ALL_MIN_VIEWS:
        return views, {"method": "none", "reason": f"{views.count} views: too few to align to each other "
                                                   f"(at least {ALL_MIN_VIEWS}); the given poses are used"}
    try:
        c2w, centring = centre_views(views)
    except UserInputError as e:
        c2w, centring = views.c2w_cv.copy(), {"turned": False, "reason": str(e)}
    along_axis = True
    coverage = np.ones(views.count)
    rounds_report = []
    for r in range(rounds):
        current = replace(views, c2w_cv=c2w)
        try:
            region = object_region(current, outlier_fraction=outlier_fraction, table_z_m=table_z_m)
        except UserInputError as e:  # the views agree on no closed region even with the tolerance
            if r == 0:
                return views, {"method": "none", "reason": f"the views' silhouettes do not bound a region ({e}); "
                                                           "the given poses are used"}
            break  # the rounds done so far stand
        if r == 0:
            along_axis = not cameras_far(c2w, region)
        # the round-0 verdict stands for all rounds, as for the moves along the axes
        voxels = rounds_hull_voxels(current, region, table_z_m, far=not along_axis)
        surfaces, (lo, hi) = leave_one_out_surfaces(current, outlier_fraction=outlier_fraction,
                                                    table_z_m=table_z_m, voxels=voxels, region=region)
        moved = c2w.copy()
        for i in range(views.count):
            if progress:
                progress(f"poses of all views, round {r + 1}/{rounds}", i, views.count)
            if len(surfaces[i]):
                moved[i], coverage[i] = align_view(current, i, surfaces[i], max_evaluations=max_evaluations,
                                                   along_axis=along_axis, spill_weight=ALL_SPILL_WEIGHT)
        moved, rig = remove_rig_motion(views.c2w_cv, moved, 0.5 * (lo + hi))
        turned, shifted = pose_errors(moved, c2w)
        rounds_report.append({"rig_motion_removed": rig, "median_turn_deg": round(float(np.median(turned)), 4),
                              "median_move_mm": round(float(np.median(shifted)), 3),
                              "others_hull_voxels": voxels})
        c2w = moved
    placement = {}
    if not along_axis and rounds_report and "median_miss_px" in centring:
        from real2sim.reconstruct.poses.size_placement import placed_by_size, size_move_bound_m

        c2w, placement["by_size"] = placed_by_size(replace(views, c2w_cv=c2w), progress=progress,
                                                   max_move_m=size_move_bound_m(views, centring))
        if not placement["by_size"]["moved"]:
            warnings.warn(f"the object is placed among the cameras by the given poses' mean alone: "
                          f"{placement['by_size']['reason']}", RuntimeWarning, stacklevel=2)
    turned_deg, moved_mm = pose_errors(c2w, views.c2w_cv)
    report = {"method": "silhouette coherence of all views", "centring": centring,
              "moved_along_optical_axes": along_axis, "rounds": rounds_report, "object_placed": placement,
              "poorly_covered": [views.names[i] for i in np.nonzero(coverage < 0.95)[0]],
              "views": {name: {"mask_coverage": round(float(cov), 4), "moved_mm": round(float(mm), 3),
                               "turned_deg": round(float(deg), 4)}
                        for name, cov, deg, mm in zip(views.names, coverage, turned_deg, moved_mm)}}
    return replace(views, c2w_cv=c2w, unrefined=()), report
