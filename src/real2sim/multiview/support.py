"""The support plane and the object standing on it, from dense points (:mod:`real2sim.multiview.fusion`).

The cameras look at one region: the point nearest, in least squares, to all their optical axes, and a
radius as large as a median camera's picture is (half its shorter side) at its distance from that point.
The *support plane* is the dominant plane of the points near that region (within twice the radius):
RANSAC over 3-point samples scored by MSAC, the first of the best hypotheses that has at least 90 % of the
cameras on one side and the look-at point on theirs, refitted by least squares on its inliers. The inlier
band is a few pixel footprints of the points (their own spread, not a length in metres): the unit of the
world may be a COLMAP model's. The *object* is the points higher above the plane than a few bands, within
the radius of the look-at point's foot, linked into clusters by a voxel grid of the points' own spacing:
the largest cluster, and every other whose points stand, half of them at least, inside its footprint on the
plane (the convex hull of its points there): a textureless band splits an object into stacked clusters, and a
bottle's neck stands inside the ring of its body's seen surface, not on it; and every cluster within two
cells of it (a handle whose join to the body has no trusted depth). Its height is a high percentile of its points' heights.

Frames: the points' world frame (any unit). The plane is ``normal . x = offset`` with ``normal`` towards
the cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.multiview.fusion import DensePoints
from real2sim.multiview.voxel_grid import voxel_parts
from real2sim.plumbing.errors import UserInputError


@dataclass(frozen=True)
class SupportConfig:
    """How :func:`support_and_object` finds the plane and the object."""

    band_footprints: float = 3.0
    """Half-width of the plane's inlier band, in median pixel footprints of the points near the look-at region
    (> 0): a depth a pixel or two off still counts as on the plane."""
    min_height_bands: float = 3.0
    """A point stands on the plane when it is at least this many bands above it (> 0)."""
    iterations: int = 600
    """RANSAC hypotheses (>= 1)."""
    min_object_points: int = 50
    """An object needs at least this many points (>= 1); fewer: no object stands on the plane."""
    top_percentile: float = 99.0
    """The object's height is this percentile of its points' heights above the plane (50-100): the highest few
    are the noise of the depth."""
    seed: int = 0
    """Seed of the RANSAC samples."""


@dataclass(frozen=True)
class SupportScene:
    """The support plane and the object on it (world units of the points).

    ``normal``: (3,) unit, towards the cameras; ``offset``: the plane is ``normal . x = offset``;
    ``band``: half-width of the inlier band; ``plane_inliers``: points within it; ``look_at``: (3,) the
    cameras' common point; ``radius``: of the region they frame; ``object_index``: (M,) indices of the object's
    points in the :class:`DensePoints`; ``height``: the object's height above the plane; ``centre``: (3,) the
    object's points' footprint centre on the plane.
    """

    normal: np.ndarray
    offset: float
    band: float
    plane_inliers: int
    look_at: np.ndarray
    radius: float
    object_index: np.ndarray
    height: float
    centre: np.ndarray

    def heights(self, points: np.ndarray) -> np.ndarray:
        """(P,) signed distance of ``points`` (P, 3) above the plane."""
        return np.asarray(points) @ self.normal - self.offset


def axes_point(c2w_cv: np.ndarray) -> np.ndarray:
    """(3,) the point nearest, in least squares, to the optical axes of cameras ``c2w_cv`` (V, 4, 4)."""
    centres, axes = c2w_cv[:, :3, 3], c2w_cv[:, :3, 2]
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    return np.linalg.lstsq(proj.sum(axis=0), (proj @ centres[:, :, None]).sum(axis=0)[:, 0], rcond=None)[0]


def framed_radius(c2w_cv: np.ndarray, look_at: np.ndarray, fl_px: float, short_side_px: int) -> float:
    """Half the shorter side of a median camera's picture, in world units at its distance from ``look_at``."""
    distance = np.linalg.norm(c2w_cv[:, :3, 3] - look_at[None], axis=1)
    return float(np.median(distance) * 0.5 * short_side_px / fl_px)


