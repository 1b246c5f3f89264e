"""The ``robot_frame`` stage of ``run``: a COLMAP capture (arbitrary frame and scale) -> a metric dataset copy.

Input: a dataset folder with ``images/``, masks for every frame, and a COLMAP model in
``sparse/0`` (cameras, images, points3D), or the masks stage's copy of one (which adds a
``transforms.json`` holding the model's poses, still in the model frame), or what nerfstudio's
``ns-process-data`` writes: a ``transforms.json`` in COLMAP's frame with axes swapped
(``applied_transform``), its sparse points in ``ply_file_path`` (``sparse_pc.ply``, in the same
frame) and the model in ``colmap/sparse/0`` (used, moved by ``applied_transform``, when the
point cloud is missing). Output:
``ASSETDIR/.run/robot_frame/``, a dataset in the robot frame -- z up, the table top at
z = 0, the object's footprint centred at x = y = 0, metres -- with ``transforms.json``
(OpenGL camera-to-world), the frames' images and masks, and ``robot_frame.json`` (the
similarity ``robot_from_model`` and how it was found). The math is in
:mod:`real2sim.capture.phone.robot_frame`.

Steps (all lengths before the last one in model units):

1. the sparse points within ``near_radius`` x (median camera distance) of the point the
   cameras look at, minus those inside the object's masks: the table around the object;
2. RANSAC plane, normal towards the cameras -> a rigid "table frame" (z up, table z = 0,
   origin under the look-at point); the plane of the **dense points** instead
   (:func:`table_plane_or_dense`, :mod:`real2sim.multiview.dense`) where the masks came from geometry
   (which found it already: ``dense_geometry.json``) or where the sparse points give none (a dozen
   close-ups triangulate a few dozen points near the object);
3. the object's height and footprint centre from the **visual hull of the masks, carved in
   the table frame** (:func:`real2sim.multiview.hull.visual_hull_mesh`, ``hull_voxels``
   along its longest side). Why the hull and not the sparse points above the plane: (a)
   the silhouettes bound the top in every view, while a real capture's sparse cloud is
   thin on the object, often empty on a plain lid; (b) the asset is built from the same
   silhouettes, so with ``--object-height-m H`` the reconstruction comes out H tall (up
   to the grids' voxels). The price: the hull is an outer bound. Over a wide flat top
   that no view sees edge-on (a mug shot from above), every silhouette holds the top
   face's image, and the hull rises over it as a cone, r tan(lowest elevation) high
   (docs/design-notes/capture.md#normalise-object-top). So the top of the
   **sparse points on the object** (surface points, not a bound: the median of the
   ``top_points`` highest) replaces the hull's when the hull rises more than ``top_gap``
   of its height above them *and* what stands above them is such a cap, not the object
   going on full width (a featureless lid the SfM found no points on): the hull's volume
   above them under ``cap_fill`` of a prism on its cross-section there (a cone's is 1/3), that
   cross-section at least ``narrow_top`` of the hull's widest (a cap stands on a top face as wide as
   the object; a bottle's nozzle above the points is the object narrowing, too thin for them).
   Otherwise the hull's height, with a WARNING when the two disagree by more than ``top_gap``
   (:func:`object_top`). With the dense plane, the dense points on the object (their 99th
   percentile) stand in for the sparse ones, by the same rule;
4. scale: ``scale`` (metres per model unit) as given, or ``object_height_m`` / measured height, or with
   ``marker_mm`` the printed markers' side over their triangulated side; the markers' corners then give
   the table plane of step 2 too (:mod:`real2sim.capture.phone.markers`).

Ground truth: a simulated capture moved into a COLMAP frame (tests, benchmarks) keeps
``ground_truth/`` in its original robot frame and records the move as
``ground_truth/model_from_world.json`` (``{"model_from_world": 4x4 similarity}``). The
stage then knows ``robot_from_world = robot_from_model @ model_from_world`` -- ideally a
turn about z and an x/y shift -- records its errors (scale, table tilt and height:
:func:`real2sim.capture.phone.robot_frame.frame_errors`), and writes the copy's
``ground_truth/`` re-expressed in the new frame by the *rigid part* of that map (the true
object keeps its true size, so a scale error shows as a reconstruction error; the map is
exact at the true world's origin, the object's footprint centre on the table): the truth
comparison of ``run`` then aligns by the known similarity, with no ICP. ``depth/`` is
not copied (millimetres of the original frame; ``run`` does not read it). Without
``model_from_world.json`` the copy has no ``ground_truth/`` and ``run`` has no truth stage.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import (
    MODEL_FRAME_KEYS,
    Dataset,
    check_inside,
    describe_model_frame,
    is_model_frame,
    load_mask,
    read_dataset,
    read_ground_truth,
    write_transforms,
)
from real2sim.formats.colmap_model import read_colmap_model
from real2sim.plumbing.digests import tree_files
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import publish_dir, write_json_atomic
from real2sim.plumbing.progress import ProgressFn
from real2sim.capture.phone import robot_frame as rf
from real2sim.capture.phone.markers import markers_frame
from real2sim.capture.phone.normalise_config import NormaliseConfig
from real2sim.capture.phone.object_height import measure_object, object_top

MODEL_FROM_WORLD = "model_from_world.json"  # in ground_truth/: how a simulated capture was moved into the model frame
RECORD_NAME = "robot_frame.json"


def check_frame_options(ds: Dataset, scale_given: bool) -> None:
    """UserInputError (one line) unless a model-frame dataset (:func:`is_model_frame`: a COLMAP model,
    a nerfstudio-processed capture) comes with --object-height-m, --scale or --marker-mm (``scale_given``),
    and a metric transforms.json dataset (table at z = 0) with none."""
    if is_model_frame(ds) and not scale_given:
        raise UserInputError(f"{ds.root} is {describe_model_frame(ds)}: its poses have no metric scale and no "
                             "table frame; pass --object-height-m H (the object's height above the table, m), "
                             "--scale S (metres per model unit) or --marker-mm S (printed square markers' side)")
    if scale_given and not is_model_frame(ds):
        raise UserInputError(f"{ds.root} has a transforms.json in metres with the table at z = 0: --object-height-m, "
                             "--scale and --marker-mm are for a COLMAP model dataset (images + sparse/0) or an "
                             "ns-process-data folder (transforms.json with applied_transform)")


def write_model_transforms(root: Path) -> None:
    """Give a COLMAP dataset folder a ``transforms.json`` with the model's poses (still in the model frame),
    so that the masks stage can point its frames to masks; ``model_frame`` marks it."""
    ds = read_colmap_model(root)
    write_transforms(Path(root) / "transforms.json",
                     replace(ds, extra={"model_frame": "COLMAP sparse/0: arbitrary frame and scale, not metres"}))


def _colmap_points(model: Path) -> np.ndarray:
    """(P, 3) points3D of the COLMAP model folder ``model``, in its frame."""
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(model))
    except Exception as exc:  # pycolmap raises generic errors on bad files
        raise UserInputError(f"could not read COLMAP model {model}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    return np.array([p.xyz for p in rec.points3D.values()], dtype=float).reshape(-1, 3)


def _applied_transform(ds: Dataset) -> np.ndarray:
    """nerfstudio's ``applied_transform`` (3x4 or 4x4, model -> transforms.json frame) as a 3x4 array."""
    try:
        matrix = np.asarray(ds.extra["applied_transform"], dtype=float)
        if matrix.shape not in ((3, 4), (4, 4)) or not np.all(np.isfinite(matrix)):
            raise ValueError(f"shape {matrix.shape}")
    except (ValueError, TypeError) as exc:
        raise UserInputError(f"{ds.root / 'transforms.json'}: applied_transform is not a 3x4 matrix ({exc})") from None
    return matrix[:3]


