"""Posed views for reconstruction: images, masks and cameras as arrays, checked once.

Frames (all in the dataset's world frame, metres): ``c2w_cv`` is camera-to-world
with OpenCV camera axes (x right, y down, z forward). Pixel (u, v) has its centre
at (u + 0.5, v + 0.5), as in the dataset format. Rays are unit directions in the
world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import (
    POSE_REFINED_KEY,
    CameraIntrinsics,
    Dataset,
    describe_model_frame,
    is_model_frame,
    load_image_rgb,
    load_mask,
    read_dataset,
)
from real2sim.plumbing.errors import UserInputError

MIN_VIEWS = 8


@dataclass(frozen=True)
class PosedViews:
    """N posed images of one camera.

    ``rgb``: (N, H, W, 3) float32 in [0, 1]; ``mask``: (N, H, W) float32, 1 = object;
    ``c2w_cv``: (N, 4, 4) float64 camera-to-world, OpenCV axes, metres;
    ``names``: the frames' ``file_path`` values.
    """

    rgb: np.ndarray
    mask: np.ndarray
    c2w_cv: np.ndarray
    intrinsics: CameraIntrinsics
    names: tuple[str, ...]
    # the views whose poses refine-poses could not refine (the robot's, millimetres off): see reconstruct.poses
    unrefined: tuple[str, ...] = ()

    @property
    def count(self) -> int:
        return len(self.c2w_cv)

    @property
    def is_unrefined(self) -> np.ndarray:
        """(N,) bool: which views are named in ``unrefined``."""
        unrefined = set(self.unrefined)
        return np.array([name in unrefined for name in self.names], dtype=bool)

    def subset(self, index: np.ndarray) -> "PosedViews":
        index = np.asarray(index, dtype=int)
        names = tuple(self.names[i] for i in index)
        unrefined = tuple(n for n, u in zip(names, self.is_unrefined[index]) if u)
        return PosedViews(self.rgb[index], self.mask[index], self.c2w_cv[index], self.intrinsics, names, unrefined)


def working_size(k: CameraIntrinsics, max_side_px: int | None) -> tuple[int, int]:
    """(width, height) px of images no longer than ``max_side_px`` on their longer side, the
    aspect ratio kept; the camera's own size when it fits or ``max_side_px`` is None."""
    longest = max(k.width, k.height)
    if max_side_px is None or longest <= max_side_px:
        return k.width, k.height
    scale = max_side_px / longest
    return max(1, round(k.width * scale)), max(1, round(k.height * scale))


