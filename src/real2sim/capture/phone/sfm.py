"""Structure from motion from scratch (no poses given): phone photos or video frames -> camera poses,
one pinhole camera and undistorted images, with pycolmap.

Steps (:func:`structure_from_motion`):

1. images grouped into cameras (:func:`camera_groups`): photos by their size and EXIF camera (make,
   model, focal length), so each group of images from one camera setting shares one estimated
   camera; video frames are all one camera. EXIF orientation is applied first (a phone stores a
   portrait photo as a landscape image plus a rotation tag);
2. SIFT features; matching exhaustive for up to ``exhaustive_max_images`` photos, else (and for video
   frames always) each image with its ``sequential_overlap`` successors plus loop-closure pairs among
   key frames spaced ``loop_every`` apart. COLMAP's own loop detection needs a vocabulary-tree file that
   would have to be downloaded; an orbit around an object closes its loop through the key frames;
3. COLMAP's incremental mapper with the OPENCV model (focal length, principal point, k1, k2, p1, p2
   estimated per camera); the largest model is kept, and every image it does not hold is listed with
   the reason (no features, no verified match, matched but not registered);
3b. with a printed board given: each camera's focal length measured on the board where it is seen,
   and the model adjusted to it (:mod:`real2sim.capture.phone.board_focal`: SfM's own focal length is a
   fraction of a percent off, and the board's metres with it);
4. every registered image resampled (OpenCV's remap) into one distortion-free pinhole camera: the
   largest group's focal length and principal point at its size. The poses do not change.

Frames: poses are camera-to-world 4x4 in the model's arbitrary frame and scale, OpenCV camera axes
(x right, y down, z forward). pycolmap is imported inside the functions.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from real2sim.capture.phone.board import BoardSpec
from real2sim.capture.phone.sfm_images import camera_groups, stage_images, undistorted
from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress

#: File name endings read as photos (case-insensitive).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
MIN_REGISTERED = 8


@dataclass(frozen=True)
class SfmConfig:
    """Structure from motion settings: how images are matched, and the thresholds of COLMAP's incremental
    mapper."""

    exhaustive_max_images: int = 150
    """Photos are matched all against all up to this count; more photos, and video frames always, are matched
    sequentially with loop key frames."""
    sequential_overlap: int = 10
    """Successors each image is matched with in sequential matching (>= 1)."""
    loop_every: int = 5
    """Spacing of the key frames that are matched all against all for loop closure (>= 1)."""
    max_num_features: int = 8192
    """Most SIFT features per image."""
    max_image_size: int = 2000
    """Longer side (px) an image is reduced to for feature extraction."""
    small_image_px: int = 400
    """Images up to this many px on their longer side are small: SIFT doubles them first (octave -1) and
    takes features of lower contrast (peak threshold 0.004), for enough features to match."""
    first_octave: int | None = None
    """SIFT's first octave: -1 doubles the image first (finer features, COLMAP's default), 0 starts at its
    size; None: -1 for small images (``small_image_px``), else 0."""
    guided_matching: bool = False
    """Match again under each verified pair's epipolar geometry (COLMAP's guided matching): more matches
    on close, wide-baseline pairs, at more matching time."""
    min_group_images: int = 3
    """Images a camera group (one size and EXIF camera) needs for its camera to be estimated; smaller groups'
    images are left out."""
    min_registered: int = MIN_REGISTERED
    """Fewest images the model must register; fewer is a UserInputError."""
    focal_length_factor: float = 0.8
    """First guess of the focal length, times the image's longer side, when EXIF has none: a phone's main
    camera sees about 65-75 degrees across (COLMAP's own 1.2 guesses a 45 degree lens)."""
    init_min_num_inliers: int = 50
    """Inliers the mapper's first image pair needs (COLMAP's default: 100).
    (why: docs/design-notes/capture.md#sfm-mapper)"""
    init_min_tri_angle_deg: float = 8.0
    """Triangulation angle (degrees) the mapper's first image pair needs (COLMAP's default: 16).
    (why: docs/design-notes/capture.md#sfm-mapper)"""
    abs_pose_min_num_inliers: int = 15
    """Matches to the model's points an image needs to be registered (COLMAP's default: 30).
    (why: docs/design-notes/capture.md#sfm-mapper)"""
    num_threads: int = -1
    """COLMAP's threads; -1: every core."""
    seed: int = 0
    """The mapper's random seed."""


@dataclass(frozen=True)
class SfmResult:
    """``names``: the undistorted registered images written (file names in ``out_images``), in input order,
    ``sources`` the input file names they came from; ``camera_to_world``: (N, 4, 4) in the model frame,
    OpenCV axes; ``intrinsics``: the common pinhole camera of the undistorted images; ``points``: (P, 3) sparse
    points, model frame; ``left_out``: input name -> why it is not registered; ``cameras``: each
    group's estimated OPENCV camera."""

    names: tuple[str, ...]
    sources: tuple[str, ...]
    camera_to_world: np.ndarray
    intrinsics: CameraIntrinsics
    points: np.ndarray
    left_out: dict[str, str]
    cameras: tuple[dict, ...]
    mean_reprojection_px: float
    matching: str
    timings_s: dict = field(default_factory=dict)
    focal_from_board: tuple[dict, ...] = ()

    def to_json(self) -> dict:
        return {"registered": len(self.names), "left_out": self.left_out, "cameras": list(self.cameras),
                "points3d": len(self.points), "mean_reprojection_px": self.mean_reprojection_px,
                "matching": self.matching, "timings_s": self.timings_s, "focal_from_board": list(self.focal_from_board)}


def list_images(folder: Path) -> list[Path]:
    """The photos directly in ``folder`` (or in its ``images/`` when it has one), sorted by name."""
    folder = Path(folder)
    if (folder / "images").is_dir():
        folder = folder / "images"
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                  and not p.name.startswith("."))