def _point_cloud_file(ds: Dataset) -> str | None:
    """The point cloud a nerfstudio-processed transforms.json names (relative path), when it exists."""
    rel = ds.extra.get("ply_file_path")
    if not isinstance(rel, str):
        return None
    check_inside(Path(ds.root), rel, "transforms.json ply_file_path")
    return rel if (Path(ds.root) / rel).is_file() else None


def sparse_point_files(ds: Dataset) -> list[str]:
    """The files :func:`read_sparse_points` may read, relative to ``ds.root`` (for the run's input hashes)."""
    root, files = Path(ds.root), []
    for model in ("sparse/0", "colmap/sparse/0"):
        if (root / model).is_dir():
            files += [f"{model}/{rel}" for rel in tree_files(root / model)]
    cloud = _point_cloud_file(ds)
    return files + ([cloud] if cloud is not None else [])


def read_sparse_points(ds: Dataset) -> tuple[np.ndarray, str]:
    """(P, 3) sparse SfM points in ``ds``'s frame, and where they came from (a path relative to ``ds.root``).

    A COLMAP dataset (or the masks stage's copy of one): ``sparse/0``. A nerfstudio-processed
    capture: the point cloud ``ply_file_path`` names (nerfstudio writes it in the transforms.json
    frame), else ``colmap/sparse/0`` moved by ``applied_transform``."""
    root = Path(ds.root)
    if ds.extra.get("source") == "colmap" or "model_frame" in ds.extra:
        points, source = _colmap_points(root / "sparse" / "0"), "sparse/0"
    elif _point_cloud_file(ds) is not None:
        import trimesh

        rel = _point_cloud_file(ds)
        try:
            cloud = trimesh.load(root / rel)
            points = np.asarray(cloud.vertices, dtype=float).reshape(-1, 3)
        except Exception as exc:  # noqa: BLE001 -- trimesh raises many kinds on a bad file
            raise UserInputError(f"cannot read the sparse point cloud {root / rel}: "
                                 f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
        source = rel
    elif (root / "colmap" / "sparse" / "0").is_dir() and "applied_transform" in ds.extra:
        applied = _applied_transform(ds)
        points = _colmap_points(root / "colmap" / "sparse" / "0") @ applied[:, :3].T + applied[:, 3]
        source = "colmap/sparse/0 (moved by applied_transform)"
    else:
        raise UserInputError(f"{root}: no sparse points to find the table in: expected the point cloud that "
                             "transforms.json's ply_file_path names, or a COLMAP model in colmap/sparse/0")
    return points[np.all(np.isfinite(points), axis=1)], source


def _masks(ds: Dataset) -> np.ndarray:
    missing = [f.file_path for f in ds.frames if f.mask_path is None]
    if missing:
        raise UserInputError(f"{len(missing)} frames of {ds.root} have no mask (first: {missing[0]}): a COLMAP "
                             "capture needs masks to find the object; pass --mask provided|maskrcnn|background")
    return np.stack([load_mask(ds.root / f.mask_path) for f in ds.frames])


def points_near_object(c2w_cv: np.ndarray, points: np.ndarray, config: NormaliseConfig
                       ) -> tuple[np.ndarray, float, np.ndarray]:
    """(the point the cameras look at, the median camera distance from it, the sparse points within
    ``near_radius`` of those distances of it): step 1 without the masks (model units)."""
    look_at = rf.optical_axes_point(c2w_cv)
    distance = float(np.median(np.linalg.norm(c2w_cv[:, :3, 3] - look_at, axis=1)))
    return look_at, distance, points[np.linalg.norm(points - look_at, axis=1) <= config.near_radius * distance]


def table_plane(points: np.ndarray, c2w_cv: np.ndarray, distance: float, config: NormaliseConfig,
                seed: int) -> rf.Plane:
    """Step 2's plane: RANSAC on ``points`` (thresholds as fractions of ``distance``), normal towards the cameras."""
    plane = rf.fit_plane_ransac(points, config.inlier_threshold * distance, seed=seed,
                                iterations=config.ransac_iterations, min_inliers=config.min_table_points)
    return rf.orient_towards_cameras(plane, c2w_cv[:, :3, 3])


def table_plane_or_dense(ds: Dataset, points: np.ndarray, off_object: np.ndarray, c2w_cv: np.ndarray,
                         distance: float, config: NormaliseConfig, seed: int) -> tuple[rf.Plane, dict | None, dict]:
    """Step 2's plane, from the dense points (:mod:`real2sim.multiview.dense`) where the masks stage found them
    (``dense_geometry.json``: masks from geometry) or where the sparse points ``off_object`` (near the object, off
    its masks) give no plane; else from those. The plane, the dense record (None: not used) and how it was found.
    A WARNING when the sparse and the dense planes disagree by more than ``config.max_plane_disagreement_deg``,
    and for each doubt of the dense geometry found here."""
    import warnings

    from real2sim.multiview.dense import DENSE_RECORD, dataset_geometry, scene_json

    sparse, why = None, None
    try:
        sparse = table_plane(off_object, c2w_cv, distance, config, seed)
    except UserInputError as exc:
        why = str(exc)
    path = Path(ds.root) / DENSE_RECORD
    if path.is_file():
        dense = json.loads(path.read_text())
        record = {"from": "the dense points (the masks from geometry found them)"}
    elif sparse is None:
        geometry, _ = dataset_geometry(ds, points)
        for doubt in geometry.doubts:
            warnings.warn(f"dense geometry is doubtful: {doubt}", RuntimeWarning, stacklevel=2)
        dense = scene_json(geometry)
        record = {"from": "the dense points (the sparse points give no plane)"}
    else:
        return sparse, None, {"from": "the sparse points near the object"}
    plane = rf.Plane(np.asarray(dense["normal"], float), float(dense["offset"]), int(dense["record"]["plane_inliers"]),
                     int(dense["record"]["points_near"]), float(dense["band"]))
    record.update({"dense": dense["record"], "sparse_plane": why or f"{sparse.inliers} of {len(off_object)} points"})
    if sparse is not None:
        tilt = float(np.degrees(np.arccos(np.clip(abs(sparse.normal @ plane.normal), -1.0, 1.0))))
        record["sparse_vs_dense_deg"] = tilt
        if tilt > config.max_plane_disagreement_deg:
            warnings.warn(f"the table planes of the sparse and the dense points differ by {tilt:.1f} degrees: the "
                          "dense one is used; check that the table is flat and in view around the object",
                          RuntimeWarning, stacklevel=2)
    return plane, dense, record


def find_robot_frame(ds: Dataset, points: np.ndarray, masks: np.ndarray, config: NormaliseConfig,
                     seed: int) -> tuple[rf.Similarity, dict]:
    """``robot_from_model`` and a JSON-ready record of how it was found (steps 1-4 of the module docstring)."""
    c2w_cv = ds.poses_c2w_cv()
    look_at, distance, near = points_near_object(c2w_cv, points, config)
    on_object = rf.object_point_mask(near, ds.intrinsics, c2w_cv, masks, config.object_vote_fraction)
    markers, dense, plane_record = None, None, {"from": "the sparse points near the object"}
    if config.marker_mm is not None:  # scale and plane from the printed markers
        markers = markers_frame([ds.root / f.file_path for f in ds.frames], ds.intrinsics, c2w_cv, config.marker_mm,
                                config.marker_dictionary)
        plane = markers.plane
        plane_record = {"from": "the printed markers' corners"}
    else:
        plane, dense, plane_record = table_plane_or_dense(ds, points, near[~on_object], c2w_cv, distance, config, seed)
    table = rf.table_similarity(plane, centre=look_at)
    hull = measure_object(ds, masks, table, config)
    if not hull.top > 0:
        raise UserInputError("the masks' visual hull has no height above the fitted table plane")
    if config.object_height_m is not None and dense is not None:  # measured on the dense object
        height, top_record = object_top(hull, None, config, dense_top=dense["height"])
    elif config.object_height_m is not None:
        height, top_record = object_top(hull, table.apply(near[on_object])[:, 2], config)
    else:  # the height sets nothing
        given = "--scale" if config.scale is not None else "--marker-mm"
        height, top_record = hull.top, {"hull_top_units": hull.top, "from": f"the visual hull ({given} given)"}
    centre_xy = hull.centre_xy
    scale = (config.scale if config.scale is not None else markers.scale if markers is not None
             else config.object_height_m / height)
    centre = table.inverse().apply(np.array([centre_xy[0], centre_xy[1], 0.0]))
    robot_from_model = rf.table_similarity(plane, centre=centre, scale=scale)
    record = {
        "robot_from_model": robot_from_model.to_json(),
        "scale_from": ("scale" if config.scale is not None else "marker_mm" if markers is not None
                       else "object_height_m"),
        "object_height_m_given": config.object_height_m,
        "scale_given": config.scale,
        "hull_height_units": hull.top,
        "hull_height_m": hull.top * scale,
        "height_units": height,
        "height_m": height * scale,
        "object_top": top_record,
        "sparse_points": {"total": len(points), "near_object": len(near), "on_object": int(on_object.sum()),
                          "table_inliers": plane.inliers},
        "table_plane_model": {"normal": plane.normal.tolist(), "offset_units": plane.offset},
        "table_plane_from": plane_record,
        "table_fit_rms_mm": 1000.0 * plane.rms * scale,
        "inlier_threshold_mm": 1000.0 * plane.threshold * scale,
        "median_camera_distance_m": distance * scale,
        "seed": seed,
        **({"markers": markers.to_json()} if markers is not None else {}),
        "height_from": f"{top_record['from']}; the visual hull of the masks in the table frame, {config.hull_voxels} "
                       "voxels on its longest side",
    }
    return robot_from_model, record


def _copy_ground_truth(source: Path, target: Path, robot_from_world: rf.Similarity) -> None:
    """``source/ground_truth`` re-expressed in the robot frame by the rigid part of ``robot_from_world``."""
    rigid = robot_from_world.rigid_part()
    gt_src, gt_dst = source / "ground_truth", target / "ground_truth"
    skip = {"depth", "transforms.json", "object_pose.json", MODEL_FROM_WORLD}
    gt_dst.mkdir()
    for entry in gt_src.iterdir():
        if entry.name not in skip:
            (shutil.copytree if entry.is_dir() else shutil.copy2)(entry, gt_dst / entry.name)
    pose_file = gt_src / "object_pose.json"
    world_from_mesh = (np.asarray(json.loads(pose_file.read_text())["world_from_mesh"], float)
                       if pose_file.is_file() else np.eye(4))
    write_json_atomic(gt_dst / "object_pose.json", {
        "world_from_mesh": (rigid.matrix() @ world_from_mesh).tolist(),
        "note": "4x4 placing ground_truth/mesh.obj in this copy's robot frame: the source's world_from_mesh "
                "moved by the rigid part of robot_from_world (robot_frame.json), metres"})
    true_poses = read_ground_truth(source)
    if true_poses is not None:
        moved = rf.transform_poses(rigid, true_poses.poses_c2w_gl())
        frames = tuple(replace(f, transform_matrix=m) for f, m in zip(true_poses.frames, moved))
        write_transforms(gt_dst / "transforms.json", replace(true_poses, frames=frames))


def model_from_world(source: Path) -> rf.Similarity | None:
    path = Path(source) / "ground_truth" / MODEL_FROM_WORLD
    if not path.is_file():
        return None
    try:
        matrix = json.loads(path.read_text())["model_from_world"]
    except (ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"{path}: no readable model_from_world ({exc})") from None
    return rf.Similarity.from_matrix(matrix)


def normalise(source: Path, target: Path, config: NormaliseConfig, *, seed: int = 0,
              progress: ProgressFn | None = None) -> dict:
    """Write the robot-frame copy of ``source`` to ``target`` (whole or not at all); return the record."""
    config.validate()
    source, target = Path(source), Path(target)
    ds = read_dataset(source)
    if progress:
        progress("table plane, object height", 0, 0)
    points, points_from = read_sparse_points(ds)
    robot_from_model, record = find_robot_frame(ds, points, _masks(ds), config, seed)
    record["sparse_points"]["from"] = points_from
    truth, robot_from_world = model_from_world(source), None
    if truth is not None:  # model_from_world.json lives in ground_truth/
        robot_from_world = robot_from_model @ truth
        record["robot_from_world"] = robot_from_world.to_json()
        record["errors_vs_ground_truth"] = rf.frame_errors(robot_from_world)
    elif (source / "ground_truth").is_dir():
        record["ground_truth"] = f"not carried over: no ground_truth/{MODEL_FROM_WORLD} relates it to the model frame"
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        for frame in ds.frames:
            for rel in (frame.file_path, frame.mask_path):
                if not (source / rel).resolve().is_relative_to(source.resolve()):
                    raise UserInputError(f"{rel}: path points outside the dataset folder {source}")
                (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source / rel, tmp / rel)
        moved = rf.transform_poses(robot_from_model, ds.poses_c2w_gl())
        frames = tuple(replace(f, transform_matrix=m) for f, m in zip(ds.frames, moved))
        extra = {k: v for k, v in ds.extra.items() if k not in MODEL_FRAME_KEYS}
        extra["robot_frame"] = f"normalised from {describe_model_frame(ds)} by real2sim run: see {RECORD_NAME}"
        write_transforms(tmp / "transforms.json", Dataset(tmp, ds.intrinsics, frames, extra))
        if robot_from_world is not None:
            _copy_ground_truth(source, tmp, robot_from_world)
        write_json_atomic(tmp / RECORD_NAME, record)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, target)
    return record
