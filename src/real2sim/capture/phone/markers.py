"""Metres and the table plane from any printed square fiducials (ArUco, AprilTag) lying flat on the table:
found in the registered photos, their corners triangulated with the SfM cameras.

Steps (:func:`markers_frame`):

1. every image searched with OpenCV's aruco detector (corners refined by AprilTag's edge fit) for each
   candidate dictionary
   (the one given, else :data:`COMMON_DICTIONARIES`); the dictionary with the most detections wins;
   an id seen twice in one image is dropped there (a false detection);
2. each corner of each marker seen in at least ``MIN_MARKER_VIEWS`` views triangulated (linear, then
   the reprojection error minimised; views more than ``OUTLIER_PX`` off are left out and the corner
   refitted);
3. a marker whose four corners do not make a flat square (sides within ``SQUARE_TOLERANCE`` of their
   mean, diagonals too) is left out: a wrong id or a corner hidden by the object;
4. scale = the printed side / the mean triangulated side (model units); the table plane: the least-squares
   plane of every kept corner, its normal towards the cameras (the printed paper is the table top, to a
   sheet's thickness).

Pixels: the project's convention (a pixel's centre at u + 0.5); OpenCV's (u) only inside
:func:`detect_markers`. Poses: camera-to-world 4x4, OpenCV camera axes, the SfM model's frame and units.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.capture.phone import robot_frame as rf
from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress

#: Dictionaries tried when none is given: the largest of each cell grid (a smaller one is a prefix of it).
COMMON_DICTIONARIES = ("DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL",
                       "DICT_APRILTAG_36h11", "DICT_APRILTAG_25h9")
#: A marker's corners are triangulated from at least this many views; scale needs one such marker.
MIN_MARKER_VIEWS = 3
#: A view whose corner lies more than this far (px) from the triangulated corner's projection is left out.
OUTLIER_PX = 2.0
#: A marker's four sides and its two diagonals / sqrt(2) must lie within this fraction of their mean.
SQUARE_TOLERANCE = 0.03


def aruco_dictionary(name: str):
    """OpenCV's predefined aruco dictionary called ``name`` (e.g. "DICT_4X4_50"); UserInputError otherwise."""
    import cv2

    names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
    if name not in names:
        raise UserInputError(f"--marker-dictionary {name!r} is not an OpenCV aruco dictionary (one of "
                             f"{', '.join(names)})")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def marker_cells(name: str) -> int:
    """Cells along a marker's side in dictionary ``name``, its black border included."""
    return int(aruco_dictionary(name).markerSize) + 2


def detect_markers(rgb: np.ndarray, dictionary: str) -> dict[int, np.ndarray]:
    """Markers of ``dictionary`` in the image ``rgb`` (H, W, 3) uint8: id -> (4, 2) corners, px (project
    convention), in the dictionary's order (the printed marker's top-left, top-right, bottom-right,
    bottom-left). Ids seen more than once are dropped."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    # AprilTag's edge fit: unbiased where SUBPIX (built for chessboard X-corners) pulls an L-corner
    # inwards, 1-2 % of the side on 30-60 px markers (docs/design-notes/capture.md#marker-scale)
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners, ids, _ = detector.detectMarkers(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY))
    if ids is None:
        return {}
    ids = ids.ravel().tolist()
    return {i: np.asarray(c, float).reshape(4, 2) + 0.5 for i, c in zip(ids, corners) if ids.count(i) == 1}


def _projection(k: CameraIntrinsics, c2w_cv: np.ndarray) -> np.ndarray:
    """(V, 3, 4) pixel projection matrices of V cameras (project pixel convention)."""
    w2c = np.linalg.inv(c2w_cv)
    return k.matrix()[None] @ w2c[:, :3, :]


def _triangulate(proj: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The point (3,) whose projections through ``proj`` (V, 3, 4) best match ``uv`` (V, 2): linear DLT, then
    the reprojection error minimised (Gauss-Newton)."""
    rows = np.concatenate([uv[:, :1] * proj[:, 2] - proj[:, 0], uv[:, 1:] * proj[:, 2] - proj[:, 1]])
    x = np.linalg.svd(rows)[2][-1]
    point = x[:3] / x[3]
    for _ in range(5):
        h = proj[:, :, :3] @ point + proj[:, :, 3]
        res = (h[:, :2] / h[:, 2:] - uv).ravel()
        jac = ((proj[:, :2, :3] * h[:, 2, None, None] - h[:, :2, None] * proj[:, 2:3, :3])
               / h[:, 2, None, None] ** 2).reshape(-1, 3)
        step = np.linalg.lstsq(jac, -res, rcond=None)[0]
        point = point + step
        if np.linalg.norm(step) < 1e-12 * max(1.0, np.linalg.norm(point)):
            break
    return point


