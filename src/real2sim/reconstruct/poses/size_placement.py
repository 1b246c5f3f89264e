"""Where the object stands among far cameras whose every pose came from their silhouettes: from how
large it looks in each view (used by :func:`real2sim.reconstruct.poses.silhouette.align_all`).

The views agree with each other in any frame (:mod:`real2sim.reconstruct.poses.silhouette`), and the rig
motion taken out after each round keeps the cameras where the given poses put them; but where the object stands *among* them is not a motion of the
rig. Through a long lens each view's turn hides it: a degree's turn and a 22 mm sideways shift of the object
give the same image 1.3 m away, so the common point the views are turned onto is only as sure as the mean of
their given orientations (docs/design-notes/reconstruct.md#size-placement), and the rounds do not move it
(cameras that far are not moved along their axes).
What the turns do not hide is the distance: the object looks larger from a camera it is nearer to, and the
camera centres are known to millimetres. With the placed object at truth + d, log(mask size / size of the
placed hull's projection) in view i is -d . u_i / r_i (u_i the unit vector from the object to camera i, r_i
its distance) and a constant. Parts of that ratio that come from the shape (the hull spills over the object
more from some sides) are alike from opposite sides through a long lens (an orthographic silhouette and its
mirror image have one size), so they are fitted as even functions of u_i and the offset, odd, is what is
left. Directions the cameras do not spread over (the vertical of a single ring, whatever its elevation:
u_i . z is the same for every view) cannot be told from the constant and are not searched.
The hull is carved from the views as they stand, so it follows a move in part: moving the object takes
out only a share of the offset the sizes saw, and that share varies with the capture
(docs/design-notes/reconstruct.md#size-placement). So it is measured, not assumed: the object is moved by
a probe along each searched direction and the change of the offset read (a Jacobian by finite
differences); the move is the offset over the mean share. Sizes that do not follow the moves (masks larger from one side whatever the placement) are not
believed, and the cameras are left as they came.

World frame, metres; cameras are camera-to-world with OpenCV axes, as in :mod:`real2sim.multiview.views`.
"""

from __future__ import annotations

import numpy as np

from real2sim.reconstruct.poses.centring import mask_centres, turned_onto
from real2sim.reconstruct.poses.view_fit import hull_surface_points, splatted_silhouette
from real2sim.multiview.views import PosedViews, project

SIZE_VOXELS = 160
#: The hull the sizes are compared with is carved with this tolerance: with the 0.15 of the rounds it spills
#: further from some sides than others (why: docs/design-notes/reconstruct.md#size-placement).
SIZE_OUTLIER_FRACTION = 0.03
#: Fewer views with the whole object in frame than this: the sizes are not used.
SIZE_MIN_VIEWS = 12
#: A direction along which the cameras' directions from the object spread less than this share of the most
#: (variance) is one they do not spread over: the object is not moved along it.
SIZE_MIN_SPREAD_SHARE = 0.05
#: The probe move, as a share of the hull's longest side (2.4 mm on a 12 cm can).
PROBE_SHARE = 0.02
#: A probe must take out between these shares of itself from the offset the sizes see (see above).
MIN_RESPONSE, MAX_RESPONSE = 0.1, 2.0
#: Steps (each re-measures the offset and moves by it over the share).
SIZE_STEPS = 2
#: The sizes may move the object this many times as far as the given poses leave it uncertain. Not 3: that
#: uncertainty is estimated from a median miss, and the move (the offset over the probes' share) carries the
#: share's own error (why: docs/design-notes/reconstruct.md#size-placement).
SIZE_MAX_SIGMAS = 4.0


def silhouette_size_px(views: PosedViews, c2w_cv: np.ndarray, points_m: np.ndarray) -> float:
    """sqrt of the area (px) the points (a surface's boundary voxels, dense enough to leave no gaps once
    closed) cover seen from ``c2w_cv``."""
    from scipy.ndimage import binary_closing

    covered = binary_closing(splatted_silhouette(views, c2w_cv, points_m) > 0, np.ones((3, 3), bool))
    return float(np.sqrt(covered.sum()))


