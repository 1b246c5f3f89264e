"""A dataset from ``images/`` and a COLMAP model (``sparse/0``): poses in COLMAP's own frame and scale
(:mod:`real2sim.capture.phone.normalise` moves them into the robot frame)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from real2sim.formats.posed_images import CV_FROM_GL, CameraIntrinsics, Dataset, Frame, check_frame_files
from real2sim.plumbing.errors import UserInputError


def _colmap_intrinsics(camera) -> CameraIntrinsics:
    p = np.asarray(camera.params, dtype=float)
    name = camera.model.name if hasattr(camera.model, "name") else str(camera.model)
    w, h = int(camera.width), int(camera.height)
    if name == "SIMPLE_PINHOLE":
        return CameraIntrinsics(w, h, p[0], p[0], p[1], p[2])
    if name == "PINHOLE":
        return CameraIntrinsics(w, h, p[0], p[1], p[2], p[3])
    if name == "SIMPLE_RADIAL":
        return CameraIntrinsics(w, h, p[0], p[0], p[1], p[2], k1=p[3])
    if name == "RADIAL":
        return CameraIntrinsics(w, h, p[0], p[0], p[1], p[2], k1=p[3], k2=p[4])
    if name == "OPENCV":
        return CameraIntrinsics(w, h, *p[:8])
    raise UserInputError(f"COLMAP camera model {name} not supported (use PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV)")


def read_colmap_model(root: Path, model_dir: Path | None = None, images_dir: str = "images") -> Dataset:
    """Build a Dataset from ``images/`` + a COLMAP model (default ``root/sparse/0``), poses in COLMAP's frame."""
    root = Path(root)
    model_dir = Path(model_dir) if model_dir is not None else root / "sparse" / "0"
    try:
        import pycolmap
    except ImportError:
        raise UserInputError("reading a COLMAP model needs pycolmap (pip install pycolmap)") from None
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises generic errors on bad files
        raise UserInputError(f"could not read COLMAP model {model_dir}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    if rec.num_cameras() != 1:
        raise UserInputError(f"COLMAP model {model_dir} has {rec.num_cameras()} cameras; one camera is supported")
    intr = _colmap_intrinsics(next(iter(rec.cameras.values())))
    frames = []
    for image_id in sorted(rec.reg_image_ids(), key=lambda i: rec.image(i).name):
        img = rec.image(image_id)
        cam_from_world = np.eye(4)
        cam_from_world[:3, :] = img.cam_from_world().matrix()
        c2w_gl = np.linalg.inv(cam_from_world) @ CV_FROM_GL
        fp = f"{images_dir}/{img.name}"
        if not (root / fp).is_file():
            raise UserInputError(f"COLMAP model names image {img.name}, but {root / fp} is missing")
        mp = f"masks/{Path(img.name).stem}.png"
        frames.append(Frame(file_path=fp, transform_matrix=c2w_gl,
                            mask_path=mp if (root / mp).is_file() else None))
    if not frames:
        raise UserInputError(f"COLMAP model {model_dir} has no registered images")
    ds = Dataset(root=root, intrinsics=intr, frames=tuple(frames), extra={"source": "colmap"})
    check_frame_files(ds, str(model_dir))
    return ds
