"""Object masks for a dataset: provided, Mask R-CNN (local weights), or background difference.

Masks are 8-bit PNGs, 255 = object, 0 = ignore, the size of their image; each
frame of ``transforms.json`` points to its mask with ``mask_path`` (nerfstudio's
convention). Methods:

- ``provided``: the masks already named by the frames (rendered by ``capture``
  or supplied with a real capture) -- or, for frames without ``mask_path``, a
  file ``masks/<image stem>.png``; checked for existence and size.
- ``maskrcnn``: torchvision's Mask R-CNN (ResNet-50 FPN) from a local weights
  file; a pixel is the object where the top-scoring instance's mask probability
  exceeds 0.5 (as in the paper). torchvision is an optional dependency (extra
  ``maskrcnn``), imported through :mod:`real2sim.capture.masks.torchvision_compat`.
- ``background``: difference to an image of the empty scene from the same pose
  (``background/<image name>``), thresholded, cleaned with morphology, holes filled.

Computed masks are written to ``masks_<method>/`` and the frames are pointed to
them; when ``ground_truth/masks/`` exists the IoU against it is reported. A rerun replaces
that folder only when `mask` made it and it holds nothing else (:mod:`real2sim.capture.masks.folder`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from real2sim.capture.masks.folder import check_mask_folder, write_mask_marker
from real2sim.formats.dataset import (Dataset, Frame, check_dataset_outputs, load_image_rgb, load_mask, read_dataset,
                                      write_transforms)
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import current_umask
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.geometry.silhouettes import check_not_full

METHODS = ("provided", "maskrcnn", "background")


@dataclass(frozen=True)
class MaskConfig:
    """Settings of the background-difference and Mask R-CNN mask methods (``provided`` reads none). Masks
    always come back at the image's own size."""

    background_threshold: float = 12.0
    """Background difference: a pixel is object where its largest channel difference to the empty scene
    exceeds this (0-255)."""
    low_threshold: float | None = None
    """Hysteresis: pixels whose difference exceeds this (0-255) join the object where they touch pixels above
    ``background_threshold``; None: off."""
    max_hole_fraction: float = 0.01
    """Holes up to this fraction of the object's area are filled."""
    hole_background_max_diff: float = 3.0
    """Larger holes are filled too when their median difference exceeds this (0-255): a hole that matches
    the background (a mug handle's opening) is background."""
    open_px: int = 1
    """Radius (px) of the morphological opening that removes speckle; 0: none."""
    close_px: int = 3
    """Radius (px) of the closing that joins parts the threshold split; 0: none."""
    min_area_fraction: float = 0.05
    """Connected parts smaller than this fraction of the largest are dropped."""
    score_threshold: float = 0.5
    """Mask R-CNN: an instance is picked only when it scores above this (0-1)."""
    maskrcnn_mask_threshold: float = 0.5
    """Mask R-CNN: a pixel is object where the picked instance's mask probability exceeds this (0-1)."""
    mask_weights: Path | None = None
    """Mask R-CNN: the local weights file (a state dict); required by ``maskrcnn``, never downloaded."""
    device: str = "cpu"
    """Mask R-CNN: the torch device it runs on."""
    maskrcnn_min_size_px: int = 800
    """Mask R-CNN resizes each image so that its short side is this many pixels, unless its long side would
    exceed ``maskrcnn_max_size_px`` (torchvision's default, which the COCO weights were trained with); smaller
    is faster on a CPU (about quadratically) and coarser."""
    maskrcnn_max_size_px: int = 1333
    """Mask R-CNN: the long side's limit of that resize, pixels (torchvision's default; >= the min size)."""
    maskrcnn_max_instances: int = 100
    """Mask R-CNN: most detections per image (torchvision's default; >= 1); each costs a mask-head pass,
    and only the top-scoring ones can be picked."""


@dataclass(frozen=True)
class MaskResult:
    method: str
    num_frames: int
    mask_dir: str
    mean_object_fraction: float
    mean_iou: float | None = None
    min_iou: float | None = None


def _disk(radius: int) -> np.ndarray:
    r = int(radius)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return x * x + y * y <= r * r


