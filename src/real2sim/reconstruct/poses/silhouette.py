"""Poses from the masks, for the views whose poses refine-poses could not refine.

`refine-poses` marks a frame it could not register (too few triangulated features: on a 3.5 cm box, the
low ring of views sees mostly the box's narrow sides) and leaves the robot's pose on it, a few millimetres
and a degree off. Such a view cuts the visual hull where its mask and pose disagree, and leaving it out
loses the only views from its direction (docs/design-notes/reconstruct.md#unrefined-views). So
:func:`align_unrefined` moves each such view's camera onto the visual hull of the refined views
(:func:`real2sim.reconstruct.poses.view_fit.align_view`). A view whose mask the moved hull still leaves
more than ``1 - min_coverage`` uncovered is left out: its mask or its pose is wrong in a way a small
motion does not explain. When refine-poses refined (almost) none, :func:`align_all` aligns every view
to the others (below).

World frame, metres; cameras are camera-to-world with OpenCV axes, as in :mod:`real2sim.multiview.views`.
"""

from __future__ import annotations

import warnings

import numpy as np

from real2sim.formats.dataset import pose_errors
from real2sim.plumbing.errors import UserInputError
from real2sim.reconstruct.poses.centring import centre_views
from real2sim.reconstruct.poses.others_hull import cameras_far, leave_one_out_surfaces, rounds_hull_voxels
from real2sim.reconstruct.poses.size_placement import placed_by_size, size_move_bound_m
from real2sim.reconstruct.poses.view_fit import align_view, hull_surface_points
from real2sim.multiview.views import MIN_VIEWS, PosedViews


def align_unrefined(views: PosedViews, *, outlier_fraction: float, table_z_m: float, min_coverage: float = 0.97,
                    progress=None, device: str = "cpu") -> tuple[PosedViews, dict]:
    """``views`` with its unrefined views' cameras moved onto the refined views' visual hull (those whose
    masks it then still leaves uncovered are left out), and a report (per view: coverage of its mask,
    how far its camera moved, kept or not). ``views`` as it is when fewer than 8 views are refined. ``device``:
    where the refined views' hull is scored, most of what this costs on a host CPU
    (why: docs/design-notes/reconstruct.md#unrefined-views)."""
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
# closer (docs/design-notes/reconstruct.md#all-views). That common motion is taken out after each
# round, so the world frame stays the robot's, with its table at z = 0.

#: A point of the others' hull is inside when at most this share of the other views that see it put it outside.
ALL_OUTLIER_FRACTION = 0.15
#: The spill's weight when every view is aligned to the others (``SPILL_WEIGHT`` is for views aligned to a hull
#: of refined views, which contains the object). A view the image border cuts may show one side edge of the
#: object only, and its roll then shows only in how that edge leans: at 0.03 the fit rolled such views until
#: the hull covered a few more mask pixels for hundreds spilled (why: docs/design-notes/reconstruct.md#all-views).
ALL_SPILL_WEIGHT = 0.1
ALL_ROUNDS = 3
#: Fewer views than this are left as given: the others' hull is then too loose to align a view to
#: (why: docs/design-notes/reconstruct.md#all-views).
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
