"""`run PHOTOS_DIR|VIDEO`: unposed phone photos or a video -> a dataset the rest of `run` reads.

Two stages before the usual ones (:mod:`real2sim.pipeline.run`):

1. ``sfm``: for a video, frames chosen for sharpness and even spacing (:mod:`real2sim.capture.phone.video`);
   then structure from motion from scratch (:mod:`real2sim.capture.phone.sfm`; the printed board, where it
   is seen, measures each camera's focal length: :mod:`real2sim.capture.phone.board_focal`) ->
   ``ASSETDIR/.run/sfm/``, a COLMAP dataset: ``images/`` (undistorted, one pinhole camera),
   ``sparse/0`` (that camera, the registered images' poses and the sparse points, the model's
   arbitrary frame and scale) and ``sfm.json`` (what registered, what was left out and why, the
   estimated cameras, the chosen video frames). Cached like every stage: a later failure (no board)
   does not redo it.
2. ``board_frame`` (without ``--object-height-m``/``--scale``): the printed board
   (:mod:`real2sim.capture.phone.board`) found in the undistorted images gives the world frame
   (:func:`real2sim.capture.phone.board_frame.world_from_board_views`: table top z = 0, z up, the board's
   centre the origin, metres) -> ``ASSETDIR/.run/phone/``, a metric transforms.json dataset, with
   ``board_frame.json``. With ``--object-height-m`` or ``--scale`` the COLMAP dataset of stage 1 goes
   to the ``robot_frame`` stage instead, as a COLMAP capture does.

Ground truth (simulated captures, tests, benchmarks): a ``ground_truth/`` folder in PHOTOS_DIR, or
beside the VIDEO, with ``transforms.json`` (true poses; frames named like the photos, or for a video
one frame per clip frame in order) and ``mesh.obj``, in the board's frame. The sfm stage relates the
model to it by the similarity of the camera centres (``ground_truth/model_from_world.json``, what
:mod:`real2sim.capture.phone.normalise` reads), and the board_frame stage copies it unchanged: its
frame is the world frame the board defines, so every error of the board's frame shows in the truth
comparison.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from real2sim.capture.phone.sfm import SfmConfig, list_images
from real2sim.capture.phone.video import DEFAULT_FRAMES, VIDEO_SUFFIXES
from real2sim.formats.dataset import CV_FROM_GL, Dataset, Frame, read_ground_truth, write_transforms
from real2sim.geometry.silhouettes import filled_triangles
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import publish_dir, write_json_atomic
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.plumbing import digests

if TYPE_CHECKING:
    from real2sim.capture.phone.board import BoardSpec

SFM_DIRNAME, PHONE_DIRNAME = "sfm", "phone"
SFM_RECORD, BOARD_RECORD = "sfm.json", "board_frame.json"


@dataclass(frozen=True)
class PhoneInput:
    """A phone capture given to `run`: ``kind`` "photos" (``path`` a folder of images) or "video" (``path``
    the clip); ``files``: what the sfm stage reads, relative to ``root`` (its input hashes)."""

    path: Path
    kind: str
    root: Path
    files: tuple[str, ...]


@dataclass(frozen=True)
class PhoneConfig:
    """How a phone capture (photos or a video) becomes the dataset the rest of `run` reads."""

    frames: int = DEFAULT_FRAMES
    """Frames kept from a video for structure from motion; >= 1 (photos: unused)."""
    board_square_mm: float | None = None
    """The printed board's square as measured on the print, mm; > 0 (None: the board's own size)."""
    board: BoardSpec | None = None
    """The printed board (a :class:`real2sim.capture.phone.board.BoardSpec`); None: ``real2sim board``'s default."""
    sfm: SfmConfig = field(default_factory=SfmConfig)
    """Structure-from-motion settings."""


