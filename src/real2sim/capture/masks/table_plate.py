"""The table's own image (a *plate*), gathered from every view, and the mask pixels it explains.

The parallax masks (:mod:`real2sim.capture.masks.parallax`) judge each pixel against a few
neighbouring views warped through the table plane. Two places defeat that test, both where the
masks then grow too large: table seen through a hole of the object (a mug's handle), whose table
point the neighbours see hidden behind the handle or the body, and table right beside a silhouette
that only a few steep views see past the object. Yet the table point behind such a pixel is seen,
unhidden, by many other views of the capture, some far from it.

So the table plane is sampled on a grid of texels around the object, each texel's colour the
median over the views that see it outside their masks (dilated by ``occluder_margin_px``: the
masks of the first rounds hold the object, so a view whose mask covers the texel's image may see the
object there instead), after each view's per-channel exposure gain against the others. Rendered
into a view through the plane, the plate is that view's image of an empty table. A mask pixel is
*explained* when its image differs from the plate by less than ``threshold`` (largest channel, RGB in
[0, 1], the smallest difference over the plate shifted by up to a pixel: a printed edge resampled
differently is no evidence), averaged over a window of ``2 window_px + 1`` pixels, and the plate varies
there (``min_texture``, the plate's grey standard deviation over the window): two plain patches of one
colour (a black dot of the object over a black square) match whatever lies where.

With ``pixel_threshold`` set, the window may slide (stereo's shiftable windows): a pixel is explained
when *some* window that holds it passes, and the pixel itself differs by less than ``pixel_threshold``.
The masks' excess beside a silhouette is a band a few pixels wide: the window centred on a table pixel
there holds the object's edge and fails, one further out holds table only; the pixel's own test keeps
the object's edge pixels out of the windows that reach over them. It takes more of that band and a little
more of the object too; the parallax masks use it (``ParallaxConfig.plate_pixel_threshold``;
docs/design-notes/capture.md#parallax-plate-sliding).

A view that explains part of the object by chance does not carve it alone: the explained pixels join
the table verdict of one more round of the standing hull, where a voxel goes only when several views call
it table. But views a few degrees apart (a video's) repeat one chance match, so there each explained pixel
gets a second opinion from the object (:func:`explained_by_object`, on where
``ParallaxConfig.plate_object_threshold`` is set): where the neighbouring views see the same colour on the
masks' solid, the pixel stays object. World frame: the views', table plane z = ``table_z_m``, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import binary_dilation, uniform_filter

from real2sim.multiview.rays import SurfaceRays
from real2sim.multiview.views import PosedViews, bilinear, pixel_rays, plane_hits, project_torch

#: the plate has at most this many texels along a side (its texel grows for a very wide table)
MAX_TEXELS = 2048
#: a plate texel needs this many views that see it unhidden
MIN_PLATE_VIEWS = 3
#: ... and a view's exposure gain is measured on at least this many of its table pixels
MIN_GAIN_PIXELS = 500
#: the views' gains are measured on at most this many chunks of texels
GAIN_CHUNKS = 16


@dataclass(frozen=True)
class TablePlate:
    """``colour``: (T, T, 3) float32 RGB of the table plane on a square grid of texels (NaN where fewer
    than :data:`MIN_PLATE_VIEWS` views saw it); texel (r, c) covers x = ``origin_xy_m[0]`` + c
    ``texel_m`` and y = ``origin_xy_m[1]`` + r ``texel_m`` (its corner); ``seen_by``: (T, T) views;
    ``view_gain``: (N, 3) each view's per-channel exposure gain against the others, measured on the table."""

    colour: np.ndarray
    seen_by: np.ndarray
    origin_xy_m: tuple[float, float]
    texel_m: float
    table_z_m: float
    view_gain: np.ndarray


