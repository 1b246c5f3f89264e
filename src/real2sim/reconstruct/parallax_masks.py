"""Object masks from the capture itself: what moves against the table between views (no weights, no empty scene).

A pixel that sees the table looks the same from a neighbouring camera once that camera's
image is warped through the table plane (a homography); a pixel that sees something above
the table does not, by the parallax of its height. Per view:

1. each of ``neighbours`` views (8 to 35 degrees away, seen from the cameras' common point)
   is warped onto it through the plane z = ``table_z_m``, with a per-channel gain for
   cameras that change exposure between shots;
2. a neighbour *agrees* at a pixel when the pixel's colour lies within ``threshold`` of the
   range its warped image spans ``match_reach_px`` around (Birchfield and Tomasi: a sharp edge
   printed on the table, resampled a fraction of a pixel off or blurred differently by another
   view's focus, is no evidence). A pixel is
   *table* when ``agreement`` of the neighbours that see its table point agree and the image
   has texture around it; *not table* when they do not and it has texture; each plain patch
   (a white table, a grey wall, the plain side of a can) takes the verdict of the textured
   pixels around it (:func:`_plain_patches_decided`). Each neighbour sees the object's own
   surface at a different place, so a patterned object does not agree with all of them.
   Parallax moves a point along the line towards the neighbour's epipole, so a neighbour
   whose parallax runs along an edge cannot tell the edge's height (the aperture problem):
   it votes only where a share (``min_parallax_share``) of the local gradient lies across its
   parallax (:func:`_parallax_across_edges`), and a textured pixel that fewer than two
   neighbours can judge is a *barrier*: it neither votes nor joins a plain patch. Texture is
   measured per colour channel. Table specks smaller than ``min_table_speck_share`` of the image
   (chance matches on a patterned object) are dropped;
3. everything not table is a candidate, and the candidates' visual hull
   (:func:`real2sim.reconstruct.hull.carve`, with a generous outlier allowance)
   is the object: a voxel survives only if no more than a few views see table through it;
4. the object stands on the table, and within a few millimetres of the plane the parallax is
   below a pixel, so the bottom of the object can look like table, the more so the wider the
   reach of step 2. So the table is judged twice, with ``match_reach_px`` (a black-and-white
   board's edges, blurred unlike in the neighbours, are then no evidence: the object keeps
   less halo) and with the stricter ``base_reach_px``, whose hull, up to the height the views'
   parallax cannot tell from the table (``base_parallax_px``, :func:`low_parallax_height_m`),
   also lets more views call a voxel table (``base_outlier_fraction``); under each column of
   the first hull, the second hull's voxels are added (its halo lies outside those columns,
   and under a mug's handle it has nothing above that height). Then each column whose lowest
   voxel lies within ``bottom_band`` of the table is filled down to it (a handle, higher up,
   is not extended);
5. steps 2-4 again, now that the first object tells which table points each neighbour has
   hidden behind it: those neighbours do not vote, and the table right next to the object,
   which the first round could not confirm, is confirmed;
6. the table plate (:mod:`real2sim.reconstruct.table_plate`): the empty table's image, each point's
   colour from the views that see it past the second round's masks, judges the mask pixels again; the
   pixels whose image it explains join the table verdict for steps 3-4 once more. It takes the table
   seen through a hole (a mug's handle), which the neighbours see hidden behind the object, and some
   of the table beside a silhouette that only a few steep views see past the object. The plate also matches
   the object's print by chance, and a video's frames repeat one match until the hull carves it through: there
   an explained pixel whose image the round's solid explains as well (the neighbours see the same colour where
   its ray meets the solid) stays object (``plate_object_threshold``, which `run` sets for a phone capture);
7. the masks are that solid, ray cast into every view (Embree, through trimesh).

Steps 1-2 are :mod:`real2sim.reconstruct.parallax_table`'s, step 6 :mod:`real2sim.reconstruct.table_plate`'s,
steps 3-5 and 7 this module's.

World frame: the views', table plane z = ``table_z_m``; lengths in the views' units. The
method needs a textured table (or floor) around the object and poses good to about a pixel
(refine them first); on a plain table step 3 finds nothing to carve with and the hull does
not close (one-line error).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.formats.errors import UserInputError
from real2sim.formats.progress import ProgressFn, null_progress
from real2sim.reconstruct.hull import carve, object_region
from real2sim.reconstruct.voxel_grid import VoxelGrid, surface_from_grid, voxel_footprint_px, voxel_parts
from real2sim.reconstruct.parallax_table import neighbour_views, table_evidence
from real2sim.reconstruct.views import PosedViews, pixel_rays, project, project_torch


#: Masks are doubtful when they reach the image border in more than this share of the views (the object found
#: is not wholly in view: measured 16 of 16 views on a 16-view 96x72 can capture whose masks had IoU 0.47 against
#: the truth, 0 of 60 on a 60-view 160x120 one at IoU 0.95) or cover more than MAX_MEDIAN_COVERAGE of the
#: median image: the capture frames the object with table around it.
MAX_BORDER_SHARE = 0.5
MAX_MEDIAN_COVERAGE = 0.5
#: ``ParallaxConfig.plate_object_threshold`` of a phone capture: `run` of photos or a clip turns the object's second
#: opinion on at this level, and for photos the plate round's stricter outlier share
#: (``PHONE_PHOTOS_PLATE_OUTLIER_FRACTION``); the measurements are in the config's docstring
PHONE_PLATE_OBJECT_THRESHOLD = 0.08
PHONE_PHOTOS_PLATE_OUTLIER_FRACTION = 0.04
#: The hull's voxels span at least this many pixels of a typical view (the masks are its silhouettes, cast at
#: full resolution, so finer voxels only cost time).
MIN_VOXEL_PX = 0.5


@dataclass(frozen=True)
class ParallaxConfig:
    """``neighbours``: views warped onto each view; chosen among those whose direction from the
    cameras' common point differs by ``min_angle_deg`` to ``max_angle_deg`` (more angle, more
    parallax, more of the table hidden differently). ``threshold``: largest channel difference
    (0-255) of a table pixel to its empty table. ``min_texture``: local standard deviation
    (0-255, grey, ``texture_px`` radius) below which a pixel is undecided. ``outlier_fraction``:
    share of the views seeing a voxel that may call it table and not carve it. ``hull_voxels``:
    the hull grid's longest side. ``max_image_px``: images are reduced to this longer side first (the
    masks come back at full size). ``bottom_band``: fraction of the hull's height above the table
    filled down to it (step 4). ``match_reach_px``: how far (pixels) around a warped pixel its colour range
    reaches (step 2); ``base_reach_px``: the same for the object's base (step 4), at most ``match_reach_px``.
    On a simulated phone capture of the mug (60 views at 640x480, the board under it; masks against the true
    ones) a reach of 0.5 px for both gave masks 7.0 % larger than the truth (0.5 % missed), 1 px for both
    2.9 % larger but 3.5 % missed (the base), 1 px with 0.5 px for the base 5.3 % and 0.8 %.

    ``outlier_fraction`` 0.05: a voxel goes when more than one view in twenty sees table through it. Under a
    mug's handle and through its ring only a few oblique views see the table, so at 0.1 (the value before) the
    hull kept that space: on the phone capture of the mug (60 photos at 640x480, its true poses) the masks
    covered the ring's hole and a band down to the table, 5.3 % larger than the truth and 0.9 % missed. The
    foot, whose parallax is under a few pixels, is what the lower fraction takes: up to
    :func:`low_parallax_height_m` (``base_parallax_px``, 8: 13 mm on that capture) the base's hull keeps
    ``base_outlier_fraction`` (0.1); with 0.05 there as well the 160x120 can of the tests lost its foot (37
    of 60 views' masks reached within 2 px of the truth's lowest row, against 57). Mug masks now 2.3 % larger,
    3.0 % missed (IoU 0.941 -> 0.948), and the field reconstructed from them (same poses) 1.92 mm Chamfer
    instead of 2.80 (1.65 from the true masks). The bottle's phone capture: 5.0 -> 3.0 % larger, 0.1 -> 0.9 %
    missed, IoU 0.952 -> 0.962 (worst view 0.935 -> 0.949). At 0.03 the views that wrongly see table on the
    object carve it (14 % of the mug missed).

    ``min_parallax_share`` (0.25, i.e. the parallax within 60 degrees of the gradient; 0 turns the test
    off): a neighbour votes on a pixel only where at least this share of the local gradient energy lies along
    its parallax. From a video (one orbit, the camera's height changing slowly) every neighbour of a view
    moves sideways, along the horizontal edges of the mug's plain dark-blue foot band; those edges then
    matched the table, and the band, joined through its blurred lower edge to the board's plain black
    squares, became table in most views: the masks missed 10.0 % of the mug (its lowest 18 mm, 5-8 mm deep;
    median IoU 0.891, the mug from a 20 s video at 640x480, 80 frames, against its true silhouettes). With the
    test and texture taken per channel: 3.9 % missed, 1.0 % extra, IoU 0.949, and the run's reconstruction
    2.23 -> 1.32 mm Chamfer. The mug's 60 photos: IoU 0.947 -> 0.959, 2.9 -> 1.6 % missed, 2.5 -> 2.9 %
    extra.

    ``min_table_speck_share`` (0.0005 of the image, 154 px at 640x480; 0 keeps them): parts of a view's
    table verdict smaller than this are dropped (step 2). A neighbour's warp matches a patterned object by
    chance in specks; since the body's hull carves what one view in twenty calls table, the specks of the
    bottle from a 20 s video lined up into a tunnel through its printed middle (masks with holes of up to
    2600 px in 40 of 80 views, 3.7 % of the bottle missed, a hollow reconstruction 3.36 mm from the truth,
    `phone_run_bottle_aperture.md`). Without the specks (against true silhouettes, by script): bottle
    video IoU 0.958 -> 0.964, missed 3.7 -> 0.6 %, extra 2.1 -> 3.2 %; mug video 0.949 -> 0.960, 3.9 ->
    1.5 %, 1.0 -> 2.6 %; mug photos 0.958 -> 0.952, 1.6 -> 0.9 %, 2.9 -> 4.6 % (more of the handle's ring
    covered: the table through it is seen in small parts).

    ``plate_threshold`` (0.06, RGB in [0, 1]; 0 leaves step 6 out), ``plate_window_px`` (2) and
    ``plate_min_texture`` (0.02): step 6's test (:func:`real2sim.reconstruct.table_plate.explained_by_plate`).
    On the phone capture of the mug (60 photos at 640x480, capture seed 2, its SfM poses) the masks of steps
    1-5 covered 4.98 % more than the truth, 2.70 % in the handle's hole and 2.29 % beside the silhouettes
    (0.71 % missed), and the reconstruction from them was 1.67 mm from the true mug; from the same masks with
    the truth's in the hole alone 1.00 mm, beside the silhouettes alone 1.25 mm (by script, the same poses),
    the true masks 0.61 mm (`bench_phone.py --true-masks`). With step 6: 3.24 % more (1.59 in the hole, 1.65
    beside), 1.57 % missed, and 1.30 mm by script (through `run`: 1.67 -> 1.37 mm; seed 1 2.10 -> 1.95, seed 0
    1.51-1.73 -> 1.35). Without the texture floor (0) 2.57 % more but 2.13 % missed (the mug's black dots over
    the board's black squares explained), 1.27 mm; at 0.01 the same as 0.02 within 0.15 %.

    ``plate_pixel_threshold`` (0.04; 0 turns it off): step 6 with sliding windows (any window holding the pixel,
    and the pixel's own difference below this; :mod:`real2sim.reconstruct.table_plate`). Measured on kept phone
    runs masked again with the same poses (`bench_phone.py --remask`, `phone_remask_sliding_*.md`), the mug's
    four 60-photo runs (capture seeds 0, 1, 2 and a second run of seed 1) and the bottle's: off (the default
    before) 1.25 / 1.55 / 1.42 / 1.73 mm and 0.81 mm; at 0.06 0.98 / 1.70 / 1.29 / 1.32 and 0.93 (the bottle's
    masks missed 0.3 -> 0.72 %: it traded the bottle for the mug); at 0.04 1.02 / 1.53 / 1.24 / 1.35 and 0.78,
    better on every run (the mug's mean 1.49 -> 1.29 mm; its masks' excess 2.8-3.2 -> 2.3-2.7 %, what they
    miss 1.6 -> 2.2-2.5 %; the bottle's 3.77 -> 3.44 % and 0.31 -> 0.43 %); at 0.03 the second seed-1 run
    1.56 and the bottle 0.77. The mug from a 20 s video through `run` with it: 1.11 mm, as without it
    (`phone_run_video_sliding004.md`). The bottle from the same kind of video is where step 6 fails: its run with
    these gave 2.28 mm, and its kept dataset masked again 0.79 mm without the plate and 1.67 with the centred
    windows (the default before; `phone_remask_bottle_video_noplate.md`, `_centred.md`): the plate explains
    the bottle's printed label in patches that line up across the frames of one orbit into hollows (masks
    with holes in 71 of 80 views). The target is missed on it either way (1.5 mm); the photos, where the
    default run gains, are the main path.

    ``plate_min_island_share`` (0: off): step 6's explained pixels that form an island of their own (a part
    of the view's table verdict holding none of steps 2-5's table) smaller than this share of the image are
    dropped (:func:`_plate_joined`). At 0.0005 (step 2's speck size) the bottle's video went 2.28 -> 1.45 mm
    (at 0.002 the same: what is left is attached to the table's verdict) and its photos 0.78 -> 0.79
    (`phone_remask_islands.md`), but the mug's two seed-1 runs 1.53 -> 1.80 and 1.35 -> 1.48 (the table
    through its handle is such an island in many views): off; for a video the object's second opinion below does that job.

    ``plate_object_threshold`` (0: off; `run` of phone photos or a video sets :data:`PHONE_PLATE_OBJECT_THRESHOLD`, 0.08, RGB in
    [0, 1]): an explained pixel stays object when the round's solid explains its image as well: the neighbours
    that see, unhidden, the point where its ray meets the solid see the same colour there (median over them,
    averaged over the window; :func:`real2sim.reconstruct.table_plate.explained_by_object`). Kept runs masked
    again on their own poses (`bench_phone.py --remask`, `phone_remask_object_*.md`) and runs with it on: the
    bottle's video 2.52 -> 1.07 mm, 1.17 in a run (its masks missed 1.81 -> 0.67 %: the hollows are gone;
    without the plate 0.79), the mug's video 1.11 -> 1.10 (a run), the bottle's photos 0.78-0.81 -> 0.80 (a
    run); but the mug's photos, capture seeds 0, 1, 2: 1.26 -> 1.16, 1.71 -> 2.06 (1.82 at 0.05), 1.27 ->
    1.43 mm. The plate's chance matches on the mug's body had also carved some of its handle's hole (more
    views calling those voxels table), so with them taken back the masks cover more of the hole and the band
    beside the mug again (seed 1: hole 0.97 -> 1.16 %, beside 1.57 -> 1.77 %, missed 2.22 -> 1.29 %). Of the
    explained pixels it takes back 59-87 % of those on the object and 13-16 % of those on the table. Hence on
    for a video, whose frames, a few degrees apart along one path, repeat one chance match until the
    hull carves it through; for photos with ``plate_outlier_fraction`` below. The window's largest score instead of its
    mean (fewer table pixels taken back): the bottle's video 1.63 mm, the mug's seed 1 2.05. The hull carved
    both ways and the second one's voxels restored only within 6 voxels behind the taken-back pixels'
    surface (their deeper votes kept for the handle's hole): 1.66 and 1.73 (`phone_remask_object_shell.md`).

    ``plate_outlier_fraction`` (None: ``outlier_fraction``; `run` of phone photos sets 0.04 with the second
    opinion): the share of the views that may call a voxel table in step 6's hull. With the object's chance
    matches taken back, fewer views may carve: the handle's hole and the band beside the mug go. The mug's
    photos, capture seeds 0, 1, 2, masked again: 1.26 / 1.71 / 1.27 -> **0.93 / 1.25 / 1.16 mm** (seed 1's
    masks: extra 2.54 -> 2.24 %, missed 2.22 -> 1.62 %), the bottle's photos 0.80 -> 0.71
    (`phone_remask_object_of004_*.md`); but the bottle's video 1.07 -> 2.11 (its repeated matches are not
    all taken back, and fewer views then carve them), so a clip keeps 0.05. On the 40-view 320x240 mug of
    the tests it misses more of the mug (12.1 -> 15.8 %): not the default for robot captures."""

    neighbours: int = 8
    min_angle_deg: float = 8.0
    max_angle_deg: float = 35.0
    threshold: float = 14.0
    agreement: float = 0.6
    min_texture: float = 4.0
    texture_px: int = 2
    outlier_fraction: float = 0.05
    base_outlier_fraction: float = 0.1
    base_parallax_px: float = 8.0
    hull_voxels: int = 160
    max_image_px: int = 640
    bottom_band: float = 0.08
    table_z_m: float = 0.0
    match_reach_px: float = 1.0
    base_reach_px: float = 0.5
    min_parallax_share: float = 0.25
    min_table_speck_share: float = 0.0005
    plate_threshold: float = 0.06
    plate_window_px: int = 2
    plate_min_texture: float = 0.02
    plate_pixel_threshold: float = 0.04
    plate_min_island_share: float = 0.0
    plate_object_threshold: float = 0.0
    plate_outlier_fraction: float | None = None

    def validate(self) -> None:
        if self.neighbours < 2:
            raise UserInputError("parallax masks need at least 2 neighbouring views per view")
        if not 0 <= self.min_angle_deg < self.max_angle_deg <= 90:
            raise UserInputError("parallax masks: need 0 <= min_angle_deg < max_angle_deg <= 90")
        if not 0 <= self.base_reach_px <= self.match_reach_px <= 1:
            raise UserInputError("parallax masks: need 0 <= base_reach_px <= match_reach_px <= 1 (pixels)")
        if not 0 <= self.outlier_fraction <= self.base_outlier_fraction < 1 or self.base_parallax_px < 0:
            raise UserInputError("parallax masks: need 0 <= outlier_fraction <= base_outlier_fraction < 1 and "
                                 "base_parallax_px >= 0")
        if min(self.plate_threshold, self.plate_window_px, self.plate_min_texture, self.plate_pixel_threshold,
               self.plate_object_threshold) < 0:
            raise UserInputError("parallax masks: need plate_threshold, plate_window_px, plate_min_texture, "
                                 "plate_pixel_threshold and plate_object_threshold >= 0")
        if self.plate_outlier_fraction is not None and not 0 <= self.plate_outlier_fraction < 1:
            raise UserInputError("parallax masks: need 0 <= plate_outlier_fraction < 1 (a share of the views)")
        if not 0 <= self.min_parallax_share <= 1 or not 0 <= self.min_table_speck_share < 1 \
                or not 0 <= self.plate_min_island_share < 1:
            raise UserInputError("parallax masks: need 0 <= min_parallax_share <= 1, 0 <= min_table_speck_share < 1 "
                                 "and 0 <= plate_min_island_share < 1 (shares)")




def _filled_to_table(scores: np.ndarray, band: float) -> np.ndarray:
    """The hull's scores (a grid whose lowest layer stands on the table) with each column whose lowest
    inside voxel lies within ``band`` (fraction of the hull's height) of the table raised to 1 down to the
    table (step 4)."""
    inside = scores >= 0.5
    if not inside.any():
        return scores
    top = int(np.nonzero(inside.any(axis=(0, 1)))[0].max())
    band_voxels = max(2, int(np.ceil(band * (top + 1))))
    lowest = _lowest_inside(inside)
    fill = (((lowest < scores.shape[2]) & (lowest <= band_voxels))[..., None]
            & (np.arange(scores.shape[2])[None, None] < lowest[..., None]))
    out = scores.copy()
    out[fill] = 1.0
    return out


def parallax_masks(views: PosedViews, config: ParallaxConfig = ParallaxConfig(),
                   progress: ProgressFn = null_progress) -> trimesh.Trimesh:
    """The object standing on the table, as a closed mesh (metres, the views' world frame), found from the
    images and poses of ``views`` alone (their masks are not read). Its silhouettes
    (:func:`render_silhouettes`) are the masks, at any image size. A RuntimeWarning says why when they
    cannot be the object's silhouettes (:func:`mask_doubts`)."""
    config.validate()
    from scipy.ndimage import binary_dilation

    masks = None
    for _ in range(2):  # the second round knows, from the first one's object, which table points each view sees
        occluders = None if masks is None else binary_dilation(masks, np.ones((1, 3, 3), bool))
        table, base_table = table_evidence(views, config, (config.match_reach_px, config.base_reach_px),
                                           occluders, progress)
        solid = _standing_hull(views, table, base_table, config)
        masks = render_silhouettes(solid, views.intrinsics, views.c2w_cv, progress)
    if config.plate_threshold > 0:  # step 6: the table's plate, seen by every view, judges what neighbours could not
        from real2sim.reconstruct.table_plate import explained_by_object, explained_by_plate, table_plate

        progress("parallax masks: table plate", 0, 0)
        plate = table_plate(views, masks, config.table_z_m)
        explained = explained_by_plate(views, masks, plate, threshold=config.plate_threshold,
                                       window_px=config.plate_window_px, min_texture=config.plate_min_texture,
                                       pixel_threshold=config.plate_pixel_threshold or None)
        if config.plate_object_threshold > 0:  # what the object's own surface explains as well stays object
            explained &= ~explained_by_object(views, explained, solid, neighbour_views(views, config), plate.view_gain,
                                              threshold=config.plate_object_threshold, window_px=config.plate_window_px)
        share = config.plate_min_island_share
        plate_config = config if config.plate_outlier_fraction is None else \
            replace(config, outlier_fraction=config.plate_outlier_fraction)
        solid = _standing_hull(views, _plate_joined(table, explained, share),
                               _plate_joined(base_table, explained, share), plate_config)
        masks = render_silhouettes(solid, views.intrinsics, views.c2w_cv, progress)
    doubt = mask_doubts(masks)
    if doubt is not None:  # an object wholly in view is the method's premise: say when the result breaks it
        warnings.warn(f"parallax masks cannot be trusted: {doubt}. The method "
                      "needs a textured table around an object wholly in view, poses accurate to a pixel "
                      "(refine-poses) and many views (60 at 160x120 work); check the masks or use another --method",
                      RuntimeWarning, stacklevel=2)
    return solid


def _plate_joined(table: np.ndarray, explained: np.ndarray, min_share: float) -> np.ndarray:
    """The table verdict (N, H, W) with the plate's ``explained`` pixels joined, less each view's islands of
    explained pixels alone (parts of the union holding no table of step 2) smaller than ``min_share`` of its
    image (step 6). The plate explains a patterned object by chance in specks, as a neighbour's warp does in
    step 2; lined up across views they tunnel through it (the bottle from a video, the plate's sliding
    windows on: masks with holes in 71 of 80 views, a hollow reconstruction 2.28 mm from the truth)."""
    out = table | explained
    if min_share <= 0:
        return out
    for i, view in enumerate(out):
        labels, sizes = voxel_parts(view)
        anchored = np.zeros(len(sizes), bool)
        anchored[np.unique(labels[table[i]])] = True
        small = (sizes < min_share * view.size) & ~anchored
        small[0] = False
        out[i] &= ~small[labels]
    return out


def mask_doubts(masks: np.ndarray) -> str | None:
    """Why the masks (N, H, W) bool of one object cannot be its silhouettes, measured without ground truth, or
    None: they reach the image border in more than :data:`MAX_BORDER_SHARE` of the views, or cover more than
    :data:`MAX_MEDIAN_COVERAGE` of the median image."""
    border = masks[:, 0].any(axis=1) | masks[:, -1].any(axis=1) | masks[:, :, 0].any(axis=1) | masks[:, :, -1].any(axis=1)
    coverage = float(np.median(masks.mean(axis=(1, 2))))
    reasons = []
    if border.mean() > MAX_BORDER_SHARE:
        reasons.append(f"they reach the image border in {int(border.sum())} of {len(masks)} views")
    if coverage > MAX_MEDIAN_COVERAGE:
        reasons.append(f"they cover {100 * coverage:.0f} % of the median image")
    if not reasons:
        return None
    return " and ".join(reasons) + f" (median coverage {100 * coverage:.0f} %)" * (coverage <= MAX_MEDIAN_COVERAGE)


def _standing_hull(views: PosedViews, table: np.ndarray, base_table: np.ndarray,
                   config: ParallaxConfig) -> trimesh.Trimesh:
    """The visual hull of what is not ``table``, with the hull of what is not ``base_table`` (the stricter
    verdict) under its columns and its columns near the table filled down to it (steps 3-4)."""
    def candidates(table_px: np.ndarray) -> PosedViews:
        return PosedViews(views.rgb, (~table_px).astype(np.float32), views.c2w_cv, views.intrinsics, views.names)

    try:
        # "not table" is a region the object lies within, not its silhouette: no view may carve alone. The
        # stricter verdict's region is the larger one: the grid covers it
        base_views = candidates(base_table)
        lo, hi = object_region(base_views, outlier_fraction=config.base_outlier_fraction, table_z_m=config.table_z_m)
        grid = _hull_grid(views, lo, hi, config)
        scores = base_scores = carve(base_views, grid, config.outlier_fraction, trust_consistent=False)
        lenient_foot = config.base_outlier_fraction != config.outlier_fraction
        if lenient_foot:
            # near the table, where the views' parallax cannot tell the foot from the table, more views may
            # call a voxel table and not carve it
            low = np.arange(grid.shape[2]) <= np.ceil(low_parallax_height_m(views, config, 0.5 * (lo + hi))
                                                      / grid.voxel_m)
            lenient = carve(base_views, grid, config.base_outlier_fraction, trust_consistent=False)
            base_scores = np.where(low[None, None], lenient, scores)
        if not np.array_equal(table, base_table):
            scores = _base_added(carve(candidates(table), grid, config.outlier_fraction, trust_consistent=False),
                                 base_scores)
        elif lenient_foot:  # one verdict: the body's hull is the strict base's
            scores = _base_added(scores, base_scores)
        filled = _without_specks(_filled_to_table(scores, config.bottom_band))
        return surface_from_grid(filled, grid, 0.5, config.table_z_m)
    except UserInputError as exc:
        raise UserInputError(f"parallax masks found no object standing on the table ({exc}); the method needs a "
                             "textured table around the object and poses accurate to a pixel") from None


def _hull_grid(views: PosedViews, lo: np.ndarray, hi: np.ndarray, config: ParallaxConfig) -> VoxelGrid:
    """The hull's grid over (lo, hi) (metres): ``config.hull_voxels`` along its longest side, fewer where a
    voxel would span less than :data:`MIN_VOXEL_PX` of a typical view (a small image gains nothing from them,
    and the carving's time grows with their square)."""
    grid = VoxelGrid.covering(lo, hi, config.hull_voxels, config.table_z_m)
    footprint_px = voxel_footprint_px(views, grid)
    if footprint_px >= MIN_VOXEL_PX:
        return grid
    voxels = max(32, int(np.ceil(config.hull_voxels * footprint_px / MIN_VOXEL_PX)))
    return VoxelGrid.covering(lo, hi, voxels, config.table_z_m)


def _without_specks(scores: np.ndarray, min_fraction: float = 0.05) -> np.ndarray:
    """``scores`` with the inside voxels (>= 0.5) of each connected part (26-neighbours) smaller than
    ``min_fraction`` of the largest part set to 0: the specks go on the grid, before the surface is made,
    where finding them is cheap (on the surface, splitting the mesh took seconds)."""
    labels, size = voxel_parts(scores >= 0.5)
    if len(size) <= 2:  # one part or none
        return scores
    small = size < min_fraction * size.max()
    small[0] = False
    return np.where(small[labels], 0.0, scores).astype(scores.dtype)


def _base_added(scores: np.ndarray, base_scores: np.ndarray) -> np.ndarray:
    """``scores`` (a grid whose last axis is up) with ``base_scores`` taken wherever they are inside, below the
    lowest inside voxel of each column that has one (step 4)."""
    lowest = _lowest_inside(scores >= 0.5)
    below = (lowest < scores.shape[2])[..., None] & (np.arange(scores.shape[2])[None, None] < lowest[..., None])
    return np.where(below & (base_scores >= 0.5), base_scores, scores)


def low_parallax_height_m(views: PosedViews, config: ParallaxConfig, centre_m: np.ndarray) -> float:
    """Height above the table (metres) up to which a point at ``centre_m``'s place moves less than
    ``config.base_parallax_px`` against the table between a view and its neighbours (median over the pairs):
    the height within which the views may take an object's foot for table. Linear in the height for the
    small heights it is used for; measured with a point 1 cm up."""
    lifted = np.array([centre_m[0], centre_m[1], config.table_z_m + 0.01])
    origins = views.c2w_cv[:, :3, 3]
    rays = lifted - origins
    level = np.abs(rays[:, 2]) < 1e-9  # a camera at the point's height sees no table behind it
    # the table point each view sees behind the lifted point
    behind = origins + rays * ((config.table_z_m - origins[:, 2]) / np.where(level, 1.0, rays[:, 2]))[:, None]
    uv, _ = project(views.intrinsics, views.c2w_cv, np.vstack([lifted[None], behind]))  # (views, 1 + views, 2)
    neighbours = neighbour_views(views, config)  # (views, k)
    seen_from = np.arange(views.count)[:, None]
    rates = np.linalg.norm(uv[neighbours, 0] - uv[neighbours, 1 + seen_from], axis=-1)[~level] / 0.01
    rate = float(np.median(rates)) if rates.size else 0.0
    return config.base_parallax_px / rate if rate > 0 else float("inf")


def _lowest_inside(inside: np.ndarray) -> np.ndarray:
    """(X, Y) int: each column's lowest inside voxel of ``inside`` (X, Y, Z) bool (z up); Z where it has none."""
    return np.where(inside.any(axis=2), np.argmax(inside, axis=2), inside.shape[2])


def render_silhouettes(mesh: trimesh.Trimesh, intrinsics: CameraIntrinsics, c2w_cv: np.ndarray,
                       progress: ProgressFn = null_progress) -> np.ndarray:
    """(N, H, W) bool: the pixels of cameras ``c2w_cv`` (N, 4, 4) whose ray through the pixel centre meets
    ``mesh`` (metres, world frame)."""
    k = intrinsics
    v_px, u_px = np.mgrid[0:k.height, 0:k.width]
    lo, hi = mesh.bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w2c = torch.from_numpy(np.linalg.inv(c2w_cv)).float()
    u, v, depth = project_torch(k, w2c, torch.from_numpy(corners.astype(np.float32)))
    out = np.zeros((len(c2w_cv), k.height, k.width), dtype=bool)
    for i in range(len(c2w_cv)):
        if bool((depth[i] > 0).all()):  # only the pixels inside the projected box are cast (a margin for distortion)
            box = ((u_px >= float(u[i].min()) - 2) & (u_px <= float(u[i].max()) + 2)
                   & (v_px >= float(v[i].min()) - 2) & (v_px <= float(v[i].max()) + 2))
        else:  # the camera is inside the box's extent in depth: cast them all
            box = np.ones_like(u_px, dtype=bool)
        if box.any():
            origin, direction = pixel_rays(k, c2w_cv[i], u_px[box] + 0.5, v_px[box] + 0.5)
            out[i][box] = mesh.ray.intersects_any(origin, direction)
        progress("parallax masks: silhouettes", i + 1, len(c2w_cv))
    return out