def phone_input(path: Path | str) -> PhoneInput | None:
    """``path`` as a phone capture, or None when it is a dataset (transforms.json, a COLMAP model) or
    something else that the dataset checks will name. UserInputError (one line) for a folder with no
    images."""
    path = Path(path).resolve()
    if path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES:
        truth = path.parent / "ground_truth"
        files = [path.name] + ([f"ground_truth/{p.relative_to(truth)}" for p in sorted(truth.rglob("*"))
                                if p.is_file()] if truth.is_dir() else [])
        return PhoneInput(path, "video", path.parent, tuple(files))
    if not path.is_dir() or (path / "transforms.json").exists() or (path / "sparse" / "0").is_dir():
        return None
    images = list_images(path)
    if not images:
        raise UserInputError(f"{path} holds no images (.jpg, .png, ...), no transforms.json and no COLMAP model "
                             "(sparse/0): give the folder of your photos, a video, or a dataset")
    truth = path / "ground_truth"
    files = [str(p.relative_to(path)) for p in images]
    files += [str(p.relative_to(path)) for p in sorted(truth.rglob("*")) if p.is_file()] if truth.is_dir() else []
    return PhoneInput(path, "photos", path, tuple(files))


def _write_model(folder: Path, names: tuple[str, ...], c2w_cv: np.ndarray, intrinsics, points: np.ndarray) -> None:
    """``folder/sparse/0``: a COLMAP model with one PINHOLE camera, the images' poses and the points."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    k = intrinsics
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=k.width, height=k.height,
                                                    params=[k.fl_x, k.fl_y, k.cx, k.cy], camera_id=1))
    for image_id, (name, pose) in enumerate(zip(names, c2w_cv), start=1):
        cfw = np.linalg.inv(pose)[:3, :]
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=image_id),
                                         pycolmap.Rigid3d(cfw))
    for xyz in points:
        rec.add_point3D(np.asarray(xyz, float), pycolmap.Track(), np.zeros(3, np.uint8))
    (folder / "sparse" / "0").mkdir(parents=True)
    rec.write(str(folder / "sparse" / "0"))


def _true_centres(truth_root: Path, sources: tuple[str, ...], frame_index: dict[str, int] | None) -> np.ndarray | None:
    """(N, 3) true camera centres of the registered images, or None when the truth does not name them all."""
    if frame_index is not None:  # a video: frames name their clip frame (else one per clip frame, in order)
        frames = json.loads((truth_root / "ground_truth" / "transforms.json").read_text()).get("frames", [])
        by_index = {int(f.get("real2sim_video_frame", i)): f["transform_matrix"] for i, f in enumerate(frames)}
        if not all(frame_index[s] in by_index for s in sources):
            return None
        return np.stack([np.asarray(by_index[frame_index[s]], float)[:3, 3] for s in sources])
    gt = read_ground_truth(truth_root)
    if gt is None:
        return None
    by_stem = {Path(f.file_path).stem: f.transform_matrix for f in gt.frames}
    if not all(Path(s).stem in by_stem for s in sources):
        return None
    return np.stack([np.asarray(by_stem[Path(s).stem], float)[:3, 3] for s in sources])


def _copy_truth(source: Path, target: Path, c2w_cv: np.ndarray, sources: tuple[str, ...],
                frame_index: dict[str, int] | None, record: dict) -> None:
    """``source/ground_truth`` copied to ``target`` with ``model_from_world.json``: the similarity of the true
    camera centres onto the model's (what the robot_frame stage and the board_frame stage's errors use)."""
    from real2sim.capture.poses.refinement import umeyama
    from real2sim.capture.phone.normalise import MODEL_FROM_WORLD

    truth = source / "ground_truth"
    centres = _true_centres(source, sources, frame_index) if (truth / "transforms.json").is_file() else None
    if centres is None:
        record["ground_truth"] = "none, or its transforms.json does not name the registered images"
        return
    shutil.copytree(truth, target / "ground_truth", ignore=shutil.ignore_patterns("depth", MODEL_FROM_WORLD))
    s, r, t = umeyama(centres, c2w_cv[:, :3, 3])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = s * r, t
    residual = np.linalg.norm(s * centres @ r.T + t - c2w_cv[:, :3, 3], axis=1) / s
    write_json_atomic(target / "ground_truth" / MODEL_FROM_WORLD, {
        "model_from_world": m.tolist(),
        "note": "similarity of the true camera centres onto the SfM model's, for the truth comparison only"})
    record["ground_truth"] = {"camera_centre_rms_mm": float(1000 * np.sqrt(np.mean(residual ** 2))),
                              "camera_centre_max_mm": float(1000 * residual.max())}


def run_sfm(phone: PhoneInput, target: Path, config: PhoneConfig, progress: ProgressFn | None = None) -> dict:
    """Stage 1 (module docstring) into ``target`` (whole or not at all); the record it writes as sfm.json."""
    from real2sim.capture.phone.sfm import structure_from_motion

    progress = progress or null_progress
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        record: dict = {"input": str(phone.path), "kind": phone.kind}
        frame_index = None
        if phone.kind == "video":
            from real2sim.capture.phone.video import decode_frames

            frames = decode_frames(phone.path, config.frames, progress, folder=tmp / "frames")
            paths = list(frames.paths)
            frame_index = {p.name: i for p, i in zip(paths, frames.indices)}
            record["video"] = frames.to_json()
        else:
            paths = list_images(phone.path)
        result = structure_from_motion(paths, tmp / "images", config.sfm, sequential=phone.kind == "video",
                                       progress=progress, board=board_layout(config))
        shutil.rmtree(tmp / "frames", ignore_errors=True)
        _write_model(tmp, result.names, result.camera_to_world, result.intrinsics, result.points)
        record.update(result.to_json())
        record["images"] = dict(zip(result.names, result.sources))
        if result.left_out:
            import warnings

            warnings.warn(f"structure from motion left out {len(result.left_out)} of "
                          f"{len(result.left_out) + len(result.names)} images (reasons in {SFM_RECORD}; first: "
                          f"{next(iter(result.left_out))}: {next(iter(result.left_out.values()))})",
                          RuntimeWarning, stacklevel=2)
        _copy_truth(phone.root, tmp, result.camera_to_world, result.sources, frame_index, record)
        write_json_atomic(tmp / SFM_RECORD, record)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, target)
    return record


def board_layout(config: PhoneConfig):
    """The board as printed, whatever its measured square: what the sfm stage looks for (a focal length
    measured on it does not depend on the board's size)."""
    from real2sim.capture.phone.board import DEFAULT_BOARD

    return config.board if config.board is not None else DEFAULT_BOARD


def board_spec(config: PhoneConfig):
    """The board with its measured square (``board_square_mm``): what the board_frame stage's metres rest on."""
    from dataclasses import replace

    board = board_layout(config)
    if config.board_square_mm is None:
        return board
    ratio = config.board_square_mm / (1000.0 * board.square_m)
    return replace(board, square_m=board.square_m * ratio, marker_m=board.marker_m * ratio)


def run_board_frame(source: Path, target: Path, config: PhoneConfig, progress: ProgressFn | None = None) -> dict:
    """Stage 2 (module docstring): the sfm stage's COLMAP dataset ``source`` -> the metric dataset ``target``."""
    from real2sim.capture.phone.board import detect_board
    from real2sim.capture.phone.board_frame import MIN_BOARD_VIEWS, world_from_board_views
    from real2sim.formats.colmap_model import read_colmap_model
    from real2sim.formats.dataset import load_image_rgb
    from real2sim.capture.phone import robot_frame as rf
    from real2sim.capture.phone.normalise import model_from_world

    progress = progress or null_progress
    spec = board_spec(config)
    ds = read_colmap_model(source)
    c2w_cv = {f.file_path: f.transform_matrix @ CV_FROM_GL for f in ds.frames}
    views = {}
    for i, frame in enumerate(ds.frames):
        views[frame.file_path] = detect_board(load_image_rgb(source / frame.file_path), spec, ds.intrinsics.matrix())
        progress("looking for the board", i + 1, len(ds.frames))
    found = sum(v is not None for v in views.values())
    if found < MIN_BOARD_VIEWS:  # here, naming the board: the world frame below cannot rest on fewer
        seen = "was not found in any" if found == 0 else f"was found in only {found}"
        fix = ("check that --board is the file `real2sim board` wrote for the board in the photos"
               if spec.source else "lay it flat under the object and keep it in view (`real2sim board` prints one; "
               "--board FILE for another layout)")
        raise UserInputError(f"the printed board ({spec.label()}) {seen} of the {len(views)} registered views; at "
                             f"least {MIN_BOARD_VIEWS} are needed for its world frame: {fix}, or pass "
                             "--object-height-m H (the object's height, m) or --scale S")
    frame = world_from_board_views(c2w_cv, views, spec)
    sim = rf.Similarity.from_matrix(frame.board_from_sfm)
    record = {"board": spec.to_json(), "found_in": found, "registered": len(views), "scale_m_per_unit": frame.scale,
              "views_used": len(frame.views_used), "views_rejected": list(frame.views_rejected),
              "camera_centre_residual_mm": frame.residual_mm, "reprojection_px": frame.reprojection_px,
              "board_from_sfm": frame.board_from_sfm.tolist()}
    truth = model_from_world(source)
    if truth is not None:  # the board's frame is the simulated world's: ideally the identity
        record["errors_vs_ground_truth"] = rf.frame_errors(sim @ truth)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        (tmp / "images").mkdir()
        frames = []
        for f in ds.frames:
            shutil.copy2(source / f.file_path, tmp / f.file_path)
            moved = rf.transform_poses(sim, f.transform_matrix[None])[0]
            frames.append(Frame(file_path=f.file_path, transform_matrix=moved))
        extra = {"real2sim": {"source": "phone capture: structure from motion, world frame from the printed board",
                              "world_frame": "the board's: table top z=0, z up, its centre the origin, metres"}}
        write_transforms(tmp / "transforms.json", Dataset(tmp, ds.intrinsics, tuple(frames), extra))
        if (source / "ground_truth").is_dir():
            from real2sim.capture.phone.normalise import MODEL_FROM_WORLD

            shutil.copytree(source / "ground_truth", tmp / "ground_truth", ignore=shutil.ignore_patterns(MODEL_FROM_WORLD))
        write_json_atomic(tmp / BOARD_RECORD, record)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, target)
    return record


