"""Photo-consistent carving: open the concavities that silhouettes cannot see (a mug's cavity).

The visual hull fills every concavity a silhouette cannot reveal: seen from any
side, a mug's cavity is hidden by its rim. The views that look down into it see
its floor and inner wall, and those disagree about the colour of any point of
the lid the hull puts across it: each view sees a different point behind it.
A point on the real surface looks nearly the same from every view that sees it.

So, as in space carving (Kutulakos and Seitz, 2000), voxels on the surface of
the current solid are tested against the views that see them (a ray from the
camera reaches the voxel before the current surface stops it) and removed when
those views disagree; removing them exposes the voxels behind, which are tested
in the next round, until no surface voxel is removed. The radiance field then
starts from the carved solid, because its gradients cannot open a cavity by
themselves (a filled cavity renders nearly like a lid with a painted top).

The test, per surface voxel: the colours at its projection in the views that
see it (images blurred over half a voxel's footprint), their per-channel
median, and each view's distance from it (RGB in [0, 1]); the *spread* is the
``spread_quantile`` of those distances, and the voxel disagrees when it exceeds
``max_spread`` and at least ``min_views`` views see it. Three guards keep true
surfaces, measured on the bundled objects:

* brightness alone differs between views of a shiny or curved surface (the
  can's lid): a carve *starts* only where the hues disagree too (colour over
  brightness), and then grows through voxels next to what it removed, but not
  into a wall: a voxel that some views reach through the carved space and others
  from outside has two true faces whose colours differ (without this guard the
  carve ate through the mug's wall into its handle and rim);
* texture edges make isolated disagreeing voxels: a voxel goes only when most
  of the surface voxels around it disagree too;
* what is carved in the end is kept only in connected parts of at least
  ``min_component_fraction`` of the hull's volume;
* the silhouettes have the last word: a ray through a mask pixel that met the hull
  must still meet the carved solid, so carving that emptied such a ray gets put back
  (``mask_recheck``): where the views disagree for another reason than a concavity --
  poses a few millimetres off, which make every textured surface disagree -- carving
  would otherwise eat the object from the top down.

It stops early where the views inside a concavity agree for want of texture (a
deep cup's floor and lower wall, one flat colour, seen only from steep views):
there any depth looks the same from every view. So, once a concavity is open,
a second pass (*the hollow prior*, ``hollow_prior``) chooses the hollow shape where
the images cannot place a surface: a voxel of the concavity's surface goes when at least
``min_views`` views see it through the carved space, fewer than ``min_views``
from outside, it is more than ``min_wall_voxels`` from the visual hull's outside
and the table, and its views either look at featureless image (RGB contrast
below ``featureless_contrast`` over ``contrast_window_voxels`` footprints) or
disagree at least ``min_spread_to_contrast`` times as much as the image varies
there (a true textured surface is seen alike from every view), or would agree as well
(within ``depth_test_margin``) about a surface ``depth_test_voxels`` deeper along their
mean line of sight: views that cannot tell this depth from a deeper one do not place a
surface here, however much the image varies around (the *depth test*: a cup's plain
lower wall seen through its mouth, where the rim and a printed band make the contrast
high). Walls keep what
the silhouettes vouch for; the masks then judge the second pass on its own (a ray it
emptied gets back what it took). On the bundled mug (100 views, 320x240, 80
voxels, `bench_reconstruct`'s capture) the carved solid's wrong voxels (centres
outside the true mesh kept + inside it removed) fell from 46039 + 12 after the
first pass to 7480 + 2842 after the second (ratio 1.5). The ratio is 1.25: measured on four
captures (the robot mug, a 60-photo handheld mug with parallax masks, `bench_shapes`' bowl and
bin; `docs/benchmarks/carving_ratio_cuda.md`), 1.25 lowered the Chamfer distance of every one
against 1.5 (mug 0.77 -> 0.66 mm, handheld mug 1.88 -> 1.79, bowl 1.27 -> 1.14, bin 1.01 -> 0.94)
with no IoU lower by more than 0.005, while 1.0 opened the mugs further but ate the bowl's
wall (IoU 0.73 -> 0.61) and 1.1 part of it (0.67). A concavity
the first pass never opens (no colour disagreement anywhere) stays filled.
World frame, metres; the lowest layer of voxels (standing on the table) is never carved.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.ndimage import binary_dilation, binary_erosion, convolve, distance_transform_edt, gaussian_filter

from real2sim.formats.progress import ProgressFn
from real2sim.reconstruct.carving_views import Occluder, in_image, observations, occluder
from real2sim.reconstruct.hull import VoxelGrid, voxel_footprint_px, voxel_parts
from real2sim.reconstruct.mask_recheck import put_back_for_masks
from real2sim.reconstruct.views import PosedViews, project


@dataclass(frozen=True)
class CarvingConfig:
    """Photo-consistent carving settings; see the module docstring."""

    voxels: int = 80  # the carving grid has at least this many voxels along the longest side
    max_spread: float = 0.15
    spread_quantile: float = 0.75
    max_hue_spread: float = 0.15
    hue_quantile: float = 0.75
    hue_floor: float = 0.3
    min_views: int = 4
    neighbour_fraction: float = 0.5
    blur_voxels: float = 0.5
    max_rounds: int = 150
    visibility_tolerance_voxels: float = 1.0
    # how a view's line of sight to a voxel is tested against the solid: "mesh" (Embree on its
    # marching-cubes surface, rebuilt each round), "voxels" (the ray walked through the solid's
    # trilinear interpolation with torch, voxel_rays.segments_clear), or "auto": the mesh on a CPU,
    # the voxels on a GPU (carving_views.py)
    visibility: str = "auto"
    min_component_fraction: float = 0.1
    # the second pass, the hollow prior (see module docstring); the image contrast (RGB std over a
    # window of ``contrast_window_voxels`` footprints) below which a view cannot place a surface
    hollow_prior: bool = True
    featureless_contrast: float = 0.03
    contrast_window_voxels: float = 2.0
    # ... or where its views disagree at least this many times as much as its images vary locally
    min_spread_to_contrast: float = 1.25
    # ... or where the views would agree as well (within ``depth_test_margin``) about a surface this many
    # voxels deeper (0: no such test). On the handheld mug 1.83 -> 1.02 mm; the bowl 1.14 -> 1.06 mm and the
    # bin 0.94 -> 0.95 mm, both with IoU 0.08 lower (docs/benchmarks/carving_ratio_depth_cpu.md)
    depth_test_voxels: float = 2.0
    depth_test_margin: float = 0.02
    # the hollow prior keeps every voxel within this many voxels of the visual hull's outside (or the table)
    min_wall_voxels: float = 2.0
    # each view's exposure and white balance taken out of its images first (view_exposure.py)
    exposure_correction: bool = True
    # the masks' re-check puts back first what lies within this many voxels of the carved solid, round
    # by round (at most ``max_restore_rounds``), and then fills the voids its skin closes off: openings
    # at most 2 * ``void_gap_voxels`` wide do not count as a way out (``mask_recheck.put_back_for_masks``)
    restore_band_voxels: int = 1
    max_restore_rounds: int = 20
    void_gap_voxels: int = 2


@dataclass(frozen=True)
class CarvingResult:
    """``solid``: bool (``grid.shape``), the carved solid; ``carved_voxels``; ``rounds`` run;
    ``restored_voxels``: carved voxels put back because the masks' rays needed them."""

    solid: np.ndarray
    carved_voxels: int
    rounds: int
    restored_voxels: int = 0
    opened_voxels: int = 0  # of ``carved_voxels``, those the second pass (the hollow prior) removed
    # each view's exposure and white balance (view_exposure.py): whether they were taken out, and how large
    exposure: dict | None = None


