"""Simulated phone captures: what a person walking around an object with a phone gets.

An orbit at varying height and distance (:func:`handheld_poses`), the camera rolled a few degrees,
aimed a little off the object, some views so close that the image border cuts it; a phone lens
(about 65 degrees horizontal field of view), motion blur, a little auto-exposure drift and JPEG.
Asked for: a room behind the table (:mod:`real2sim.capture.sim.room`), auto-exposure that follows each
view's brightness (:func:`auto_exposure_gain`), printed square markers around the object
(:mod:`real2sim.capture.sim.printed_markers`).
With a board (:mod:`real2sim.capture.phone.board`), the printed board lies flat on the table under the object and its
frame is the world frame: the board's centre is the origin, the table top (the paper) is z = 0,
x along the board's long side -- the same world as every other simulated capture, so
``ground_truth/`` compares directly with what a reconstruction in the board's frame gives.

Output: a folder as a phone gives it, images only, plus the truth for tests and benchmarks::

    OUT/
      IMG_0001.jpg ...          the photos (EXIF: make, model, 35 mm-equivalent focal length)
      clip.mp4                  instead of the photos with ``video`` (H.264, ``fps`` frames a second)
      ground_truth/
        transforms.json         exact poses (OpenGL camera-to-world, metres, the world frame above) and
                                intrinsics; file_path is the photo (relative to OUT), or for a video
                                ``clip.mp4#frame=00012`` with ``real2sim_video_frame`` / ``real2sim_time_s``
        masks/IMG_0001.png      rendered object masks, 255 = object (photos only)
        depth/IMG_0001.png      16-bit depth, mm along the optical axis (photos only)
        mesh.obj (+ .mtl, .png), object_pose.json, capture_config.json
        board.json              the board's BoardSpec and world_from_board (identity), with ``board``
        markers.json            with ``markers``: the dictionary, the side and each marker's true corners
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import trimesh

from real2sim.capture.phone.media import VideoWriter, phone_exif, photo_name
from real2sim.capture.sim.capture_config import CaptureResult
from real2sim.capture.sim.capture_output import save_png
from real2sim.capture.sim.handheld_config import HandheldConfig
from real2sim.capture.sim.handheld_scene import HandheldRenderer, build_handheld_scene
from real2sim.capture.sim.hard_rigs import apply_colour_gains, colour_gains
from real2sim.capture.sim.look_at import look_at_c2w_gl
from real2sim.capture.sim.printed_markers import MarkerLayout, marker_layout
from real2sim.capture.sim.render_scene import OBJECT_LABEL
from real2sim.capture.sim.textures import export_textured_obj
from real2sim.capture.sim.wrist_camera import object_frame, render_ready
from real2sim.formats.dataset import CV_FROM_GL, CameraIntrinsics, Dataset, Frame, write_transforms
from real2sim.multiview.srgb import srgb_to_linear
from real2sim.plumbing.outputs import atomic_output_dir
from real2sim.plumbing.progress import ProgressFn, null_progress

#: Name of the video a ``video`` capture writes.
VIDEO_NAME = "clip.mp4"


# ----------------------------------------------------------------------------- the path


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, rms: float, cycles: tuple[int, ...] = (2, 3, 5, 7)) -> np.ndarray:
    """A smooth random signal of ``t`` in [0, 1) (a few sinusoids, random phases), RMS ``rms``."""
    out = np.zeros_like(t)
    for c in cycles:
        out += np.sin(2 * np.pi * (c * t + rng.random()))
    return rms * out / np.sqrt(len(cycles) / 2.0)


def _rolled(c2w_gl: np.ndarray, roll_rad: np.ndarray) -> np.ndarray:
    """Each camera turned by its roll about its own optical axis."""
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    rz = np.zeros((len(roll_rad), 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    out = c2w_gl.copy()
    out[:, :3, :3] = c2w_gl[:, :3, :3] @ rz
    return out


#: A close view steps nearer by this factor until the image border cuts the object ...
CLOSE_STEP = 0.85
#: ... but no nearer than this many bounding radii from the object's middle.
CLOSE_MIN_RADII = 1.3


def cuts_object(cam: CameraIntrinsics, c2w_gl: np.ndarray, points_m: np.ndarray) -> bool:
    """Whether the image border of the camera ``c2w_gl`` (OpenGL axes) cuts the object ``points_m`` (P, 3):
    some of its points project outside the image, or lie behind the camera."""
    w2c = np.linalg.inv(c2w_gl @ CV_FROM_GL)
    p = points_m @ w2c[:3, :3].T + w2c[:3, 3]
    if np.any(p[:, 2] <= 1e-6):
        return True
    u, v = cam.fl_x * p[:, 0] / p[:, 2] + cam.cx, cam.fl_y * p[:, 1] / p[:, 2] + cam.cy
    return bool(np.any((u < 0) | (u > cam.width) | (v < 0) | (v > cam.height)))


def handheld_poses(config: HandheldConfig, target_m: np.ndarray, radius_m: float,
                   object_points_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """((views, 4, 4) camera-to-world poses, OpenGL axes; indices of the close views).

    One loop around the object (a little more for a video, whose ends overlap), the height
    swinging twice between ``elevation_deg``, the distance varying smoothly; photos add per-shot
    jitter (a person stops, frames and shoots), a video stays smooth. A close view stands at
    ``close_factor`` x the base distance; with ``close_cut`` and the object's points ``object_points_m``
    (P, 3), it then steps nearer by CLOSE_STEP until the image border cuts the object (a tall object seen from above
    fills less of the view than its bounding sphere), no nearer than CLOSE_MIN_RADII bounding radii."""
    rng = np.random.default_rng((config.seed, 29))
    n = int(config.views)
    t = np.arange(n) / n
    cam = config.camera()
    base_m = radius_m / np.tan(config.fill_fraction * np.arctan(0.5 * cam.height / cam.fl_y))
    lo_e, hi_e = np.radians(config.elevation_deg)
    phase = rng.random()
    elev = lo_e + (hi_e - lo_e) * 0.5 * (1 - np.cos(2 * np.pi * (2 * t + phase)))
    lo_d, hi_d = config.distance_factors
    dist = base_m * (lo_d + (hi_d - lo_d) * 0.5 * (1 + np.sin(2 * np.pi * (3 * t + rng.random()))))
    az = 2 * np.pi * (t * (1.08 if config.video else 1.0) + rng.random())
    roll = np.radians(_smooth_noise(rng, t, config.roll_deg))
    aim = np.stack([_smooth_noise(rng, t, config.aim_jitter * radius_m / np.sqrt(3)) for _ in range(3)], axis=1)
    close = np.zeros(0, dtype=int)
    if not config.video:
        az += rng.normal(0.0, 0.3 * np.pi / n, n)
        elev = np.clip(elev + np.radians(rng.normal(0.0, 3.0, n)), np.radians(5.0), np.radians(88.0))
        dist *= np.exp(rng.normal(0.0, 0.04, n))
        roll += np.radians(rng.normal(0.0, 0.5 * config.roll_deg, n))
        aim += rng.normal(0.0, 0.5 * config.aim_jitter * radius_m / np.sqrt(3), (n, 3))
        count = int(round(config.close_fraction * n))
        if count:
            close = np.unique(np.floor((np.arange(count) + 0.3) * n / count).astype(int))
            dist[close] = base_m * config.close_factor
    look = target_m + aim

    def poses(d: np.ndarray) -> np.ndarray:
        pos = target_m + np.c_[d * np.cos(elev) * np.cos(az), d * np.cos(elev) * np.sin(az), d * np.sin(elev)]
        return _rolled(np.stack([look_at_c2w_gl(p[None], q)[0] for p, q in zip(pos, look)]), roll)

    c2w = poses(dist)
    if object_points_m is not None and config.close_cut:
        for i in close:
            while not cuts_object(cam, c2w[i], object_points_m) and dist[i] * CLOSE_STEP >= CLOSE_MIN_RADII * radius_m:
                dist[i] *= CLOSE_STEP
                c2w[i] = poses(dist)[i]
    return c2w, close


def _blur_streaks(config: HandheldConfig) -> np.ndarray:
    """(views, 2) motion-blur streaks, px: independent hand shake per photo, a smooth one in a video."""
    rng = np.random.default_rng((config.seed, 30))
    n, rms = int(config.views), config.motion_blur_px * config.width / 640.0
    if config.video:
        t = np.arange(n) / n
        cycles = tuple(int(c) for c in np.maximum(1, np.round(np.array([3, 7, 13, 29]) * n / 600)))
        return np.stack([_smooth_noise(rng, t, rms / np.sqrt(2), cycles) for _ in range(2)], axis=1)
    angle = rng.uniform(0, np.pi, n)
    length = np.abs(rng.normal(0.0, rms, n))
    return np.c_[length * np.cos(angle), length * np.sin(angle)]


def _exposure_gains(config: HandheldConfig) -> np.ndarray:
    """(views, 3) gains: the phone's auto exposure (a smooth drift in a video), no white-balance change."""
    if config.video:
        t = np.arange(config.views) / config.views
        stops = _smooth_noise(np.random.default_rng((config.seed, 31)), t, config.exposure_jitter_stops)
        return np.repeat((2.0 ** stops)[:, None], 3, axis=1)
    return colour_gains(config.views, config.exposure_jitter_stops, 0.0, config.seed)


