"""Simulated phone captures: what a person walking around an object with a phone gets.

An orbit at varying height and distance (:func:`handheld_poses`), the camera rolled a few degrees,
aimed a little off the object, some views so close that the image border cuts it; a phone lens
(about 65 degrees horizontal field of view), motion blur, a little auto-exposure drift and JPEG.
With a board (:mod:`.board`), the printed board lies flat on the table under the object and its
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
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import trimesh

from real2sim.capture.phone.board import BoardSpec, board_centre_on_page_dots, page_image
from real2sim.capture.sim.capture_output import save_png
from real2sim.capture.sim.hard_rigs import apply_colour_gains, colour_gains
from real2sim.capture.phone.media import LensWarp, VideoWriter, motion_blur, phone_exif, photo_name
from real2sim.capture.sim.render_scene import OBJECT_LABEL, RenderScene
from real2sim.capture.sim.textures import export_textured_obj, procedural_texture
from real2sim.capture.sim.wrist_camera import CaptureResult, look_at_c2w_gl, object_frame, render_ready
from real2sim.formats.dataset import CV_FROM_GL, CameraIntrinsics, Dataset, Frame, write_transforms
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import atomic_output_dir
from real2sim.plumbing.progress import ProgressFn, null_progress

#: The table top lies this far under the paper (z = 0), metres: a sheet's thickness, enough for the
#: depth buffer to keep the two apart.
PAPER_THICKNESS_M = 0.0002
#: Resolution of the board's texture on the table, dots per mm.
BOARD_TEXTURE_DOTS_PER_MM = 6
#: Printed paper is not a perfect white nor ink a perfect black under room light (0-255).
PAPER_WHITE, INK_BLACK = 236, 28
#: Name of the video a ``video`` capture writes.
VIDEO_NAME = "clip.mp4"


@dataclass(frozen=True)
class HandheldConfig:
    """A handheld phone capture. ``views``: photos, or video frames (``video``: ``views / fps`` seconds).

    ``fov_deg``: horizontal field of view (square pixels, centred principal point).
    ``elevation_deg``: the range the orbit's height swings through (two up-and-down swings in one
    loop), seen from the object's middle; ``distance_factors``: the range of the camera's distance
    as a multiple of the distance at which the object (with the board: at least most of the board)
    fills ``fill_fraction`` of the view's height; ``close_fraction`` of the photos are taken at
    ``close_factor`` of it, close enough for the border to cut the object. ``roll_deg``,
    ``aim_jitter``: RMS roll about the optical axis, degrees, and RMS aim off the object's middle as
    a fraction of its radius. ``motion_blur_px``: RMS blur streak length, px at 640 wide (photos:
    hand shake in a random direction; video: along the image motion over half a frame interval).
    ``exposure_jitter_stops``: RMS auto-exposure change. ``supersample``: rendered at this many
    times the size and averaged down (anti-aliasing, as a lens and sensor do).
    ``video_rotation_deg`` (0, 90, 180, 270): the video's frames are stored turned and the stream's
    display matrix says to turn them back by this much, counter-clockwise, as a phone held upright
    records (270: portrait); ``width`` x ``height`` and ground_truth/ are the picture as displayed.
    ``distortion_k1``, ``distortion_k2``: the lens's radial distortion (OpenCV's; phones mostly
    correct it, so 0 by default; k1 < 0 is barrel), stated in ground_truth/'s intrinsics.
    """

    views: int = 60
    width: int = 640
    height: int = 480
    fov_deg: float = 65.0
    seed: int = 0
    board: BoardSpec | None = None
    video: bool = False
    fps: float = 30.0
    jpeg_quality: int = 90
    elevation_deg: tuple[float, float] = (20.0, 72.0)
    distance_factors: tuple[float, float] = (0.85, 1.3)
    fill_fraction: float = 0.7
    close_fraction: float = 0.12
    close_factor: float = 0.55
    roll_deg: float = 4.0
    aim_jitter: float = 0.12
    motion_blur_px: float = 1.5
    exposure_jitter_stops: float = 0.1
    supersample: int = 2
    video_rotation_deg: int = 0
    distortion_k1: float = 0.0
    distortion_k2: float = 0.0
    table_size_m: float = 2.4
    texture_seed: int = 7

    def camera(self) -> CameraIntrinsics:
        fl = 0.5 * self.width / np.tan(np.radians(self.fov_deg) / 2)
        return CameraIntrinsics(width=self.width, height=self.height, fl_x=float(fl), fl_y=float(fl),
                                cx=self.width / 2.0, cy=self.height / 2.0, k1=float(self.distortion_k1),
                                k2=float(self.distortion_k2))

    def validate(self) -> None:
        if int(self.views) < 1:
            raise UserInputError(f"--views must be at least 1 (got {self.views})")
        if not (16 <= self.width <= 8192 and 16 <= self.height <= 8192):
            raise UserInputError(f"image size {self.width}x{self.height} out of range (16..8192 px)")
        if self.video and (self.width % 2 or self.height % 2):
            raise UserInputError(f"--video needs an even --width and --height (H.264), got {self.width}x{self.height}")
        if not (np.isfinite(self.fov_deg) and 20.0 <= self.fov_deg <= 120.0):
            raise UserInputError(f"--fov-deg must be in 20..120 for a handheld capture (got {self.fov_deg})")
        if not (np.isfinite(self.fps) and 1.0 <= self.fps <= 240.0):
            raise UserInputError(f"--fps must be in 1..240 (got {self.fps})")
        for name in ("distortion_k1", "distortion_k2"):
            if not (np.isfinite(getattr(self, name)) and abs(getattr(self, name)) <= 0.5):
                raise UserInputError(f"--{name.replace('_', '-')} must be in -0.5..0.5 (got {getattr(self, name)})")
        if self.video_rotation_deg not in (0, 90, 180, 270):
            raise UserInputError(f"--video-rotation-deg must be 0, 90, 180 or 270 (got {self.video_rotation_deg})")
        if self.video_rotation_deg and not self.video:
            raise UserInputError("--video-rotation-deg needs --video")
        if not 1 <= int(self.jpeg_quality) <= 100:
            raise UserInputError(f"--jpeg-quality must be in 1..100 (got {self.jpeg_quality})")
        if self.board is not None:
            self.board.validate()


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


def handheld_poses(config: HandheldConfig, target_m: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """((views, 4, 4) camera-to-world poses, OpenGL axes; indices of the close views).

    One loop around the object (a little more for a video, whose ends overlap), the height
    swinging twice between ``elevation_deg``, the distance varying smoothly; photos add per-shot
    jitter (a person stops, frames and shoots), a video stays smooth."""
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
    pos = target_m + np.c_[dist * np.cos(elev) * np.cos(az), dist * np.cos(elev) * np.sin(az), dist * np.sin(elev)]
    look = target_m + aim
    c2w = np.stack([look_at_c2w_gl(p[None], q)[0] for p, q in zip(pos, look)])
    return _rolled(c2w, roll), close


# ----------------------------------------------------------------------------- the scene


def _textured_quad_obj(path: Path, size_m: tuple[float, float], z_m: float, texture_png: Path) -> Path:
    """An OBJ of one upward-facing rectangle centred on the origin at height ``z_m``, its texture's
    top row towards +y (the printed page's top edge, as the board frame has it)."""
    w, h = size_m[0] / 2, size_m[1] / 2
    path.write_text(
        f"mtllib {path.stem}.mtl\nusemtl paper\n"
        f"v {-w} {-h} {z_m}\nv {w} {-h} {z_m}\nv {w} {h} {z_m}\nv {-w} {h} {z_m}\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    path.with_suffix(".mtl").write_text(f"newmtl paper\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nmap_Kd {texture_png.name}\n")
    return path


def _add_anchored(scene: RenderScene, shape, pose_m: np.ndarray, name: str, label: int, diffuse_map: Path | None) -> None:
    """Add a visible (perception) shape fixed in the world to an already built scene."""
    from pydrake.geometry import GeometryInstance, PerceptionProperties, RenderLabel
    from pydrake.math import RigidTransform

    geom = GeometryInstance(RigidTransform(pose_m), shape, name)
    props = PerceptionProperties()
    props.AddProperty("label", "id", RenderLabel(label))
    if diffuse_map is not None:
        props.AddProperty("phong", "diffuse_map", str(diffuse_map))
    geom.set_perception_properties(props)
    scene.sg.RegisterGeometry(scene.sg_context, scene.source, scene.sg.world_frame_id(), geom)


def _build_scene(config: HandheldConfig, mesh_obj: Path, world_from_mesh: np.ndarray, work: Path,
                 cam: CameraIntrinsics, far_m: float) -> RenderScene:
    """The object on a textured table, with the printed board under it when ``config.board``."""
    from pydrake.geometry import Box, Mesh

    from real2sim.capture.sim.render_scene import TABLE_LABEL

    # No table from RenderScene: ours sits a sheet's thickness lower, so that the paper is z = 0.
    scene = RenderScene(mesh_obj, world_from_mesh, None, config.table_size_m, cam, stand_m=None, far_m=far_m)
    table_png = work / "table_texture.png"
    save_png(table_png, procedural_texture(2048, config.texture_seed))
    top_m = -PAPER_THICKNESS_M if config.board is not None else 0.0
    thickness = 0.04
    pose = np.eye(4)
    pose[2, 3] = top_m - thickness / 2
    _add_anchored(scene, Box(config.table_size_m, config.table_size_m, thickness), pose, "table", TABLE_LABEL, table_png)
    if config.board is not None:
        page = page_image(config.board, "a4", BOARD_TEXTURE_DOTS_PER_MM)
        page = (INK_BLACK + (PAPER_WHITE - INK_BLACK) * (page.astype(float) / 255.0)).astype(np.uint8)
        page_png = work / "board_page.png"
        save_png(page_png, np.repeat(page[:, :, None], 3, axis=2))
        # Metres per texture dot from the squares themselves (a whole number of dots each), so that
        # the rendered squares are exactly ``square_m`` whatever the rounding of the page.
        m_per_dot = config.board.square_m / round(config.board.square_m * 1000.0 * BOARD_TEXTURE_DOTS_PER_MM)
        offset = board_centre_on_page_dots(config.board, page.shape, BOARD_TEXTURE_DOTS_PER_MM) * m_per_dot
        quad = _textured_quad_obj(work / "board.obj", (page.shape[1] * m_per_dot, page.shape[0] * m_per_dot), 0.0,
                                  page_png)
        pose = np.eye(4)
        pose[:2, 3] = -offset  # the chequered area's centre at the origin
        _add_anchored(scene, Mesh(str(quad)), pose, "board", TABLE_LABEL, None)
    return scene


# ----------------------------------------------------------------------------- rendering


class _Renderer:
    """Colour at ``supersample`` times the size (averaged down), depth and labels at the image's size,
    each rendered on the lens's pinhole canvas and seen through its distortion (:class:`LensWarp`)."""

    def __init__(self, scene: RenderScene, cam: CameraIntrinsics, supersample: int, far_m: float):
        from pydrake.geometry import ClippingRange, ColorRenderCamera, DepthRange, DepthRenderCamera, RenderCameraCore
        from pydrake.math import RigidTransform
        from pydrake.systems.sensors import CameraInfo

        k = int(supersample)
        self.lens = LensWarp(cam, cam.k1, cam.k2)
        c = self.lens.canvas

        def core(scale: int):
            # Pixel centres at u + 0.5 on both grids: a k x k block's mean lands on the small pixel's centre.
            info = CameraInfo(c.width * scale, c.height * scale, c.fl_x * scale, c.fl_y * scale, c.cx * scale,
                              c.cy * scale)
            return RenderCameraCore("vtk", info, ClippingRange(0.01, far_m), RigidTransform())

        self.big = ColorRenderCamera(core(k), False)
        self.small = ColorRenderCamera(core(1), False)
        self.depth = DepthRenderCamera(core(1), DepthRange(0.02, 0.9 * far_m))
        self.scene, self.k, self._RigidTransform = scene, k, RigidTransform

    def render(self, c2w_gl: np.ndarray, blur_px: np.ndarray, truth: bool):
        """(RGB uint8, depth m or None, label or None); ``blur_px``: the streak (2,), px of the output."""
        s = self.scene
        query = s.sg.get_query_output_port().Eval(s.sg_context)
        x_wc = self._RigidTransform(c2w_gl @ CV_FROM_GL)
        world = s.sg.world_frame_id()
        big = query.RenderColorImage(self.big, world, x_wc).data[:, :, :3].astype(np.float32)
        big = motion_blur(big, np.asarray(blur_px, dtype=float) * self.k)
        h, w = big.shape[0] // self.k, big.shape[1] // self.k
        rgb = self.lens.apply(big.reshape(h, self.k, w, self.k, 3).mean(axis=(1, 3)))
        rgb = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
        if not truth:
            return rgb, None, None
        # depth along the optical axis belongs to the 3D point, which the lens only moves in the image
        depth = self.lens.apply(query.RenderDepthImage(self.depth, world, x_wc).data[:, :, 0].copy(), nearest=True)
        label = self.lens.apply(query.RenderLabelImage(self.small, world, x_wc).data[:, :, 0].copy(), nearest=True)
        return rgb, depth, label


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


def _write_truth_files(gt: Path, config: HandheldConfig, cam: CameraIntrinsics, world_from_mesh: np.ndarray,
                       frames: list[Frame], close: np.ndarray) -> None:
    block = {"source": "simulated handheld phone capture (Drake VTK)", "world_frame":
             "the board's frame: its centre the origin, the paper (table top) z = 0, z up, x along its long side, metres"
             if config.board is not None else "table top z=0, the object's footprint centre the origin, z up, metres",
             "paths_relative_to": "..", "close_views": [int(i) for i in close]}
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
    poses, close = handheld_poses(config, target, radius)
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
        renderer = _Renderer(_build_scene(config, work / "object.obj", world_from_mesh, work, cam, far_m), cam,
                             config.supersample, far_m)
        video = VideoWriter(tmp / VIDEO_NAME, config.width, config.height, config.fps, config.jpeg_quality,
                            config.video_rotation_deg) if config.video else None
        exif = None if config.video else phone_exif(config.fov_deg)
        frames = []
        t_render = time.perf_counter()
        for i, c2w in enumerate(poses):
            rgb, depth_m, label = renderer.render(c2w, streaks[i], truth=not config.video)
            rgb = apply_colour_gains(rgb, gains[i])
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
                                    extra={"real2sim_close": bool(np.isin(i, close))}))
            progress("rendering", i + 1, len(poses))
        if video is not None:
            video.close()
        render_s = time.perf_counter() - t_render
        del renderer
        shutil.rmtree(work)
        _write_truth_files(gt, config, cam, world_from_mesh, frames, close)
    return CaptureResult(out_dir=Path(out_dir).resolve(), num_views=len(poses), render_seconds=render_s,
                         total_seconds=time.perf_counter() - t_start)