#: Parts of the carved solid smaller than this fraction of it, cut off from the rest, are dropped.
FLOATER_FRACTION = 0.01

_FACES = np.zeros((3, 3, 3), bool)
_FACES[1, 1, :] = _FACES[1, :, 1] = _FACES[:, 1, 1] = True


def photo_carve(views: PosedViews, grid: VoxelGrid, solid: np.ndarray, config: CarvingConfig = CarvingConfig(),
                progress: ProgressFn | None = None, device: str = "cpu") -> CarvingResult:
    """Carve the photo-inconsistent surface voxels of ``solid`` (bool, ``grid.shape``) round by round.
    ``device``: where the masks' rays are walked (torch); the colour tests run on the CPU."""
    original, solid = solid, solid.copy()
    footprint_px = voxel_footprint_px(views, grid)
    images = _blurred(views.rgb, config.blur_voxels * footprint_px)
    floor = np.zeros(solid.shape, bool)
    floor[:, :, 0] = True
    candidates = _surface(solid) & ~floor
    exposure = None
    if config.exposure_correction:
        images, exposure = _exposure_corrected(views, images, grid, solid, candidates, config, device)
    rounds = 0
    for rounds in range(1, config.max_rounds + 1):
        if not candidates.any():
            break
        idx, verdict = _tested(views, images, grid, candidates, original, solid, config, device)
        # a carve starts only where the views disagree in hue, and grows wherever they disagree
        # at all: brightness alone differs between views of a shiny or curved true surface
        bad, hue_bad = np.zeros(solid.shape, bool), np.zeros(solid.shape, bool)
        inconsistent = (verdict.seen >= config.min_views) & (verdict.spread > config.max_spread)
        bad[tuple(idx[inconsistent].T)] = True
        hue_bad[tuple(idx[inconsistent & (verdict.hue_spread > config.max_hue_spread)].T)] = True
        grows = binary_dilation(original & ~solid, _FACES)
        # a voxel some views reach through the carved space and others from outside is a wall
        grows[tuple(idx[(verdict.through >= config.min_views) & (verdict.outside >= config.min_views)].T)] = False
        carve = bad & (grows | hue_bad) & _mostly_bad_neighbourhood(bad, _surface(solid), config.neighbour_fraction)
        if progress:
            progress("photo-consistent carving", rounds, config.max_rounds)
        if not carve.any():
            break
        solid &= ~carve
        candidates = _surface(solid) & _near(carve) & ~floor
    recheck = dict(band_voxels=config.restore_band_voxels, max_rounds=config.max_restore_rounds,
                   void_gap_voxels=config.void_gap_voxels, device=device)
    put_back = put_back_for_masks(views, grid, original, solid, **recheck)
    solid |= put_back
    solid |= _small_components(original & ~solid, config.min_component_fraction * original.sum())
    restored, opened_count = int(put_back.sum()), 0
    if config.hollow_prior and (original & ~solid).any():
        contrast = _local_contrast(images, config.contrast_window_voxels * footprint_px)
        opened = _open_concavity(views, images, contrast, grid, original, solid, floor, config, progress, device)
        # the masks judge the second pass on its own: a ray it emptied gets back what that pass took
        # from it (the concavity the first pass opened stays open)
        again = put_back_for_masks(views, grid, solid, opened, **recheck)
        opened |= again
        opened_count, restored = int((solid & ~opened).sum()), restored + int(again.sum())
        solid = opened
    # A ray that lost a thin rim to carving gets back every carved voxel on it, specks in mid-air
    # included; what is left of them floating is no object.
    solid &= ~_small_components(solid, FLOATER_FRACTION * solid.sum())
    return CarvingResult(solid=solid, carved_voxels=int((original & ~solid).sum()), rounds=rounds,
                         restored_voxels=restored, opened_voxels=opened_count, exposure=exposure)