def phone_stages(runner, phone: PhoneInput, run_dir: Path, config) -> Path:
    """Run (or skip, when current) the sfm and board_frame stages with ``runner``
    (:class:`real2sim.pipeline.runner.Runner`) for `run`'s ``config`` (a RunConfig); the dataset the
    following stages read: ``run_dir/phone`` (metric, the board's frame), or with object_height_m /
    scale ``run_dir/sfm`` (a COLMAP dataset for the robot_frame stage)."""
    from real2sim.pipeline import manifest as mf

    cfg = config.phone or PhoneConfig()
    settings = {"kind": phone.kind, "sfm": cfg.sfm, "board_layout": board_layout(cfg).to_json(),
                **({"frames": cfg.frames} if phone.kind == "video" else {})}
    sfm_dir, phone_dir = run_dir / SFM_DIRNAME, run_dir / PHONE_DIRNAME

    def sfm_work() -> dict:
        record = run_sfm(phone, sfm_dir, cfg, runner.progress)
        return {"result": {k: record[k] for k in ("registered", "mean_reprojection_px", "matching")}
                | {"left_out": len(record["left_out"])}}

    upstream = runner.stage("sfm", {"input": digests.files_digest(phone.root, list(phone.files))}, settings, None,
                            [f"{mf.RUN_DIRNAME}/{SFM_DIRNAME}"], sfm_work)
    if config.robot_frame() is not None:  # the user's scale: the robot_frame stage finds the table
        if runner.manifest.entry("board_frame"):
            runner.manifest.forget("board_frame")
            shutil.rmtree(phone_dir, ignore_errors=True)
        return sfm_dir

    def board_work() -> dict:
        record = run_board_frame(sfm_dir, phone_dir, cfg, runner.progress)
        keys = ("found_in", "registered", "scale_m_per_unit", "camera_centre_residual_mm", "reprojection_px")
        return {"result": {k: record[k] for k in keys} | {k: record[k] for k in ("errors_vs_ground_truth",) if k in record}}

    runner.stage("board_frame", {"sfm": digests.files_digest(sfm_dir, digests.tree_files(sfm_dir))},
                 {"board": board_spec(cfg).to_json()}, upstream, [f"{mf.RUN_DIRNAME}/{PHONE_DIRNAME}"], board_work)
    return phone_dir