def table_plate(views: PosedViews, masks: np.ndarray, table_z_m: float, *, occluder_margin_px: int = 3,
                chunk: int = 20_000) -> TablePlate:
    """The plate of ``views`` whose object ``masks`` (N, H, W) bool cover (see the module docstring),
    over the table points that the pixels near the masks see, at about one texel per pixel."""
    k = views.intrinsics
    centre_xy, half_m, texel_m = _plate_extent(views, masks, table_z_m)
    n = int(np.ceil(2 * half_m / texel_m))
    origin = (float(centre_xy[0] - half_m), float(centre_xy[1] - half_m))
    xs = origin[0] + (np.arange(n) + 0.5) * texel_m
    ys = origin[1] + (np.arange(n) + 0.5) * texel_m
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    points = torch.from_numpy(np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, table_z_m)], 1).astype(np.float32))
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float()
    images = torch.from_numpy(np.ascontiguousarray(views.rgb.transpose(0, 3, 1, 2)))
    side = 2 * occluder_margin_px + 1
    hidden_px = torch.from_numpy(binary_dilation(masks, np.ones((1, side, side), bool))[:, None].astype(np.float32))
    colour = np.full((n * n, 3), np.nan, np.float32)
    seen_by = np.zeros(n * n, np.int32)

    def sampled(start: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(V, P) whether each view sees the chunk's texels unhidden, (V, P, 3) their colours there."""
        u, v, z = project_torch(k, w2c, points[start:start + chunk])
        grid = torch.stack([u * (2.0 / k.width) - 1.0, v * (2.0 / k.height) - 1.0], -1)[:, None]
        seen = (z > 0) & (grid[:, 0].abs() <= 1).all(-1)
        seen &= torch.nn.functional.grid_sample(hidden_px, grid, mode="nearest", align_corners=False)[:, 0, 0] < 0.5
        rgb = torch.nn.functional.grid_sample(images, grid, mode="bilinear", align_corners=False)[:, :, 0]
        return seen, rgb.permute(0, 2, 1)

    starts = range(0, n * n, chunk)
    with torch.no_grad():
        # the gains from at most GAIN_CHUNKS chunks spread over the plate: enough table, bounded memory
        gain = _view_gains([sampled(start) for start in starts[::max(1, len(starts) // GAIN_CHUNKS)]], views.count)
        for start in starts:
            seen, rgb = sampled(start)
            rgb = torch.where(seen[..., None], rgb / gain[:, None, :], torch.full_like(rgb, float("nan")))
            colour[start:start + rgb.shape[1]] = torch.nanmedian(rgb, dim=0).values.numpy()
            seen_by[start:start + rgb.shape[1]] = seen.sum(0).numpy()
    colour[seen_by < MIN_PLATE_VIEWS] = np.nan
    return TablePlate(colour.reshape(n, n, 3), seen_by.reshape(n, n), origin, float(texel_m), float(table_z_m),
                      gain.numpy().astype(np.float64))


def _plate_extent(views: PosedViews, masks: np.ndarray, table_z_m: float) -> tuple[np.ndarray, float, float]:
    """(centre xy, half side, texel) in metres: a square around the table points that the pixels of the
    masks' boxes see (each view's rays through its mask's bounding box, grown by a quarter), with texels
    the size of a pixel at the median view's distance."""
    k = views.intrinsics
    hits, distances = [], []
    for i in range(views.count):
        rows, cols = np.nonzero(masks[i].any(axis=1))[0], np.nonzero(masks[i].any(axis=0))[0]
        if not len(rows):
            continue
        h_pad, w_pad = 0.25 * (rows[-1] - rows[0] + 1), 0.25 * (cols[-1] - cols[0] + 1)
        v = np.clip([rows[0] - h_pad, rows[-1] + h_pad], 0, k.height)
        u = np.clip([cols[0] - w_pad, cols[-1] + w_pad], 0, k.width)
        uu, vv = np.meshgrid(np.linspace(u[0], u[1], 9), np.linspace(v[0], v[1], 9))
        origin, direction = pixel_rays(k, views.c2w_cv[i], uu.ravel(), vv.ravel())
        on_plane, down = plane_hits(origin, direction, table_z_m)
        hits.append(on_plane[down, :2])
        distances.append(float(np.median(np.linalg.norm(on_plane[down] - origin[down], axis=-1)))
                         if down.any() else np.nan)
    points = np.concatenate(hits) if hits else np.zeros((0, 2))
    if len(points) == 0:
        return np.zeros(2), 0.0, 1.0
    lo, hi = np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)
    half_m = float(0.5 * np.max(hi - lo))
    # a pixel's footprint where its ray meets the table, at the median view's distance
    texel_m = float(np.nanmedian(distances)) / max(k.fl_x, k.fl_y)
    texel_m = max(texel_m, 2 * half_m / MAX_TEXELS)
    return 0.5 * (lo + hi), half_m, texel_m


def _view_gains(samples: list, count: int) -> torch.Tensor:
    """(V, 3): each view's per-channel exposure gain against the median of the views seeing the same
    texels (medians of ratios over the texels it shares with at least :data:`MIN_PLATE_VIEWS` views);
    ``samples``: (seen (V, P), colours (V, P, 3)) per chunk of texels."""
    ratios: list[list[torch.Tensor]] = [[] for _ in range(count)]
    for seen, rgb in samples:
        nan_rgb = torch.where(seen[..., None], rgb, torch.full_like(rgb, float("nan")))
        reference = torch.nanmedian(nan_rgb, dim=0).values  # (P, 3)
        shared = seen & (seen.sum(0) >= MIN_PLATE_VIEWS)[None] & (reference.min(-1).values > 0.05)[None]
        for i in range(count):
            if shared[i].any():
                ratios[i].append(rgb[i][shared[i]] / reference[shared[i]])
    gains = torch.ones(count, 3)
    for i, r in enumerate(ratios):
        if r and sum(len(x) for x in r) >= MIN_GAIN_PIXELS:
            gains[i] = torch.cat(r).median(dim=0).values.clamp(0.5, 2.0)
    return gains


def plate_in_view(plate: TablePlate, views: PosedViews, i: int,
                  mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) the plate as view ``i`` would see an empty table, and (H, W) bool where it has one.
    With the view's object ``mask`` (H, W) bool, at the view's exposure: per channel, the median ratio of
    its image to the plate over its table beyond the mask (grown by 4 px)."""
    k = views.intrinsics
    v_px, u_px = np.mgrid[0:k.height, 0:k.width]
    on_plane, down = plane_hits(*pixel_rays(k, views.c2w_cv[i], u_px.ravel() + 0.5, v_px.ravel() + 0.5),
                                plate.table_z_m)
    n = plate.colour.shape[0]
    gx = (on_plane[:, 0] - plate.origin_xy_m[0]) / (plate.texel_m * n) * 2.0 - 1.0
    gy = (on_plane[:, 1] - plate.origin_xy_m[1]) / (plate.texel_m * n) * 2.0 - 1.0
    grid = torch.from_numpy(np.stack([gx, gy], -1).astype(np.float32))[None, None]
    seen = np.isfinite(plate.colour[..., 0])
    texels = torch.from_numpy(np.concatenate([np.nan_to_num(plate.colour), seen[..., None]], -1).transpose(2, 0, 1)
                              [None].astype(np.float32).copy())
    sampled = torch.nn.functional.grid_sample(texels, grid, mode="bilinear", align_corners=False)[0, :, 0].T.numpy()
    # a pixel whose bilinear sample touches an unseen texel has no plate
    valid = (down & (np.abs(gx) <= 1) & (np.abs(gy) <= 1) & (sampled[:, 3] > 0.999)).reshape(k.height, k.width)
    background = sampled[:, :3].reshape(k.height, k.width, 3)
    if mask is not None:
        table = valid & ~binary_dilation(mask, np.ones((9, 9), bool))
        if table.sum() >= MIN_GAIN_PIXELS:
            gain = np.median(views.rgb[i][table], 0) / np.maximum(np.median(background[table], 0), 1e-3)
            background = background * np.clip(gain, 0.5, 2.0)
    return background, valid


def explained_by_plate(views: PosedViews, masks: np.ndarray, plate: TablePlate, *, threshold: float = 0.06,
                       window_px: int = 2, min_texture: float = 0.02,
                       pixel_threshold: float | None = None) -> np.ndarray:
    """(N, H, W) bool: the pixels of ``masks`` whose image the plate explains (module docstring)."""
    out = np.zeros_like(masks, dtype=bool)
    side = 2 * window_px + 1
    for i in range(views.count):
        if not masks[i].any():
            continue
        background, valid = plate_in_view(plate, views, i, masks[i])
        image = views.rgb[i]
        difference = np.full(image.shape[:2], np.inf, np.float32)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                gap = np.abs(image - np.roll(background, (dy, dx), axis=(0, 1)))
                # the largest channel by elementwise maxima: numpy reduces a last axis of 3 about 5x slower
                difference = np.minimum(difference, np.maximum(np.maximum(gap[..., 0], gap[..., 1]), gap[..., 2]))
        pixel = np.where(valid, difference, 1.0).astype(np.float32)
        grey = background.mean(-1)
        variance = uniform_filter(grey * grey, side) - uniform_filter(grey, side) ** 2
        whole = uniform_filter(valid.astype(np.float32), side) > 0.999  # the window lies on the plate
        windows = whole & (uniform_filter(pixel, side) < threshold) & (np.sqrt(np.maximum(variance, 0.0)) > min_texture)
        if pixel_threshold is None:  # the centred window only
            out[i] = masks[i] & windows
        else:
            out[i] = masks[i] & binary_dilation(windows, np.ones((side, side), bool)) & (pixel < pixel_threshold)
    return out


def explained_by_object(views: PosedViews, explained: np.ndarray, solid, neighbours: np.ndarray,
                        view_gain: np.ndarray, *, threshold: float = 0.08, window_px: int = 2, min_views: int = 2,
                        visibility_tolerance: float = 0.01) -> np.ndarray:
    """(N, H, W) bool: the plate's ``explained`` pixels whose image the object explains as well.

    The plate matches some of the object by chance: a printed label whose colours happen to be the table's
    behind it. From a video the views come a few degrees apart, so such a patch is explained in many views
    in a row and the hull carves a hollow through the object. Each explained pixel has a second hypothesis:
    that it sees the surface of ``solid`` (the masks' solid, metres, world frame) where its ray first meets
    it. ``neighbours`` (N, K) are views with parallax against it (``parallax_table.neighbour_views``); those
    that see that surface point unhidden (nothing of ``solid`` nearer than ``visibility_tolerance`` of the
    distance) sample their image there, the best of the sample shifted by up to a pixel, each view at its
    exposure (``view_gain`` (N, 3)). The object explains the pixel when at least ``min_views`` of them see
    the point and the median of their differences (largest channel, RGB in [0, 1]), averaged over the
    scored pixels of a ``2 window_px + 1`` window, is below ``threshold``. Where the pixel sees the table
    (through a handle, beside a silhouette) the hull's surface lies centimetres in front of it and the
    neighbours see other things there; on a label the hull lies within millimetres of the surface and
    they see the same print."""

    k = views.intrinsics
    side = 2 * window_px + 1
    images = torch.from_numpy(np.ascontiguousarray(views.rgb, dtype=np.float32))
    out = np.zeros_like(explained, dtype=bool)
    surface = SurfaceRays(solid)
    for i in range(views.count):
        rows, cols = np.nonzero(explained[i])
        if not len(rows):
            continue
        origin, direction = pixel_rays(k, views.c2w_cv[i], cols + 0.5, rows + 0.5)
        t = surface.first_hit(origin, direction)
        ray_of = np.nonzero(np.isfinite(t))[0]
        if not len(ray_of):
            continue
        hits = origin[ray_of] + t[ray_of, None] * direction[ray_of]
        colour = views.rgb[i][rows[ray_of], cols[ray_of]] / view_gain[i]
        others = neighbours[i]
        centres = views.c2w_cv[others, :3, 3]
        offsets = hits[None] - centres[:, None]  # (K, P, 3)
        distance = np.linalg.norm(offsets, axis=-1)
        ray_origin = np.repeat(centres, len(hits), axis=0)
        ray_direction = (offsets / distance[..., None]).reshape(-1, 3)
        first = surface.first_hit(ray_origin, ray_direction)
        unhidden = first.reshape(distance.shape) >= (1 - visibility_tolerance) * distance
        w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv[others])).float()
        u, v, depth = project_torch(k, w2c, torch.from_numpy(hits.astype(np.float32)))  # (K, P)
        # in front, and a pixel inside the border for the shifted bilinear samples
        seen = unhidden & ((depth > 0) & (u >= 1) & (u < k.width - 2) & (v >= 1) & (v < k.height - 2)).numpy()
        view_of = torch.from_numpy(np.repeat(others, len(hits)))
        best = torch.full((len(others) * len(hits),), float("inf"), dtype=torch.float64)
        target = torch.from_numpy(np.tile(colour, (len(others), 1)))
        gain = torch.from_numpy(np.repeat(view_gain[others], len(hits), axis=0))
        for dv in (-1.0, 0.0, 1.0):  # a print resampled a fraction of a pixel off is no evidence
            for du in (-1.0, 0.0, 1.0):
                uv = torch.stack([u.reshape(-1) + du, v.reshape(-1) + dv], -1)
                sampled = bilinear(images, view_of, uv) / gain
                best = torch.minimum(best, (sampled - target).abs().max(-1).values)
        difference = np.where(seen, best.numpy().reshape(seen.shape), np.nan)
        scored = seen.sum(0) >= min_views
        at = rows[ray_of][scored], cols[ray_of][scored]
        score = np.zeros(explained.shape[1:], np.float32)
        counted = np.zeros(explained.shape[1:], np.float32)
        score[at] = np.nanmedian(difference[:, scored], axis=0)
        counted[at] = 1.0
        mean = uniform_filter(score, side) / np.maximum(uniform_filter(counted, side), 1e-6)
        out[i] = (counted > 0) & (mean < threshold)
    return out
