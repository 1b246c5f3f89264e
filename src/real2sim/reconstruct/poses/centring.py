"""Every view off by many pixels: the cameras turned onto a common point first, before the views are aligned
to each other (:func:`real2sim.reconstruct.poses.silhouette.align_all`).

Through a long lens a degree of rotation moves the object's image by tens of pixels (29 px at fx = 1650 px),
a quarter of its size: the others' hull that a view is fitted to is then eroded to a sliver, and the fit
pulls every camera toward the object (docs/design-notes/reconstruct.md#common-point). Before the rounds,
each view is turned about its own centre, the least turn, so that one common point projects onto the
centre of its mask. The point is where the views' mask-centre rays meet in least squares (the pose noise's
rotation dominates it, so turning is the correction it asks for); an axis of a mask that touches the image
border has no centre and is neither used nor corrected. A mask's centre is the middle of its extent (0.2
and 99.8 % quantiles): on a body of revolution seen from a level ring it is exactly the projection of a
point on the axis; in general it is not, by a few pixels, which is why it is only used where the views
disagree by more than ``CENTRE_MIN_OFFSET`` of the object's size, and the rounds refine what it leaves.

World frame, metres; cameras are camera-to-world with OpenCV axes, as in :mod:`real2sim.multiview.views`.
"""

from __future__ import annotations

import numpy as np

from real2sim.multiview.views import PosedViews, project, undistorted_normalized
from real2sim.plumbing.errors import UserInputError

#: The views are turned onto a common point when their mask centres miss it by more than this share of the
#: object's size in the image (median view) (why: docs/design-notes/reconstruct.md#common-point).
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
