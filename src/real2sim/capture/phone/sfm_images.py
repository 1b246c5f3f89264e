"""The images of structure from motion (:mod:`real2sim.capture.phone.sfm`): grouped into cameras by size and
EXIF, staged upright for COLMAP, and resampled into one pinhole camera at the end.

Pixels: the project's convention (a pixel's centre at u + 0.5), COLMAP's too; OpenCV's (u) only inside
:func:`undistorted`.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError

_EXIF_ORIENTATION, _EXIF_MAKE, _EXIF_MODEL, _EXIF_FOCAL = 0x0112, 0x010F, 0x0110, 0x920A


def _exif_key(image) -> tuple:
    exif = image.getexif()
    focal = exif.get_ifd(0x8769).get(_EXIF_FOCAL) if hasattr(exif, "get_ifd") else None
    return (str(exif.get(_EXIF_MAKE, "")).strip(), str(exif.get(_EXIF_MODEL, "")).strip(),
            float(focal) if focal is not None else None)


def camera_groups(paths: list[Path], min_group_images: int = 3) -> tuple[list[int], dict[str, str]]:
    """Each image's camera group (by size after EXIF rotation and EXIF make/model/focal length;
    -1: left out) and the images left out with the reason. UserInputError (one line) for an unreadable
    image (each is decoded whole: a truncated one too, before any work), or when the groups too small to
    estimate a camera hold more than half the images."""
    from PIL import Image, UnidentifiedImageError

    keys = []
    for path in paths:
        try:
            with Image.open(path) as image:
                w, h = image.size
                if image.getexif().get(_EXIF_ORIENTATION, 1) in (5, 6, 7, 8):
                    w, h = h, w  # stored sideways, shown upright
                keys.append((w, h) + _exif_key(image))
                # a JPEG at 1/8 scale still reads its whole stream (a cut one fails), in a fraction of the time
                image.draft(None, (max(1, image.size[0] // 8), max(1, image.size[1] // 8)))
                image.load()
        except (OSError, UnidentifiedImageError, ValueError) as exc:
            raise UserInputError(f"cannot read image {path}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    distinct = sorted(set(keys), key=lambda k: -keys.count(k))
    small = {k for k in distinct if keys.count(k) < min_group_images}
    stray = [i for i, k in enumerate(keys) if k in small]
    if 2 * len(stray) > len(paths) or len(small) == len(distinct):
        sizes = sorted({f"{k[0]}x{k[1]}" for k in keys})
        raise UserInputError(f"{len(paths)} images of mixed sizes or cameras that do not form camera groups "
                             f"({len(distinct)} groups, {len(stray)} images in groups of fewer than "
                             f"{min_group_images}; sizes {', '.join(sizes[:6])}{', ...' if len(sizes) > 6 else ''}): "
                             "take the photos with one camera at one setting")
    group_of = {k: g for g, k in enumerate(k for k in distinct if k not in small)}
    left_out = {paths[i].name: f"its size/camera ({keys[i][0]}x{keys[i][1]} {keys[i][2]} {keys[i][3]}) is shared "
                               f"by fewer than {min_group_images} images" for i in stray}
    return [group_of.get(k, -1) for k in keys], left_out


def stage_images(paths: list[Path], groups: list[int], folder: Path) -> list[str]:
    """COLMAP's image names (``g<group>/<index>.png``), images written upright (EXIF orientation
    applied): one sub-folder per camera group, which COLMAP's PER_FOLDER mode makes one camera each."""
    from PIL import Image, ImageOps

    names = []
    for i, (path, group) in enumerate(zip(paths, groups)):
        name = f"g{group}/{i:05d}{path.suffix.lower()}"
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        with Image.open(path) as image:
            upright = image.getexif().get(_EXIF_ORIENTATION, 1) in (1, None)
            if upright:
                try:
                    os.symlink(path.resolve(), folder / name)
                except OSError:
                    shutil.copyfile(path, folder / name)
            else:
                name = name.rsplit(".", 1)[0] + ".png"
                ImageOps.exif_transpose(image).convert("RGB").save(folder / name)
        names.append(name)
    return names


def undistorted(image: np.ndarray, camera, target: CameraIntrinsics) -> np.ndarray:
    """``image`` (taken by COLMAP ``camera``, OPENCV model) resampled into the pinhole ``target``."""
    import cv2

    fx, fy, cx, cy, k1, k2, p1, p2 = np.asarray(camera.params, float)[:8]
    # COLMAP and the project put pixel (u, v)'s centre at (u + 0.5, v + 0.5), OpenCV at (u, v)
    k_src = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1.0]])
    k_dst = target.matrix() - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
    maps = cv2.initUndistortRectifyMap(k_src, np.array([k1, k2, p1, p2]), None, k_dst,
                                       (target.width, target.height), cv2.CV_32FC1)
    return cv2.remap(image, *maps, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