def searched_directions(views: PosedViews, centre_m: np.ndarray) -> np.ndarray:
    """(3, k) orthonormal world directions the cameras' directions from ``centre_m`` spread over (see the
    module docstring): k = 2 for a single ring, 3 for a hemisphere."""
    arm = views.c2w_cv[:, :3, 3] - centre_m
    distance = np.linalg.norm(arm, axis=1)
    directions = arm / distance[:, None] * (np.median(distance) / distance)[:, None]
    spread, axes = np.linalg.eigh(np.cov(directions.T))
    return axes[:, spread > SIZE_MIN_SPREAD_SHARE * spread.max()]


def size_offset(views: PosedViews, points_m: np.ndarray, use: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, float]:
    """(k,) metres along ``axes`` ((3, k), :func:`searched_directions`): how far the object stands from
    where ``points_m`` (its hull as the views place it now) is, as the sizes of the views ``use`` (bool (N,):
    those with the whole object in frame) see it at first order; and the fit's residual RMS (log size)."""
    ref = points_m.mean(axis=0)
    index = np.nonzero(use)[0]
    mask_size = np.sqrt((views.mask[index] >= 0.5).reshape(len(index), -1).sum(axis=1))
    model_size = np.array([silhouette_size_px(views, views.c2w_cv[i], points_m) for i in index])
    ok = (mask_size > 0) & (model_size > 0)
    arm = views.c2w_cv[index[ok], :3, 3] - ref
    distance = np.linalg.norm(arm, axis=1)
    typical = float(np.median(distance))
    along = (arm / distance[:, None] * (typical / distance)[:, None]) @ axes  # u_i . axis, scaled by r / r_i
    k = along.shape[1]
    # even terms of the shape: a constant and the traceless quadratic forms (the trace is the constant again,
    # up to the small spread the cameras have along the directions not searched, which it must not fit)
    even = [along[:, i] * along[:, j] * 2.0 for i in range(k) for j in range(i + 1, k)]
    even += [along[:, i] ** 2 - along[:, i + 1] ** 2 for i in range(k - 1)]
    design = np.column_stack([along, np.ones(len(along)), *even])
    y = np.log(mask_size[ok] / model_size[ok])
    solution = np.linalg.lstsq(design, y, rcond=1e-6)[0]
    residual = y - design @ solution
    # log(mask / model) = -d . u / r: where the object looks larger than the placed hull, it is nearer that
    # camera than placed; the offset asked for is -d
    return typical * solution[:axes.shape[1]], float(np.sqrt(np.mean(residual ** 2)))


def object_moved(views: PosedViews, from_m: np.ndarray, to_m: np.ndarray) -> np.ndarray:
    """(N, 4, 4) each camera of ``views`` turned about its own centre, the least turn, so ``to_m`` is seen
    where ``from_m`` is now: the object they see together moves by ``to_m - from_m``."""
    uv, _ = project(views.intrinsics, views.c2w_cv, from_m[None])
    return turned_onto(views, to_m, uv[:, 0], np.ones((views.count, 2), dtype=bool))


