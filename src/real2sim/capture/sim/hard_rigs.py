"""What real capture rigs do that the default simulated capture does not (issue #28, part 7).

Each piece is a plain function of arrays, used by :func:`real2sim.capture.sim.wrist_camera.capture`
when its :class:`~real2sim.capture.sim.capture_config.CaptureConfig` asks for it:

- :func:`ring_poses`: a turntable rig -- one horizontal ring of cameras at a fixed elevation
  (0 = level with the object's middle), evenly spaced in azimuth;
- :func:`cut_off_poses`: some views aimed off the object, so that the image border cuts it;
- :func:`colour_gains` / :func:`apply_colour_gains`: per-view exposure and white balance, applied in
  linear light to the rendered (sRGB-encoded) image, as a camera's auto-exposure would;
- :func:`stand_size_m`: the thin post an object stands on when there is no table;
- :func:`save_image`: PNG or JPEG.

World frame as in ``wrist_camera``: metres, z up, the object's lowest point at z = 0; camera poses
are camera-to-world in OpenGL axes (x right, y up, looking along -z).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from real2sim.capture.sim.look_at import look_at_c2w_gl
from real2sim.formats.dataset import CV_FROM_GL, CameraIntrinsics
from real2sim.multiview.srgb import linear_to_srgb, srgb_to_linear

#: How far past the image border a cut-off view pushes the object: a fraction of the object's
#: extent in the image along the shift, drawn uniformly in this range (enough to matter, while
#: most of the object stays in view, as in real photographs cut by the frame).
CUT_OFF_OVERFLOW = (0.2, 0.4)


def ring_poses(views: int, elevation_deg: float, distance_m: float, target_m: np.ndarray) -> np.ndarray:
    """(views, 4, 4) camera-to-world poses (OpenGL) on one ring around ``target_m`` looking at it.

    ``elevation_deg``: the cameras' elevation seen from the target (0 = level with it, negative =
    below it); ``distance_m``: their distance from it; azimuths 0, 360/views, ... degrees from +x.
    """
    e = np.radians(elevation_deg)
    az = 2 * np.pi * np.arange(views) / views
    pos = np.c_[distance_m * np.cos(e) * np.cos(az), distance_m * np.cos(e) * np.sin(az),
                np.full(views, distance_m * np.sin(e))]
    return look_at_c2w_gl(np.asarray(target_m, dtype=float) + pos, np.asarray(target_m, dtype=float))


def cut_off_views(views: int, fraction: float) -> np.ndarray:
    """Indices of the views to cut: ``round(fraction * views)`` of them, spread evenly over the sequence."""
    count = int(round(fraction * views))
    if count == 0:
        return np.zeros(0, dtype=int)
    return np.unique(np.floor((np.arange(count) + 0.5) * views / count).astype(int))


def _project_px(c2w_gl: np.ndarray, cam: CameraIntrinsics, points_w: np.ndarray) -> np.ndarray:
    """(N, 2) continuous pixel coordinates of world points in one camera (pixel centres at +0.5)."""
    w2c = np.linalg.inv(c2w_gl @ CV_FROM_GL)
    pc = points_w @ w2c[:3, :3].T + w2c[:3, 3]
    return np.c_[cam.fl_x * pc[:, 0] / pc[:, 2] + cam.cx, cam.fl_y * pc[:, 1] / pc[:, 2] + cam.cy]


def _aim_off(c2w_gl: np.ndarray, cam: CameraIntrinsics, shift_px: np.ndarray) -> np.ndarray:
    """The camera turned about its centre so that what was at the image centre moves by ``shift_px``.

    The rotation takes the ray through pixel (cx, cy) + shift onto the optical axis: the smallest
    turn that does so (no spin about the axis beyond what it implies)."""
    from scipy.spatial.transform import Rotation

    d = np.array([shift_px[0] / cam.fl_x, shift_px[1] / cam.fl_y, 1.0])
    d /= np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(d, z)
    angle = np.arctan2(np.linalg.norm(axis), d @ z)
    turn = Rotation.from_rotvec(axis / max(np.linalg.norm(axis), 1e-15) * angle).as_matrix()
    c2w_cv = c2w_gl @ CV_FROM_GL
    out = c2w_cv.copy()
    out[:3, :3] = c2w_cv[:3, :3] @ turn
    return out @ CV_FROM_GL


def cut_off_poses(c2w_gl: np.ndarray, cam: CameraIntrinsics, object_points_w: np.ndarray, fraction: float,
                  seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(poses, cut indices): ``fraction`` of the views turned so that the object crosses the image border.

    Views to cut are spread evenly (:func:`cut_off_views`); each in turn is shifted right, up, left
    or down, so that ``CUT_OFF_OVERFLOW`` (uniform, seeded) of the object's extent in the image lies
    past that border. ``object_points_w``: (N, 3) points of the object in the world (its vertices).
    """
    rng = np.random.default_rng((seed, 2))
    idx = cut_off_views(len(c2w_gl), fraction)
    out = c2w_gl.copy()
    for k, i in enumerate(idx):
        axis, sign = [(0, 1), (1, -1), (0, -1), (1, 1)][k % 4]  # right, up (v decreases), left, down
        overflow = rng.uniform(*CUT_OFF_OVERFLOW)
        size = (cam.width, cam.height)[axis]
        shift = np.zeros(2)
        # Perspective bends the shift a little: correct it from the object's actual image, a few times.
        for _ in range(4):
            uv = _project_px(_aim_off(c2w_gl[i], cam, shift), cam, object_points_w)[:, axis]
            lo, hi = uv.min(), uv.max()
            edge = hi if sign > 0 else lo
            want = size + overflow * (hi - lo) if sign > 0 else -overflow * (hi - lo)
            shift[axis] += want - edge
        out[i] = _aim_off(c2w_gl[i], cam, shift)
    return out, idx


