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
   (:func:`real2sim.multiview.hull.carve`, with a generous outlier allowance)
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
   hidden behind it (from the same warps and comparisons: they are made once): those neighbours do
   not vote, and the table right next to the object, which the first round could not confirm, is
   confirmed;
6. the table plate (:mod:`real2sim.capture.masks.table_plate`): the empty table's image, each point's
   colour from the views that see it past the second round's masks, judges the mask pixels again; the
   pixels whose image it explains join the table verdict for steps 3-4 once more. It takes the table
   seen through a hole (a mug's handle), which the neighbours see hidden behind the object, and some
   of the table beside a silhouette that only a few steep views see past the object. The plate also matches
   the object's print by chance, and a video's frames repeat one match until the hull carves it through: there
   an explained pixel whose image the round's solid explains as well (the neighbours see the same colour where
   its ray meets the solid) stays object (``plate_object_threshold``, which `run` sets for a phone capture);
7. the masks are that solid, ray cast into every view (Embree, through trimesh).

Steps 1-2 are :mod:`real2sim.capture.masks.parallax_table`'s, step 6 :mod:`real2sim.capture.masks.table_plate`'s,
steps 3-5 and 7 this module's.

World frame: the views', table plane z = ``table_z_m``; lengths in the views' units. The
method needs a textured table (or floor) around the object and poses good to about a pixel
(refine them first); on a plain table step 3 finds nothing to carve with and the hull does
not close (one-line error).
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import torch
import trimesh

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.multiview.hull import carve, object_region
from real2sim.capture.masks.parallax_config import ParallaxConfig
from real2sim.multiview.voxel_grid import VoxelGrid, surface_from_grid, voxel_footprint_px, voxel_parts
from real2sim.capture.masks.parallax_table import neighbour_views, neighbour_votes, table_evidence
from real2sim.multiview.views import PosedViews, pixel_rays, project, project_torch


#: Masks are doubtful when they reach the image border in more than this share of the views (the object found
#: is not wholly in view) or cover more than MAX_MEDIAN_COVERAGE of the median image: the capture frames the
#: object with table around it. (why: docs/design-notes/capture.md#parallax-doubts)
MAX_BORDER_SHARE = 0.5
MAX_MEDIAN_COVERAGE = 0.5
#: The hull's voxels span at least this many pixels of a typical view (the masks are its silhouettes, cast at
#: full resolution, so finer voxels only cost time).
MIN_VOXEL_PX = 0.5


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
    votes = neighbour_votes(views, config, (config.match_reach_px, config.base_reach_px), progress)
    for _ in range(2):  # the second round knows, from the first one's object, which table points each view sees
        occluders = None if masks is None else binary_dilation(masks, np.ones((1, 3, 3), bool))
        table, base_table = table_evidence(views, config, votes, occluders, progress)
        solid = _standing_hull(views, table, base_table, config)
        masks = render_silhouettes(solid, views.intrinsics, views.c2w_cv, progress)
    if config.plate_threshold > 0:  # step 6: the table's plate, seen by every view, judges what neighbours could not
        from real2sim.capture.masks.table_plate import explained_by_object, explained_by_plate, table_plate

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
    step 2; lined up across views they tunnel through it (docs/design-notes/capture.md#parallax-plate-islands)."""
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