def placed_by_size(views: PosedViews, *, max_move_m: float, voxels: int = SIZE_VOXELS,
                   outlier_fraction: float = SIZE_OUTLIER_FRACTION, steps: int = SIZE_STEPS,
                   progress=None) -> tuple[np.ndarray, dict]:
    """(N, 4, 4) the cameras of ``views`` turned so the object stands among them where its sizes in the
    views say (see the module docstring), and a report; as they are when too few views hold the whole object,
    the sizes do not follow the object's moves, or they ask for a move longer than ``max_move_m`` (metres:
    what the given poses leave uncertain, :func:`size_move_bound_m`; a size a mask recipe biases on one
    side of the rig by a per cent reads as a centimetre at a metre)."""
    from dataclasses import replace

    _, whole, _ = mask_centres(views)
    use = whole.all(axis=1)
    if use.sum() < SIZE_MIN_VIEWS:
        return views.c2w_cv.copy(), {"moved": False, "reason": f"{int(use.sum())} views hold the whole object "
                                                               f"(at least {SIZE_MIN_VIEWS} needed)"}
    probes = 3 + steps + 1  # hulls carved: the start, a probe per direction (at most 3), a step each
    done = 0

    def hull(c2w: np.ndarray) -> np.ndarray:
        nonlocal done
        if progress:
            progress("where the object stands, from its sizes", done, probes)
        done += 1
        return hull_surface_points(replace(views, c2w_cv=c2w), outlier_fraction=outlier_fraction, table_z_m=None,
                                   longest_side_voxels=voxels)

    def seen(c2w: np.ndarray, points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(the object's centre, its offset along the axes, the fit's residual) with the cameras ``c2w``."""
        points = hull(c2w) if points is None else points
        offset, residual = size_offset(replace(views, c2w_cv=c2w), points, use, axes)
        return points.mean(axis=0), offset, residual

    points = hull(views.c2w_cv)
    axes = searched_directions(views, points.mean(axis=0))
    probe_m = PROBE_SHARE * float(np.ptp(points, axis=0).max())
    centre, offset, residual = seen(views.c2w_cv, points)
    jacobian = np.zeros((axes.shape[1], axes.shape[1]))
    for j in range(axes.shape[1]):
        _, probed, _ = seen(object_moved(views, centre, centre + probe_m * axes[:, j]))
        jacobian[:, j] = (probed - offset) / probe_m
    # a probe moves the object; the offset the sizes see should drop by a share of it: -J, near g * I
    response = np.linalg.eigvalsh(-0.5 * (jacobian + jacobian.T))
    report = {"searched_axes": [[round(float(x), 4) for x in axis] for axis in axes.T],
              "probe_mm": round(1000.0 * probe_m, 3), "response": [round(float(x), 3) for x in sorted(response)],
              "offset_seen_mm": [round(1000.0 * float(x), 3) for x in axes @ offset],
              "size_residual_rms": round(residual, 5), "views": int(use.sum())}
    if response.min() < MIN_RESPONSE or response.max() > MAX_RESPONSE:
        return views.c2w_cv.copy(), {**report, "moved": False, "reason": (
            f"the sizes did not follow the object's moves (a probe took out {100 * response.min():.0f}-"
            f"{100 * response.max():.0f} % of itself, {100 * MIN_RESPONSE:.0f}-{100 * MAX_RESPONSE:.0f} % expected): "
            "left as aligned")}
    # the share is the mean over the probes: by a ring's symmetry it is one number across it, and the
    # probes' own scatter makes the full Jacobian's step too long (why: docs/design-notes/reconstruct.md#size-placement)
    share = float(np.mean(response))
    first = axes @ (offset / share)
    if np.linalg.norm(first) > max_move_m:
        return views.c2w_cv.copy(), {**report, "moved": False, "reason": (
            f"the sizes ask to move the object {1000 * np.linalg.norm(first):.1f} mm, more than the given poses "
            f"leave uncertain ({1000 * max_move_m:.1f} mm): the masks' sizes differ from one side to another; "
            "left as aligned")}
    c2w, total, taken = views.c2w_cv.copy(), np.zeros(3), []
    for _ in range(steps):
        move = axes @ (offset / share)
        c2w = object_moved(replace(views, c2w_cv=c2w), centre, centre + move)
        total += move
        taken.append(round(1000.0 * float(np.linalg.norm(move)), 3))
        centre, offset, residual = seen(c2w)
    return c2w, {**report, "moved": True, "moved_mm": [round(1000.0 * float(x), 3) for x in total],
                 "steps_mm": taken, "offset_left_mm": [round(1000.0 * float(x), 3) for x in axes @ offset],
                 "size_residual_rms_after": round(residual, 5)}


def size_move_bound_m(views: PosedViews, centring: dict) -> float:
    """Metres: how far :func:`placed_by_size` may move the object, :data:`SIZE_MAX_SIGMAS` times how
    sure the given poses are of where it stands. Each view's mask centre misses the views' common point
    by about its orientation error times the focal length (``centring``'s median miss, before any turn),
    that is by that error times its distance at the object; the common point averages those over the
    views, two directions each."""
    point = np.asarray(centring["point_m"], dtype=float)
    distance = float(np.median(np.linalg.norm(views.c2w_cv[:, :3, 3] - point, axis=1)))
    per_view_m = float(centring["median_miss_px"]) / views.intrinsics.fl_x * distance
    return SIZE_MAX_SIGMAS * per_view_m * float(np.sqrt(2.0 / max(int(centring["views_with_whole_mask"]), 1)))
