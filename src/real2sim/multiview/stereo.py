"""Dense depth per view without masks: a coarse-to-fine plane sweep with normalised cross-correlation.

For each reference view a few neighbour views are chosen by the angle they make at the cameras'
common look-at point (:func:`neighbour_views`). Depth hypotheses are spaced evenly in inverse depth
between bounds from the sparse points, or from the cameras' common region when there are none
(:func:`depth_bounds`). The photometric cost of a hypothesis is one minus the zero-mean normalised
cross-correlation of a small window of the reference's grey image with the neighbour's, warped
through that depth; a pixel's cost is the mean over the better half of its neighbours, so that a
neighbour that does not see the point (occluded, outside its picture) does not count. The sweep runs
first on a small image (about :attr:`StereoConfig.coarsest_side_px` long) over the whole range, with as many
planes as the widest neighbour's disparity swing has pixels there (at most ``max_planes``), then at double the
size, again and again up to the working size, over a few steps around the depth found, and ends with a
parabola through the best cost and its two neighbours (sub-step depth). The hypotheses go a few planes at a
time, and the five window sums a colour correlation needs are running sums (:func:`box_sum`).

Frames: the views' world frame (any unit: a COLMAP model's or metres); depth is along each camera's
optical axis (OpenCV axes), in world units. Pixel centres at +0.5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.multiview.views import PosedViews, common_look_at_point, project_torch, undistorted_normalized, working_size


@dataclass(frozen=True)
class StereoConfig:
    """How the plane sweep of :func:`depth_maps` works."""

    max_side_px: int = 640
    """Longer side of the images the depth is found on, pixels (>= 64); a 1920x1080 photo becomes 640x360.
    Finer costs time as its square and, measured, gains little (docs/design-notes/reconstruct.md#dense-stereo);
    :func:`real2sim.multiview.dense.dense_geometry` chooses it from the object's size in the photos."""
    neighbours: int = 4
    """Neighbour views each reference view is matched against (>= 1)."""
    min_angle_deg: float = 3.0
    """Neighbours make at least this angle with the reference at the look-at point, degrees: a smaller
    baseline cannot tell depth."""
    window_px: int = 7
    """Side of the correlation window, pixels at each level's size (odd, >= 3)."""
    coarsest_side_px: int = 160
    """The sweep over the whole depth range runs on images about this long (longer side, pixels, >= 16), each
    finer level twice as long up to the working size: as many levels as that takes."""
    max_planes: int = 96
    """At most this many depth planes on the coarsest level (a wide baseline asks for more): the coarse sweep
    was two thirds of the time at 192, and 96 kept the trusted depths as accurate (9 % fewer of them)."""
    refine_steps: int = 2
    """A finer level tries the depth found above and this many steps of half its spacing on either side: two
    reach the coarser level's neighbouring planes (4 took a third longer for the same depths)."""

    def levels(self, side_px: int) -> int:
        """Pyramid levels for a working size whose longer side is ``side_px``."""
        return 1 + max(0, int(round(np.log2(max(side_px, 1) / self.coarsest_side_px))))


@dataclass(frozen=True)
class DepthMaps:
    """Per-view depth found by :func:`depth_maps`.

    ``depth``: (V, h, w) float32 along each camera's optical axis, world units (0: no depth);
    ``score``: (V, h, w) float32 the correlation (-1..1) of the depth chosen; ``intrinsics``: the camera at
    (w, h); ``c2w_cv``: (V, 4, 4) float64 camera-to-world, OpenCV axes; ``rgb``: (V, h, w, 3) float32 the images
    matched (0-1); ``neighbours``: (V, n) int the views each was matched against.
    """

    depth: np.ndarray
    score: np.ndarray
    intrinsics: CameraIntrinsics
    c2w_cv: np.ndarray
    rgb: np.ndarray
    neighbours: np.ndarray


def neighbour_views(c2w_cv: np.ndarray, look_at: np.ndarray, count: int, min_angle_deg: float) -> np.ndarray:
    """(V, count) int: for each view, the views whose directions to ``look_at`` (3,) make the smallest angles
    with its own of those at least ``min_angle_deg`` apart (closest first; fewer candidates: the nearest
    of the rest fill in)."""
    d = look_at[None] - c2w_cv[:, :3, 3]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(d @ d.T, -1.0, 1.0)))
    np.fill_diagonal(angle, np.inf)
    order_key = np.where(angle >= min_angle_deg, angle, 1e3 + (min_angle_deg - angle))  # too close: last resort
    np.fill_diagonal(order_key, np.inf)
    count = min(count, len(c2w_cv) - 1)
    return np.argsort(order_key, axis=1)[:, :count]