#: In ``ASSETDIR/.run/``: the reconstruction's outline drawn over a few of the photos, to check by eye.
OUTLINE_PNG = "outline.png"


def write_outline(dataset: Path, mesh_path: Path, out_png: Path, views: int = 4, side_px: int = 480) -> Path:
    """``out_png``: the outline of the mesh at ``mesh_path`` (the frame of ``dataset``'s poses) drawn in green over
    ``views`` of ``dataset``'s photos spread through it, each no longer than ``side_px``, side by side in two rows.
    The check a capture without truth allows: an outline that leaves the object, or cuts into it, shows where
    the reconstruction (or its scale, or the table) went wrong."""
    import cv2
    from PIL import Image

    from real2sim.formats.dataset import load_image_rgb, read_dataset
    from real2sim.geometry.mesh_io import load_mesh

    ds = read_dataset(dataset)
    mesh = load_mesh(mesh_path)
    k = ds.intrinsics
    scale = min(1.0, side_px / max(k.width, k.height))
    size = (max(1, round(k.width * scale)), max(1, round(k.height * scale)))
    small = k.scaled(*size)
    picks = np.unique(np.linspace(0, len(ds.frames) - 1, min(views, len(ds.frames))).round().astype(int))
    panels = []
    for i in picks:
        frame = ds.frames[i]
        image = np.asarray(Image.fromarray(load_image_rgb(Path(dataset) / frame.file_path)).resize(size)).copy()
        w2c = np.linalg.inv(frame.transform_matrix @ CV_FROM_GL)
        cam = mesh.vertices @ w2c[:3, :3].T + w2c[:3, 3]
        z = np.maximum(cam[:, 2], 1e-9)
        uv = np.stack([small.fl_x * cam[:, 0] / z + small.cx, small.fl_y * cam[:, 1] / z + small.cy], axis=1)
        front = (cam[mesh.faces, 2] > 0).all(axis=1)
        drawn = filled_triangles(size[1], size[0], uv[mesh.faces[front]])
        contours, _ = cv2.findContours(drawn, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        contours = [c for c in contours if cv2.contourArea(c) >= 0.002 * drawn.size]
        cv2.drawContours(image, contours, -1, (40, 255, 40), max(1, round(side_px / 320)))
        panels.append(image)
    while len(panels) % 2:
        panels.append(np.zeros_like(panels[0]))
    rows = [np.concatenate(panels[j:j + 2], axis=1) for j in range(0, len(panels), 2)]
    out_png = Path(out_png)
    tmp = out_png.with_name(f".{out_png.name}.tmp")
    Image.fromarray(np.concatenate(rows, axis=0)).save(tmp, format="PNG")
    tmp.replace(out_png)
    return out_png
