"""Masks for `real2sim mask` and `run`: the capture stage's methods, and ``parallax`` from the reconstruct stage.

``parallax`` (:mod:`real2sim.capture.masks.parallax`) needs poses and the table plane, not
weights or an empty scene: for a dataset in the robot frame the plane is z = ``table_z_m``; for a
COLMAP model (a phone capture, arbitrary frame and scale) it is found first by RANSAC on the sparse
points around the point the cameras look at, and the views are moved into that plane's frame.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from real2sim.formats.dataset import MODEL_FRAME_KEYS, Dataset, check_dataset_outputs, is_model_frame, read_dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress

PARALLAX = "parallax"


def make_masks(dataset_dir: Path | str, method: str, cfg=None, *, table_z_m: float = 0.0, seed: int = 0,
               progress: ProgressFn = null_progress, may_replace: str = "unchanged"):
    """:func:`real2sim.capture.compute_masks` for its methods (``cfg``: its MaskConfig), or parallax masks;
    a :class:`~real2sim.capture.masks.methods.MaskResult` either way; for parallax ``cfg`` may be a
    :class:`~real2sim.capture.masks.parallax_config.ParallaxConfig` (its table height is ``table_z_m``'s). ``masks_<method>/`` is replaced only
    when `mask` made it and holds nothing else (:mod:`real2sim.capture.masks.folder`; ``may_replace``: its
    policy, "edited" for ``mask --overwrite``, "any" for `run`'s private copy of a dataset)."""
    from real2sim.capture.masks.folder import check_mask_folder
    from real2sim.capture.masks.methods import MaskConfig, compute_masks, publish_masks

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