def _area_resized(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (H, W) or (H, W, 3), float32, averaged over each new pixel's footprint (PIL's box
    filter maps pixel edges to edges, as ``CameraIntrinsics.scaled`` maps the camera)."""
    from PIL import Image

    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    channels = [image] if image.ndim == 2 else [image[..., c] for c in range(image.shape[2])]
    out = [np.asarray(Image.fromarray(np.ascontiguousarray(c, dtype=np.float32), mode="F").resize(size, Image.BOX))
           for c in channels]
    return out[0] if image.ndim == 2 else np.stack(out, axis=-1)


def load_views(dataset: Dataset | Path | str, *, need_masks: bool = True,
               max_side_px: int | None = None) -> PosedViews:
    """Read every image and mask of a dataset; UserInputError (one line) for anything unusable.

    Checks: poses in a metric frame (not a COLMAP model's, :func:`is_model_frame`), at least 8 frames, masks present for every frame when ``need_masks``,
    every image readable and of the intrinsics' size, masks of the same size, and
    cameras that look at a common region (:func:`common_look_at_point`).

    Frames refine-poses marked as not refined are named in ``unrefined`` (kept; the reconstruct stage
    moves their cameras, :mod:`real2sim.reconstruct.poses.silhouette`).
    Images longer than ``max_side_px`` are reduced (area average; masks become soft at their
    edges) and the camera with them, one image at a time: a phone capture of 200 photos at
    4032x3024 would need 29 GB as float images, and the field's grid cannot use the detail.
    """
    ds = dataset if isinstance(dataset, Dataset) else read_dataset(dataset)
    unrefined = tuple(f.file_path for f in ds.frames if f.extra.get(POSE_REFINED_KEY) is False)
    full = ds.intrinsics
    k = full.scaled(*working_size(full, max_side_px)) if max_side_px is not None else full
    if is_model_frame(ds):
        raise UserInputError(f"{ds.root} is {describe_model_frame(ds)}: reconstruction needs poses in metres with "
                             "the table top at z = 0; `real2sim run DATASET --object-height-m H` finds both first")
    if len(ds.frames) < MIN_VIEWS:
        raise UserInputError(f"{ds.root}: {len(ds.frames)} views; reconstruction needs at least {MIN_VIEWS}")
    missing = [f.file_path for f in ds.frames if f.mask_path is None]
    if need_masks and missing:
        raise UserInputError(
            f"{ds.root}: {len(missing)} of {len(ds.frames)} frames have no mask (first: {missing[0]}); "
            "run `real2sim mask DATASET --method ...` first")
    rgb = np.empty((len(ds.frames), k.height, k.width, 3), dtype=np.float32)
    mask = np.ones((len(ds.frames), k.height, k.width), dtype=np.float32)
    size = (k.width, k.height)
    for i, frame in enumerate(ds.frames):
        image = load_image_rgb(_inside(ds.root, frame.file_path))
        if image.shape[:2] != (full.height, full.width):
            raise UserInputError(f"{frame.file_path}: image is {image.shape[1]}x{image.shape[0]} px but the "
                                 f"dataset's camera is {full.width}x{full.height}; all images must have one size")
        rgb[i] = _area_resized(image.astype(np.float32) / np.float32(255.0), size)
        if frame.mask_path is not None:
            m = load_mask(_inside(ds.root, frame.mask_path))
            if m.shape != (full.height, full.width):
                raise UserInputError(f"{frame.mask_path}: mask is {m.shape[1]}x{m.shape[0]} px, image is "
                                     f"{full.width}x{full.height}")
            mask[i] = _area_resized(m.astype(np.float32), size)
    if need_masks and not np.any(mask.reshape(len(mask), -1).max(axis=1) > 0):
        raise UserInputError(f"{ds.root}: every mask is empty")
    if need_masks:  # an all-white mask carves nothing: the hull or field fills the working volume
        from real2sim.geometry.silhouettes import check_not_full

        check_not_full((mask > 0.5).mean(axis=(1, 2)), [f.file_path for f in ds.frames], f"the masks of {ds.root}")
    views = PosedViews(rgb, mask, ds.poses_c2w_cv(), k, tuple(f.file_path for f in ds.frames), unrefined)
    common_look_at_point(views)
    return views


#: masks whose edges colour would move by less than this (pixels, median over the views) are kept as given
MIN_EDGE_SHIFT_PX = 0.5


def refined_mask_edges(views: PosedViews) -> tuple[PosedViews, dict]:
    """The views with each mask's edge moved to its image's colour edge
    (:func:`real2sim.geometry.silhouettes.colour_refined_mask`, within
    :func:`~real2sim.geometry.silhouettes.edge_band_px` pixels), and a report.

    Only where the masks are off: when the median view's edge would move by less than
    :data:`MIN_EDGE_SHIFT_PX` on average (pixels changed over the outline's length), the masks
    already follow the colours and are kept as given. Exact masks (rendered) differ from the
    colours only at a few mixed pixels, such as a thin rim seen edge-on, and those are better left.
    A dozen views spread over the capture decide. The report gives the band, their median shift,
    whether the masks were changed, and the share of mask pixels added and removed (per cent of the
    masks' area, mean and largest over the views refined).
    """
    from dataclasses import replace

    from scipy.ndimage import binary_erosion

    from real2sim.geometry.silhouettes import colour_refined_mask, edge_band_px

    k = views.intrinsics
    band_px = edge_band_px(k.width, k.height)
    masks = views.mask.copy()
    added, removed, shift_px = [], [], []

    def refine(i: int) -> None:
        masks[i] = colour_refined_mask(views.rgb[i], views.mask[i], band_px)
        before, after = views.mask[i] >= 0.5, masks[i] >= 0.5
        area = max(int(before.sum()), 1)
        outline = max(int((before & ~binary_erosion(before)).sum()), 1)
        added.append(100.0 * float((after & ~before).sum()) / area)
        removed.append(100.0 * float((before & ~after).sum()) / area)
        shift_px.append(float((after != before).sum()) / outline)

    # a dozen views spread over the capture decide; the rest are refined only when it is needed
    sample = np.unique(np.linspace(0, views.count - 1, min(views.count, 12)).round().astype(int))
    for i in sample:
        refine(int(i))
    median_shift_px = float(np.median(shift_px))
    applied = median_shift_px >= MIN_EDGE_SHIFT_PX
    if applied:
        for i in sorted(set(range(views.count)) - set(sample.tolist())):
            refine(i)
    report = {"method": "colour", "band_px": band_px, "median_edge_shift_px": round(median_shift_px, 3),
              "applied": applied,
              "added_percent": {"mean": round(float(np.mean(added)), 3), "max": round(float(np.max(added)), 3)},
              "removed_percent": {"mean": round(float(np.mean(removed)), 3), "max": round(float(np.max(removed)), 3)}}
    if not applied:
        report["note"] = (f"kept as given: the masks' edges are within {MIN_EDGE_SHIFT_PX} px of the colours' "
                          "(median view)")
        return views, report
    return replace(views, mask=masks), report


def _inside(root: Path, rel: str) -> Path:
    path = (Path(root) / rel).resolve()
    if not path.is_relative_to(Path(root).resolve()):
        raise UserInputError(f"{rel}: path points outside the dataset folder {root}")
    return path


def undistorted_normalized(k: CameraIntrinsics, u_px: np.ndarray, v_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalized image coordinates (x/z, y/z) of continuous pixel positions, undoing OpenCV distortion."""
    x = (np.asarray(u_px, dtype=np.float64) - k.cx) / k.fl_x
    y = (np.asarray(v_px, dtype=np.float64) - k.cy) / k.fl_y
    if k.k1 == k.k2 == k.p1 == k.p2 == 0.0:
        return x, y
    xd, yd = x.copy(), y.copy()
    for _ in range(10):  # fixed-point inversion; converges for the mild distortion of real lenses
        r2 = x * x + y * y
        radial = 1 + k.k1 * r2 + k.k2 * r2 * r2
        dx = 2 * k.p1 * x * y + k.p2 * (r2 + 2 * x * x)
        dy = k.p1 * (r2 + 2 * y * y) + 2 * k.p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return x, y


def project_torch(k: CameraIntrinsics, w2c_cv, points_m) -> tuple:
    """(u, v, z), each a (N_views, P) float32 tensor: pixel position and depth of world points (P, 3).

    ``w2c_cv``: (N_views, 4, 4) world-to-camera tensor. Distortion is applied, so the
    positions match the images as captured.
    """
    # one (3 V, 3) x (3, P) product, laid out as (V, 3, P) already: a batch of V products with an inner size
    # of 3 took twice as long, and transposing a (P, 3 V) product costs a copy as large as the result
    rows = w2c_cv[:, :3, :].reshape(-1, 4)
    cam = rows[:, 3:].addmm(rows[:, :3], points_m.T).view(len(w2c_cv), 3, -1)
    z = cam[:, 2]
    inv_z = 1.0 / z.clamp_min(1e-9)
    x, y = cam[:, 0] * inv_z, cam[:, 1] * inv_z
    if not (k.k1 == k.k2 == k.p1 == k.p2 == 0.0):
        r2 = x * x + y * y
        radial = 1 + k.k1 * r2 + k.k2 * r2 * r2
        x, y = (x * radial + 2 * k.p1 * x * y + k.p2 * (r2 + 2 * x * x),
                y * radial + k.p1 * (r2 + 2 * y * y) + 2 * k.p2 * x * y)
    return x.mul_(k.fl_x).add_(k.cx), y.mul_(k.fl_y).add_(k.cy), z


def project(k: CameraIntrinsics, c2w_cv: np.ndarray, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (N_views, P, 2) and depths (N_views, P) of world points (P, 3); float32, see :func:`project_torch`."""
    import torch

    w2c = torch.from_numpy(np.linalg.inv(c2w_cv)).float()
    u, v, z = project_torch(k, w2c, torch.from_numpy(np.asarray(points_m, dtype=np.float32)))
    return torch.stack([u, v], dim=-1).numpy(), z.numpy()


def pixel_rays(k: CameraIntrinsics, c2w_cv: np.ndarray, u_px: np.ndarray, v_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame ray origins and unit directions (P, 3) through continuous pixel positions of one camera."""
    x, y = undistorted_normalized(k, u_px, v_px)
    d_cam = np.stack([x, y, np.ones_like(x)], axis=-1)
    d = d_cam @ c2w_cv[:3, :3].T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(c2w_cv[:3, 3], d.shape).copy(), d


def plane_hits(origin_m: np.ndarray, direction: np.ndarray, plane_z_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Where rays (P, 3 origins, metres; P, 3 unit directions, world) meet the plane z = ``plane_z_m`` in front
    of their origins: the points (P, 3; a ray that does not meet it keeps its origin) and (P,) bool whether it
    does. Their distance along the ray is ``np.linalg.norm(points - origin_m, axis=-1)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (plane_z_m - origin_m[:, 2]) / direction[:, 2]
    hit = np.isfinite(t) & (t > 0)
    return origin_m + np.where(hit, t, 0.0)[:, None] * direction, hit


def common_look_at_point(views: PosedViews, min_fraction: float = 0.8) -> np.ndarray:
    """The world point (3,) closest, in least squares, to every camera's optical axis.

    UserInputError unless it lies in front of, and inside the image of, at least
    ``min_fraction`` of the cameras: then the cameras do not share a region to reconstruct.
    """
    centres = views.c2w_cv[:, :3, 3]
    axes = views.c2w_cv[:, :3, 2]
    # sum over views of (I - a a^T) (p - c) = 0
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    a = proj.sum(axis=0)
    b = (proj @ centres[:, :, None]).sum(axis=0)[:, 0]
    if np.linalg.cond(a) > 1e8:
        raise UserInputError("the cameras' optical axes are (nearly) parallel: they do not look at a common region")
    point = np.linalg.solve(a, b)
    uv, z = project(views.intrinsics, views.c2w_cv, point[None])
    k = views.intrinsics
    seen = (z[:, 0] > 0) & (uv[:, 0, 0] >= 0) & (uv[:, 0, 0] <= k.width) & (uv[:, 0, 1] >= 0) & (uv[:, 0, 1] <= k.height)
    if seen.mean() < min_fraction:
        raise UserInputError(
            f"the cameras do not look at a common region: the point nearest all optical axes is in view of only "
            f"{int(seen.sum())} of {views.count} cameras")
    return point


def held_out_split(count: int, every: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Indices (train, held_out): every ``every``-th view (from the 5th) is held out, never trained on."""
    idx = np.arange(count)
    held = idx[(idx % every) == every // 2]
    return np.setdiff1d(idx, held), held


def bilinear(images: torch.Tensor, view_of: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Colours (N, 3, float64) of images[view_of] at continuous pixel positions ``uv`` (N, 2) (pixel centres
    at +0.5)."""
    import torch

    u, v = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    h, w = images.shape[1:3]
    u0 = torch.floor(u).to(torch.int64).clamp(0, w - 2)
    v0 = torch.floor(v).to(torch.int64).clamp(0, h - 2)
    fu = torch.clamp(u.to(torch.float64) - u0, 0, 1)[:, None]
    fv = torch.clamp(v.to(torch.float64) - v0, 0, 1)[:, None]
    return ((1 - fu) * (1 - fv) * images[view_of, v0, u0] + fu * (1 - fv) * images[view_of, v0, u0 + 1]
            + (1 - fu) * fv * images[view_of, v0 + 1, u0] + fu * fv * images[view_of, v0 + 1, u0 + 1])


def ray_box(origins: torch.Tensor, directions: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor):
    """Entry and exit distances (R,) of rays through the box [lo, hi]; exit <= entry when they miss."""
    import torch

    inv = 1.0 / torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t0, t1 = (lo - origins) * inv, (hi - origins) * inv
    t_near = torch.minimum(t0, t1).max(dim=-1).values.clamp_min(0.0)
    t_far = torch.maximum(t0, t1).min(dim=-1).values
    return t_near, torch.maximum(t_far, t_near)