#: The surface voxels the exposure is estimated on, at most (evenly spread over the surface).
EXPOSURE_SAMPLE_VOXELS = 20_000


def _exposure_corrected(views: PosedViews, images: np.ndarray, grid: VoxelGrid, solid: np.ndarray,
                        surface: np.ndarray, config: CarvingConfig, device: str) -> tuple[np.ndarray, dict]:
    """``images`` with each view's exposure and white balance divided out, as the views see the
    ``surface`` voxels of ``solid`` (:mod:`view_exposure`), and a report of the gains."""
    from real2sim.reconstruct.view_exposure import corrected_images, gains_summary, view_gains

    idx = np.argwhere(surface)
    idx = idx[::max(1, -(-len(idx) // EXPOSURE_SAMPLE_VOXELS))]
    view_of, point_of, pixel_uv, _ = observations(views, grid, grid.origin_m + idx * grid.voxel_m,
                                                  occluder(grid, solid, config.visibility, device),
                                                  config.visibility_tolerance_voxels)
    gains, evidence = view_gains(_bilinear(images, view_of, pixel_uv), view_of, point_of, views.count,
                                 min_views=config.min_views)
    if not evidence["applied"]:
        return images, evidence
    return corrected_images(images, gains), {**evidence, **gains_summary(gains)}


def _tested(views: PosedViews, images: np.ndarray, grid: VoxelGrid, candidates: np.ndarray, original: np.ndarray,
            solid: np.ndarray, config: CarvingConfig, device: str,
            contrast: np.ndarray | None = None, behind_m: float = 0.0) -> tuple[np.ndarray, _Verdict]:
    """The indices (P, 3) of the ``candidates`` voxels and the views' :class:`_Verdict` on each, seen
    against the current ``solid`` (carved so far: ``original & ~solid``)."""
    idx = np.argwhere(candidates)
    sight = occluder(grid, solid, config.visibility, device)
    return idx, _spread(views, images, grid, idx, sight, original & ~solid, config, contrast, behind_m)


def _open_concavity(views: PosedViews, images: np.ndarray, contrast: np.ndarray, grid: VoxelGrid,
                    original: np.ndarray, solid: np.ndarray, floor: np.ndarray, config: CarvingConfig,
                    progress: ProgressFn | None, device: str) -> np.ndarray:
    """``solid`` (a copy) with the space behind an opened concavity that the images cannot place a
    surface in removed, round by round (the hollow prior of the module docstring). ``contrast``:
    :func:`_local_contrast` of ``images``; ``floor``: voxels never carved."""
    solid = solid.copy()
    # the wall the silhouettes vouch for: near the hull's outside, or near the table under it
    keep = floor | (distance_transform_edt(np.pad(original, 1))[1:-1, 1:-1, 1:-1] <= config.min_wall_voxels)
    candidates = _surface(solid) & binary_dilation(original & ~solid, _FACES) & ~keep
    for rounds in range(1, config.max_rounds + 1):
        if not candidates.any():
            break
        idx, verdict = _tested(views, images, grid, candidates, original, solid, config, device, contrast,
                               behind_m=config.depth_test_voxels * grid.voxel_m)
        unplaced = (verdict.contrast < config.featureless_contrast) | \
            (verdict.spread >= config.min_spread_to_contrast * verdict.contrast)
        if verdict.behind is not None:
            unplaced |= verdict.behind <= verdict.spread + config.depth_test_margin
        open_ = (verdict.through >= config.min_views) & (verdict.outside < config.min_views) & unplaced
        if progress:
            progress("hollow prior", rounds, config.max_rounds)
        if not open_.any():
            break
        carve = np.zeros(solid.shape, bool)
        carve[tuple(idx[open_].T)] = True
        solid &= ~carve
        candidates = _surface(solid) & _near(carve) & ~keep
    return solid


def _small_components(carved: np.ndarray, min_voxels: float) -> np.ndarray:
    """The connected parts (26-neighbours) of ``carved`` smaller than ``min_voxels`` (carved parts to
    put back; applied to the solid, floaters to drop).

    Shading and highlights that differ between views (a can's shiny lid) make small
    inconsistent patches that carving deepens into pits; a concavity that changes how
    an object moves is a large share of its volume.
    """
    labels, sizes = voxel_parts(carved)
    small = sizes < min_voxels
    small[0] = False
    return small[labels]


def _blurred(rgb: np.ndarray, sigma_px: float) -> np.ndarray:
    if sigma_px <= 0:
        return rgb
    return gaussian_filter(rgb, sigma=(0, sigma_px, sigma_px, 0)).astype(np.float32)


def _surface(solid: np.ndarray) -> np.ndarray:
    """Voxels of ``solid`` with an empty face neighbour (outside the grid counts as empty)."""
    return solid & ~binary_erosion(solid, _FACES, border_value=0)


def _near(removed: np.ndarray) -> np.ndarray:
    """Voxels within two (26-neighbour steps) of ``removed``: only those can change verdict after a
    round: the newly exposed ones and those that now see more views. Both passes use it; re-testing
    only the face neighbours in the second pass left more wrong voxels (kept outside the true solid
    plus removed inside it, 80 voxels, the benchmark captures: mug 11315 against 10322, bowl 27660
    against 27349)."""
    return binary_dilation(removed, np.ones((3, 3, 3), bool), iterations=2)


def _mostly_bad_neighbourhood(bad: np.ndarray, surface: np.ndarray, fraction: float) -> np.ndarray:
    """Where at least ``fraction`` of the surface voxels in the 3x3x3 neighbourhood are ``bad``."""
    cube = np.ones((3, 3, 3), np.float32)
    bad_count = convolve(bad.astype(np.float32), cube, mode="constant")
    surface_count = convolve(surface.astype(np.float32), cube, mode="constant")
    return bad_count >= fraction * np.maximum(surface_count, 1.0)


class _Verdict(NamedTuple):
    """Per tested voxel: its views' colour ``spread`` and ``hue_spread`` (see :func:`_spread`), how
    many views see it (``seen``), how many of those reach it through the carved space (``through``)
    and from outside (``outside``), the median image ``contrast`` around its projections in
    the views that see it (NaN when none does, or when no contrast map was given), and the spread
    those views would see of a surface deeper along their line of sight (``behind``,
    :func:`_spread_behind`; None when not asked for)."""

    spread: np.ndarray
    hue_spread: np.ndarray
    seen: np.ndarray
    through: np.ndarray
    outside: np.ndarray
    contrast: np.ndarray
    behind: np.ndarray | None = None


def _spread(views: PosedViews, images: np.ndarray, grid: VoxelGrid, idx: np.ndarray, sight: Occluder,
            carved: np.ndarray, config: CarvingConfig, contrast: np.ndarray | None = None,
            behind_m: float = 0.0) -> _Verdict:
    """The verdict on each voxel of ``idx`` (P, 3): the ``spread_quantile`` of its views' colour
    distances from their median, the same for their hues, and the counts of :class:`_Verdict`."""
    points = grid.origin_m + idx * grid.voxel_m
    height, width = views.mask.shape[1:]
    view_of, point_of, pixel_uv, directions = observations(views, grid, points, sight,
                                                           config.visibility_tolerance_voxels)
    # a view reaches the voxel through carved space when the ray is in it just before the voxel
    before = points[point_of] - 1.5 * grid.voxel_m * directions
    cell = np.clip(np.round((before - grid.origin_m) / grid.voxel_m).astype(int), 0, np.asarray(grid.shape) - 1)
    through = carved[tuple(cell.T)]
    through_count = np.bincount(point_of, weights=through, minlength=len(points))
    outside_count = np.bincount(point_of, weights=~through, minlength=len(points))
    colours = _bilinear(images, view_of, pixel_uv)
    # hue: colour over brightness, damped for dark pixels whose ratios are noise
    hues = 3.0 * colours / (colours.sum(axis=1, keepdims=True) + config.hue_floor)
    seen = np.bincount(point_of, minlength=len(points))
    some = seen > 0
    spreads = [np.nan_to_num(_colour_spread(values, view_of, point_of, len(points), views.count, quantile))
               for values, quantile in ((colours, config.spread_quantile), (hues, config.hue_quantile))]
    median_contrast = np.full(len(points), np.nan)
    if contrast is not None and some.any():
        u, v = (np.clip(pixel_uv[:, k].astype(int), 0, n - 1) for k, n in ((0, width), (1, height)))
        per_view = np.full((len(points), views.count), np.nan, dtype=np.float32)
        per_view[point_of, view_of] = contrast[view_of, v, u]
        median_contrast[some] = _row_nanquantile(per_view[some], 0.5)
    behind = None
    if behind_m > 0 and some.any():
        behind = _spread_behind(views, images, points, view_of, point_of, directions, behind_m, config)
    return _Verdict(spreads[0], spreads[1], seen, through_count, outside_count, median_contrast, behind)


def _spread_behind(views: PosedViews, images: np.ndarray, points: np.ndarray, view_of: np.ndarray,
                   point_of: np.ndarray, directions: np.ndarray, behind_m: float, config: CarvingConfig) -> np.ndarray:
    """Per point: the colour spread its views would see were the surface ``behind_m`` farther along their
    mean line of sight (the same views, the same quantile as :func:`_spread`; NaN where fewer than two of
    them see that point inside their image). Where it is no larger than the spread at the point itself,
    the views cannot tell this depth from a deeper one."""
    mean_dir = np.zeros_like(points)
    np.add.at(mean_dir, point_of, directions)
    mean_dir /= np.maximum(np.linalg.norm(mean_dir, axis=1, keepdims=True), 1e-12)
    deeper = points + behind_m * mean_dir
    uv_all, depth_all = project(views.intrinsics, views.c2w_cv, deeper)  # (V, P, 2), (V, P)
    uv = uv_all[view_of, point_of]
    inside = in_image(views, uv, depth_all[view_of, point_of])
    return _colour_spread(_bilinear(images, view_of[inside], uv[inside]), view_of[inside], point_of[inside],
                          len(points), views.count, config.spread_quantile, min_views=2)


def _colour_spread(values: np.ndarray, view_of: np.ndarray, point_of: np.ndarray, points: int, views: int,
                   quantile: float, min_views: int = 1) -> np.ndarray:
    """Per point: the ``quantile`` of its observations' distances from their per-channel median
    (``values`` (N, 3), one row per observation); NaN where fewer than ``min_views`` observe it."""
    per_point = np.full((points, views, 3), np.nan, dtype=np.float32)
    per_point[point_of, view_of] = values
    spread = np.full(points, np.nan)
    some = np.bincount(point_of, minlength=points) >= min_views
    if some.any():
        rows = per_point[some]  # (S, V, 3): the per-channel median over views, by rows of (S * 3, V)
        median = _row_nanquantile(rows.transpose(0, 2, 1).reshape(-1, views), 0.5).reshape(-1, 3)
        spread[some] = _row_nanquantile(np.linalg.norm(rows - median[:, None], axis=2), quantile)
    return spread


def _local_contrast(images: np.ndarray, window_px: float) -> np.ndarray:
    """Per pixel (V, H, W): the RGB standard deviation (norm over channels) over a square window
    ``window_px`` wide: how well a view can tell one depth of a surface from another there."""
    from scipy.ndimage import uniform_filter

    width = max(3, int(round(window_px)) | 1)
    contrast = np.empty(images.shape[:3], np.float32)
    for i, image in enumerate(images):  # a view at a time: whole-stack temporaries were 1 GB at 640x480
        mean = uniform_filter(image, size=(width, width, 1))
        mean_sq = uniform_filter(image * image, size=(width, width, 1))
        contrast[i] = np.sqrt(np.clip(mean_sq - mean * mean, 0.0, None).sum(axis=-1))
    return contrast


def _row_nanquantile(values: np.ndarray, quantile: float) -> np.ndarray:
    """``np.nanquantile(values, quantile, axis=1)`` (linear interpolation) for rows (P, V) with at
    least one number each. numpy's own runs a Python function per row when there are NaNs: 10 s
    of a 21 s mug carving."""
    ordered = np.sort(values, axis=1)  # NaNs last
    count = (~np.isnan(values)).sum(axis=1)
    position = quantile * (count - 1)
    below = np.floor(position).astype(np.int64)
    above = np.minimum(below + 1, count - 1)
    low = np.take_along_axis(ordered, below[:, None], axis=1)[:, 0]
    high = np.take_along_axis(ordered, above[:, None], axis=1)[:, 0]
    return low + (high - low) * (position - below)


def _bilinear(images: np.ndarray, view_of: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Colours (N, 3) of images[view_of] at continuous pixel positions ``uv`` (N, 2) (pixel centres at +0.5)."""
    u, v = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    h, w = images.shape[1:3]
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    fu, fv = np.clip(u - u0, 0, 1)[:, None], np.clip(v - v0, 0, 1)[:, None]
    return ((1 - fu) * (1 - fv) * images[view_of, v0, u0] + fu * (1 - fv) * images[view_of, v0, u0 + 1]
            + (1 - fu) * fv * images[view_of, v0 + 1, u0] + fu * fv * images[view_of, v0 + 1, u0 + 1])
