"""Geometry before masks, end to end: the registered photos alone -> trusted depth, the support plane, the object
standing on it, its solid and each view's mask; at a resolution chosen from the object's size in the photos.

:func:`dense_geometry` chains :mod:`~real2sim.multiview.stereo` (depth per view),
:mod:`~real2sim.multiview.fusion` (the depths neighbours agree with, as points),
:mod:`~real2sim.multiview.support` (the plane and the object on it) and :mod:`~real2sim.multiview.solid` (the
object's solid). The working size: a first pass at ``probe_side_px`` finds the object; its extent in the median
view that sees it, in the photos' own pixels, says how much the photos may shrink for the object to span
``object_px`` pixels; when that is larger than the probe by a quarter or more the depth is found again there
(never above ``stereo.max_side_px`` nor the photos' size). A close-up capture keeps its small probe, a capture
of a small, far object goes finer. :func:`geometry_masks` draws each view's mask from the solid at the photos'
size. The result says what is doubtful (:attr:`DenseGeometry.doubts`): few trusted depths, a plane that holds
few of the points around the object, an object of few points; the caller warns.

Frames: the views' world frame, any unit (a COLMAP model's or metres).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from real2sim.formats.dataset import MODEL_FRAME_KEYS, Dataset
from real2sim.multiview.fusion import DensePoints, FusionConfig, consistent_depth, fused_points
from real2sim.multiview.solid import ObjectSolid, SolidConfig, object_solid, solid_masks
from real2sim.multiview.stereo import DepthMaps, StereoConfig, depth_maps
from real2sim.multiview.support import SupportConfig, SupportScene, support_and_object
from real2sim.multiview.views import PosedViews, load_views, project_torch


@dataclass(frozen=True)
class DenseConfig:
    """How :func:`dense_geometry` finds the object from the photos alone."""

    stereo: StereoConfig = field(default_factory=lambda: StereoConfig(max_side_px=960))
    """The plane sweep; its ``max_side_px`` is the finest working size the object's size may ask for."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """Which depths are trusted."""
    support: SupportConfig = field(default_factory=SupportConfig)
    """The support plane and the object on it."""
    solid: SolidConfig = field(default_factory=SolidConfig)
    """The object's carved solid."""
    probe_side_px: int = 320
    """Longer side of the first pass's images, pixels (>= 64): enough to find an object filling a fifth of a
    photo (a 60 px object), a quarter of the cost of 640."""
    object_px: int = 200
    """The object should span this many pixels (its longer extent in the median view that sees it) at the
    working size (>= 16): the mug at 320x240 (its extent 150-200 px) gave masks of IoU 0.85."""
    min_trusted_share: float = 0.01
    """Doubtful when fewer than this share (0-1) of the pixels have a trusted depth (measured 2.5-12 % on the
    bundled objects' handheld captures, the least with a room behind at 480x270)."""
    min_plane_share: float = 0.3
    """Doubtful when the support plane holds fewer than this share (0-1) of the points near where the cameras
    look (measured 0.3-0.6 with the object in them)."""
    min_object_share: float = 0.02
    """Doubtful when the object holds fewer than this share (0-1) of the dense points."""


@dataclass(frozen=True)
class DenseGeometry:
    """What :func:`dense_geometry` found: the depth maps (``maps``) and their trusted pixels (``trusted``, (V, h, w)
    bool), the fused points, the support ``scene``, the object's ``solid``, a JSON-ready ``record`` and the
    ``doubts`` (one line each; empty when nothing is doubtful)."""

    maps: DepthMaps
    trusted: np.ndarray
    dense: DensePoints
    scene: SupportScene
    solid: ObjectSolid
    record: dict
    doubts: tuple[str, ...]


def _pass(views: PosedViews, side_px: int, config: DenseConfig, points: np.ndarray | None,
          device: str | torch.device) -> tuple[DepthMaps, np.ndarray, DensePoints, SupportScene]:
    maps = depth_maps(views, replace(config.stereo, max_side_px=side_px), points, device)
    agreeing = consistent_depth(maps, config.fusion, device)
    trusted = agreeing >= config.fusion.min_agreeing
    dense = fused_points(maps, agreeing, config.fusion)
    k = maps.intrinsics
    scene = support_and_object(dense, maps.c2w_cv, k.fl_x, min(k.width, k.height), config.support)
    return maps, trusted, dense, scene


def object_extent_px(views: PosedViews, points: np.ndarray, device: str | torch.device = "cpu") -> float:
    """The object's longer extent (pixels of ``views``' own size) in the median view among those that see at
    least a tenth of its ``points`` (P, 3, world); its bounding box is clipped to the picture, so a close-up that
    cuts it counts what it shows. 0 when no view sees it."""
    k = views.intrinsics
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float().to(device)
    u, v, z = (t.cpu().numpy() for t in project_torch(k, w2c, torch.from_numpy(points.astype(np.float32)).to(device)))
    extents = []
    for i in range(len(u)):
        seen = (z[i] > 0) & (u[i] >= 0) & (u[i] <= k.width) & (v[i] >= 0) & (v[i] <= k.height)
        if seen.sum() >= max(10, 0.1 * len(points)):
            extents.append(max(np.ptp(u[i][seen]), np.ptp(v[i][seen])))
    return float(np.median(extents)) if extents else 0.0


