"""A phone camera's focal length measured on the printed board, for structure from motion.

Why: SfM alone estimates the focal length from the scene's own points, and on an orbit around
an object that estimate is a fraction of a percent off. The board's frame then inherits that error as a
scale error: a longer focal length puts the board, seen at its printed size, further from each camera.
The board is a calibration target of known geometry seen from many angles, which measures the focal
length far better (docs/design-notes/capture.md#board-focal-length): Zhang's planar calibration, here OpenCV's
``calibrateCamera`` with the focal length and the radial distortion (k1, k2) free, the principal
point, square pixels and SfM's tangential distortion held. The radial distortion must be free:
SfM's, found with its own focal length, leans the same way, and held it pulls the board's focal
length short. The camera then starts the last bundle adjustment from the board's focal
length (held) and radial distortion (refined again with every SfM point).

The estimate is used only when it is sound: at least ``MIN_VIEWS`` views with the board, and the
views split in two (alternate views) agree within ``MAX_SPLIT_DISAGREEMENT``; otherwise SfM's own
focal length stays, and the record says why. :func:`set_focal_from_board` does this for every camera
of a COLMAP reconstruction (:mod:`real2sim.capture.phone.sfm`'s step 3b).

Pixel convention: the project's (a pixel's centre at u + 0.5), converted to OpenCV's inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from real2sim.plumbing.progress import ProgressFn

if TYPE_CHECKING:
    from real2sim.capture.phone.board import BoardSpec

#: The fewest views with the board for its focal length.
MIN_VIEWS = 6
#: Alternate halves of the views must agree this well (relative) for the estimate to be used.
MAX_SPLIT_DISAGREEMENT = 0.005


@dataclass(frozen=True)
class BoardFocal:
    """``focal_px``: the board's focal length (None when not measured or not sound, ``reason`` says
    why) and ``k1``, ``k2`` the radial distortion measured with it; ``sfm_focal_px``: what SfM had;
    ``views``: views with the board; ``split_disagreement``: relative difference of the two halves'
    focal lengths; ``rms_px``: reprojection error of the corners."""

    sfm_focal_px: float
    views: int
    focal_px: float | None = None
    split_disagreement: float | None = None
    rms_px: float | None = None
    reason: str = ""
    k1: float | None = None
    k2: float | None = None

    def to_json(self) -> dict:
        out = {"sfm_focal_px": self.sfm_focal_px, "board_views": self.views, "board_focal_px": self.focal_px,
               "board_k1": self.k1, "board_k2": self.k2, "split_disagreement": self.split_disagreement,
               "corner_rms_px": self.rms_px}
        if self.focal_px is not None:
            out["change_pct"] = 100.0 * (self.focal_px / self.sfm_focal_px - 1.0)
        if self.reason:
            out["not_used"] = self.reason
        return out


def _calibrate(object_points: list[np.ndarray], image_points: list[np.ndarray], size: tuple[int, int],
               K_cv: np.ndarray, dist: np.ndarray) -> tuple[float, float, float, float]:
    """(focal px, k1, k2, RMS px): the focal length and the radial distortion free, the principal point,
    square pixels and the tangential distortion held (OpenCV pixel convention in and out)."""
    import cv2

    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_TANGENT_DIST)
    rms, K, d, *_ = cv2.calibrateCamera(object_points, image_points, size, K_cv.copy(), dist.copy(), flags=flags)
    d = np.asarray(d, dtype=float).ravel()
    return float(K[0, 0]), float(d[0]), float(d[1]), float(rms)


def focal_from_board(views: list, K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> BoardFocal:
    """The focal length (px) of the camera ``K`` (3x3, project pixel convention, fx = fy), ``dist``
    (OpenCV k1, k2, p1, p2: k1, k2 the first guess, p1, p2 held), image ``size`` (width, height),
    from ``views``: the :class:`real2sim.capture.phone.board.BoardView` of each image where the board was
    found (None entries are skipped). See the module docstring for when the estimate is refused."""
    K = np.asarray(K, dtype=float)
    found = [v for v in views if v is not None and len(v.image_points_px) >= 4]
    sfm_f = float(K[0, 0])
    if len(found) < MIN_VIEWS:
        return BoardFocal(sfm_f, len(found), reason=f"the board was found in {len(found)} views (fewer than {MIN_VIEWS})")
    import cv2

    from real2sim.capture.phone.board import opencv_camera_matrix

    K_cv = opencv_camera_matrix(K)
    d = np.zeros(5)
    d[:4] = np.asarray(dist, dtype=float).ravel()[:4]
    obj = [np.ascontiguousarray(v.board_points_m, dtype=np.float32) for v in found]
    img = [np.ascontiguousarray(v.image_points_px - 0.5, dtype=np.float32) for v in found]
    try:
        f, k1, k2, rms = _calibrate(obj, img, size, K_cv, d)
        f_even = _calibrate(obj[0::2], img[0::2], size, K_cv, d)[0]
        f_odd = _calibrate(obj[1::2], img[1::2], size, K_cv, d)[0]
    except cv2.error as exc:  # degenerate views (all alike): no calibration, SfM's value stays
        text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        return BoardFocal(sfm_f, len(found), reason=f"OpenCV's calibration failed on the board views: {text}")
    split = abs(f_even - f_odd) / f
    if not (np.isfinite(f) and f > 0 and split <= MAX_SPLIT_DISAGREEMENT):
        return BoardFocal(sfm_f, len(found), split_disagreement=float(split), rms_px=rms,
                          reason=f"the two halves of the board views disagree on the focal length by "
                                 f"{100 * split:.2f} % (more than {100 * MAX_SPLIT_DISAGREEMENT:g} %)")
    return BoardFocal(sfm_f, len(found), focal_px=f, split_disagreement=float(split), rms_px=rms, k1=k1, k2=k2)


def set_focal_from_board(rec, image_dir: Path, board: "BoardSpec", progress: ProgressFn) -> tuple[dict, ...]:
    """Each camera of the pycolmap reconstruction ``rec`` (OPENCV model) measured on the board in its
    registered images (``image_dir`` / each image's name); where the measure is sound the camera takes
    its focal length and radial distortion (the caller then adjusts the model with the focal length
    held), otherwise it keeps SfM's and a RuntimeWarning says why. One record per camera
    (:meth:`BoardFocal.to_json`, with ``camera_id`` and its images' count)."""
    import warnings

    from PIL import Image

    from real2sim.capture.phone.board import detect_board

    images_of: dict[int, list] = {}
    for image_id in rec.reg_image_ids():
        image = rec.image(image_id)
        images_of.setdefault(image.camera_id, []).append(image.name)
    total, done, records = sum(map(len, images_of.values())), 0, []
    for camera_id, names in sorted(images_of.items()):
        camera = rec.camera(camera_id)
        params = np.asarray(camera.params, float)
        K = np.array([[params[0], 0.0, params[2]], [0.0, params[1], params[3]], [0.0, 0.0, 1.0]])
        views = []
        for name in names:
            with Image.open(Path(image_dir) / name) as im:
                views.append(detect_board(np.asarray(im.convert("RGB")), board, K, params[4:8]))
            done += 1
            progress("structure from motion: the board's focal length", done, total)
        result = focal_from_board(views, K, params[4:8], (int(camera.width), int(camera.height)))
        records.append({"camera_id": int(camera_id), "images": len(views), **result.to_json()})
        if result.focal_px is None:
            if result.views:  # a board was there but could not be trusted: say so
                warnings.warn(f"the camera's focal length stays SfM's ({result.sfm_focal_px:.1f} px), not the "
                              f"board's: {result.reason}", RuntimeWarning, stacklevel=3)
            continue
        params[0] = params[1] = result.focal_px
        params[4:6] = result.k1, result.k2  # the adjustment's start; it refines the distortion again
        camera.params = params.tolist()
    return tuple(records)