def _reprojection_px(proj: np.ndarray, point: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h = proj[:, :, :3] @ point + proj[:, :, 3]
    return np.linalg.norm(h[:, :2] / h[:, 2:] - uv, axis=1)


def _robust_corner(proj: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, int, float] | None:
    """(point, views kept, RMS px) after leaving out the views more than OUTLIER_PX off; None when fewer
    than MIN_MARKER_VIEWS stay."""
    keep = np.ones(len(uv), bool)
    for _ in range(3):
        if keep.sum() < MIN_MARKER_VIEWS:
            return None
        point = _triangulate(proj[keep], uv[keep])
        err = _reprojection_px(proj, point, uv)
        new = err <= max(OUTLIER_PX, 3.0 * float(np.median(err[keep])))
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() < MIN_MARKER_VIEWS:
        return None
    return point, int(keep.sum()), float(np.sqrt(np.mean(err[keep] ** 2)))


def _is_square(corners: np.ndarray) -> tuple[bool, float]:
    """(flat square within SQUARE_TOLERANCE, mean side) of (4, 3) corners in order around the square."""
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
    diagonals = np.linalg.norm(corners[:2] - corners[2:], axis=1) / np.sqrt(2.0)
    mean = float(sides.mean())
    lengths = np.r_[sides, diagonals]
    return bool(mean > 0 and np.all(np.abs(lengths - mean) <= SQUARE_TOLERANCE * mean)), mean


@dataclass(frozen=True, eq=False)
class MarkerFrame:
    """What the markers measure in the SfM model: ``scale`` metres per model unit (the printed side over the
    mean triangulated side ``side_units``), the table ``plane`` (model units, normal towards the cameras),
    each kept marker's triangulated ``corners`` (id -> (4, 3), model frame) and ``views`` (id -> views it was
    found in); ``rejected``: id -> why it was left out."""

    dictionary: str
    marker_m: float
    side_units: float
    scale: float
    plane: rf.Plane
    corners: dict[int, np.ndarray]
    views: dict[int, int]
    rejected: dict[int, str]
    views_with_markers: int
    reprojection_px: float

    def to_json(self) -> dict:
        sides = {i: float(np.linalg.norm(c - np.roll(c, -1, axis=0), axis=1).mean()) for i, c in self.corners.items()}
        return {"dictionary": self.dictionary, "marker_mm": 1000.0 * self.marker_m, "side_units": self.side_units,
                "scale_m_per_unit": self.scale, "markers_used": sorted(self.corners),
                "views_per_marker": {str(i): n for i, n in sorted(self.views.items())},
                "side_mm_per_marker": {str(i): 1000.0 * s * self.scale for i, s in sorted(sides.items())},
                "rejected": {str(i): why for i, why in sorted(self.rejected.items())},
                "views_with_markers": self.views_with_markers, "corner_reprojection_rms_px": self.reprojection_px,
                "table_plane_model": {"normal": self.plane.normal.tolist(), "offset_units": self.plane.offset},
                "table_fit_rms_mm": 1000.0 * self.plane.rms * self.scale}


def find_markers(images: list[np.ndarray] | list[Path], dictionary: str | None,
                 progress: ProgressFn | None = None) -> tuple[str, list[dict[int, np.ndarray]]]:
    """(the dictionary, each image's detections) for ``images`` (arrays or paths); ``dictionary`` None: the
    one of :data:`COMMON_DICTIONARIES` with the most detections (step 1)."""
    from real2sim.formats.dataset import load_image_rgb

    progress = progress or null_progress
    candidates = (dictionary,) if dictionary is not None else COMMON_DICTIONARIES
    for name in candidates:
        aruco_dictionary(name)
    found = {name: [] for name in candidates}
    for i, image in enumerate(images):
        rgb = load_image_rgb(image) if isinstance(image, (str, Path)) else image
        for name in candidates:
            found[name].append(detect_markers(rgb, name))
        progress("looking for square markers", i + 1, len(images))
    best = max(candidates, key=lambda n: sum(len(d) for d in found[n]))
    return best, found[best]


def markers_frame(images: list[np.ndarray] | list[Path], intrinsics: CameraIntrinsics, c2w_cv: np.ndarray,
                  marker_mm: float, dictionary: str | None = None, progress: ProgressFn | None = None) -> MarkerFrame:
    """Scale and the table plane from the printed markers of side ``marker_mm`` in the registered
    ``images`` (undistorted, ``intrinsics``) with camera-to-world poses ``c2w_cv`` (V, 4, 4) (module
    docstring). UserInputError (one line) when no marker is seen in at least MIN_MARKER_VIEWS views or none
    triangulates as a square."""
    name, detections = find_markers(images, dictionary, progress)
    with_any = sum(bool(d) for d in detections)
    by_id: dict[int, list[int]] = {}
    for v, found in enumerate(detections):
        for marker in found:
            by_id.setdefault(marker, []).append(v)
    what = f"square markers ({name if dictionary is not None else 'any common ArUco/AprilTag dictionary'})"
    if not by_id or max(len(v) for v in by_id.values()) < MIN_MARKER_VIEWS:
        most = max((len(v) for v in by_id.values()), default=0)
        raise UserInputError(f"{what} were found in {with_any} of {len(detections)} registered views (each marker "
                             f"in at most {most}); at least {MIN_MARKER_VIEWS} views of one marker are needed for "
                             "--marker-mm: keep the markers flat on the table and in view, or give --object-height-m")
    proj = _projection(intrinsics, np.asarray(c2w_cv, float))
    corners, views, rejected, rms = {}, {}, {}, []
    for marker, seen in sorted(by_id.items()):
        if len(seen) < MIN_MARKER_VIEWS:
            rejected[marker] = f"seen in {len(seen)} views"
            continue
        fitted = [_robust_corner(proj[seen], np.stack([detections[v][marker][c] for v in seen])) for c in range(4)]
        if any(f is None for f in fitted):
            rejected[marker] = "its corners do not agree between views"
            continue
        points = np.stack([f[0] for f in fitted])
        square, _ = _is_square(points)
        if not square:
            rejected[marker] = "its triangulated corners are not a flat square"
            continue
        corners[marker], views[marker] = points, len(seen)
        rms += [f[2] for f in fitted]
    if not corners:
        raise UserInputError(f"{what} were seen in {with_any} registered views, but none triangulates as a flat "
                             f"square ({'; '.join(f'id {i}: {w}' for i, w in rejected.items())}): check the "
                             "markers lie flat, or give --object-height-m")
    stacked = np.concatenate(list(corners.values()))
    side = float(np.mean([_is_square(c)[1] for c in corners.values()]))
    centre = stacked.mean(axis=0)
    _, sv, vt = np.linalg.svd(stacked - centre, full_matrices=False)
    plane = rf.Plane(vt[-1], float(vt[-1] @ centre), inliers=len(stacked), candidates=len(stacked),
                     threshold=0.0, rms=float(sv[-1] / np.sqrt(len(stacked))))
    plane = rf.orient_towards_cameras(plane, np.asarray(c2w_cv, float)[:, :3, 3])
    marker_m = marker_mm / 1000.0
    return MarkerFrame(name, marker_m, side, marker_m / side, plane, corners, views, rejected, with_any,
                       float(np.sqrt(np.mean(np.square(rms)))))
