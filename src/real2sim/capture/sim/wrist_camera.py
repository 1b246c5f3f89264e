"""Simulated wrist-camera capture of an object on a table, rendered by Drake's VTK engine.

World frame (metres): the table top is the plane z = 0, the object stands on it
with the centre of its footprint at the origin; z is up. The robot arm's base
sits at one side of the table (``ReachabilityModel.base_xy_m``), so its wrist
camera reaches the far side of the object only from high elevations -- the
uneven coverage of the paper's Fig. 4. Captures like real rigs' (a turntable ring, a long lens,
views cut by the image border, a thin stand instead of the table, exposure jitter, JPEG) are
``CaptureConfig`` options (:mod:`real2sim.capture.sim.hard_rigs`); without a table the object's lowest
point is still z = 0.

Output (a nerfstudio dataset, see ``docs/capture.md``)::

    OUT/
      transforms.json           poses as the robot reports them (exact poses + calibration noise)
      images/frame_00000.png    colour, 8-bit RGB (frame_00000.jpg with ``jpeg_quality``)
      masks/frame_00000.png     rendered object mask, 255 = object (never the table or a stand)
      background/frame_00000.png  (with_background) the empty table from the same poses
      ground_truth/
        transforms.json         the exact poses, same file_paths (relative to OUT, not to ground_truth/)
        depth/frame_00000.png   16-bit depth in millimetres along the optical axis (object, table or stand), 0 = none
        masks/frame_00000.png   copy of the rendered masks (reference for other maskers)
        mesh.obj (+ .mtl, .png) the object in its own frame
        object_pose.json        4x4 world_from_mesh placing mesh.obj in the world frame
        capture_config.json     the CaptureConfig used
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from real2sim.capture.sim.capture_config import CaptureConfig, CaptureResult
from real2sim.capture.sim.capture_output import render_views, save_png, write_transforms_files
from real2sim.capture.sim.hard_rigs import colour_gains, cut_off_poses, ring_poses, stand_size_m
from real2sim.capture.sim.look_at import look_at_c2w_gl
from real2sim.capture.sim.render_scene import (OBJECT_LABEL, STAND_LABEL, TABLE_LABEL,  # noqa: F401 (labels: public here)
                                           RenderScene)
from real2sim.capture.sim.textures import (export_textured_obj, has_texture, procedural_texture,  # noqa: F401
                                       with_procedural_texture)
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import atomic_output_dir
from real2sim.plumbing.progress import ProgressFn, null_progress


# ----------------------------------------------------------------------------- poses


def render_ready(mesh: trimesh.Trimesh | Path | str, texture_seed: int) -> trimesh.Trimesh:
    """The object as the captures render it: loaded (metres) when a path, checked (a valid mesh of an
    object's size), and given a procedural texture when it has none."""
    from real2sim.geometry.mesh_io import check_object_size, load_mesh, validate_mesh

    if not isinstance(mesh, trimesh.Trimesh):
        mesh = load_mesh(mesh)
    validate_mesh(mesh)
    check_object_size(mesh)
    if not has_texture(mesh):
        mesh = with_procedural_texture(mesh, seed=texture_seed + 1)
    return mesh


def object_frame(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray, float]:
    """(world_from_mesh 4x4, look-at target in world, bounding radius m): footprint centre at origin, bottom at z=0."""
    lo, hi = mesh.bounds
    world_from_mesh = np.eye(4)
    world_from_mesh[:3, 3] = [-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]]
    height = hi[2] - lo[2]
    target = np.array([0.0, 0.0, 0.45 * height])
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    return world_from_mesh, target, radius