def depth_bounds(c2w_cv: np.ndarray, look_at: np.ndarray, points: np.ndarray | None = None,
                 k: CameraIntrinsics | None = None) -> np.ndarray:
    """(V, 2) near and far depth for each view, world units.

    With ``points`` (P, 3, sparse structure-from-motion points) and ``k``: the 1st and 99th percentile of the
    depths of those in the view's picture, widened by a quarter, the near one no farther than without. Without: the region the cameras share, a
    ball around ``look_at`` as large as the cameras' median distance to it (so a camera's far bound is about
    twice its distance), the near bound at least a quarter of the camera's distance.
    """
    distance = np.linalg.norm(c2w_cv[:, :3, 3] - look_at[None], axis=1)
    radius = float(np.median(distance))
    near = np.maximum(distance - radius, 0.25 * distance)
    far = distance + radius
    if points is not None and k is not None and len(points) >= 8:
        w2c = np.linalg.inv(c2w_cv)
        cam = np.einsum("vij,pj->vpi", w2c[:, :3, :3], points) + w2c[:, None, :3, 3]
        z = cam[..., 2]
        u = k.fl_x * cam[..., 0] / np.maximum(z, 1e-12) + k.cx
        v = k.fl_y * cam[..., 1] / np.maximum(z, 1e-12) + k.cy
        seen = (z > 0) & (u >= 0) & (u <= k.width) & (v >= 0) & (v <= k.height)
        for i in np.nonzero(seen.sum(axis=1) >= 8)[0]:
            lo, hi = np.percentile(z[i, seen[i]], [1.0, 99.0])
            # the near bound no farther than the cameras' region's: a few close-ups triangulate the table
            # around the object and little of it, and its top is nearer than any of them
            near[i], far[i] = min(0.75 * lo, near[i]), 1.25 * hi
    return np.stack([near, far], axis=1)


def image_pyramid(rgb: np.ndarray, size: tuple[int, int], levels: int) -> list[torch.Tensor]:
    """Images (V, 3, h, w) float32, finest (``size`` = (w, h)) first, each next one half as large
    (area average)."""
    out = []
    grey = torch.from_numpy(np.ascontiguousarray(rgb)).float().permute(0, 3, 1, 2)
    w, h = size
    for level in range(levels):
        lw, lh = max(8, round(w / 2 ** level)), max(8, round(h / 2 ** level))
        out.append(torch.nn.functional.interpolate(grey, size=(lh, lw), mode="area"))
    return out