#: Auto-exposure brings the metered luminance (linear light) to this middle grey ...
AUTO_EXPOSURE_GREY = 0.18
#: ... within this many stops either way (a phone's exposure range for one scene).
AUTO_EXPOSURE_LIMIT_STOPS = 2.0


def auto_exposure_gain(rgb: np.ndarray) -> float:
    """The gain (linear light) a phone's auto-exposure gives the photo ``rgb`` (H, W, 3) uint8: its
    centre-weighted mean luminance (a Gaussian of 0.3 image sides) brought to middle grey, within
    +-AUTO_EXPOSURE_LIMIT_STOPS."""
    small = srgb_to_linear(np.asarray(rgb[::4, ::4], float) / 255.0)
    luminance = small @ np.array([0.2126, 0.7152, 0.0722])
    h, w = luminance.shape
    y, x = (np.arange(h) + 0.5) / h - 0.5, (np.arange(w) + 0.5) / w - 0.5
    weight = np.exp(-0.5 * (y[:, None] ** 2 + x[None, :] ** 2) / 0.3 ** 2)
    metered = float((weight * luminance).sum() / weight.sum())
    limit = 2.0 ** AUTO_EXPOSURE_LIMIT_STOPS
    return float(np.clip(AUTO_EXPOSURE_GREY / max(metered, 1e-6), 1.0 / limit, limit))