def dense_geometry(views: PosedViews, config: DenseConfig = DenseConfig(), points: np.ndarray | None = None,
                   device: str | torch.device = "cpu") -> DenseGeometry:
    """The dense geometry of ``views`` (module docstring). ``points``: (P, 3) sparse points for the depth bounds
    (None: from the cameras). UserInputError (one line) when no object stands on a plane where the cameras look."""
    start = time.perf_counter()
    longest = max(views.intrinsics.width, views.intrinsics.height)
    probe = min(config.probe_side_px, longest)
    maps, trusted, dense, scene = _pass(views, probe, config, points, device)
    extent = object_extent_px(views, dense.points[scene.object_index], device)
    wanted = longest * config.object_px / extent if extent > 0 else config.stereo.max_side_px
    side = int(min(max(wanted, probe), config.stereo.max_side_px, longest))
    record = {"probe_side_px": probe, "object_extent_px": extent, "object_px": config.object_px}
    if side >= 1.25 * probe:
        maps, trusted, dense, scene = _pass(views, side, config, points, device)
    else:
        side = probe
    solid = object_solid(maps, trusted, scene, dense, config.solid, device)
    near = np.linalg.norm(dense.points - scene.look_at, axis=1) <= 2.0 * scene.radius
    trusted_share = float(trusted.mean())
    plane_share = scene.plane_inliers / max(int(near.sum()), 1)
    object_share = len(scene.object_index) / max(len(dense.points), 1)
    h, w = maps.depth.shape[1:]
    record.update({"working_size_px": [w, h], "trusted_share": trusted_share, "dense_points": len(dense.points),
                   "points_near": int(near.sum()), "plane_inliers": scene.plane_inliers, "plane_share": plane_share,
                   "object_points": len(scene.object_index), "object_share": object_share,
                   "solid_voxels": int(solid.occupied.sum()), "seconds": time.perf_counter() - start})
    doubts = []
    if trusted_share < config.min_trusted_share:
        doubts.append(f"only {100 * trusted_share:.1f} % of the pixels have a depth their neighbour views agree with "
                      f"(at least {100 * config.min_trusted_share:.0f} % expected): little texture, or poses off")
    if plane_share < config.min_plane_share:
        doubts.append(f"the support plane holds only {100 * plane_share:.0f} % of the dense points around the object "
                      f"(at least {100 * config.min_plane_share:.0f} % expected): little table in view")
    if object_share < config.min_object_share:
        doubts.append(f"the object holds only {100 * object_share:.1f} % of the dense points: little of it has "
                      "a trusted depth")
    return DenseGeometry(maps, trusted, dense, scene, solid, record, tuple(doubts))


def geometry_masks(geometry: DenseGeometry, views: PosedViews, size: tuple[int, int] | None = None,
                   device: str | torch.device = "cpu") -> np.ndarray:
    """(V, H, W) bool masks of ``views``: the solid's outline snapped to their colour edges
    (:func:`real2sim.multiview.solid.solid_masks`) at ``views``' size, then brought to ``size`` (W, H; None: kept)."""
    masks = solid_masks(geometry.solid, views.intrinsics, views.c2w_cv, views.rgb, device)
    if size is not None and tuple(size) != (views.intrinsics.width, views.intrinsics.height):
        t = torch.from_numpy(masks)[:, None]
        masks = torch.nn.functional.interpolate(t, size=(size[1], size[0]), mode="bilinear", align_corners=False)[:, 0].numpy()
    return masks > 0.5


#: What :func:`scene_json` writes beside a dataset's masks from geometry: the plane and the object in its frame.
DENSE_RECORD = "dense_geometry.json"


def dataset_geometry(ds: Dataset, points: np.ndarray | None = None, config: DenseConfig = DenseConfig(),
                     device: str | torch.device = "cpu") -> tuple[DenseGeometry, PosedViews]:
    """:func:`dense_geometry` of a dataset's photos in its own frame, a COLMAP model's too (any unit: nothing here
    needs metres), read no longer than ``config.stereo.max_side_px``; the geometry and the views it read."""
    rigid = replace(ds, extra={k: v for k, v in ds.extra.items() if k not in MODEL_FRAME_KEYS})
    views = load_views(rigid, need_masks=False, max_side_px=config.stereo.max_side_px)
    return dense_geometry(views, config, points, device), views


def scene_json(geometry: DenseGeometry) -> dict:
    """The support plane and the object of ``geometry`` as JSON (the views' frame and unit): ``normal`` (towards
    the cameras) and ``offset`` of the plane ``normal . x = offset``, its inlier ``band``, the object's ``height``
    above it and footprint ``centre``, ``object_heights``' top percentiles, the ``record`` and the ``doubts``."""
    s = geometry.scene
    heights = s.heights(geometry.dense.points[s.object_index])
    return {"normal": s.normal.tolist(), "offset": float(s.offset), "band": float(s.band), "height": float(s.height),
            "centre": s.centre.tolist(), "look_at": s.look_at.tolist(), "radius": float(s.radius),
            "object_heights": {str(q): float(np.percentile(heights, q)) for q in (50, 90, 99, 100)},
            "record": geometry.record, "doubts": list(geometry.doubts)}