def colour_gains(views: int, exposure_stops: float, white_balance: float, seed: int) -> np.ndarray:
    """(views, 3) per-view RGB gains in linear light: exposure 2**N(0, ``exposure_stops``) on all
    channels, times exp(N(0, ``white_balance``)) on red and blue (green is the reference)."""
    rng = np.random.default_rng((seed, 1))  # its own stream: the pose noise stays as without jitter
    exposure = 2.0 ** rng.normal(0.0, exposure_stops, views) if exposure_stops > 0 else np.ones(views)
    wb = np.exp(rng.normal(0.0, white_balance, (views, 2))) if white_balance > 0 else np.ones((views, 2))
    return exposure[:, None] * np.c_[wb[:, 0], np.ones(views), wb[:, 1]]


def apply_colour_gains(rgb: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """An 8-bit sRGB image (H, W, 3) with each channel scaled by ``gains`` (3,) in linear light,
    clipped as a sensor saturates."""
    levels = srgb_to_linear(np.arange(256) / 255.0)
    out = np.empty_like(rgb)
    for c in range(3):
        lut = np.round(255.0 * np.clip(linear_to_srgb(levels * gains[c]), 0.0, 1.0)).astype(np.uint8)
        out[..., c] = lut[rgb[..., c]]
    return out


def stand_size_m(mesh_bounds_m: np.ndarray) -> tuple[float, float]:
    """(radius, length) of the post under an object with these (2, 3) bounds: at most 5 mm thick and
    a quarter of the narrower footprint side, so that it hides under the object seen from above;
    long enough (1 m) to leave every view through the bottom of the image."""
    footprint = np.asarray(mesh_bounds_m[1] - mesh_bounds_m[0])[:2]
    return float(min(0.005, 0.25 * 0.5 * footprint.min())), 1.0


def save_image(path: Path, rgb: np.ndarray, jpeg_quality: int | None = None) -> None:
    """PNG (fast, lossless), or JPEG at ``jpeg_quality`` (1-100) when given."""
    from PIL import Image

    if jpeg_quality is None:
        Image.fromarray(rgb).save(path, compress_level=1)
    else:
        Image.fromarray(rgb).save(path, format="JPEG", quality=int(jpeg_quality))