def clean_mask(mask: np.ndarray, cfg: MaskConfig, weak: np.ndarray | None = None,
               diff: np.ndarray | None = None) -> np.ndarray:
    """Morphological clean-up: opening, hysteresis growth into ``weak``, closing, small
    components dropped, and holes filled up to ``max_hole_fraction`` of the object's area
    -- and larger ones too when their median ``diff`` (background difference) exceeds
    ``hole_background_max_diff``; a large hole that matches the background, such as
    the opening of a mug's handle, is real background."""
    from scipy import ndimage

    m = mask
    if cfg.open_px > 0:
        m = ndimage.binary_opening(m, structure=_disk(cfg.open_px))
    if weak is not None:
        # Pixels that differ only a little belong to the object if they touch a strong region.
        lab, _ = ndimage.label(weak | m)
        m = np.isin(lab, np.unique(lab[m])) & (lab > 0)
    if cfg.close_px > 0:
        # Pad so that closing does not eat into objects touching the border.
        pad = cfg.close_px + 1
        m = ndimage.binary_closing(np.pad(m, pad, mode="edge"), structure=_disk(cfg.close_px))[pad:-pad, pad:-pad]
    labels, n = ndimage.label(m)
    if n > 1:
        areas = ndimage.sum(m, labels, index=np.arange(1, n + 1))
        keep = np.nonzero(areas >= cfg.min_area_fraction * areas.max())[0] + 1
        m = np.isin(labels, keep)
    holes, nh = ndimage.label(ndimage.binary_fill_holes(m) & ~m)
    if nh:
        idx = np.arange(1, nh + 1)
        fill = ndimage.sum(np.ones_like(m), holes, index=idx) <= cfg.max_hole_fraction * m.sum()
        if diff is not None:
            # A large hole that still differs from the background is object of a similar colour;
            # one that matches the background (a mug handle's opening) is real background.
            fill |= ndimage.median(diff, holes, index=idx) > cfg.hole_background_max_diff
        m = m | np.isin(holes, idx[fill])
    return m


def background_difference_mask(image: np.ndarray, background: np.ndarray, cfg: MaskConfig = MaskConfig()
                               ) -> np.ndarray:
    """(H, W) bool object mask from an image and the empty scene from the same pose (uint8 RGB).

    A pixel is object when its largest channel difference exceeds ``background_threshold``, or
    exceeds ``low_threshold`` and connects to such a pixel (hysteresis); then :func:`clean_mask`."""
    if image.shape != background.shape:
        raise UserInputError(f"background image size {background.shape[:2]} differs from image size {image.shape[:2]}")
    diff = np.abs(image.astype(np.int16) - background.astype(np.int16)).max(axis=2)
    weak = None if cfg.low_threshold is None else diff > cfg.low_threshold
    return clean_mask(diff > cfg.background_threshold, cfg, weak=weak, diff=diff)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


# ----------------------------------------------------------------------------- Mask R-CNN


def load_maskrcnn(weights: Path | str | None, device: str = "cpu", min_size_px: int = 800,
                  max_size_px: int = 1333, score_threshold: float = 0.05, max_instances: int = 100):
    """torchvision Mask R-CNN (ResNet-50 FPN) with weights from a local file; never downloads.

    The file holds a state dict (or a checkpoint with a ``model`` entry) for the
    COCO layout (91 classes) or any class count (inferred from the box predictor).
    ``min_size_px`` / ``max_size_px``: the model's internal resize (see :class:`MaskConfig`).
    ``score_threshold``: detections scoring at most this are dropped inside the model
    (torchvision's ``box_score_thresh``); passing :func:`maskrcnn_mask`'s own threshold
    gives the same selected instance -- a lower-scoring box never suppresses a higher one
    in NMS -- and spares the mask head the boxes that could never be picked.
    ``max_instances``: torchvision's ``box_detections_per_img``.
    torchvision is imported through :mod:`real2sim.capture.masks.torchvision_compat`, which makes a
    CUDA build of torchvision usable on a CPU-only torch (its NMS replaced by ours).
    """
    if weights is None:
        raise UserInputError("--method maskrcnn needs --mask-weights PATH (a local Mask R-CNN weights file)")
    weights = Path(weights)
    if not weights.is_file():
        from real2sim.plumbing.paths import missing

        raise UserInputError(f"Mask R-CNN weights {weights} is not a regular file" if weights.exists()
                             else missing(weights, "Mask R-CNN weights file"))
    if not (0 < int(min_size_px) <= int(max_size_px)):
        raise UserInputError(f"Mask R-CNN resize needs 0 < min size <= max size (got {min_size_px}, {max_size_px} px)")
    if int(max_instances) < 1:
        raise UserInputError(f"Mask R-CNN needs at least 1 instance per image (got {max_instances})")
    from real2sim.capture.masks.torchvision_compat import import_maskrcnn_builder

    maskrcnn_resnet50_fpn = import_maskrcnn_builder()  # UserInputError when torchvision is missing
    import torch

    try:
        with warnings.catch_warnings():  # torch warns about the pickle of a file it then refuses anyway
            warnings.simplefilter("ignore")
            state = torch.load(weights, map_location="cpu", weights_only=True)
    except Exception:  # torch raises many kinds on a bad file
        # torch's own message suggests weights_only=False, i.e. running the file's code: not advice to relay
        raise UserInputError(f"{weights} is not a Mask R-CNN weights file (torch cannot load it as a saved "
                             "state dict of tensors)") from None
    if isinstance(state, dict) and "model" in state and isinstance(state["model"], dict):
        state = state["model"]
    key = "roi_heads.box_predictor.cls_score.weight"
    if not isinstance(state, dict) or key not in state:
        raise UserInputError(f"{weights} is not a torchvision Mask R-CNN state dict (no {key})")
    model = maskrcnn_resnet50_fpn(weights=None, weights_backbone=None, num_classes=int(state[key].shape[0]),
                                  min_size=int(min_size_px), max_size=int(max_size_px),
                                  box_score_thresh=float(score_threshold), box_detections_per_img=int(max_instances))
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise UserInputError(f"{weights} does not fit Mask R-CNN ResNet-50 FPN: {str(exc).splitlines()[0]}") from None
    return model.eval().to(device)


