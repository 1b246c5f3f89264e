"""Steps 1-2 of the parallax masks (:mod:`real2sim.capture.masks.parallax`): which pixels of each view see
the textured table, judged by warping neighbouring views onto it through the table plane.

This module holds the per-view image work (the warps, the Birchfield-Tomasi match, texture, the aperture
test, plain patches, table specks); the settings are :class:`~real2sim.capture.masks.parallax_config.ParallaxConfig`;
the masks' module holds the standing hull made of these verdicts, and its silhouettes.
World frame: the views', table plane z = ``config.table_z_m``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.multiview.voxel_grid import voxel_parts
from real2sim.multiview.views import PosedViews, common_look_at_point, pixel_rays, plane_hits, project_torch

if TYPE_CHECKING:
    from real2sim.capture.masks.parallax_config import ParallaxConfig

TABLE_VOTE_RATIO = 3.0


def neighbour_views(views: PosedViews, config: ParallaxConfig) -> np.ndarray:
    """(N, neighbours) indices: for each view, the views nearest in direction from the common point
    among those at least ``min_angle_deg`` away (the nearest beyond it when too few are in range)."""
    centre = common_look_at_point(views)
    dirs = views.c2w_cv[:, :3, 3] - centre
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0)))
    n = views.count
    if n - 1 < config.neighbours:
        raise UserInputError(f"parallax masks need more than {config.neighbours} views (got {n})")
    # too close (no parallax) or too far (too much hidden differently) sort after the views in range
    penalty = np.where(angle < config.min_angle_deg, 1e3, 0.0) + np.where(angle > config.max_angle_deg, 1e3, 0.0)
    cost = angle + penalty
    np.fill_diagonal(cost, np.inf)
    return np.argsort(cost, axis=1)[:, :config.neighbours]


def _half_pixel_range(image: torch.Tensor, reach_px: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """(low, high), each (..., C, H, W): the range of ``image`` (..., C, H, W) over each pixel and the four
    points ``reach_px`` (at most 1) away, linearly interpolated (Birchfield and Tomasi's sampling-insensitive
    range, at half a pixel): a sharp edge printed on the table, resampled a fraction of a pixel off, is no
    evidence of height. Wider (a whole 3x3 window) and a black-and-white pattern on the object would match
    anything."""
    return _reached(image, _cross_extremes(image), reach_px)


def _cross_extremes(image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(min, max) of each pixel of ``image`` (..., C, H, W) and its four neighbours (edges replicated)."""
    flat = image.reshape(-1, *image.shape[-3:])
    padded = torch.nn.functional.pad(flat, (1, 1, 1, 1), mode="replicate")
    padded = padded.reshape(*image.shape[:-2], *(n + 2 for n in image.shape[-2:]))
    h, w = image.shape[-2:]
    low, high = image.clone(), image.clone()
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        shifted = padded[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        torch.minimum(low, shifted, out=low)
        torch.maximum(high, shifted, out=high)
    return low, high


def _reached(image: torch.Tensor, extremes: tuple[torch.Tensor, torch.Tensor],
             reach_px: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The range of :func:`_half_pixel_range` from the pixel's :func:`_cross_extremes`: the points ``reach_px``
    towards each neighbour are linear blends, so their extremes are the blend of the pixel and its neighbours'
    extremes (one pass serves every reach)."""
    low, high = extremes
    return torch.lerp(image, low, reach_px), torch.lerp(image, high, reach_px)


def _channel_std(image: torch.Tensor, radius: int) -> torch.Tensor:
    """(H, W) the largest over the channels of ``image`` (C, H, W) of :func:`_local_std`: a dark blue band
    beside black squares differs in one channel, hardly in grey."""
    return _local_std(image, radius).amax(dim=0)


def _parallax_across_edges(image: torch.Tensor, c2w: np.ndarray, neighbour_c2w: np.ndarray,
                           intrinsics: CameraIntrinsics, radius: int) -> np.ndarray:
    """(K, H, W): for each neighbour (``neighbour_c2w`` (K, 4, 4), OpenCV camera-to-world) the share of the
    local image gradient energy of ``image`` (C, H, W; structure tensor summed over channels, over a
    (2r+1)^2 window) that lies along the direction in which the neighbour's parallax moves each pixel of the
    view at ``c2w``: 1 across an edge, 0 along it, 1/2 at a corner or a blob. A camera that moves along a
    horizontal edge (an orbit past a band printed round a mug) sees the same edge whatever its height."""
    k = intrinsics
    h, w = image.shape[-2:]
    moved = (c2w[:3, :3].T @ (neighbour_c2w[:, :3, 3] - c2w[:3, 3]).T).T  # (K, 3), in the view's camera frame
    x = (np.arange(w) + 0.5 - k.cx) / k.fl_x
    y = (np.arange(h) + 0.5 - k.cy) / k.fl_y
    # image motion of a point at depth Z when the camera moves by d: (d_x - x d_z, d_y - y d_z) / Z
    mx = moved[:, 0, None, None] - x[None, None, :] * moved[:, 2, None, None]
    my = moved[:, 1, None, None] - y[None, :, None] * moved[:, 2, None, None]
    length = np.maximum(np.hypot(mx, my), 1e-12)
    mx, my = mx / length, my / length
    padded = torch.nn.functional.pad(image[None], (1, 1, 1, 1), mode="replicate")[0]
    gx = 0.5 * (padded[:, 1:-1, 2:] - padded[:, 1:-1, :-2])
    gy = 0.5 * (padded[:, 2:, 1:-1] - padded[:, :-2, 1:-1])

    def window(a: torch.Tensor) -> np.ndarray:  # summed over the channels, averaged over the window
        return _window_mean(a.sum(dim=0), radius).numpy()

    jxx, jxy, jyy = window(gx * gx), window(gx * gy), window(gy * gy)
    along = mx * mx * jxx + 2 * mx * my * jxy + my * my * jyy
    return along / np.maximum(jxx + jyy, 1e-12)


def _window_mean(image: torch.Tensor, radius: int) -> torch.Tensor:
    """(..., H, W): the mean of ``image`` (..., H, W) over a (2r+1)^2 window around each pixel (edges
    replicated)."""
    flat = image.reshape(-1, 1, *image.shape[-2:])
    padded = torch.nn.functional.pad(flat, (radius,) * 4, mode="replicate")
    return torch.nn.functional.avg_pool2d(padded, 2 * radius + 1, stride=1).reshape(image.shape)


def _local_std(gray: torch.Tensor, radius: int) -> torch.Tensor:
    """(..., H, W) standard deviation over a (2r+1)^2 window (edges replicated)."""
    mean = _window_mean(gray, radius)
    return (_window_mean(gray * gray, radius) - mean * mean).clamp_min(0.0).sqrt()


@dataclass(frozen=True)
class NeighbourVotes:
    """What each view's neighbours say of its pixels before any view is known to hide the table (steps 1-2
    without the occluders): each round of :func:`table_evidence` reads them, so the warps, exposure gains,
    texture and aperture tests are made once however many rounds judge the table. Boolean arrays are
    bit-packed along the image rows (``np.packbits``, last axis): a 60-view capture at 640x480 holds some
    80 MB instead of 600 MB."""

    reaches_px: tuple[float, ...]
    """The Birchfield-Tomasi reaches (pixels) the verdicts were judged with."""
    near: np.ndarray
    """(N, K) int: each view's neighbours (:func:`neighbour_views`)."""
    valid: np.ndarray
    """(N, K, H, W / 8) packed bool: the neighbour sees the table point behind the pixel."""
    close: np.ndarray
    """(R, N, K, H, W / 8) packed bool: the pixel's colour lies within the threshold of the range of the
    neighbour's warped image, per reach of ``reaches_px``."""
    informative: np.ndarray | None
    """(N, K, H, W / 8) packed bool: the neighbour's parallax crosses the local edge; None without the
    aperture test (``min_parallax_share`` 0)."""
    textured: np.ndarray
    """(N, H, W) bool: the image has texture around the pixel (unpacked: its width is the images')."""

    def unpacked(self, packed: np.ndarray) -> torch.Tensor:
        """A packed array of this record as a bool tensor of the images' full width."""
        return torch.from_numpy(np.unpackbits(packed, axis=-1, count=self.textured.shape[-1]).view(bool))


def _table_points_in_neighbours(views: PosedViews, near: np.ndarray, i: int, table_z_m: float,
                                w2c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Where the table point behind each pixel of view ``i`` falls in each of its neighbours ``near`` (K,):
    (grid, valid), (K, H, W, 2) normalised image coordinates for ``grid_sample`` and (K, H, W) bool, the
    neighbour sees it (in front of it, inside its image, the pixel's ray meets the plane)."""
    k = views.intrinsics
    h, w = k.height, k.width
    v_px, u_px = np.mgrid[0:h, 0:w]
    on_plane, hits = plane_hits(*pixel_rays(k, views.c2w_cv[i], u_px.ravel() + 0.5, v_px.ravel() + 0.5), table_z_m)
    u, v, z = project_torch(k, w2c[near], torch.from_numpy(on_plane.astype(np.float32)))
    grid = torch.stack([u * (2.0 / w) - 1.0, v * (2.0 / h) - 1.0], dim=-1).reshape(len(near), h, w, 2)
    valid = (z > 0).reshape(-1, h, w) & (grid.abs() <= 1).all(dim=-1) & torch.from_numpy(hits.reshape(1, h, w))
    return grid, valid


def neighbour_votes(views: PosedViews, config: ParallaxConfig, reaches_px: tuple[float, ...],
                    progress: ProgressFn = null_progress) -> NeighbourVotes:
    """Each view's neighbours warped onto it through the table plane and compared with it (steps 1-2 of
    :mod:`real2sim.capture.masks.parallax`), with each reach of ``reaches_px`` (pixels; the neighbours are
    warped once): the votes :func:`table_evidence` counts."""
    k = views.intrinsics
    images = torch.from_numpy(np.ascontiguousarray(views.rgb.transpose(0, 3, 1, 2)))  # (N, 3, H, W), [0, 1]
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float()
    near = neighbour_views(views, config)
    valid_all, close_all, informative_all, textured_all = [], [], [], []

    def packed(a: torch.Tensor) -> np.ndarray:
        return np.packbits(a.numpy(), axis=-1)

    with torch.no_grad():
        for i in range(views.count):
            grid, valid = _table_points_in_neighbours(views, near[i], i, config.table_z_m, w2c)
            warped = torch.nn.functional.grid_sample(images[near[i]], grid, mode="bilinear", align_corners=False)
            own = images[i]
            # exposure: per-channel gain of each neighbour on the pixels both see (medians: the object is a minority)
            for j in range(len(near[i])):
                m = valid[j]
                if m.sum() > 100:
                    gain = own[:, m].median(dim=1).values / warped[j][:, m].median(dim=1).values.clamp_min(1e-3)
                    warped[j] *= gain.clamp(0.5, 2.0)[:, None, None]
            textured_all.append((_channel_std(own * 255.0, config.texture_px) >= config.min_texture).numpy())
            if config.min_parallax_share > 0:  # parallax along the local edge cannot tell the edge's height
                informative_all.append(packed(torch.from_numpy(_parallax_across_edges(
                    own, views.c2w_cv[i], views.c2w_cv[near[i]], k, config.texture_px) >= config.min_parallax_share)))
            extremes = _cross_extremes(warped)
            close = []
            for reach in reaches_px:  # per neighbour, against the range of its warped image around (Birchfield-Tomasi)
                low, high = _reached(warped, extremes, reach)
                close.append(packed(torch.maximum(own - high, low - own).clamp_min(0.0).amax(dim=1) * 255.0
                                    <= config.threshold))
            valid_all.append(packed(valid))
            close_all.append(np.stack(close))
            progress("parallax masks: table", i + 1, views.count)
    return NeighbourVotes(tuple(reaches_px), near, np.stack(valid_all), np.stack(close_all, axis=1),
                          np.stack(informative_all) if informative_all else None, np.stack(textured_all))


def table_evidence(views: PosedViews, config: ParallaxConfig, votes: NeighbourVotes,
                   occluders: np.ndarray | None = None, progress: ProgressFn = null_progress) -> np.ndarray:
    """(len(votes.reaches_px), N, H, W) bool: the pixels that see the textured table (steps 1-2 of
    :mod:`real2sim.capture.masks.parallax`), judged with each reach of the neighbours' ``votes``
    (:func:`neighbour_votes` of the same views and config).

    ``occluders`` (N, H, W) bool, optional: where each view sees the object (a first estimate). A neighbour
    in whose image the table point behind a pixel falls there cannot show that point and does not vote;
    a pixel with fewer than two voting neighbours keeps the verdict it gets with every neighbour voting."""
    k = views.intrinsics
    h, w = k.height, k.width
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float()
    out = np.zeros((len(votes.reaches_px), views.count, h, w), dtype=bool)
    occ = None if occluders is None else torch.from_numpy(occluders[:, None].astype(np.float32))
    with torch.no_grad():
        for i in range(views.count):
            near = votes.near[i]
            valid = votes.unpacked(votes.valid[i])
            textured = votes.textured[i]
            beyond = (valid.sum(dim=0) < 2).numpy()
            # the neighbours that vote: those that can show the table point behind the pixel, where at least
            # two can (all that see it otherwise)
            voters = valid
            if occ is not None:  # a table point lies behind the object in a neighbour that sees it inside
                grid, _ = _table_points_in_neighbours(views, near, i, config.table_z_m, w2c)
                hidden = torch.nn.functional.grid_sample(occ[near], grid, mode="nearest", align_corners=False)[:, 0] > 0.5
                voters = torch.where((valid & ~hidden).sum(dim=0) >= 2, valid & ~hidden, valid)
            barrier = np.zeros_like(textured)
            if votes.informative is not None:
                informative = votes.unpacked(votes.informative[i])
                # only where enough neighbours see the table point at all: with fewer, the pixel cannot be
                # confirmed as table whatever its edges, and stays "not table" as without this test
                barrier = textured & ((voters.sum(dim=0) >= 2) & ((voters & informative).sum(dim=0) < 2)).numpy()
                voters = voters & informative
            decided = textured & ~barrier
            for r in range(len(votes.reaches_px)):
                matches = _agreed(voters, votes.unpacked(votes.close[r, i]), config.agreement).numpy()
                table = _plain_patches_decided(matches & decided, ~matches & decided, beyond, barrier)
                out[r, i] = _without_table_specks(table, config.min_table_speck_share)
            progress("parallax masks: table verdicts", i + 1, views.count)
    return out


def _without_table_specks(table: np.ndarray, min_share: float) -> np.ndarray:
    """``table`` (H, W) bool without its connected parts (8-neighbours) smaller than ``min_share`` of the
    image: a neighbour's warped texture matches a patterned object by chance here and there (a black dot
    landing on another), and where a few views' specks line up the hull loses a tunnel through the object.
    Table seen through a real hole (a mug's handle) is a part of some size."""
    if min_share <= 0 or not table.any():
        return table
    labels, sizes = voxel_parts(table)
    small = sizes < min_share * table.size
    small[0] = False
    return table & ~small[labels]


def _agreed(voting: torch.Tensor, match: torch.Tensor, agreement: float) -> torch.Tensor:
    """(H, W) bool: at least two neighbours vote (``voting``, (K, H, W)) and ``agreement`` of them match."""
    seeing = voting.sum(dim=0)
    return (seeing >= 2) & ((voting & match).sum(dim=0) >= agreement * seeing)


def _plain_patches_decided(table: np.ndarray, other: np.ndarray, beyond: np.ndarray,
                           barrier: np.ndarray | None = None) -> np.ndarray:
    """``table`` grown into the undecided pixels (neither ``table`` nor ``other``): each 4-connected patch of
    them is table when the decided pixels around it are table ``TABLE_VOTE_RATIO`` times as often as not. A
    plain disc printed on the table is ringed by table pixels; the plain side of a can by the parallax of its
    edges, but for its bottom edge, which stands on the table and so matches it. A patch that reaches the
    image's border and lies mostly ``beyond`` the table (rays that miss its plane or land where no neighbour
    sees) is background too: a plain wall or sky behind the object, which no view can test against the table.
    ``barrier``: textured pixels no neighbour could judge (their edge runs along every parallax): they neither
    vote nor join patches, so the plain base of an object is not joined through its blurred lower edge to
    the plain squares of a board beside it."""
    from scipy import ndimage

    undecided = ~(table | other) if barrier is None else ~(table | other | barrier)
    labels, count = ndimage.label(undecided)
    if count == 0:
        return table
    ring = np.where(undecided, 0, ndimage.maximum_filter(labels, size=3))  # decided pixels next to a patch
    votes_table = np.bincount(ring[table], minlength=count + 1)
    votes_other = np.bincount(ring[other], minlength=count + 1)
    patch_is_table = votes_table >= TABLE_VOTE_RATIO * votes_other
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    size = np.maximum(np.bincount(labels.ravel(), minlength=count + 1), 1)
    share_beyond = np.bincount(labels[beyond], minlength=count + 1) / size
    patch_is_table[border[share_beyond[border] > 0.5]] = True
    patch_is_table[0] = False
    return table | patch_is_table[labels]
