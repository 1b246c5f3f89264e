"""COLMAP's part of the pose refinement (:mod:`real2sim.capture.poses.refinement`): features,
matches of the chosen pairs, triangulation from the given poses and bundle adjustment.

pycolmap is imported inside the functions: the refinement checks for it first and says how to
install it.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from real2sim.capture.poses.refine_config import RefineConfig
from real2sim.formats.dataset import CV_FROM_GL, Dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress


def _camera_spec(ds: Dataset) -> tuple[str, str]:
    k = ds.intrinsics
    if any(v != 0.0 for v in (k.k1, k.k2, k.p1, k.p2)):
        return "OPENCV", ",".join(str(v) for v in (k.fl_x, k.fl_y, k.cx, k.cy, k.k1, k.k2, k.p1, k.p2))
    return "PINHOLE", ",".join(str(v) for v in (k.fl_x, k.fl_y, k.cx, k.cy))


def _write_feature_masks(ds: Dataset, names: list[str], mask_root: Path, dilation_px: int) -> None:
    """COLMAP masks: ``mask_root/<COLMAP image name>.png``, features kept where the mask is non-zero."""
    from PIL import Image
    from scipy import ndimage

    from real2sim.formats.dataset import load_mask

    mask_root.mkdir(parents=True, exist_ok=True)
    for f, name in zip(ds.frames, names):
        if f.mask_path is None:
            raise UserInputError(f"--features object needs masks, but frame {f.file_path} has no mask_path")
        m = load_mask(ds.root / f.mask_path)
        if dilation_px > 0:
            m = ndimage.binary_dilation(m, iterations=dilation_px)
        Image.fromarray((m * 255).astype(np.uint8)).save(mask_root / f"{name}.png")


def link_images(ds: Dataset, folder: Path) -> list[str]:
    """COLMAP's names of the dataset's images: ``folder/00000.png``, ... linked to each frame's image
    (copied where the file system has no symbolic links), in the dataset's order.

    Numbered names, because COLMAP's list of image pairs is space-separated text that cannot carry every file
    name (docs/design-notes/capture.md#refine-colmap)."""
    import os
    import shutil

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for i, f in enumerate(ds.frames):
        suffix = Path(f.file_path).suffix
        name = f"{i:05d}{suffix if suffix[1:].isalnum() else ''}"
        source = (ds.root / f.file_path).resolve()
        try:
            os.symlink(source, folder / name)
        except OSError:
            shutil.copyfile(source, folder / name)
        names.append(name)
    return names


def refine_steps(cfg: RefineConfig) -> int:
    """The refinement's counted steps: features, matching, each bundle-adjustment round, writing."""
    return 3 + cfg.ba_rounds


def run_colmap(ds: Dataset, cfg: RefineConfig, work: Path, pairs: list[tuple[int, int]],
               progress: ProgressFn | None = None
               ) -> tuple[dict[str, np.ndarray], dict[str, int], int, int, float | None, dict]:
    """Run COLMAP in ``work`` on the image ``pairs``; return refined cam_from_world (3x4, COLMAP
    frame) by file_path, observation counts by file_path, pair count, 3D point count, mean
    reprojection error, timings. :class:`ColmapFailure` when too little is found."""
    progress = progress or null_progress
    timings: dict[str, float] = {}
    image_dir = work / "images"
    names = link_images(ds, image_dir)
    db_path = _features_and_matches(ds, cfg, work, image_dir, names, pairs, progress, timings)
    c2w_cv = {name: f.transform_matrix @ CV_FROM_GL for name, f in zip(names, ds.frames)}
    rec = _seeded_reconstruction(c2w_cv, db_path, len(pairs))
    rec = _triangulate_and_adjust(ds, cfg, work, image_dir, db_path, rec, progress, timings)
    file_path = {name: f.file_path for name, f in zip(names, ds.frames)}
    refined, counts = {}, {}
    for image_id, img in rec.images.items():
        counts[file_path[img.name]] = int(img.num_points3D)
        if img.has_pose:
            refined[file_path[img.name]] = np.asarray(img.cam_from_world().matrix())
    return (refined, counts, len(pairs), rec.num_points3D(),
            float(rec.compute_mean_reprojection_error()), timings)


def _features_and_matches(ds: Dataset, cfg: RefineConfig, work: Path, image_dir: Path, names: list[str],
                          pairs: list[tuple[int, int]], progress: ProgressFn, timings: dict) -> Path:
    """SIFT features of every image (``image_dir/names``, in the dataset's order) and verified matches
    of ``pairs``: COLMAP's database in ``work``."""
    import pycolmap

    db_path = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model, reader.camera_params = _camera_spec(ds)
    if cfg.feature_region == "object":
        _write_feature_masks(ds, names, work / "feature_masks", cfg.mask_dilation_px)
        reader.mask_path = str(work / "feature_masks")
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = cfg.num_threads
    extraction.max_image_size = cfg.max_image_size
    extraction.sift.max_num_features = cfg.max_num_features
    # Upsampling (octave -1) finds more features in small images but is slower on large ones.
    extraction.sift.first_octave = (cfg.sift_first_octave if cfg.sift_first_octave is not None
                                    else (-1 if max(ds.intrinsics.width, ds.intrinsics.height) <= 400 else 0))
    extraction.use_gpu = False
    t0 = time.perf_counter()
    progress("extracting features", 0, refine_steps(cfg))
    pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    timings["features_s"] = time.perf_counter() - t0

    pairs_path = work / "pairs.txt"
    pairs_path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = cfg.num_threads
    matching.use_gpu = False
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pairs_path)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = cfg.min_num_inliers
    t0 = time.perf_counter()
    progress(f"matching {len(pairs)} pairs", 1, refine_steps(cfg))
    pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=pairing,
                               verification_options=verification, device=pycolmap.Device.cpu)
    timings["matching_s"] = time.perf_counter() - t0
    return db_path