def _write_truth_files(gt: Path, config: HandheldConfig, cam: CameraIntrinsics, world_from_mesh: np.ndarray,
                       frames: list[Frame], close: np.ndarray, markers: MarkerLayout | None) -> None:
    block = {"source": "simulated handheld phone capture (Drake VTK)", "world_frame":
             "the board's frame: its centre the origin, the paper (table top) z = 0, z up, x along its long side, metres"
             if config.board is not None else "table top z=0, the object's footprint centre the origin, z up, metres",
             "paths_relative_to": "..", "close_views": [int(i) for i in close],
             "close_factor": config.close_factor, "room": config.room, "auto_exposure": config.auto_exposure,
             "markers": int(config.markers)}
    if config.video:
        block["video"] = {"file": VIDEO_NAME, "fps": config.fps, "frames": int(config.views),
                          "display_rotation_deg": config.video_rotation_deg}
    write_transforms(gt / "transforms.json", Dataset(gt.parent, cam, tuple(frames), {"real2sim": block}))
    (gt / "object_pose.json").write_text(json.dumps({
        "world_from_mesh": world_from_mesh.tolist(),
        "note": "4x4 placing ground_truth/mesh.obj in the world frame (table top z=0), metres"}, indent=2))
    cfg = asdict(config)
    cfg["intrinsics"] = asdict(cam)
    (gt / "capture_config.json").write_text(json.dumps(cfg, indent=2, default=list))
    if config.board is not None:
        (gt / "board.json").write_text(json.dumps({
            "board": config.board.to_json(), "world_from_board": np.eye(4).tolist(),
            "note": "the board lies flat on the table, its frame is the world frame (see capture/phone/board.py)"}, indent=2))
    if markers is not None:
        (gt / "markers.json").write_text(json.dumps(markers.to_json(), indent=2))