def camera_poses(config: CaptureConfig, target_m: np.ndarray, radius_m: float) -> np.ndarray:
    """(views, 4, 4) exact camera-to-world poses (OpenGL axes): rings filtered by the arm's reach.

    Rings at ``config.elevations_deg`` and distances ``distance_factors`` x the
    distance at which the object fills ``fill_fraction`` of the vertical field of
    view; azimuths spaced evenly (count per ring proportional to its circumference),
    densified until at least ``views`` candidates are reachable, then ``views`` of
    them taken evenly along the ring order.
    """
    cam = config.camera()
    half_fov_y = np.arctan(0.5 * cam.height / cam.fl_y)
    base_dist = radius_m / np.tan(config.fill_fraction * half_fov_y)
    if config.ring_elevation_deg is not None:
        return ring_poses(config.views, config.ring_elevation_deg, base_dist * config.distance_factors[0], target_m)
    reach = config.reach
    if config.focal_px is not None or config.fov_deg is not None:
        # Another lens puts the camera nearer or farther than the wrist can: a tripod, not the arm.
        reach = replace(reach, r_min_m=0.0, r_max_m=np.inf)
    dists = base_dist * np.asarray(config.distance_factors, dtype=float)
    elevs = np.radians(np.asarray(config.elevations_deg, dtype=float))
    per_unit = max(config.views / (len(dists) * len(elevs)), 1.0)
    while True:
        cands = []
        for di, d in enumerate(dists):
            for ei, e in enumerate(elevs):
                n_az = max(1, int(np.ceil(per_unit * max(np.cos(e), 0.08) * 1.5)))
                # Stagger rings so that consecutive rings do not line up in azimuth.
                az = 2 * np.pi * (np.arange(n_az) + 0.5 * ((ei + di) % 2)) / n_az
                pos = np.c_[d * np.cos(e) * np.cos(az), d * np.cos(e) * np.sin(az), np.full(n_az, d * np.sin(e))]
                cands.append(target_m + pos)
        cands = np.concatenate(cands)
        ok = reach.reachable(cands, target_m)
        if ok.sum() >= config.views:
            break
        if len(cands) > max(20000, 50 * config.views) or (ok.sum() == 0 and len(cands) > 2000):
            raise UserInputError(
                f"the arm cannot reach {config.views} views of this object (only {int(ok.sum())} reachable); "
                "the object may be too large for the workspace")
        per_unit *= 1.5
    reach = cands[ok]
    pick = np.round(np.linspace(0, len(reach) - 1, config.views)).astype(int)
    return look_at_c2w_gl(reach[pick], target_m)


