"""The world frame of a phone capture from the printed board: the similarity that takes an SfM
model (arbitrary scale, position and orientation) into the board's frame (metres, table top z = 0,
z up, the board's centre the origin, x along its long side; see :mod:`.board`).

Each view where the board was found gives the board's pose in that camera (:class:`BoardView`);
SfM gives the same camera's pose in the model. One similarity ``board_from_sfm`` (scale s,
rotation R, translation t) must map every SfM camera onto its board pose. It is estimated in three
steps: (1) the rotation as a robust mean of the per-view rotations (views that disagree by more
than a few degrees -- a wrong detection -- are left out); (2) scale and translation from the camera
centres with that rotation, again leaving out outliers; (3) all seven parameters refined together
on the board corners' reprojection error in every kept view, with the SfM cameras held fixed.
Step 3 weighs each view by what it actually saw, where a single view's PnP pose is weak along
its viewing direction.

Camera axes: OpenCV (x right, y down, z forward), as COLMAP's; ``camera_axes="opengl"`` takes
nerfstudio's camera-to-world poses (y up, z backward) instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.capture.phone.board import BoardSpec, BoardView, opencv_camera_matrix
from real2sim.formats.dataset import CV_FROM_GL
from real2sim.plumbing.errors import UserInputError

#: The fewest views with the board for a world frame.
MIN_BOARD_VIEWS = 3
#: A view's rotation that disagrees with the consensus by more than this is a bad detection, degrees
#: (or 3x the median disagreement, when that is larger).
ROTATION_OUTLIER_DEG = 3.0
#: Likewise for camera centres after the scale fit, metres (or 4x the median residual).
CENTRE_OUTLIER_M = 0.01


@dataclass(frozen=True)
class BoardFrame:
    """``board_from_sfm``: 4x4 similarity ``[[s R, t], [0, 1]]`` taking SfM model coordinates to the
    board's frame (metres); ``scale``: s, metres per model unit; ``views_used``: names of the views
    it rests on; ``views_rejected``: names with the board found but left out as outliers;
    ``residual_mm``: RMS distance, mm, between each used camera's centre mapped from SfM and its
    centre from the board; ``reprojection_px``: RMS reprojection error of the board corners in the
    used views through the SfM cameras and the similarity."""

    board_from_sfm: np.ndarray
    scale: float
    views_used: tuple[str, ...]
    residual_mm: float
    views_rejected: tuple[str, ...] = ()
    reprojection_px: float = float("nan")

    def apply_to_c2w(self, sfm_c2w: np.ndarray) -> np.ndarray:
        """(N, 4, 4) or (4, 4) camera-to-world poses moved into the board frame (rotation kept
        orthonormal, centres scaled)."""
        c2w = np.array(sfm_c2w, dtype=float, copy=True)
        r = self.board_from_sfm[:3, :3] / self.scale
        out = c2w.copy()
        out[..., :3, :3] = r @ c2w[..., :3, :3]
        out[..., :3, 3] = c2w[..., :3, 3] @ self.board_from_sfm[:3, :3].T + self.board_from_sfm[:3, 3]
        return out


def _rotation_mean(rotations: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of (N, 3, 3) rotations (the nearest rotation to their sum)."""
    u, _, vt = np.linalg.svd(rotations.sum(axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Geodesic angle between (N, 3, 3) rotations and one rotation, degrees."""
    cos = (np.einsum("nij,ij->n", r_a, r_b) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _robust_rotation(candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, inlier mask): the candidate closest to most others seeds the consensus."""
    pair = np.stack([_angle_deg(candidates, c) for c in candidates])
    seed = int(np.argmin(np.median(pair, axis=1)))
    keep = pair[seed] <= max(ROTATION_OUTLIER_DEG, 3 * float(np.median(pair[seed])))
    rot = _rotation_mean(candidates[keep])
    err = _angle_deg(candidates, rot)
    keep = err <= max(ROTATION_OUTLIER_DEG, 3 * float(np.median(err[keep])))
    return _rotation_mean(candidates[keep]), keep


def _scale_translation(y: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """Least squares s, t of b = s y + t for (N, 3) points."""
    yc, bc = y - y.mean(0), b - b.mean(0)
    s = float(np.sum(yc * bc) / max(np.sum(yc * yc), 1e-300))
    return s, b.mean(0) - s * y.mean(0)


def _refine(rot: np.ndarray, s: float, t: np.ndarray, sfm_c2w: list[np.ndarray], views: list[BoardView]):
    """(rot, s, t, RMS px) minimising the board corners' reprojection error over all ``views``
    (robust loss), the SfM cameras fixed. Views without corner data are not used here."""
    import cv2
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    data = [(c, v) for c, v in zip(sfm_c2w, views) if len(v.image_points_px)]
    if not data:
        return rot, s, t, float("nan")

    def residuals(x: np.ndarray) -> np.ndarray:
        r = Rotation.from_rotvec(x[:3]).as_matrix() @ rot
        scale, trans = s * np.exp(x[3]), t + x[4:7]
        out = []
        for c2w, v in data:
            r_bc = r @ c2w[:3, :3]  # board_from_camera rotation
            centre = scale * r @ c2w[:3, 3] + trans
            pc = (v.board_points_m - centre) @ r_bc  # points in camera axes
            # OpenCV's pixel centres; image_points_px are the project's (+0.5)
            proj, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), opencv_camera_matrix(v.K), v.dist)
            out.append((proj.reshape(-1, 2) - (v.image_points_px - 0.5)).ravel())
        return np.concatenate(out)

    fit = least_squares(residuals, np.zeros(7), loss="soft_l1", f_scale=1.0, x_scale="jac")
    x = fit.x
    res = residuals(x).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
    return Rotation.from_rotvec(x[:3]).as_matrix() @ rot, s * float(np.exp(x[3])), t + x[4:7], rms


def world_from_board_views(sfm_camera_to_world: dict[str, np.ndarray], board_views: dict[str, BoardView],
                           spec: BoardSpec, camera_axes: str = "opencv", refine: bool = True) -> BoardFrame:
    """The similarity from the SfM model to the board's frame (module docstring).

    ``sfm_camera_to_world``: registered views' 4x4 camera-to-world poses in the model (OpenCV
    camera axes unless ``camera_axes="opengl"``); ``board_views``: :func:`~real2sim.capture.phone.board.detect_board`
    results by the same names (views missing from either are ignored). ``refine``: the joint
    reprojection refinement (step 3). UserInputError (one line) when fewer than ``MIN_BOARD_VIEWS``
    registered views show the board, or when the good ones are too few or the cameras do not move."""
    if camera_axes not in ("opencv", "opengl"):
        raise ValueError(f"camera_axes must be 'opencv' or 'opengl', not {camera_axes!r}")
    names = sorted(n for n in board_views if n in sfm_camera_to_world and board_views[n] is not None)
    if len(names) < MIN_BOARD_VIEWS:
        raise UserInputError(
            f"the board ({spec.label()}) was found in "
            f"{len(names)} of {len(sfm_camera_to_world)} registered views; at least {MIN_BOARD_VIEWS} are needed: "
            "lay it flat and keep it in view, or give --object-height-m")
    c2w = np.stack([np.asarray(sfm_camera_to_world[n], dtype=float) for n in names])
    if camera_axes == "opengl":
        c2w = c2w @ CV_FROM_GL
    views = [board_views[n] for n in names]
    b2c = np.stack([np.linalg.inv(v.camera_from_board) for v in views])  # board_from_camera
    rot, keep = _robust_rotation(b2c[:, :3, :3] @ np.transpose(c2w[:, :3, :3], (0, 2, 1)))
    y, b = c2w[:, :3, 3] @ rot.T, b2c[:, :3, 3]
    for _ in range(2):  # fit, reject centres far off, fit again
        if keep.sum() < MIN_BOARD_VIEWS:
            break
        s, t = _scale_translation(y[keep], b[keep])
        res = np.linalg.norm(s * y + t - b, axis=1)
        keep = keep & (res <= max(CENTRE_OUTLIER_M, 4 * float(np.median(res[keep]))))
    if keep.sum() < MIN_BOARD_VIEWS:
        raise UserInputError(f"the poses of the board ({spec.label()}) agree in only {int(keep.sum())} of {len(names)} "
                             f"views (at least {MIN_BOARD_VIEWS} needed): the detections or the SfM poses are wrong, "
                             "or the board is not the one in the photos")
    spread = np.linalg.norm(y[keep] - y[keep].mean(0), axis=1).max()
    if not spread > 0:
        raise UserInputError("the cameras that see the board all stand in one place: no scale can be measured")
    s, t = _scale_translation(y[keep], b[keep])
    if not s > 0:
        raise UserInputError("the board's poses and the SfM poses disagree (negative scale): a mirrored model?")
    rms_px = float("nan")
    if refine:
        rot, s, t, rms_px = _refine(rot, s, t, list(c2w[keep]), [v for v, k in zip(views, keep) if k])
    res = np.linalg.norm(s * c2w[keep, :3, 3] @ rot.T + t - b[keep], axis=1)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = s * rot, t
    used = tuple(n for n, k in zip(names, keep) if k)
    rejected = tuple(n for n, k in zip(names, keep) if not k)
    return BoardFrame(board_from_sfm=m, scale=float(s), views_used=used, residual_mm=float(1000 * np.sqrt(np.mean(res ** 2))),
                      views_rejected=rejected, reprojection_px=rms_px)