def maskrcnn_mask(model, image: np.ndarray, cfg: MaskConfig) -> np.ndarray:
    """(H, W) bool: the highest-scoring instance above ``score_threshold``, probability > ``maskrcnn_mask_threshold``.

    Among instances the one nearest the image centre wins ties of score within 0.05,
    since the capture points the camera at the object."""
    import torch

    # A copy: decoded images can be read-only arrays, which torch.from_numpy warns about.
    x = torch.from_numpy(np.array(image, dtype=np.uint8)).permute(2, 0, 1).float().div(255.0).to(cfg.device)
    with torch.no_grad():
        out = model([x])[0]
    scores = out["scores"].cpu().numpy()
    good = np.nonzero(scores > cfg.score_threshold)[0]
    if len(good) == 0:
        return np.zeros(image.shape[:2], bool)
    probs = out["masks"][good, 0].cpu().numpy()
    h, w = image.shape[:2]
    boxes = out["boxes"][good].cpu().numpy()
    centre_dist = np.hypot((boxes[:, 0] + boxes[:, 2]) / 2 - w / 2, (boxes[:, 1] + boxes[:, 3]) / 2 - h / 2)
    near_top = scores[good] >= scores[good].max() - 0.05
    pick = np.argmin(np.where(near_top, centre_dist, np.inf))
    return probs[pick] > cfg.maskrcnn_mask_threshold


# ----------------------------------------------------------------------------- dataset level


def _provided_path(ds: Dataset, f: Frame) -> Path:
    if f.mask_path is not None:
        return ds.root / f.mask_path
    return ds.root / "masks" / f"{Path(f.file_path).stem}.png"


def _ground_truth_mask(ds: Dataset, f: Frame) -> Path | None:
    p = ds.root / "ground_truth" / "masks" / Path(f.file_path).name
    return p if p.is_file() else None


def _provided_masks(root: Path, ds: Dataset, progress: ProgressFn) -> MaskResult:
    """``provided``: check the masks the frames name (or masks/<image stem>.png) and point to them."""
    w, h = ds.intrinsics.width, ds.intrinsics.height
    n = len(ds.frames)
    ious, fractions = [], []
    new_frames = []
    for i, f in enumerate(ds.frames):
        p = _provided_path(ds, f)
        if not p.is_file():
            raise UserInputError(f"--method provided: no mask for {f.file_path} (expected {p})")
        m = load_mask(p)
        if m.shape != (h, w):
            raise UserInputError(f"mask {p} is {m.shape[1]}x{m.shape[0]}, the images are {w}x{h}")
        fractions.append(m.mean())
        gt = _ground_truth_mask(ds, f)
        if gt is not None:
            ious.append(iou(m, load_mask(gt)))
        new_frames.append(replace(f, mask_path=os.path.relpath(p, ds.root)))
        progress("masks (provided)", i + 1, n)
    # an all-white mask is no silhouette: every one is exit 2 before anything is written, some a warning
    check_not_full(fractions, [f.file_path for f in ds.frames], f"the masks of {root}", stacklevel=4)
    if any(a.mask_path != b.mask_path for a, b in zip(new_frames, ds.frames)):
        write_transforms(root / "transforms.json", replace(ds, frames=tuple(new_frames)))
    return MaskResult("provided", n, "masks", float(np.mean(fractions)),
                      float(np.mean(ious)) if ious else None, float(np.min(ious)) if ious else None)