def _seeded_reconstruction(c2w_cv: dict[str, np.ndarray], db_path: Path, num_pairs: int):
    """A reconstruction with the database's ids and the given poses (camera-to-world, OpenCV axes, by
    COLMAP image name) as initialisation."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(db_path) as db:
        cameras = db.read_all_cameras()
        images = db.read_all_images()
        num_verified = db.num_verified_image_pairs()
    if num_verified == 0:
        raise ColmapFailure(f"no image pair passed geometric verification ({num_pairs} pairs tried)")
    for cam in cameras:
        rec.add_camera_with_trivial_rig(cam)
    for img in images:
        cfw = np.linalg.inv(c2w_cv[img.name])[:3, :]
        rec.add_image_with_trivial_frame(pycolmap.Image(name=img.name, camera_id=img.camera_id,
                                                        image_id=img.image_id), pycolmap.Rigid3d(cfw))
    return rec


def _triangulate_and_adjust(ds: Dataset, cfg: RefineConfig, work: Path, image_dir: Path, db_path: Path, rec,
                            progress: ProgressFn, timings: dict):
    """Rounds of triangulation (the poses fixed) and bundle adjustment (poses and points)."""
    import pycolmap

    diag = max(ds.intrinsics.width, ds.intrinsics.height)
    init_err = cfg.init_max_reproj_error_px if cfg.init_max_reproj_error_px is not None else 0.05 * diag
    tri_opts = pycolmap.IncrementalPipelineOptions()
    tri_opts.num_threads = cfg.num_threads
    tri_opts.random_seed = cfg.seed
    # The triangulator's own global bundle adjustment would also move the poses, with the gauge
    # free (singular, slow); keep it to the points and adjust the poses in _bundle_adjust.
    tri_opts.fix_existing_frames = True
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = False
    ba.refine_principal_point = False
    ba.refine_extra_params = False
    ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    ba.ceres.loss_function_scale = cfg.robust_loss_scale_px
    ba.ceres.solver_options.num_threads = cfg.num_threads
    # Ceres' defaults (no function tolerance, 100 iterations) keep iterating after the poses stop moving.
    ba.ceres.solver_options.function_tolerance = cfg.ba_function_tolerance
    ba.ceres.solver_options.max_num_iterations = cfg.ba_max_iterations
    t0 = time.perf_counter()
    for rnd in range(cfg.ba_rounds):
        # The first triangulation sees the noisy poses: widen the tolerances so tracks survive.
        err = init_err if rnd == 0 else cfg.final_max_reproj_error_px
        tri_opts.triangulation.complete_max_reproj_error = err
        tri_opts.triangulation.merge_max_reproj_error = err
        tri_opts.triangulation.create_max_angle_error = 2.0 if rnd else 6.0
        tri_opts.triangulation.continue_max_angle_error = 2.0 if rnd else 6.0
        tri_opts.mapper.filter_max_reproj_error = err
        progress(f"triangulating + bundle adjustment (round {rnd + 1}/{cfg.ba_rounds})", 2 + rnd, refine_steps(cfg))
        out = work / f"tri_{rnd}"
        out.mkdir()
        rec = pycolmap.triangulate_points(rec, db_path, image_dir, out, clear_points=True, options=tri_opts)
        if rec.num_points3D() < 10:
            raise ColmapFailure(f"triangulation produced only {rec.num_points3D()} points")
        _bundle_adjust(rec, ba)
        obs = pycolmap.ObservationManager(rec)
        obs.filter_all_points3D(cfg.final_max_reproj_error_px if rnd else 2 * cfg.final_max_reproj_error_px, 1.0)
        _bundle_adjust(rec, ba)
    timings["triangulation_ba_s"] = time.perf_counter() - t0
    return rec


def _bundle_adjust(rec, options) -> None:
    """Bundle adjustment of all registered poses and points with the gauge fixed.

    With every pose free the problem has a 7-DoF gauge freedom (similarity), which
    leaves the normal equations singular: Ceres then fails many steps and crawls.
    Fixing the gauge on two cameras removes it; the final similarity alignment
    puts the model back onto the robot frame anyway."""
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()


class ColmapFailure(RuntimeError):
    """COLMAP found too little to refine the poses (the refinement falls back to the given ones)."""


@contextmanager
def colmap_logging(quiet: bool) -> Iterator[None]:
    """COLMAP's (glog's) logging for the block: to stderr only, never to a file.

    glog otherwise leaves a log file in /tmp at the first warning of every run. COLMAP's INFO
    log is hundreds of lines, its warnings (gauge fixing) are about its internals, and its errors
    are native ``file.cc:LINE]`` lines that the refinement turns into its own outcome (too few
    pairs, points or frames: a plain warning with the reason); one of them ("Stopping thread...")
    is printed at every Ctrl-C or SIGTERM. ``quiet`` keeps only fatal ones. The previous settings
    are restored.
    """
    import pycolmap

    log = pycolmap.logging
    saved = log.minloglevel, log.logtostderr
    log.minloglevel = max(saved[0], 3) if quiet else saved[0]
    log.logtostderr = True
    try:
        yield
    finally:
        log.minloglevel, log.logtostderr = saved