def capture_handheld(mesh: trimesh.Trimesh | Path | str, out_dir: Path | str, config: HandheldConfig = HandheldConfig(),
                     progress: ProgressFn | None = None, overwrite: bool = False) -> CaptureResult:
    """Render a handheld phone capture of ``mesh`` on a table (with the board under it when
    ``config.board``) into ``out_dir``: photos or a video plus ``ground_truth/`` (module docstring).
    The folder appears whole or not at all; ``progress("rendering", done, total)`` after each view."""
    t_start = time.perf_counter()
    config.validate()
    mesh = render_ready(mesh, config.texture_seed)
    cam = config.camera()
    world_from_mesh, target, radius = object_frame(mesh)
    if config.board is not None:  # a person frames the board too, most of it
        radius = max(radius, 0.6 * 0.5 * float(np.hypot(*config.board.size_m)))
    placed = trimesh.transform_points(mesh.vertices, world_from_mesh)
    poses, close = handheld_poses(config, target, radius, placed[:: max(1, len(placed) // 4000)])
    markers = None
    if config.markers:
        extent = np.ptp(placed, axis=0)
        markers = marker_layout(int(config.markers), config.marker_mm, config.marker_dictionary,
                                0.5 * float(np.hypot(*extent[:2])), config.seed)
    far_m = max(10.0, 2.0 * float(np.linalg.norm(poses[:, :3, 3], axis=1).max()))
    streaks, gains = _blur_streaks(config), _exposure_gains(config)
    progress = progress or null_progress
    with atomic_output_dir(Path(out_dir), overwrite=overwrite) as tmp:
        gt = tmp / "ground_truth"
        gt.mkdir()
        if not config.video:
            (gt / "masks").mkdir()
            (gt / "depth").mkdir()
        export_textured_obj(mesh, gt / "mesh.obj")
        work = Path(tempfile.mkdtemp(prefix="render-", dir=tmp))
        export_textured_obj(trimesh.graph.smooth_shade(mesh, angle=np.radians(30)), work / "object.obj")
        renderer = HandheldRenderer(build_handheld_scene(config, work / "object.obj", world_from_mesh, work, cam,
                                                         far_m, markers), cam, config.supersample, far_m)
        video = VideoWriter(tmp / VIDEO_NAME, config.width, config.height, config.fps, config.jpeg_quality,
                            config.video_rotation_deg) if config.video else None
        exif = None if config.video else phone_exif(config.fov_deg)
        frames = []
        t_render = time.perf_counter()
        for i, c2w in enumerate(poses):
            rgb, depth_m, label = renderer.render(c2w, streaks[i], truth=not config.video)
            exposure = auto_exposure_gain(rgb) if config.auto_exposure else 1.0
            rgb = apply_colour_gains(rgb, exposure * gains[i])
            if video is not None:
                video.write(rgb)
                frames.append(Frame(file_path=f"{VIDEO_NAME}#frame={i:05d}", transform_matrix=c2w,
                                    extra={"real2sim_video_frame": i, "real2sim_time_s": i / config.fps}))
            else:
                from PIL import Image

                name = photo_name(i)
                Image.fromarray(rgb).save(tmp / name, format="JPEG", quality=int(config.jpeg_quality), exif=exif)
                stem = Path(name).stem + ".png"
                save_png(gt / "masks" / stem, np.where(label == OBJECT_LABEL, 255, 0).astype(np.uint8))
                depth_mm = np.where(np.isfinite(depth_m), np.round(depth_m * 1000.0), 0)
                save_png(gt / "depth" / stem, np.clip(depth_mm, 0, 65535).astype(np.uint16))
                frames.append(Frame(file_path=name, transform_matrix=c2w, mask_path=f"ground_truth/masks/{stem}",
                                    extra={"real2sim_close": bool(np.isin(i, close)),
                                           "real2sim_exposure_gain": float(exposure * gains[i][1])}))
            progress("rendering", i + 1, len(poses))
        if video is not None:
            video.close()
        render_s = time.perf_counter() - t_render
        del renderer
        shutil.rmtree(work)
        _write_truth_files(gt, config, cam, world_from_mesh, frames, close, markers)
    return CaptureResult(out_dir=Path(out_dir).resolve(), num_views=len(poses), render_seconds=render_s,
                         total_seconds=time.perf_counter() - t_start)
