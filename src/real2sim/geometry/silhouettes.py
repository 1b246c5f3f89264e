"""Checks that object masks can be silhouettes at all, without ground truth.

A silhouette of an object the cameras look at leaves some of the image to the table and
the room around it. A mask that covers (nearly) the whole image says nothing about the
object's shape: a visual hull or a field trained on it fills the whole working volume
(why: docs/design-notes/asset.md#full-masks). Shared by the mask stage (which
writes or accepts masks) and reconstruction (which reads them).
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from real2sim.plumbing.errors import UserInputError

#: Share of an image's pixels above which a mask is "full": no silhouette leaves so little background.
FULL_MASK_FRACTION = 0.95


def check_not_full(fractions: Sequence[float], names: Sequence[str], what: str, stacklevel: int = 3) -> None:
    """``fractions``: each mask's share of object pixels (0-1), in the order of ``names`` (the frames).

    UserInputError (one line) when every mask covers more than :data:`FULL_MASK_FRACTION` of its
    image; a RuntimeWarning naming how many and the first when only some do. ``what``: how the
    message names the masks (e.g. "the masks of DATASET")."""
    fractions = np.asarray(fractions, dtype=float)
    full = np.nonzero(fractions > FULL_MASK_FRACTION)[0]
    if len(full) == 0:
        return
    share = f"over {100 * FULL_MASK_FRACTION:.0f} % of the image"
    if len(full) == len(fractions):
        raise UserInputError(f"{what}: every mask covers {share} (least {100 * fractions.min():.1f} %): "
                             "masks must be object silhouettes with background around them")
    first = int(full[0])
    warnings.warn(f"{what}: {len(full)} of {len(fractions)} masks cover {share} (first: {names[first]}, "
                  f"{100 * fractions[first]:.1f} %); no silhouette leaves so little "
                  "background: check these masks", RuntimeWarning, stacklevel=stacklevel)


#: fixed-point bits of the triangles' corners given to OpenCV: 1/16 px
_SUBPIXEL_BITS = 4


def filled_triangles(height_px: int, width_px: int, corners_px: np.ndarray, closed: bool = False) -> np.ndarray:
    """(H, W) uint8 mask, 1 where the union of the triangles ``corners_px`` ((T, 3, 2) image coordinates,
    pixel (u, v) spanning [u, u + 1) x [v, v + 1)) covers a pixel's centre: a mesh's silhouette from its
    projected faces. Each triangle is drawn alone: OpenCV fills the polygons of one call by the even-odd
    rule, so overlapping faces (a surface's front and back) would cancel into holes.

    ``closed``: the triangles are the faces of a closed, consistently oriented surface, all in front of the
    camera. Every pixel of its silhouette then sees the surface entered and left as often, so the faces of
    either winding in the image cover the silhouette alone: only the fewer of the two are drawn."""
    import cv2

    drawn = np.zeros((height_px, width_px), np.uint8)
    if len(corners_px) == 0:
        return drawn
    corners = np.asarray(corners_px, dtype=np.float64) - 0.5
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    # a triangle off the picture draws nothing, and fixed-point coordinates must fit in int32
    keep = (hi[:, 0] >= -1) & (hi[:, 1] >= -1) & (lo[:, 0] <= width_px) & (lo[:, 1] <= height_px) & \
        (np.abs(corners) < 8 * max(width_px, height_px)).all(axis=(1, 2))
    if closed:
        edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        winding = np.sign(edge1[:, 0] * edge2[:, 1] - edge1[:, 1] * edge2[:, 0])
        fewer = 1.0 if (winding > 0).sum() <= (winding < 0).sum() else -1.0
        keep &= winding == fewer
    for triangle in np.round(corners[keep] * (1 << _SUBPIXEL_BITS)).astype(np.int32):
        cv2.fillConvexPoly(drawn, triangle, 1, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    return drawn


#: how far (pixels per 160 px of the image's longer side) colour may move a mask's edge
EDGE_BAND_PX_PER_160 = 1.0


def edge_band_px(width_px: int, height_px: int) -> int:
    """The band around a mask's edge (pixels) within which :func:`colour_refined_mask` may move it:
    4 px at 640x480. Real recipes (a threshold and a closing, a network's mask) miss the edge by a
    few pixels at that size, and more at a phone's resolution."""
    return max(2, int(round(EDGE_BAND_PX_PER_160 * max(width_px, height_px) / 160)))


def colour_refined_mask(rgb: np.ndarray, mask: np.ndarray, band_px: int) -> np.ndarray:
    """``mask`` (H, W, values in [0, 1]) with its edge moved, within ``band_px`` pixels of where it
    was, to where the colours of ``rgb`` (H, W, 3, values in [0, 1]) change from object to background.

    A mask made by a threshold keeps the blur and shadow around an object as a halo; one made by a
    network stops short of thin rims. Far inside the mask is object, far outside is background:
    those pixels give each side its colour model, and OpenCV's GrabCut (colour mixtures with an
    edge-aware smoothness term) decides the band in between. Pixels it does not flip keep their
    value, so a soft (anti-aliased or resized) edge stays soft where it was right. A mask with no
    inside or no outside left beyond the band is returned as it was.
    """
    import cv2

    binary = np.asarray(mask) >= 0.5
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    sure_in = cv2.erode(binary.astype(np.uint8), disk, borderType=cv2.BORDER_REPLICATE) > 0
    sure_out = cv2.dilate(binary.astype(np.uint8), disk, borderType=cv2.BORDER_REPLICATE) == 0
    if not sure_in.any() or not sure_out.any():
        return np.asarray(mask)
    # the background's colours near the object are the ones that matter: a window around the band
    rows, cols = np.nonzero(~sure_in & ~sure_out)
    margin = 4 * band_px
    window = (slice(max(rows.min() - margin, 0), rows.max() + margin + 1),
              slice(max(cols.min() - margin, 0), cols.max() + margin + 1))
    labels = np.where(sure_in, cv2.GC_FGD, np.where(sure_out, cv2.GC_BGD,
                      np.where(binary, cv2.GC_PR_FGD, cv2.GC_PR_BGD))).astype(np.uint8)[window]
    if not (labels == cv2.GC_FGD).any() or not (labels == cv2.GC_BGD).any():
        return np.asarray(mask)
    bgr = np.ascontiguousarray((np.clip(rgb[window], 0.0, 1.0)[..., ::-1] * 255.0 + 0.5).astype(np.uint8))
    background_model, object_model = np.zeros((1, 65)), np.zeros((1, 65))
    try:
        cv2.grabCut(bgr, labels, None, background_model, object_model, 3, cv2.GC_INIT_WITH_MASK)
    except cv2.error:  # a colour mixture it cannot fit (e.g. too few distinct colours on a side)
        return np.asarray(mask)
    inside = binary.copy()
    inside[window] = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    out = np.asarray(mask, dtype=np.float32).copy()
    out[inside & ~binary] = 1.0
    out[~inside & binary] = 0.0
    return out