def box_sum(x: torch.Tensor, window: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sums of ``x`` (..., h, w) over a ``window`` square around each pixel (the image's inside only), by
    running sums (four passes over ``x`` whatever the window, where pooling took twice as long), and the
    pixels each sum holds, (h, w)."""
    r = window // 2
    h, w = x.shape[-2:]
    out = x
    for axis, n in ((-1, w), (-2, h)):
        pad = [0, 0, 0, 0]
        pad[0 if axis == -1 else 2] = r + 1
        pad[1 if axis == -1 else 3] = r
        run = torch.nn.functional.pad(out, pad).cumsum(dim=axis)
        out = run.narrow(axis, window, n) - run.narrow(axis, 0, n)
    span = lambda n: (torch.arange(n, device=x.device).clamp(max=r) + 1
                      + torch.arange(n - 1, -1, -1, device=x.device).clamp(max=r)).to(x.dtype)
    return out, span(h)[:, None] * span(w)[None, :]


def box_mean(x: torch.Tensor, window: int) -> torch.Tensor:
    """Mean of ``x`` (..., h, w) over a ``window`` square around each pixel (the image's inside only)."""
    summed, count = box_sum(x, window)
    return summed / count


def mean_of_smallest(values: torch.Tensor, keep: int) -> torch.Tensor:
    """Mean over the first axis of the ``keep`` smallest of ``values`` (n, ...), by a partial selection network
    of minima and maxima: over a first axis of four, ``topk`` took five times as long."""
    rows = list(values.unbind(0))
    for i in range(min(keep, len(rows))):
        for j in range(i + 1, len(rows)):
            rows[i], rows[j] = torch.minimum(rows[i], rows[j]), torch.maximum(rows[i], rows[j])
    return torch.stack(rows[:keep]).mean(dim=0) if keep > 1 else rows[0]


def _sweep_costs(ref: torch.Tensor, sources: torch.Tensor, rays: torch.Tensor, centre: torch.Tensor,
                 w2c_src: torch.Tensor, k: CameraIntrinsics, inv_depth: torch.Tensor, window: int,
                 chunk_elements: int = 1 << 21) -> torch.Tensor:
    """(D, h, w) cost (1 - correlation, 0..2) of each inverse-depth hypothesis ``inv_depth`` (D, h, w) of the
    reference's pixels. ``ref``: (C, h, w) image; ``sources``: (N, C, h, w); ``rays``: (h*w, 3) world directions
    with unit camera-z; ``centre``: (3,) the reference camera; ``w2c_src``: (N, 4, 4). The hypotheses go a few
    planes at a time, at most ``chunk_elements`` warped samples per channel: the tensors stay in cache, where
    the whole sweep at once was bound by memory traffic."""
    d, h, w = inv_depth.shape
    n, c = sources.shape[:2]
    rot, shift = w2c_src[:, :3, :3], w2c_src[:, :3, 3] + w2c_src[:, :3, :3] @ centre  # (N, 3, 3), (N, 3)
    along = (rot @ rays.T)[:, :, None, :]  # (N, 3, 1, hw): a ray's camera-frame direction in each source
    ref = ref.reshape(c, 1, h, w)
    r_sum, count = box_sum(ref, window)  # (C, 1, h, w), (h, w)
    r_var = box_sum((ref * ref).sum(dim=0, keepdim=True), window)[0][0] - (r_sum * r_sum).sum(dim=0) / count
    keep = max(1, (n + 1) // 2)
    step = max(1, chunk_elements // (n * h * w))
    out = torch.empty((d, h, w), dtype=ref.dtype, device=ref.device)
    for s in range(0, d, step):
        e = min(d, s + step)
        out[s:e] = _chunk_cost(ref, r_sum / count, r_var, count, sources, along, shift, k, inv_depth[s:e], window,
                                keep)
    return out


def _chunk_cost(ref, r_mean, r_var, count, sources, along, shift, k, inv_depth, window, keep) -> torch.Tensor:
    """:func:`_sweep_costs` for one chunk of hypotheses (D, h, w); ``r_mean`` (C, 1, h, w) and ``r_var`` (1, h, w):
    the reference window's mean and summed variance (times the ``count`` of its pixels)."""
    d, h, w = inv_depth.shape
    n, c = sources.shape[:2]
    depth = (1.0 / inv_depth).reshape(1, d, h * w)
    cam = [along[:, i] * depth + shift[:, i, None, None] for i in range(3)]  # each (N, D, hw)
    inv_z = 1.0 / cam[2].clamp_min(1e-9)  # behind a source: far outside its picture
    x, y = cam[0] * inv_z, cam[1] * inv_z
    if not (k.k1 == k.k2 == k.p1 == k.p2 == 0.0):
        r2 = x * x + y * y
        radial = 1 + k.k1 * r2 + k.k2 * r2 * r2
        x, y = (x * radial + 2 * k.p1 * x * y + k.p2 * (r2 + 2 * x * x),
                y * radial + k.p1 * (r2 + 2 * y * y) + 2 * k.p2 * x * y)
    # grid_sample's coordinates (-1..1 across the picture) straight from the normalised ones
    gx = x * (2.0 * k.fl_x / k.width) + (2.0 * k.cx / k.width - 1.0)
    gy = y * (2.0 * k.fl_y / k.height) + (2.0 * k.cy / k.height - 1.0)
    # every bilinear tap inside the source's picture: pixel centres from -1 + 1/w to 1 - 1/w
    valid = ((gx.abs() <= 1.0 - 1.0 / k.width) & (gy.abs() <= 1.0 - 1.0 / k.height)).reshape(n, d, h, w)
    warped = torch.nn.functional.grid_sample(sources, torch.stack([gx, gy], dim=-1), mode="bilinear",
                                             padding_mode="zeros", align_corners=False).reshape(n, c, d, h, w)
    # the correlation of the window's colours, all channels at once (the table's texture is mostly hue): sums
    # of each channel, of the summed squares and of the summed products, five box filters where nine were
    stats = torch.cat([warped, (warped * warped).sum(dim=1, keepdim=True),
                       (warped * ref[None]).sum(dim=1, keepdim=True)], dim=1)
    stats = box_sum(stats, window)[0]
    s_sum = stats[:, :c]
    s_var = stats[:, c] - (s_sum * s_sum).sum(dim=1) / count
    cross = stats[:, c + 1] - (s_sum * r_mean[None]).sum(dim=1)
    ncc = cross / torch.sqrt(r_var.clamp_min(0.0) * s_var.clamp_min(0.0) + 1e-6 * count * count)
    return mean_of_smallest((1.0 - ncc).masked_fill_(~valid, 2.0), keep)


def _best(cost: torch.Tensor, inv_depth: torch.Tensor, step: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(inverse depth, cost) per pixel of the hypothesis with the lowest ``cost`` (D, h, w), moved by the
    parabola through it and its neighbours (at most half a ``step``, (h, w) or scalar, either way)."""
    best = cost.argmin(dim=0, keepdim=True)
    c0 = cost.gather(0, best)[0]
    lo = cost.gather(0, (best - 1).clamp_min(0))[0]
    hi = cost.gather(0, (best + 1).clamp_max(len(cost) - 1))[0]
    curvature = lo + hi - 2.0 * c0
    inner = (best[0] > 0) & (best[0] < len(cost) - 1) & (curvature > 1e-6)
    offset = torch.where(inner, 0.5 * (lo - hi) / curvature.clamp_min(1e-6), torch.zeros_like(c0)).clamp(-0.5, 0.5)
    return inv_depth.gather(0, best)[0] + offset * step, c0


def depth_maps(views: PosedViews, config: StereoConfig = StereoConfig(), points: np.ndarray | None = None,
               device: str | torch.device = "cpu") -> DepthMaps:
    """Depth of every view by the plane sweep of the module docstring, at ``config.max_side_px``.

    ``points``: (P, 3) sparse points in the views' world frame, for the depth bounds (None: from the cameras).
    ``device``: where the sweep runs.
    """
    size = working_size(views.intrinsics, config.max_side_px)
    pyramid = [g.to(device) for g in image_pyramid(views.rgb, size, config.levels(max(size)))]
    look_at = common_look_at_point(views)
    neighbours = neighbour_views(views.c2w_cv, look_at, config.neighbours, config.min_angle_deg)
    bounds = depth_bounds(views.c2w_cv, look_at, points, views.intrinsics)
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float().to(device)
    centres = views.c2w_cv[:, :3, 3]
    depth = np.zeros((views.count, size[1], size[0]), np.float32)
    score = np.zeros_like(depth)
    with torch.no_grad():
        for i in range(views.count):
            inv, cost = _view_depth(i, pyramid, views, w2c, neighbours[i], bounds[i], centres, config, device)
            depth[i] = (1.0 / inv.clamp_min(1e-12)).cpu().numpy()
            score[i] = (1.0 - cost).cpu().numpy()
    return DepthMaps(depth, score, views.intrinsics.scaled(*size), views.c2w_cv.copy(),
                     pyramid[0].permute(0, 2, 3, 1).cpu().numpy(), neighbours)


def _view_depth(i: int, pyramid: list[torch.Tensor], views: PosedViews, w2c: torch.Tensor, neighbours: np.ndarray,
                bounds: np.ndarray, centres: np.ndarray, config: StereoConfig,
                device: str | torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(inverse depth, cost), each (h, w) at the finest level, of view ``i``."""
    src = torch.from_numpy(np.asarray(neighbours)).to(device)
    inv_near, inv_far = 1.0 / bounds[0], 1.0 / bounds[1]
    inv = cost = step = None
    for level in reversed(range(len(pyramid))):
        grey = pyramid[level]
        h, w = grey.shape[-2:]
        k = views.intrinsics.scaled(w, h)
        rays = torch.from_numpy(camera_rays(k, views.c2w_cv[i]).reshape(-1, 3)).float().to(device)
        centre = torch.from_numpy(centres[i]).float().to(device)
        if inv is None:
            # one plane per pixel of the widest neighbour's disparity swing over the range
            baseline = float(np.linalg.norm(centres[neighbours] - centres[i], axis=1).max())
            swing_px = k.fl_x * baseline * (inv_near - inv_far)
            planes = int(np.clip(np.ceil(swing_px), 16, config.max_planes))
            hyp = torch.linspace(inv_far, inv_near, planes, device=device)[:, None, None].expand(planes, h, w)
            step = torch.tensor((inv_near - inv_far) / (planes - 1), device=device)
        else:
            inv = torch.nn.functional.interpolate(inv[None, None], size=(h, w), mode="bilinear",
                                                  align_corners=False)[0, 0]
            step = step * 0.5
            offsets = torch.arange(-config.refine_steps, config.refine_steps + 1, device=device).float()
            hyp = (inv[None] + offsets[:, None, None] * step).clamp(inv_far * 0.5, inv_near * 2.0)
        costs = _sweep_costs(grey[i], grey[src], rays, centre, w2c[src], k, hyp.contiguous(), config.window_px)
        inv, cost = _best(costs, hyp, step)
    return inv, cost


def camera_rays(k: CameraIntrinsics, c2w_cv: np.ndarray) -> np.ndarray:
    """(h, w, 3) world directions through the pixel centres of camera ``k``, scaled to unit depth along its
    optical axis (a point at depth z is the camera centre plus z times the ray)."""
    v, u = np.mgrid[0:k.height, 0:k.width]
    x, y = undistorted_normalized(k, u.ravel() + 0.5, v.ravel() + 0.5)
    rays = np.stack([x, y, np.ones_like(x)], axis=-1) @ c2w_cv[:3, :3].T
    return rays.reshape(k.height, k.width, 3)