def plane_fit(points: np.ndarray, band: float, camera_centres: np.ndarray, look_at: np.ndarray,
              iterations: int, seed: int) -> tuple[np.ndarray, float, int]:
    """(normal towards the cameras, offset, inliers) of the dominant plane of ``points`` (P, 3) that has the
    cameras on one side and ``look_at`` on theirs (module docstring); UserInputError when none has."""
    rng = np.random.default_rng(seed)
    scored = points if len(points) <= 20_000 else points[rng.choice(len(points), 20_000, replace=False)]
    a, b, c = (scored[rng.integers(0, len(scored), iterations)] for _ in range(3))
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12 * np.maximum(np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - a, axis=1), 1e-300)
    normals, a = normals[ok] / length[ok, None], a[ok]
    offsets = np.einsum("ij,ij->i", normals, a)
    cost = np.concatenate([np.minimum((scored @ normals[s:s + 64].T - offsets[s:s + 64]) ** 2, band ** 2).sum(axis=0)
                           for s in range(0, len(normals), 64)])
    for best in np.argsort(cost):
        normal, offset = normals[best], float(offsets[best])
        side = camera_centres @ normal - offset > 0
        if max(side.mean(), 1.0 - side.mean()) < 0.9:
            continue
        if side.mean() < 0.5:
            normal, offset = -normal, -offset
        if look_at @ normal - offset < -band:
            continue
        for _ in range(3):  # least squares on the inliers, twice the band then the band
            inliers = points[np.abs(points @ normal - offset) <= band]
            if len(inliers) < 3:
                break
            centre = inliers.mean(axis=0)
            fitted = np.linalg.svd(inliers - centre, full_matrices=False)[2][-1]
            normal = fitted if fitted @ normal > 0 else -fitted
            offset = float(normal @ centre)
        return normal, offset, int((np.abs(points @ normal - offset) <= band).sum())
    raise UserInputError("no support plane under the region the cameras look at: no plane of the dense points has "
                         "the cameras on one side")


def support_and_object(dense: DensePoints, c2w_cv: np.ndarray, fl_px: float, short_side_px: int,
                       config: SupportConfig = SupportConfig()) -> SupportScene:
    """The support plane and the object standing on it (module docstring); UserInputError (one line) when no
    object stands on the plane where the cameras look. ``fl_px`` and ``short_side_px``: the focal length and
    the shorter image side of the cameras (pixels, any one size of them)."""
    look_at = axes_point(c2w_cv)
    radius = framed_radius(c2w_cv, look_at, fl_px, short_side_px)
    near = np.linalg.norm(dense.points - look_at, axis=1) <= 2.0 * radius
    if near.sum() < 3 * config.min_object_points:
        raise UserInputError(f"only {int(near.sum())} dense points where the cameras look: the photos do not show "
                             "enough texture to find the table and the object")
    band = config.band_footprints * float(np.median(dense.footprint[near]))
    normal, offset, inliers = plane_fit(dense.points[near], band, c2w_cv[:, :3, 3], look_at, config.iterations,
                                        config.seed)
    height = dense.points @ normal - offset
    foot = look_at - (look_at @ normal - offset) * normal
    along = dense.points - foot
    horizontal = np.linalg.norm(along - (along @ normal)[:, None] * normal, axis=1)
    candidate = np.nonzero((height > config.min_height_bands * band) & (horizontal <= radius))[0]
    members = _object_cluster(dense, candidate, normal)
    if len(members) < config.min_object_points:
        raise UserInputError(f"no object stands on the support plane where the cameras look ({len(members)} dense "
                             f"points above it, at least {config.min_object_points} needed)")
    top = float(np.percentile(height[members], config.top_percentile))
    pts = dense.points[members]
    centre = pts.mean(axis=0)
    centre = centre - (centre @ normal - offset) * normal
    return SupportScene(normal, offset, band, inliers, look_at, radius, members, top, centre)


def _object_cluster(dense: DensePoints, candidate: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Indices of the object's points among ``candidate``: the largest cluster of a voxel grid of the points'
    spacing (four median footprints) and the clusters standing inside its footprint on the plane or within two
    cells of it."""
    if len(candidate) == 0:
        return candidate
    pts = dense.points[candidate]
    voxel = 4.0 * float(np.median(dense.footprint[candidate]))
    cell = np.floor((pts - pts.min(axis=0)) / voxel).astype(np.int64)
    shape = tuple(cell.max(axis=0) + 1)
    if np.prod(shape) > 64_000_000:  # a cloud spread too wide for a grid: no object where the cameras look
        return candidate[:0]
    occupied = np.zeros(shape, bool)
    occupied[tuple(cell.T)] = True
    labels, sizes = voxel_parts(occupied)
    point_label = labels[tuple(cell.T)]
    counts = np.bincount(point_label, minlength=len(sizes))
    counts[0] = 0
    main = int(np.argmax(counts))
    # footprints on the plane: two in-plane axes; the main cluster's is the convex hull of its points there (its
    # points are the surface the cameras saw, a ring around the inside a narrower part above stands on)
    from scipy.spatial import Delaunay, QhullError

    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    plane_xy = np.stack([pts @ u, pts @ np.cross(normal, u)], axis=1)
    keep = np.zeros(len(sizes), bool)
    keep[main] = True
    try:
        footprint = Delaunay(plane_xy[point_label == main])
    except QhullError:  # a main cluster flat in the plane's view: no footprint to stand in
        return candidate[keep[point_label]]
    inside = footprint.find_simplex(plane_xy) >= 0
    # and those that come within two cells of it: a handle whose join to the body has no trusted depth
    from scipy.ndimage import binary_dilation

    touching = np.unique(labels[binary_dilation(labels == main, iterations=2)])
    for label in np.nonzero(counts)[0]:
        if label != main:
            mine = point_label == label
            keep[label] = inside[mine].mean() >= 0.5 or label in touching
    return candidate[keep[point_label]]
