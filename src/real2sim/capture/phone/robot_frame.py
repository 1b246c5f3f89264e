"""The robot frame from a capture without a robot: table plane, z up, metres. Pure numpy.

A COLMAP model (a phone capture) has its poses and sparse points in an arbitrary
*model frame*: any rotation, origin and scale. ``real2sim run`` needs the frame a
robot capture has (docs/capture.md): z up, the table top at z = 0, the object's
footprint centred at x = y = 0, metres. The two differ by a similarity

    x_robot = s R x_model + t        (:class:`Similarity`)

found here from the sparse points and the cameras:

* the table plane is fitted to the sparse points near the object by RANSAC
  (:func:`fit_plane_ransac`; MSAC score, then least-squares refits on the inliers);
  points that project inside the object's masks are left out first
  (:func:`object_point_mask`), so a large flat face of the object cannot win over the table;
* the plane's normal is turned towards the cameras (:func:`orient_towards_cameras`):
  the cameras look down at a table, they are above it;
* R takes that normal to +z by the smallest rotation (the yaw about z is therefore
  arbitrary, the model frame's), t puts the plane at z = 0 and the object's
  centre at x = y = 0 (:func:`table_similarity`);
* s: metres per model unit, given (``--scale``) or a known length divided by the
  same length measured in model units (``--object-height-m``; the measurement is
  the caller's, :mod:`real2sim.capture.phone.normalise`).

Camera poses are 4x4 camera-to-world matrices; :func:`transform_poses` moves them
and keeps their rotations orthonormal. Lengths of the model frame are "units".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError


@dataclass(frozen=True, eq=False)
class Similarity:
    """x' = scale * rotation @ x + translation. ``rotation`` (3, 3) orthonormal, det +1; ``scale`` > 0."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    @staticmethod
    def identity() -> "Similarity":
        return Similarity(1.0, np.eye(3), np.zeros(3))

    @staticmethod
    def from_matrix(matrix: np.ndarray) -> "Similarity":
        """From a 4x4 [[s R, t], [0, 1]]; the rotation is projected onto SO(3) (UserInputError if it is none)."""
        m = np.asarray(matrix, dtype=float)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise UserInputError("a similarity must be a finite 4x4 matrix with last row 0 0 0 1")
        det = float(np.linalg.det(m[:3, :3]))
        if det <= 0:
            raise UserInputError(f"a similarity needs a positive determinant (got {det:.3g})")
        scale = det ** (1.0 / 3.0)
        return Similarity(scale, nearest_rotation(m[:3, :3] / scale), m[:3, 3].copy())

    def matrix(self) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points moved."""
        return self.scale * np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    def inverse(self) -> "Similarity":
        r_inv = self.rotation.T
        return Similarity(1.0 / self.scale, r_inv, -(r_inv @ self.translation) / self.scale)

    def __matmul__(self, other: "Similarity") -> "Similarity":
        """self after other."""
        return Similarity(self.scale * other.scale, nearest_rotation(self.rotation @ other.rotation),
                          self.scale * self.rotation @ other.translation + self.translation)

    def rigid_part(self) -> "Similarity":
        """The same rotation and translation, scale 1: agrees with ``self`` at the origin, and nowhere else
        unless the scale is 1. (Used to place a true object at its true size, see normalise.py.)"""
        return Similarity(1.0, self.rotation, self.translation)

    def to_json(self) -> dict:
        return {"scale": self.scale, "rotation": self.rotation.tolist(), "translation": self.translation.tolist(),
                "matrix": self.matrix().tolist()}


@dataclass(frozen=True, eq=False)
class Plane:
    """The plane normal . x = offset (``normal`` unit length), and how well the points fitted it.

    ``inliers``: how many points lie within ``threshold`` of it; ``rms``: their RMS distance (units).
    """

    normal: np.ndarray
    offset: float
    inliers: int = 0
    candidates: int = 0
    threshold: float = 0.0
    rms: float = 0.0
    extra: dict = field(default_factory=dict)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (units) of (..., 3) points, positive on the normal's side."""
        return np.asarray(points, dtype=float) @ self.normal - self.offset

    def flipped(self) -> "Plane":
        return Plane(-self.normal, -self.offset, self.inliers, self.candidates, self.threshold, self.rms, self.extra)


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation (det +1) nearest to a 3x3 matrix in the Frobenius norm (SVD); broadcasts over leading axes."""
    u, _, vt = np.linalg.svd(matrix)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.ones(u.shape[:-1])
    fix[..., -1] = d
    return (u * fix[..., None, :]) @ vt


def rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the direction ``a`` to the direction ``b`` (Rodrigues)."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis orthogonal to a
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def optical_axes_point(c2w_cv: np.ndarray) -> np.ndarray:
    """The point (3,) nearest, in least squares, to every camera's optical axis (OpenCV c2w: axis = +z column).

    The numpy twin of :func:`real2sim.multiview.views.common_look_at_point`, without its visibility check.
    """
    centres, axes = c2w_cv[:, :3, 3], c2w_cv[:, :3, 2]
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    a = proj.sum(axis=0)
    if np.linalg.cond(a) > 1e8:
        raise UserInputError("the cameras' optical axes are (nearly) parallel: they do not look at a common region")
    return np.linalg.solve(a, (proj @ centres[:, :, None]).sum(axis=0)[:, 0])


def project_points(k: CameraIntrinsics, c2w_cv: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (V, P, 2) and depths (V, P) of points (P, 3) in V cameras, OpenCV distortion applied."""
    w2c = np.linalg.inv(c2w_cv)
    cam = np.einsum("vij,pj->vpi", w2c[:, :3, :3], points) + w2c[:, None, :3, 3]
    z = cam[..., 2]
    safe = np.where(z > 1e-12, z, 1e-12)
    x, y = cam[..., 0] / safe, cam[..., 1] / safe
    if not (k.k1 == k.k2 == k.p1 == k.p2 == 0.0):
        r2 = x * x + y * y
        radial = 1 + k.k1 * r2 + k.k2 * r2 * r2
        x, y = (x * radial + 2 * k.p1 * x * y + k.p2 * (r2 + 2 * x * x),
                y * radial + k.p1 * (r2 + 2 * y * y) + 2 * k.p2 * x * y)
    return np.stack([k.fl_x * x + k.cx, k.fl_y * y + k.cy], axis=-1), z


