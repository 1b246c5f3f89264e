"""A posed-image dataset in memory (:class:`Dataset`: one camera, posed frames, the folder they live
in), what the keys real2sim adds to nerfstudio's ``transforms.json`` say about it, and the checks of the
files its frames name. :mod:`real2sim.formats.dataset` reads and writes it (and re-exports all of this);
:mod:`real2sim.formats.colmap_model` builds one from a COLMAP model.

The keys: whether its poses are in an SfM model's frame, whether its images show a table plane, the
support height a rig states, and which frames ``refine-poses`` refined. Each helper reads a
:class:`Dataset`'s ``extra`` (its top-level keys beyond nerfstudio's) and ``root``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError

# OpenCV camera (x right, y down, z forward) <-> OpenGL camera (x right, y up, z backward):
# both are a flip of the camera's y and z axes, applied on the right of camera-to-world.
CV_FROM_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels (pixel centres at u + 0.5), with OpenCV radial-tangential distortion."""

    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def matrix(self) -> np.ndarray:
        """3x3 calibration matrix K (continuous pixel coordinates, centre of pixel u at u + 0.5)."""
        return np.array([[self.fl_x, 0.0, self.cx], [0.0, self.fl_y, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> "CameraIntrinsics":
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fl_x=self.fl_x * sx, fl_y=self.fl_y * sy,
                       cx=self.cx * sx, cy=self.cy * sy)


def realsense_d435_intrinsics(width: int = 640, height: int = 480) -> CameraIntrinsics:
    """A RealSense D435-like colour camera: fx = fy = 615 px at 640x480, principal point at the centre."""
    fl = 615.0 * width / 640.0
    return CameraIntrinsics(width=width, height=height, fl_x=fl, fl_y=615.0 * height / 480.0,
                            cx=width / 2.0, cy=height / 2.0)


@dataclass(frozen=True)
class Frame:
    """One posed image. ``transform_matrix``: 4x4 camera-to-world, OpenGL camera axes, metres."""

    file_path: str
    transform_matrix: np.ndarray
    mask_path: str | None = None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Dataset:
    """A posed-image dataset rooted at ``root`` (paths in frames are relative to it)."""

    root: Path
    intrinsics: CameraIntrinsics
    frames: tuple[Frame, ...]
    extra: dict = field(default_factory=dict)

    def poses_c2w_gl(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses, OpenGL camera axes."""
        return np.stack([f.transform_matrix for f in self.frames])

    def poses_c2w_cv(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses, OpenCV camera axes (x right, y down, z forward)."""
        return self.poses_c2w_gl() @ CV_FROM_GL


#: transforms.json keys that say its poses are in an SfM model's frame (arbitrary scale, no table at
#: z = 0): ``source``/``model_frame`` from :func:`~real2sim.formats.dataset.read_dataset` of a COLMAP model and the masks
#: stage's copy of one; ``applied_transform``/``ply_file_path`` from nerfstudio's ``ns-process-data``.
MODEL_FRAME_KEYS = ("source", "model_frame", "applied_transform", "ply_file_path")


#: Top-level transforms.json key: ``false`` when the images show no table plane (``capture --no-table``:
#: the object on a thin stand, its lowest point at z = 0). Absent: the table top is the plane z = 0.
TABLE_PLANE_KEY = "table_plane"


def has_table_plane(ds: Dataset) -> bool:
    """False when ``ds`` says its images show no table plane (:data:`TABLE_PLANE_KEY`)."""
    return ds.extra.get(TABLE_PLANE_KEY) is not False


#: Top-level transforms.json key of a dataset without a table plane: the height (world z, metres) of the
#: plane the object stands on, when the rig knows it (a stand's or a turntable's top; ``capture --no-table``
#: writes 0, the stand's top). The object is then taken to lie above it: `reconstruct` cuts there and `run`
#: closes the asset's bottom there. Absent: the object's own lowest seen points (:mod:`pipeline.support`).
SUPPORT_Z_KEY = "support_z_m"


def stated_support_z_m(ds: Dataset) -> float | None:
    """The support height a dataset without a table plane states (:data:`SUPPORT_Z_KEY`), else None.
    UserInputError when the key holds something other than a finite number, or sits beside a table plane
    (whose top is the support already)."""
    if SUPPORT_Z_KEY not in ds.extra:
        return None
    value = ds.extra[SUPPORT_Z_KEY]
    label = f"{ds.root / 'transforms.json'}: {SUPPORT_Z_KEY}"
    if has_table_plane(ds):
        raise UserInputError(f"{label} is for a dataset without a table (\"{TABLE_PLANE_KEY}\": false); "
                             "with a table its top is the support")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserInputError(f"{label} must be a number (metres, world z), got {value!r}")
    return float(value)


#: Per-frame transforms.json key written by ``refine-poses``: whether COLMAP refined that frame's pose
#: (a frame it could not register keeps the robot's pose, with the robot's noise).
POSE_REFINED_KEY = "real2sim_pose_refined"


def is_model_frame(ds: Dataset) -> bool:
    """True when ``ds``'s poses are in an SfM model's frame and scale (a COLMAP model, or a
    nerfstudio-processed capture), not metres in a frame with the table top at z = 0."""
    return ds.extra.get("source") == "colmap" or any(k in ds.extra for k in MODEL_FRAME_KEYS[1:])


def describe_model_frame(ds: Dataset) -> str:
    """What kind of model-frame dataset ``ds`` is, for messages."""
    if ds.extra.get("source") == "colmap" or "model_frame" in ds.extra:
        return "a COLMAP model"
    return "a nerfstudio-processed capture (transforms.json with applied_transform: COLMAP's frame and scale)"


def check_inside(root: Path, relpath: str, label: str) -> None:
    """UserInputError unless ``relpath`` (relative to ``root``, or absolute) names a path inside ``root``.

    Lexical: ``..`` and absolute paths elsewhere are refused; a symbolic link inside the
    folder may still point anywhere (whoever made the folder chose it)."""
    base = os.path.abspath(root)
    full = os.path.normpath(os.path.join(base, relpath))
    if os.path.commonpath([base, full]) != base:
        raise UserInputError(f"{label} {relpath!r} points outside the dataset folder {root}")


def check_image_file(path: Path, size: tuple[int, int], label: str) -> None:
    """UserInputError unless ``path`` is a non-empty, readable image of ``size`` (width, height) px.

    Reads the header and checks the file's structure (PIL ``verify``: chunk checksums of a PNG),
    without decoding the pixels: milliseconds per image."""
    from PIL import Image

    try:
        if path.stat().st_size == 0:
            raise UserInputError(f"{label} {path} is empty (0 bytes)")
        with Image.open(path) as im:
            width, height = im.size
            im.verify()
    except UserInputError:
        raise
    except Exception as exc:  # noqa: BLE001 -- PIL raises OSError, SyntaxError, struct.error... on bad files
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UserInputError(f"{label} {path} is not a readable image ({reason})") from None
    if width == 0 or height == 0:
        raise UserInputError(f"{label} {path} is empty ({width}x{height} px)")
    if (width, height) != tuple(size):
        raise UserInputError(f"{label} {path} is {width}x{height} px, but the dataset's camera is "
                             f"{size[0]}x{size[1]} (w, h): all images and masks must be of that one size")


def check_frame_files(ds: Dataset, label: str | None = None) -> None:
    """Every frame's image and mask: inside the folder, non-empty, readable, of the camera's size.

    One line (UserInputError) naming the first bad file; nothing is decoded, so a dataset of
    hundreds of images is checked in well under a second."""
    label = label or str(ds.root)
    size = (ds.intrinsics.width, ds.intrinsics.height)
    for i, frame in enumerate(ds.frames):
        flabel = f"{label} frame {i}:"
        check_inside(ds.root, frame.file_path, f"{flabel} file_path")
        check_image_file(Path(ds.root) / frame.file_path, size, f"{flabel} image")
        if frame.mask_path is not None:
            check_inside(ds.root, frame.mask_path, f"{flabel} mask_path")
            check_image_file(Path(ds.root) / frame.mask_path, size, f"{flabel} mask")