def compute_masks(dataset_dir: Path | str, method: str, cfg: MaskConfig = MaskConfig(),
                  progress: ProgressFn | None = None, may_replace: str = "unchanged") -> MaskResult:
    """Make (or check) the object masks of a dataset and point its frames to them.

    ``provided`` writes nothing but ``transforms.json`` (when frames gain a mask_path);
    the other methods write ``masks_<method>/`` (replacing one that `mask` made earlier, whole:
    see :func:`~real2sim.capture.masks.folder.check_mask_folder`, whose ``may_replace`` policy this takes)
    and rewrite ``transforms.json`` atomically.
    """
    if method not in METHODS:
        raise UserInputError(f"unknown mask method {method!r} (use one of {', '.join(METHODS)})")
    root = Path(dataset_dir)
    ds = read_dataset(root)
    if ds.extra.get("source") == "colmap":
        raise UserInputError(f"{root} has no transforms.json; masks need one to point to them")
    if method != "provided":  # `provided` writes transforms.json only when a frame gains its mask
        check_dataset_outputs(root, files=("transforms.json",), folders=(f"masks_{method}",), what="mask output")
        check_mask_folder(root, ds, method, may_replace)
    progress = progress or null_progress
    if method == "provided":
        return _provided_masks(root, ds, progress)

    if method == "background":
        missing = [f.file_path for f in ds.frames if not (root / "background" / Path(f.file_path).name).is_file()]
        if missing:
            raise UserInputError(f"--method background needs background/<image name> for every frame; "
                                 f"{len(missing)} missing (first: background/{Path(missing[0]).name}); "
                                 "capture with --with-background")
        model = None
    else:
        model = load_maskrcnn(cfg.mask_weights, cfg.device, cfg.maskrcnn_min_size_px, cfg.maskrcnn_max_size_px,
                              cfg.score_threshold, cfg.maskrcnn_max_instances)

    def mask_of(i: int, f: Frame) -> np.ndarray:
        img = load_image_rgb(root / f.file_path)
        if method == "background":
            return background_difference_mask(img, load_image_rgb(root / "background" / Path(f.file_path).name), cfg)
        return maskrcnn_mask(model, img, cfg)

    return publish_masks(root, ds, method, mask_of, progress, may_replace=may_replace)


def publish_masks(root: Path, ds: Dataset, method: str, mask_of: Callable[[int, Frame], np.ndarray],
                  progress: ProgressFn = null_progress, may_replace: str = "unchanged") -> MaskResult:
    """Write ``mask_of(i, frame)`` ((H, W) bool) of every frame to ``root/masks_<method>/`` and point the
    frames of ``root/transforms.json`` to them, the folder replaced whole or not at all; IoU against
    ``ground_truth/masks`` when present. For methods whose masks come from elsewhere (another stage).
    An existing folder is replaced only under :func:`~real2sim.capture.masks.folder.check_mask_folder`'s
    rules under the ``may_replace`` policy (checked again here, just before the swap)."""
    from PIL import Image

    n = len(ds.frames)
    ious, fractions = [], []
    out_name = f"masks_{method}"
    target = root / out_name
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_name}.tmp-", dir=root))
    try:
        new_frames = []
        for i, f in enumerate(ds.frames):
            m = np.asarray(mask_of(i, f), dtype=bool)
            name = f"{Path(f.file_path).stem}.png"
            Image.fromarray((m * 255).astype(np.uint8)).save(tmp / name)
            fractions.append(m.mean())
            gt = _ground_truth_mask(ds, f)
            if gt is not None:
                ious.append(iou(m, load_mask(gt)))
            new_frames.append(replace(f, mask_path=f"{out_name}/{name}"))
            progress(f"masks ({method})", i + 1, n)
        # masks over (nearly) the whole image are no silhouettes: all of them is exit 2 and nothing published
        check_not_full(fractions, [f.file_path for f in ds.frames], f"the {method} masks of {root}", stacklevel=4)
        write_mask_marker(tmp, method, [Path(f.mask_path).name for f in new_frames])
        check_mask_folder(root, ds, method, may_replace)
        # Swap the folder in, then the transforms.json pointing to it.
        old = None
        if target.exists():
            old = root / f".{out_name}.old-{tmp.name[-8:]}"
            target.rename(old)
        os.chmod(tmp, 0o777 & ~current_umask())  # mkdtemp's 0700 would hide the masks from colleagues
        tmp.rename(target)
        try:
            write_transforms(root / "transforms.json", replace(ds, frames=tuple(new_frames)))
        except BaseException:
            shutil.rmtree(target, ignore_errors=True)
            if old is not None:
                old.rename(target)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return MaskResult(method, n, out_name, float(np.mean(fractions)),
                      float(np.mean(ious)) if ious else None, float(np.min(ious)) if ious else None)
