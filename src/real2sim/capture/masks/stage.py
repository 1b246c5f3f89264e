"""Masks for `real2sim mask` and `run`: the capture stage's methods, ``parallax``, ``geometry``, and ``auto``.

``parallax`` (:mod:`real2sim.capture.masks.parallax`) needs poses and the table plane, not
weights or an empty scene: for a dataset in the robot frame the plane is z = ``table_z_m``; for a
COLMAP model (a phone capture, arbitrary frame and scale) it is found first by RANSAC on the sparse
points around the point the cameras look at, and the views are moved into that plane's frame.

``geometry`` (:mod:`real2sim.multiview.dense`) needs poses alone, no table plane or scale: dense depth, the
plane and the object standing on it, each mask the object's solid drawn into the view; it writes the plane and
the object (the dataset's frame and unit) to ``dense_geometry.json`` beside transforms.json, which the
robot_frame stage reads. ``auto`` (a phone capture's default in `run`) makes parallax masks and keeps them
unless the data shows they cannot be the object's: no table plane in the sparse points, or masks that reach
the border in most views or cover nearly all of an image (:func:`real2sim.capture.masks.parallax.mask_doubts`);
then it makes masks from geometry, with a WARNING that says why. ``mask_choice.json`` says which and why.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from real2sim.formats.dataset import MODEL_FRAME_KEYS, Dataset, check_dataset_outputs, is_model_frame, read_dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress

PARALLAX, GEOMETRY, AUTO = "parallax", "geometry", "auto"
#: Beside transforms.json after ``auto``: the method chosen and why.
MASK_CHOICE = "mask_choice.json"


def make_masks(dataset_dir: Path | str, method: str, cfg=None, *, table_z_m: float = 0.0, seed: int = 0,
               progress: ProgressFn = null_progress, may_replace: str = "unchanged"):
    """:func:`real2sim.capture.compute_masks` for its methods (``cfg``: its MaskConfig), or parallax masks;
    a :class:`~real2sim.capture.masks.methods.MaskResult` either way; for parallax ``cfg`` may be a
    :class:`~real2sim.capture.masks.parallax_config.ParallaxConfig` (its table height is ``table_z_m``'s). ``masks_<method>/`` is replaced only
    when `mask` made it and holds nothing else (:mod:`real2sim.capture.masks.folder`; ``may_replace``: its
    policy, "edited" for ``mask --overwrite``, "any" for `run`'s private copy of a dataset)."""
    from real2sim.capture.masks.folder import check_mask_folder
    from real2sim.capture.masks.methods import MaskConfig, compute_masks, publish_masks

    if method == AUTO:
        return _auto_masks(Path(dataset_dir), cfg, table_z_m, seed, progress, may_replace)
    if method == GEOMETRY:
        return _geometry_masks(Path(dataset_dir), progress, may_replace)
    if method != PARALLAX:
        return compute_masks(dataset_dir, method, cfg or MaskConfig(), progress=progress, may_replace=may_replace)
    from real2sim.capture.masks.parallax_config import ParallaxConfig
    from real2sim.capture.masks.parallax import parallax_masks, render_silhouettes
    from real2sim.multiview.views import load_views

    root = Path(dataset_dir)
    ds = read_dataset(root)
    if ds.extra.get("source") == "colmap":
        raise UserInputError(f"{root} has no transforms.json; masks need one to point to them")
    check_dataset_outputs(root, files=("transforms.json",), folders=(f"masks_{PARALLAX}",), what="mask output")
    check_mask_folder(root, ds, PARALLAX, may_replace)
    config = replace(cfg if isinstance(cfg, ParallaxConfig) else ParallaxConfig(), table_z_m=table_z_m)
    table_frame = _table_frame(ds, seed) if is_model_frame(ds) else ds
    views = load_views(table_frame, need_masks=False, max_side_px=config.max_image_px)
    solid = parallax_masks(views, config, progress)
    masks = render_silhouettes(solid, table_frame.intrinsics, table_frame.poses_c2w_cv(), progress)
    return publish_masks(root, ds, PARALLAX, lambda i, _frame: masks[i], progress, may_replace=may_replace)


def _table_frame(ds: Dataset, seed: int) -> Dataset:
    """``ds`` with its poses in a rigid frame whose z = 0 is the table plane fitted to the sparse points near
    the cameras' common point (model units; the scale is not needed for masks)."""
    from real2sim.capture.phone import robot_frame as rf
    from real2sim.capture.phone.normalise import points_near_object, read_sparse_points, table_plane
    from real2sim.capture.phone.normalise_config import NormaliseConfig

    settings = NormaliseConfig()
    points, _ = read_sparse_points(ds)
    c2w_cv = ds.poses_c2w_cv()
    look_at, distance, near = points_near_object(c2w_cv, points, settings)
    # Without masks the object's own points stay in; the table around it outnumbers them in a usual capture.
    plane = table_plane(near, c2w_cv, distance, settings, seed)
    poses = rf.transform_poses(rf.table_similarity(plane, centre=look_at), ds.poses_c2w_gl())
    frames = tuple(replace(f, transform_matrix=pose) for f, pose in zip(ds.frames, poses))
    return replace(ds, frames=frames, extra={k: v for k, v in ds.extra.items() if k not in MODEL_FRAME_KEYS})


def _geometry_masks(root: Path, progress: ProgressFn, may_replace: str):
    """Masks from geometry (module docstring), and ``dense_geometry.json``; a WARNING for each doubt."""
    import warnings

    import numpy as np

    from real2sim.capture.masks.folder import check_mask_folder
    from real2sim.capture.masks.methods import publish_masks
    from real2sim.multiview.dense import DENSE_RECORD, dataset_geometry, geometry_masks, scene_json
    from real2sim.plumbing.outputs import write_json_atomic

    ds = read_dataset(root)
    if ds.extra.get("source") == "colmap":
        raise UserInputError(f"{root} has no transforms.json; masks need one to point to them")
    check_dataset_outputs(root, files=("transforms.json", DENSE_RECORD), folders=(f"masks_{GEOMETRY}",),
                          what="mask output")
    check_mask_folder(root, ds, GEOMETRY, may_replace)
    points = _sparse_points(ds)
    progress("masks from geometry: dense depth", 0, 0)
    geometry, views = dataset_geometry(ds, points)
    for doubt in geometry.doubts:
        warnings.warn(f"dense geometry is doubtful: {doubt}", RuntimeWarning, stacklevel=2)
    progress("masks from geometry: outlines", 0, 0)
    masks = geometry_masks(geometry, views, (ds.intrinsics.width, ds.intrinsics.height))
    write_json_atomic(root / DENSE_RECORD, scene_json(geometry))
    return publish_masks(root, ds, GEOMETRY, lambda i, _frame: np.asarray(masks[i]), progress,
                         may_replace=may_replace)


def _sparse_points(ds: Dataset):
    """The dataset's sparse points for the depth bounds, or None when it has none."""
    from real2sim.capture.phone.normalise import read_sparse_points

    try:
        return read_sparse_points(ds)[0]
    except UserInputError:
        return None


def _auto_masks(root: Path, cfg, table_z_m: float, seed: int, progress: ProgressFn, may_replace: str):
    """Parallax masks unless they cannot be the object's, then masks from geometry (module docstring)."""
    import warnings

    from real2sim.plumbing.outputs import write_json_atomic

    why = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = make_masks(root, PARALLAX, cfg, table_z_m=table_z_m, seed=seed, progress=progress,
                                may_replace=may_replace)
        except UserInputError as exc:
            if "table plane" not in str(exc) and "sparse points" not in str(exc):
                raise
            why = f"parallax masks need the table plane, and {exc}"
    doubts = [w for w in caught if "parallax masks cannot be trusted" in str(w.message)]
    for w in caught:  # the others as they were
        if w not in doubts:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if doubts:
        why = str(doubts[0].message).split(". The method")[0]
    if why is None:
        write_json_atomic(root / MASK_CHOICE, {"method": PARALLAX, "why": "the parallax masks pass the checks of "
                                               "real2sim.capture.masks.parallax.mask_doubts"})
        return result
    warnings.warn(f"masks from geometry instead of parallax: {why}", RuntimeWarning, stacklevel=2)
    result = _geometry_masks(root, progress, may_replace)
    write_json_atomic(root / MASK_CHOICE, {"method": GEOMETRY, "why": why})
    return result
