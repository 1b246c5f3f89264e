"""Posed-image datasets in nerfstudio's ``transforms.json`` layout: read, write, validate.

A dataset is a folder::

    DATASET/
      transforms.json      intrinsics + one entry per frame (nerfstudio layout)
      images/              the colour images the frames point to
      masks/               optional object masks (255 = object, 0 = ignore)

``transforms.json`` holds the pinhole intrinsics in pixels (``fl_x, fl_y, cx,
cy, w, h``, ``camera_model`` "OPENCV" with distortion ``k1 k2 p1 p2``) and, per
frame, ``file_path`` (relative to the folder), ``transform_matrix`` -- the 4x4
camera-to-world pose in metres in the OpenGL camera convention (x right, y up,
the camera looks along -z) -- and optionally ``mask_path``.

Pixel coordinates follow nerfstudio and COLMAP: the image spans [0, w] x [0, h]
and the centre of pixel (u, v) is at (u + 0.5, v + 0.5), so a centred principal
point is (w / 2, h / 2). Drake's ``CameraInfo`` uses the same convention.

A real capture may come as ``images/`` + ``transforms.json`` (any tool that
writes nerfstudio's format), or as ``images/`` + a COLMAP model in
``sparse/0`` (cameras/images .bin or .txt); :func:`read_dataset` converts the
latter on the fly (its poses are then in COLMAP's arbitrary frame and scale).
nerfstudio's ``ns-process-data`` output is a ``transforms.json`` in such a frame
too (COLMAP's, axes swapped): it carries ``applied_transform`` and the SfM points
in ``ply_file_path`` (:func:`is_model_frame`).

The dataset in memory, real2sim's keys and the checks of its files are
:mod:`real2sim.formats.posed_images`; the COLMAP reader is :mod:`real2sim.formats.colmap_model`.
Both sit below this module, which re-exports their names.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from real2sim.formats.colmap_model import read_colmap_model
# the in-memory dataset, its keys and its file checks live below, in posed_images; importable from here
from real2sim.formats.posed_images import (CV_FROM_GL, MODEL_FRAME_KEYS, POSE_REFINED_KEY,  # noqa: F401
                                           SUPPORT_Z_KEY, TABLE_PLANE_KEY, CameraIntrinsics, Dataset, Frame,
                                           check_frame_files, check_image_file, check_inside,
                                           describe_model_frame, has_table_plane, is_model_frame,
                                           realsense_d435_intrinsics, stated_support_z_m)
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import check_output_path
from real2sim.plumbing.outputs import write_json_atomic as _write_json_atomic
from real2sim.plumbing.paths import missing

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def check_rigid(matrix: Any, label: str, tol: float = 1e-3) -> np.ndarray:
    """Return ``matrix`` as a (4, 4) float array; UserInputError unless it is a finite rigid transform."""
    try:
        m = np.asarray(matrix, dtype=float)
    except (TypeError, ValueError):
        raise UserInputError(f"{label}: transform_matrix is not a numeric 4x4 matrix") from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise UserInputError(f"{label}: transform_matrix has shape {m.shape}, expected 4x4")
    if not np.all(np.isfinite(m)):
        raise UserInputError(f"{label}: transform_matrix has non-finite entries")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise UserInputError(f"{label}: transform_matrix last row is {m[3].tolist()}, expected [0, 0, 0, 1]")
    r = m[:3, :3]
    ortho_err = float(np.abs(r.T @ r - np.eye(3)).max())
    if ortho_err > tol or np.linalg.det(r) < 0:
        raise UserInputError(
            f"{label}: transform_matrix is not rigid (rotation part off orthonormal by {ortho_err:.3g}, "
            f"det {np.linalg.det(r):.3g})")
    return m


def _intrinsics_from_json(data: dict, label: str) -> CameraIntrinsics:
    missing = [k for k in ("fl_x", "fl_y", "cx", "cy", "w", "h") if k not in data]
    if missing and "fl_x" in data and missing == ["fl_y"]:
        data = {**data, "fl_y": data["fl_x"]}
        missing = []
    if missing:
        raise UserInputError(f"{label}: missing camera intrinsics {', '.join(missing)}")
    model = data.get("camera_model", "OPENCV")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise UserInputError(f"{label}: camera_model {model!r} not supported (use OPENCV or PINHOLE)")
    try:
        vals = {k: float(data.get(k, 0.0)) for k in ("fl_x", "fl_y", "cx", "cy", "k1", "k2", "p1", "p2")}
        w, h = int(data["w"]), int(data["h"])
    except (TypeError, ValueError):
        raise UserInputError(f"{label}: camera intrinsics are not numbers") from None
    if w <= 0 or h <= 0 or vals["fl_x"] <= 0 or vals["fl_y"] <= 0 or not all(np.isfinite(list(vals.values()))):
        raise UserInputError(f"{label}: invalid camera intrinsics (w={w}, h={h}, fl_x={vals['fl_x']}, fl_y={vals['fl_y']})")
    return CameraIntrinsics(width=w, height=h, **vals)


def intrinsics_to_json(k: CameraIntrinsics) -> dict:
    return {"camera_model": "OPENCV", "fl_x": k.fl_x, "fl_y": k.fl_y, "cx": k.cx, "cy": k.cy,
            "w": k.width, "h": k.height, "k1": k.k1, "k2": k.k2, "p1": k.p1, "p2": k.p2}


def dataset_to_json(ds: Dataset) -> dict:
    out = dict(ds.extra)
    out.update(intrinsics_to_json(ds.intrinsics))
    frames = []
    for f in ds.frames:
        entry = dict(f.extra)
        entry["file_path"] = f.file_path
        entry["transform_matrix"] = np.asarray(f.transform_matrix, dtype=float).tolist()
        if f.mask_path is not None:
            entry["mask_path"] = f.mask_path
        frames.append(entry)
    out["frames"] = frames
    return out


def write_json_atomic(path: Path, data: Any, default: Any = None) -> None:
    """:func:`real2sim.plumbing.outputs.write_json_atomic` (kept here for the stages that import it)."""
    _write_json_atomic(path, data, default=default)


def write_transforms(path: Path, ds: Dataset) -> None:
    """Write ``ds`` as nerfstudio ``transforms.json`` at ``path`` (atomically)."""
    write_json_atomic(Path(path), dataset_to_json(ds))


def _not_a_file(path: Path, kind: str) -> str:
    """Why ``path`` (an image or a mask) cannot be read as a file: a folder, a FIFO or a device is
    there (reading a FIFO would wait forever), or nothing is (:func:`~real2sim.plumbing.paths.missing`)."""
    if path.is_dir():
        return f"{kind} {path} is a folder, not a file"
    if path.exists():
        return f"{kind} {path} is not a regular file"
    return missing(path, kind)


def read_transforms(path: Path, root: Path | None = None, check_files: bool = True) -> Dataset:
    """Read and validate a nerfstudio ``transforms.json``; frame paths are relative to ``root`` (its folder)."""
    path = Path(path)
    root = Path(root) if root is not None else path.parent
    label = str(path)
    if path.exists() and not path.is_file() and not path.is_dir():
        # a FIFO or a device: reading it would wait forever for a writer
        raise UserInputError(f"{label} is not a regular file")
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise UserInputError(missing(path, "dataset file")) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserInputError(f"{label} is not readable JSON: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise UserInputError(f"{label}: expected a JSON object at the top level")
    raw_frames = data.get("frames")
    if not isinstance(raw_frames, list) or not raw_frames:
        raise UserInputError(f"{label}: no frames")
    if "fl_x" not in data and isinstance(raw_frames[0], dict) and "fl_x" in raw_frames[0]:
        # nerfstudio allows per-frame intrinsics; we support one camera, so all must agree.
        intr = _intrinsics_from_json(raw_frames[0], f"{label} frame 0")
        for i, fr in enumerate(raw_frames[1:], 1):
            if _intrinsics_from_json(fr, f"{label} frame {i}") != intr:
                raise UserInputError(f"{label}: frames have different intrinsics; one camera is supported")
    else:
        intr = _intrinsics_from_json(data, label)
    frames = []
    seen = set()
    frame_keys = {"file_path", "transform_matrix", "mask_path"}
    for i, fr in enumerate(raw_frames):
        flabel = f"{label} frame {i}"
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise UserInputError(f"{flabel}: needs file_path and transform_matrix")
        fp = str(fr["file_path"])
        if fp in seen:
            raise UserInputError(f"{flabel}: duplicate file_path {fp}")
        seen.add(fp)
        m = check_rigid(fr["transform_matrix"], f"{flabel} ({fp})")
        mp = fr.get("mask_path")
        check_inside(root, fp, f"{flabel}: file_path")
        if mp is not None:
            check_inside(root, str(mp), f"{flabel}: mask_path")
        if check_files:
            for kind, name in (("image", fp), ("mask", mp)):
                if name is not None and not (root / name).is_file():
                    raise UserInputError(f"{flabel}: {_not_a_file(root / name, kind)}")
        frames.append(Frame(file_path=fp, transform_matrix=m, mask_path=None if mp is None else str(mp),
                            extra={k: v for k, v in fr.items() if k not in frame_keys}))
    extra = {k: v for k, v in data.items() if k not in ("frames", "camera_model", "fl_x", "fl_y", "cx", "cy",
                                                         "w", "h", "k1", "k2", "p1", "p2")}
    ds = Dataset(root=root, intrinsics=intr, frames=tuple(frames), extra=extra)
    stated_support_z_m(ds)  # refused here, before any stage writes, when it is not a height
    if check_files:
        check_frame_files(ds, label)
    return ds


def check_dataset_outputs(root: Path | str, files: tuple[str, ...] = (), folders: tuple[str, ...] = (),
                          what: str = "output") -> None:
    """Before a stage writes ``files`` / ``folders`` into a dataset folder: each can be made there.

    UserInputError (one line) for a folder where a file goes or a file where a folder goes,
    a folder that cannot be written (permission), or a name the file system refuses."""
    root = Path(root)
    for name, folder in [(n, False) for n in files] + [(n, True) for n in folders]:
        path = root / name
        if path.exists() and path.is_dir() != folder:
            kind, expected = ("a file", "a folder") if folder else ("a folder", "a file")
            raise UserInputError(f"{what} {path} is {kind}; it must be {expected} (move it away)")
        check_output_path(path, what=what)


def read_dataset(path: Path | str, check_files: bool = True) -> Dataset:
    """Open a dataset folder (or its transforms.json): nerfstudio transforms.json, else images + sparse/0.

    Raises UserInputError with one line for anything unreadable: a missing folder,
    no transforms.json and no COLMAP model, bad JSON, missing frames or images,
    non-rigid or non-finite poses, bad intrinsics.
    """
    path = Path(path)
    if path.is_file() and path.suffix == ".json":
        return read_transforms(path, check_files=check_files)
    if not path.exists():
        raise UserInputError(missing(path, "dataset"))
    if not path.is_dir():
        raise UserInputError(f"dataset {path} is not a folder or a transforms.json")
    if (path / "transforms.json").exists():
        return read_transforms(path / "transforms.json", check_files=check_files)
    if (path / "sparse" / "0").is_dir():
        return read_colmap_model(path)
    raise UserInputError(f"{path} holds neither transforms.json nor a COLMAP model sparse/0")


def load_image_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB; UserInputError when unreadable."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError) as exc:
        raise UserInputError(f"cannot read image {path}: {str(exc).splitlines()[0]}") from None


def load_mask(path: Path) -> np.ndarray:
    """(H, W) bool, True where the object is (pixel value > 127)."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("L")) > 127
    except (OSError, ValueError) as exc:
        raise UserInputError(f"cannot read mask {path}: {str(exc).splitlines()[0]}") from None


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Angle(s) in degrees of the rotation(s) r_a^T r_b; broadcasts over leading axes."""
    rel = np.swapaxes(r_a, -1, -2) @ r_b
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_errors(c2w_est: np.ndarray, c2w_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame rotation error (deg) and camera-centre error (mm) between (N,4,4) camera-to-world poses."""
    rot = rotation_angle_deg(c2w_est[:, :3, :3], c2w_ref[:, :3, :3])
    trans_mm = 1000.0 * np.linalg.norm(c2w_est[:, :3, 3] - c2w_ref[:, :3, 3], axis=1)
    return rot, trans_mm


def read_ground_truth(root: Path | str) -> Dataset | None:
    """The exact poses in ``root/ground_truth/transforms.json`` (paths relative to ``root``), or None."""
    path = Path(root) / "ground_truth" / "transforms.json"
    if not path.is_file():
        return None
    return read_transforms(path, root=Path(root), check_files=False)