def perturb_poses(c2w: np.ndarray, noise_mm: float, noise_deg: float, seed: int) -> np.ndarray:
    """Calibration-like noise: each pose rotated about its camera centre and shifted, independently.

    The rotation vector and the translation are Gaussian with RMS magnitude
    ``noise_deg`` and ``noise_mm`` (isotropic, per-axis sigma = value / sqrt(3)).
    """
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    n = len(c2w)
    rotvec = rng.normal(0.0, np.radians(noise_deg) / np.sqrt(3), (n, 3))
    shift_m = rng.normal(0.0, 1e-3 * noise_mm / np.sqrt(3), (n, 3))
    out = c2w.copy()
    out[:, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix() @ c2w[:, :3, :3]
    out[:, :3, 3] += shift_m
    return out


#: Farther than this, a camera is refused: depth is written in whole millimetres as 16 bits.
MAX_CAMERA_DISTANCE_M = 25.0
#: With a table, every camera must stand at least this far above its top (else it looks at its edge or under it).
MIN_CAMERA_HEIGHT_M = 0.005


def rig_poses(config: CaptureConfig, mesh: trimesh.Trimesh, world_from_mesh: np.ndarray, target_m: np.ndarray,
              radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(exact camera-to-world poses (views, 4, 4), OpenGL; indices of the views cut by the image border).

    The arm's hemisphere (:func:`camera_poses`), or a turntable ring around the object's middle,
    then the cut-off views turned (:func:`~real2sim.capture.sim.hard_rigs.cut_off_poses`)."""
    if config.ring_elevation_deg is not None:
        target_m = np.array([0.0, 0.0, 0.5 * float(np.ptp(mesh.bounds[:, 2]))])  # elevation 0: level with the middle
    exact = camera_poses(config, target_m, radius_m)
    dist_m = float(np.linalg.norm(exact[:, :3, 3] - target_m, axis=1).max())
    if dist_m > MAX_CAMERA_DISTANCE_M:
        raise UserInputError(f"with this lens the cameras would stand {dist_m:.1f} m from the object to see it whole "
                             f"(at most {MAX_CAMERA_DISTANCE_M:g} m): use a shorter --focal-px or a wider --fov-deg")
    if not config.no_table and exact[:, 2, 3].min() < MIN_CAMERA_HEIGHT_M:
        raise UserInputError(f"--ring-elevation-deg {config.ring_elevation_deg:g} puts the cameras below the table top "
                             f"(z = {exact[:, 2, 3].min():.3f} m); raise it, or capture with --no-table")
    cut = np.zeros(0, dtype=int)
    if config.cut_off_fraction > 0:
        points_w = trimesh.transform_points(mesh.vertices, world_from_mesh)
        exact, cut = cut_off_poses(exact, config.camera(), points_w, config.cut_off_fraction, config.seed)
    return exact, cut


def capture(mesh: trimesh.Trimesh | Path | str, out_dir: Path | str, config: CaptureConfig = CaptureConfig(),
            progress: ProgressFn | None = None, overwrite: bool = False) -> CaptureResult:
    """Render a posed-image dataset of ``mesh`` standing on a textured table; write it to ``out_dir``.

    ``mesh``: a trimesh (metres; textured or not -- untextured meshes get a
    procedural texture so feature matching has something to hold on to) or a
    mesh file path. The folder appears whole or not at all. ``progress("rendering", done, total)``
    is called after each rendered view. ``config.no_table``: on a thin stand instead, and the
    dataset's transforms.json says ``"table_plane": false`` (``formats.dataset.TABLE_PLANE_KEY``).
    """
    t_start = time.perf_counter()
    config.validate()
    mesh = render_ready(mesh, config.texture_seed)
    cam = config.camera()
    world_from_mesh, target, radius = object_frame(mesh)
    exact, cut = rig_poses(config, mesh, world_from_mesh, target, radius)
    noisy = perturb_poses(exact, config.pose_noise_mm, config.pose_noise_deg, config.seed)
    jitter = config.exposure_jitter_stops > 0 or config.white_balance_jitter > 0
    gains = colour_gains(len(exact), config.exposure_jitter_stops, config.white_balance_jitter,
                         config.seed) if jitter else None
    far_m = max(10.0, 2.0 * float(np.linalg.norm(exact[:, :3, 3], axis=1).max()))

    with atomic_output_dir(Path(out_dir), overwrite=overwrite) as tmp:
        gt = tmp / "ground_truth"
        for sub in ("images", "masks", "ground_truth/depth", "ground_truth/masks"):
            (tmp / sub).mkdir(parents=True)
        if config.with_background:
            (tmp / "background").mkdir()
        export_textured_obj(mesh, gt / "mesh.obj")
        where = "the object's lowest point z=0, no table" if config.no_table else "table top z=0"
        (gt / "object_pose.json").write_text(json.dumps({
            "world_from_mesh": world_from_mesh.tolist(),
            "note": f"4x4 placing ground_truth/mesh.obj in the world frame ({where}), metres"}, indent=2))
        # The rendered copy splits vertices at sharp edges (30 deg) so that caps do not darken
        # the sides through averaged normals; the ground-truth mesh.obj stays as given.
        render_dir = Path(tempfile.mkdtemp(prefix="render-", dir=tmp))
        export_textured_obj(trimesh.graph.smooth_shade(mesh, angle=np.radians(30)), render_dir / "object.obj")
        table_tex = None
        if not config.no_table:
            table_tex = render_dir / "table_texture.png"
            save_png(table_tex, procedural_texture(2048, config.texture_seed))
        stand = stand_size_m(mesh.bounds) if config.no_table else None
        scene = RenderScene(render_dir / "object.obj", world_from_mesh, table_tex, config.table_size_m, cam,
                            stand_m=stand, far_m=far_m)
        n = len(exact)
        t_render = time.perf_counter()
        frames_noisy, frames_exact = render_views(scene, tmp, exact, noisy, config, gains, progress or null_progress)
        render_s = time.perf_counter() - t_render
        del scene
        shutil.rmtree(render_dir)
        write_transforms_files(tmp, config, cam, frames_noisy, frames_exact, cut, gains)
    return CaptureResult(out_dir=Path(out_dir).resolve(), num_views=n, render_seconds=render_s,
                         total_seconds=time.perf_counter() - t_start)
