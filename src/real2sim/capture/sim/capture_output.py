"""Writing a simulated capture's files: images (PNG or JPEG, with per-view colour gains), masks,
depth, and the two transforms.json files (reported and exact poses). Layout: see
:mod:`real2sim.capture.sim.wrist_camera`."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, replace
from pathlib import Path
import numpy as np

from real2sim.capture.sim.capture_config import CaptureConfig
from real2sim.capture.sim.hard_rigs import apply_colour_gains, save_image
from real2sim.capture.sim.render_scene import OBJECT_LABEL, RenderScene
from real2sim.formats.dataset import (SUPPORT_Z_KEY, TABLE_PLANE_KEY, CameraIntrinsics, Dataset, Frame,
                                      write_transforms)
from real2sim.plumbing.progress import ProgressFn


def save_png(path: Path, array: np.ndarray) -> None:
    save_image(path, array)


def frame_name(i: int, suffix: str = ".png") -> str:
    return f"frame_{i:05d}{suffix}"


def hard_rig_record(config: CaptureConfig, cut: np.ndarray) -> dict:
    """transforms.json's account of the hard-rig settings used (empty for the default capture)."""
    record = {}
    if config.ring_elevation_deg is not None:
        record["ring_elevation_deg"] = config.ring_elevation_deg
    if config.focal_px is not None or config.fov_deg is not None:
        record["lens"] = {"focal_px": config.focal_px, "fov_deg": config.fov_deg}
    if config.cut_off_fraction > 0:
        record["cut_off_views"] = int(len(cut))
    if config.exposure_jitter_stops > 0 or config.white_balance_jitter > 0:
        record["exposure_jitter_stops"] = config.exposure_jitter_stops
        record["white_balance_jitter"] = config.white_balance_jitter
    if config.jpeg_quality is not None:
        record["jpeg_quality"] = config.jpeg_quality
    if config.no_table:
        record["support"] = "thin stand under the object (not in the masks), dark background, no table"
    return record


def write_transforms_files(tmp: Path, config: CaptureConfig, cam: CameraIntrinsics, frames_noisy: list[Frame],
                      frames_exact: list[Frame], cut: np.ndarray, gains: np.ndarray | None) -> None:
    """transforms.json (reported poses), ground_truth/transforms.json (exact poses; per frame, whether
    the border cuts the object and its colour gains, when those were asked for) and capture_config.json."""
    gt = tmp / "ground_truth"
    cfg = asdict(config)
    cfg["intrinsics"] = asdict(cam)
    block = {"source": "simulated capture (Drake VTK)", "pose_noise_mm": config.pose_noise_mm,
             "pose_noise_deg": config.pose_noise_deg, "seed": config.seed,
             "world_frame": "table top z=0, z up, metres"}
    extra: dict = {"real2sim": block}
    rig = hard_rig_record(config, cut)
    if rig:
        block["hard_rig"] = rig
    if config.no_table:
        block["world_frame"] = "the object's lowest point z=0 (the top of a thin stand; no table), z up, metres"
        extra[TABLE_PLANE_KEY] = False
        extra[SUPPORT_Z_KEY] = 0.0  # the stand's top: the rig knows where its object stands
    write_transforms(tmp / "transforms.json", Dataset(tmp, cam, tuple(frames_noisy), extra))
    for i, f in enumerate(frames_exact):
        more = {}
        if config.cut_off_fraction > 0:
            more["real2sim_cut_off"] = bool(np.isin(i, cut))
        if gains is not None:
            more["real2sim_colour_gains"] = [float(g) for g in gains[i]]
        if more:
            frames_exact[i] = replace(f, extra={**f.extra, **more})
    gt_extra: dict = {"real2sim": {"source": "exact poses of the simulated capture", "paths_relative_to": ".."}}
    if config.no_table:
        gt_extra[TABLE_PLANE_KEY] = False
        gt_extra[SUPPORT_Z_KEY] = 0.0
    # Same file_paths as the top level: they are relative to the dataset folder, not to ground_truth/.
    write_transforms(gt / "transforms.json", Dataset(tmp, cam, tuple(frames_exact), gt_extra))
    (gt / "capture_config.json").write_text(json.dumps(cfg, indent=2, default=list))


def render_views(scene: RenderScene, tmp: Path, exact: np.ndarray, noisy: np.ndarray, config: CaptureConfig,
                  gains: np.ndarray | None, progress: ProgressFn) -> tuple[list[Frame], list[Frame]]:
    """Every view's image, mask and depth (and the empty scene's, ``with_background``) into ``tmp``;
    the frames with the reported (``noisy``) poses and with the ``exact`` ones. Images get each
    view's colour ``gains`` (background images the same as their view) and are JPEG at
    ``config.jpeg_quality`` when set; masks and depth stay PNG."""
    gt = tmp / "ground_truth"
    n = len(exact)
    total = n * (2 if config.with_background else 1)
    suffix = ".png" if config.jpeg_quality is None else ".jpg"

    def write_image(path: Path, rgb: np.ndarray, i: int) -> None:
        save_image(path, rgb if gains is None else apply_colour_gains(rgb, gains[i]), config.jpeg_quality)

    frames_noisy, frames_exact = [], []
    for i in range(n):
        name = frame_name(i)
        rgb, depth_m, label = scene.render(exact[i])
        # Exactly the object's pixels: the table, a stand, the background are not.
        mask = np.where(label == OBJECT_LABEL, 255, 0).astype(np.uint8)
        write_image(tmp / "images" / frame_name(i, suffix), rgb, i)
        save_png(tmp / "masks" / name, mask)
        shutil.copyfile(tmp / "masks" / name, gt / "masks" / name)
        depth_mm = np.where(np.isfinite(depth_m), np.round(depth_m * 1000.0), 0)
        save_png(gt / "depth" / name, np.clip(depth_mm, 0, 65535).astype(np.uint16))
        fp, mp = f"images/{frame_name(i, suffix)}", f"masks/{name}"
        frames_noisy.append(Frame(file_path=fp, transform_matrix=noisy[i], mask_path=mp))
        frames_exact.append(Frame(file_path=fp, transform_matrix=exact[i], mask_path=mp))
        progress("rendering", i + 1, total)
    if config.with_background:
        scene.remove_object()
        for i in range(n):
            rgb, _, _ = scene.render(exact[i], depth=False, label=False)
            write_image(tmp / "background" / frame_name(i, suffix), rgb, i)
            progress("rendering", n + i + 1, total)
    return frames_noisy, frames_exact