def object_point_mask(points: np.ndarray, k: CameraIntrinsics, c2w_cv: np.ndarray, masks: np.ndarray,
                      vote_fraction: float = 0.8, chunk: int = 4096) -> np.ndarray:
    """(P,) bool: the points inside the object's mask in at least ``vote_fraction`` of the views that see them.

    ``masks``: (V, H, W) bool. A table point next to the object falls inside the mask only in the
    views where the object hides it (well under 80 % of them); a point on the object, in nearly all.
    Points no view sees are not object points.
    """
    v_count, h, w = masks.shape
    out = np.zeros(len(points), dtype=bool)
    for start in range(0, len(points), chunk):
        uv, z = project_points(k, c2w_cv, points[start:start + chunk])
        col, row = np.floor(uv[..., 0]).astype(np.int64), np.floor(uv[..., 1]).astype(np.int64)
        seen = (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        views = np.broadcast_to(np.arange(v_count)[:, None], seen.shape)
        inside = np.zeros(seen.shape, dtype=bool)
        inside[seen] = masks[views[seen], row[seen], col[seen]]
        n_seen = seen.sum(axis=0)
        out[start:start + chunk] = (n_seen > 0) & (inside.sum(axis=0) >= vote_fraction * np.maximum(n_seen, 1))
    return out


def _plane_through(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares plane of (P, 3) points: (unit normal, offset, RMS distance)."""
    centre = points.mean(axis=0)
    _, sv, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    return normal, float(normal @ centre), float(sv[-1] / np.sqrt(len(points)))


def fit_plane_ransac(points: np.ndarray, threshold: float, *, seed: int, iterations: int = 1000,
                     max_scored: int = 20_000, min_inliers: int = 30, refits: int = 3) -> Plane:
    """The dominant plane of (P, 3) points: RANSAC over 3-point samples, vectorised.

    Hypotheses are scored by MSAC (sum of min(d^2, threshold^2)) on at most ``max_scored``
    points (a seeded subset); the best one is refitted by least squares on its inliers among
    all points, ``refits`` times. UserInputError (one line) when there are fewer than
    ``min_inliers`` points or the best plane has fewer inliers than that.
    """
    points = np.asarray(points, dtype=float)
    if len(points) < max(min_inliers, 3):
        raise UserInputError(f"only {len(points)} sparse points near the object: the table plane needs at least "
                             f"{max(min_inliers, 3)} (is the COLMAP model's points3D empty?)")
    rng = np.random.default_rng(seed)
    scored = points if len(points) <= max_scored else points[rng.choice(len(points), max_scored, replace=False)]
    samples = rng.integers(0, len(scored), size=(iterations, 3))  # a repeated index gives no normal: dropped below
    a, b, c = scored[samples[:, 0]], scored[samples[:, 1]], scored[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-12 * np.maximum(np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - a, axis=1), 1e-300)
    if not ok.any():
        raise UserInputError("the sparse points near the object are (nearly) collinear: no table plane to fit")
    normals, a = normals[ok] / lengths[ok, None], a[ok]
    offsets = np.einsum("ij,ij->i", normals, a)
    best, best_cost = 0, np.inf
    for start in range(0, len(normals), 64):  # (64, max_scored) distances at a time
        d = scored @ normals[start:start + 64].T - offsets[start:start + 64]
        cost = np.minimum(d * d, threshold * threshold).sum(axis=0)
        i = int(np.argmin(cost))
        if cost[i] < best_cost:
            best, best_cost = start + i, float(cost[i])
    normal, offset = normals[best], float(offsets[best])
    rms = 0.0
    for _ in range(refits):
        inliers = np.abs(points @ normal - offset) <= threshold
        if inliers.sum() < 3:
            break
        normal, offset, rms = _plane_through(points[inliers])
    count = int((np.abs(points @ normal - offset) <= threshold).sum())
    if count < min_inliers:
        raise UserInputError(f"no table plane in the sparse points near the object: the best plane holds {count} "
                             f"of {len(points)} points (at least {min_inliers} needed)")
    return Plane(normal, offset, count, len(points), threshold, rms)


def orient_towards_cameras(plane: Plane, camera_centres: np.ndarray, min_agreement: float = 0.9) -> Plane:
    """The plane with its normal on the cameras' side; UserInputError when the cameras are on both sides
    (fewer than ``min_agreement`` on one side): that plane is not a table the cameras look down on."""
    above = float(np.mean(plane.distance(camera_centres) > 0))
    if max(above, 1.0 - above) < min_agreement:
        raise UserInputError(f"the plane fitted to the sparse points has cameras on both sides ({100 * above:.0f} % "
                             "above): it is not the table under the object")
    return plane if above >= 0.5 else plane.flipped()


def table_similarity(plane: Plane, centre: np.ndarray | None = None, scale: float = 1.0) -> Similarity:
    """Model frame -> robot frame: ``plane`` (normal towards the cameras) becomes z = 0 with +z along the
    normal, the model point ``centre`` (if given) lands on the z axis, lengths times ``scale``."""
    rotation = rotation_taking(plane.normal, np.array([0.0, 0.0, 1.0]))
    translation = np.array([0.0, 0.0, -plane.offset])  # R n = z, so z' = n . x - offset
    if centre is not None:
        moved = rotation @ np.asarray(centre, float) + translation
        translation = translation - np.array([moved[0], moved[1], 0.0])
    return Similarity(scale, rotation, scale * translation)


def transform_poses(sim: Similarity, c2w: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses (either camera convention) moved by ``sim``: the rotations are
    turned by ``sim.rotation`` (and re-orthonormalised), the camera centres moved by the similarity."""
    c2w = np.asarray(c2w, dtype=float)
    out = np.tile(np.eye(4), (len(c2w), 1, 1))
    out[:, :3, :3] = nearest_rotation(sim.rotation[None] @ c2w[:, :3, :3])
    out[:, :3, 3] = sim.apply(c2w[:, :3, 3])
    return out


def frame_errors(robot_from_world: Similarity) -> dict:
    """How far a normalised frame is from a known true robot frame, given the map true -> normalised.

    Ideally a turn about z and an x/y shift (both arbitrary). Recorded: the relative scale error,
    the tilt of the true table's normal (deg), the true table origin's height (mm), and the yaw (deg)
    and x/y shift (mm), which are free.
    """
    r, t = robot_from_world.rotation, robot_from_world.translation
    tilt = np.degrees(np.arccos(np.clip(r[2, 2], -1.0, 1.0)))
    return {"scale_rel_error": float(robot_from_world.scale - 1.0), "table_tilt_deg": float(tilt),
            "table_origin_height_mm": float(1000.0 * t[2]), "yaw_deg": float(np.degrees(np.arctan2(r[1, 0], r[0, 0]))),
            "xy_shift_mm": [float(1000.0 * t[0]), float(1000.0 * t[1])]}