def match_pairs(count: int, overlap: int, loop_every: int) -> list[tuple[int, int]]:
    """Image pairs (i < j) for ordered frames: each frame with its ``overlap`` successors, and the key
    frames (every ``loop_every``-th) with each other, which closes an orbit's loop."""
    pairs = {(i, j) for i in range(count) for j in range(i + 1, min(count, i + overlap + 1))}
    keys = list(range(0, count, max(1, loop_every)))
    pairs |= {(a, b) for n, a in enumerate(keys) for b in keys[n + 1:]}
    return sorted(pairs)


def _features_and_matches(work: Path, image_dir: Path, names: list[str], sequential: bool, config: SfmConfig,
                          max_side_px: int, progress: ProgressFn) -> str:
    import pycolmap

    db_path = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "RADIAL"
    reader.default_focal_length_factor = config.focal_length_factor
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = config.num_threads
    extraction.max_image_size = config.max_image_size
    extraction.sift.max_num_features = config.max_num_features
    # small images: upsample once (octave -1) for enough features, as the pose refinement does
    small = max_side_px <= config.small_image_px
    extraction.sift.first_octave = config.first_octave if config.first_octave is not None else -1 if small else 0
    if small:  # and a lower contrast threshold (docs/design-notes/capture.md#sfm-features)
        extraction.sift.peak_threshold = 0.004
    extraction.use_gpu = False
    progress("structure from motion: features", 0, 3)
    pycolmap.extract_features(db_path, image_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE if sequential else pycolmap.CameraMode.PER_FOLDER,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    matching.use_gpu = False
    matching.guided_matching = config.guided_matching
    if not sequential and len(names) <= config.exhaustive_max_images:
        progress(f"structure from motion: matching all {len(names) * (len(names) - 1) // 2} pairs", 1, 3)
        pycolmap.match_exhaustive(db_path, matching_options=matching, device=pycolmap.Device.cpu)
        return "exhaustive"
    if not sequential:
        import warnings

        warnings.warn(f"{len(names)} photos are more than {config.exhaustive_max_images} to match all against all: each "
                      "is matched with the photos taken just before and after it (by file name) and with key photos; "
                      "photos not taken in order around the object may not register", RuntimeWarning, stacklevel=2)
    pairs = match_pairs(len(names), config.sequential_overlap, config.loop_every)
    (work / "pairs.txt").write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(work / "pairs.txt")
    progress(f"structure from motion: matching {len(pairs)} sequential and loop pairs", 1, 3)
    pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    return f"sequential (overlap {config.sequential_overlap}) + loop key frames every {config.loop_every}"


def _map(work: Path, image_dir: Path, config: SfmConfig, progress: ProgressFn):
    """The largest model COLMAP's incremental mapper builds, or None."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = config.num_threads
    options.random_seed = config.seed
    options.ba_refine_focal_length = True
    options.ba_refine_principal_point = False  # poorly constrained from an orbit; the image centre is close
    options.ba_refine_extra_params = True
    options.mapper.init_min_num_inliers = config.init_min_num_inliers
    options.mapper.init_min_tri_angle = config.init_min_tri_angle_deg
    options.mapper.abs_pose_min_num_inliers = config.abs_pose_min_num_inliers
    progress("structure from motion: mapping", 2, 3)
    (work / "sparse").mkdir()
    models = pycolmap.incremental_mapping(work / "database.db", image_dir, work / "sparse", options=options)
    if not models:
        return None
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    _opencv_adjustment(rec, config)
    return rec


def _opencv_adjustment(rec, config: SfmConfig) -> None:
    """Each RADIAL camera (f, cx, cy, k1, k2) of ``rec`` turned into OPENCV (fx = fy = f, p1 = p2 = 0), then
    one bundle adjustment of poses, points and the distortion (k1, k2, p1, p2), the focal length kept.

    The mapper runs with one focal length (a phone's pixels are square) because fx and fy free are
    degenerate for an orbit (docs/design-notes/capture.md#sfm-mapper)."""
    import pycolmap

    for camera in rec.cameras.values():
        f, cx, cy, k1, k2 = np.asarray(camera.params, float)[:5]
        camera.model = pycolmap.CameraModelId.OPENCV
        camera.params = [f, f, cx, cy, k1, k2, 0.0, 0.0]
    _adjust_fixed_focal(rec, config)


def _adjust_fixed_focal(rec, config: SfmConfig) -> None:
    """One bundle adjustment of ``rec``'s poses, points and lens distortion, focal lengths and
    principal points held."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = False
    options.refine_principal_point = False
    options.refine_extra_params = True
    options.print_summary = False
    options.ceres.solver_options.num_threads = config.num_threads
    ba_config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        ba_config.add_image(image_id)
    ba_config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, ba_config, rec).solve()


def _reasons(db_path: Path, rec, names: list[str]) -> dict[str, str]:
    """Why each image named in the database is not in ``rec`` (COLMAP name -> reason)."""
    import pycolmap

    registered = {rec.image(i).name for i in rec.reg_image_ids()} if rec is not None else set()
    with pycolmap.Database.open(db_path) as db:
        images = {img.image_id: img.name for img in db.read_all_images()}
        keypoints = {name: db.num_keypoints_for_image(i) for i, name in images.items()}
        pair_ids, geometries = db.read_two_view_geometries()
    verified = {name: 0 for name in images.values()}
    for pair_id, geometry in zip(pair_ids, geometries):
        if len(geometry.inlier_matches) > 0:
            for image_id in pycolmap.pair_id_to_image_pair(pair_id):
                verified[images[image_id]] += 1
    reasons = {}
    for name in names:
        if name in registered:
            continue
        if keypoints.get(name, 0) == 0:
            reasons[name] = "no features found (blank, blurred or too dark)"
        elif verified.get(name, 0) == 0:
            reasons[name] = f"{keypoints[name]} features, but no image pair passed geometric verification"
        else:
            reasons[name] = (f"matched with {verified[name]} images, but the mapper could not register it in the "
                             "largest model (too few matches to its points, or another part of the scene)")
    return reasons


def _camera_record(camera) -> dict:
    params = np.asarray(camera.params, float)
    return {"model": camera.model.name, "width": int(camera.width), "height": int(camera.height),
            "params": params.tolist(), "param_names": "fx, fy, cx, cy, k1, k2, p1, p2"}


def structure_from_motion(paths: list[Path], out_images: Path, config: SfmConfig = SfmConfig(), *,
                          sequential: bool = False, progress: ProgressFn | None = None,
                          board: BoardSpec | None = None) -> SfmResult:
    """Poses and one undistorted pinhole camera for the images ``paths`` (module docstring); the
    registered images are written, undistorted, as ``out_images/<stem>.png``. ``sequential``: frames
    of one video (one camera; sequential and loop matching). ``board``: the printed board's layout
    (its square size does not matter here), looked for in the registered images to measure each
    camera's focal length (:mod:`real2sim.capture.phone.board_focal`; step 3b). UserInputError (one line)
    when fewer than ``config.min_registered`` images register."""
    import pycolmap
    from PIL import Image

    from real2sim.capture.poses.colmap import colmap_logging

    progress = progress or null_progress
    paths = [Path(p) for p in paths]
    if sequential:
        groups, left_out = [0] * len(paths), {}
    else:
        groups, left_out = camera_groups(paths, config.min_group_images)
    kept = [i for i, g in enumerate(groups) if g >= 0]
    timings: dict[str, float] = {}
    work = Path(tempfile.mkdtemp(prefix="real2sim-sfm-"))
    try:
        image_dir = work / "images"
        names = stage_images([paths[i] for i in kept], [groups[i] for i in kept], image_dir)
        with Image.open(image_dir / names[0]) as first:
            max_side = max(first.size)
        with colmap_logging(quiet=True):
            t0 = time.perf_counter()
            matching = _features_and_matches(work, image_dir, names, sequential, config, max_side, progress)
            timings["features_matching_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            rec = _map(work, image_dir, config, progress)
            timings["mapping_s"] = time.perf_counter() - t0
        source_of = {name: paths[i].name for name, i in zip(names, kept)}
        left_out.update({source_of[n]: why for n, why in _reasons(work / "database.db", rec, names).items()})
        count = rec.num_reg_images() if rec is not None else 0
        if count < config.min_registered:
            raise UserInputError(f"structure from motion registered {count} of {len(paths)} images (need at least "
                                 f"{config.min_registered}): take more photos, overlapping, of a textured scene "
                                 f"around the object{_first_reason(left_out)}")
        focal = ()
        if board is not None:  # step 3b
            from real2sim.capture.phone.board_focal import set_focal_from_board

            t0 = time.perf_counter()
            focal = set_focal_from_board(rec, image_dir, board, progress)
            if any(record["board_focal_px"] is not None for record in focal):
                _adjust_fixed_focal(rec, config)
            timings["board_focal_s"] = time.perf_counter() - t0
        return replace(_result(rec, image_dir, names, source_of, left_out, out_images, matching, timings, progress),
                       focal_from_board=focal)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _first_reason(left_out: dict[str, str]) -> str:
    if not left_out:
        return ""
    name, why = next(iter(left_out.items()))
    return f" (e.g. {name}: {why})"


def _result(rec, image_dir: Path, names: list[str], source_of: dict[str, str], left_out: dict[str, str], out_images: Path,
            matching: str, timings: dict, progress: ProgressFn) -> SfmResult:
    """Undistorted images and the result from the largest model ``rec``."""
    from PIL import Image

    t0 = time.perf_counter()
    by_name = {rec.image(i).name: rec.image(i) for i in rec.reg_image_ids()}
    order = [n for n in names if n in by_name]
    per_camera = {}
    for n in order:
        per_camera[by_name[n].camera_id] = per_camera.get(by_name[n].camera_id, 0) + 1
    main = rec.camera(max(per_camera, key=per_camera.get))
    fx, fy, cx, cy = np.asarray(main.params, float)[:4]
    target = CameraIntrinsics(int(main.width), int(main.height), fx, fy, cx, cy)
    out_images = Path(out_images)
    out_images.mkdir(parents=True, exist_ok=True)
    c2w, image_dir_names, sources, written = [], [], [], set()
    for k, n in enumerate(order):
        image = by_name[n]
        cfw = np.eye(4)
        cfw[:3, :] = image.cam_from_world().matrix()
        c2w.append(np.linalg.inv(cfw))
        with Image.open(image_dir / n) as im:
            rgb = np.asarray(im.convert("RGB"))
        out_name = f"{Path(source_of[n]).stem}.png"
        if out_name in written:  # a.jpg and a.png: keep both
            out_name = f"{Path(source_of[n]).stem}_{k:05d}.png"
        written.add(out_name)
        Image.fromarray(undistorted(rgb, rec.camera(image.camera_id), target)).save(out_images / out_name)
        image_dir_names.append(out_name)
        sources.append(source_of[n])
        progress("undistorting images", k + 1, len(order))
    timings["undistort_s"] = time.perf_counter() - t0
    points = np.array([p.xyz for p in rec.points3D.values()], float).reshape(-1, 3)
    cameras = tuple({**_camera_record(rec.camera(cid)), "images": per_camera[cid]} for cid in sorted(per_camera))
    return SfmResult(tuple(image_dir_names), tuple(sources), np.stack(c2w), target, points, dict(left_out), cameras,
                     float(rec.compute_mean_reprojection_error()), matching, timings)
