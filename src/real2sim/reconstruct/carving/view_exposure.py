"""Each view's exposure and white balance, from how the views agree on the object's surface.

Photographs taken with automatic exposure or white balance differ in brightness and tint from
view to view. Photo-consistent carving (:mod:`real2sim.reconstruct.carving.photo`) compares colours
across views, so it reads such differences as a surface that is not there, and carves into a solid
convex object (docs/design-notes/reconstruct.md#exposure).

Cameras change exposure and white balance by gains in linear light, before the sRGB encoding.
So the colours the views see of the visual hull's surface points are decoded to linear light
and each view gets one gain per channel: the median, over the points it sees, of its colour
over the point's reference colour (the mean in log space over the views that see the point,
with the current gains taken out), four times over, each time on the half of the points the
views agree on best. Pixels near black or clipped carry no gain and are left out. The gains are
scaled so that their geometric mean over the views is 1 in each channel: the images keep their
overall level, which the carving's thresholds assume. They are used only where they make the
views agree clearly better (:data:`GAIN_EVIDENCE`); the texture's misregistration on a voxel grid is
what limits them (docs/design-notes/reconstruct.md#exposure).

The field learns its own per-view colour corrections (:mod:`real2sim.reconstruct.field.view_corrections`);
this is for the steps before it that compare raw colours.
"""

from __future__ import annotations

import numpy as np

from real2sim.multiview.srgb import linear_to_srgb, srgb_to_linear

#: Linear-light values below this, or sRGB values above ``CLIPPED``, say nothing about a gain.
DARK_LINEAR = 0.01
CLIPPED = 0.98
#: Gains are taken out only when they bring the surface points' median spread below this share of
#: what it was without them.
GAIN_EVIDENCE = 0.8


def view_gains(colours_srgb: np.ndarray, view_of: np.ndarray, point_of: np.ndarray, views: int, *,
               min_views: int = 4, iterations: int = 4) -> tuple[np.ndarray, dict]:
    """(views, 3) RGB gains in linear light, geometric mean 1 per channel, from observations: the
    sRGB colour (N, 3) that view ``view_of[n]`` sees of surface point ``point_of[n]``; and how much
    they made the views agree. Points seen by fewer than ``min_views`` views say nothing; a view
    that sees none of the rest keeps gain 1.

    Each round fits the gains on the points the views agree on best (the half with the smallest
    spread under the current gains): the hull's surface also spans what is not there (the lid over
    a mug's cavity, whose colour differs from view to view by nature). The gains are all 1 unless
    they lower the median spread of the points below ``GAIN_EVIDENCE`` of what it was: a capture
    without exposure changes keeps its images as they are."""
    colours_srgb = np.asarray(colours_srgb, dtype=np.float64)
    linear = srgb_to_linear(colours_srgb)
    usable = (colours_srgb < CLIPPED).all(axis=1) & (linear > DARK_LINEAR).all(axis=1)
    view_of, point_of, log_colour = view_of[usable], point_of[usable], np.log(linear[usable])
    points = int(point_of.max()) + 1 if len(point_of) else 0
    shared = np.bincount(point_of, minlength=points)[point_of] >= min_views
    view_of, point_of, log_colour = view_of[shared], point_of[shared], log_colour[shared]
    none = np.ones((views, 3))
    if len(view_of) == 0:
        return none, {"applied": False, "reason": "no surface point seen well by enough views"}

    def spread(log_gain: np.ndarray, trusted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per point: the mean absolute deviation (log units, summed over channels) of its views'
        corrected colours from their mean; and the residual per observation."""
        corrected = log_colour - log_gain[view_of]
        weight = trusted[point_of].astype(np.float64)
        count = np.bincount(point_of, weights=weight, minlength=points)
        reference = np.stack([np.bincount(point_of, weights=weight * corrected[:, c], minlength=points)
                              for c in range(3)], axis=1) / np.maximum(count, 1.0)[:, None]
        residual = log_colour - reference[point_of]
        deviation = np.abs(residual - log_gain[view_of]).sum(axis=1)
        per_point = np.bincount(point_of, weights=deviation, minlength=points) / \
            np.maximum(np.bincount(point_of, minlength=points), 1)
        return per_point, residual

    seen = np.bincount(point_of, minlength=points) > 0
    trusted = seen.copy()
    log_gain = np.zeros((views, 3))
    before = float(np.median(spread(log_gain, trusted)[0][seen]))
    for _ in range(iterations):
        _, residual = spread(log_gain, trusted)
        use = trusted[point_of]
        order = np.argsort(view_of[use], kind="stable")
        ratio = residual[use][order]
        bounds = np.searchsorted(view_of[use][order], np.arange(views + 1))
        observed = bounds[1:] > bounds[:-1]
        for v in np.nonzero(observed)[0]:
            log_gain[v] = np.median(ratio[bounds[v]:bounds[v + 1]], axis=0)
        log_gain[observed] -= log_gain[observed].mean(axis=0)
        per_point, _ = spread(log_gain, trusted)
        trusted = seen & (per_point <= np.median(per_point[seen]))
    after = float(np.median(spread(log_gain, seen)[0][seen]))
    info = {"spread_before": round(before, 4), "spread_after": round(after, 4)}
    if after >= GAIN_EVIDENCE * before:
        return none, {**info, "applied": False,
                      "reason": "the views agree as well without gains: no exposure or white-balance change"}
    return np.exp(log_gain), {**info, "applied": True}


def corrected_images(images_srgb: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """(V, H, W, 3) sRGB images with each view's linear-light ``gains`` (V, 3) divided out."""
    out = np.empty(images_srgb.shape, np.float32)
    for i, image in enumerate(images_srgb):  # a view at a time: whole-stack temporaries are large at 640x480
        out[i] = linear_to_srgb(srgb_to_linear(image) / gains[i].astype(np.float32))
    return out


def gains_summary(gains: np.ndarray) -> dict:
    """The gains as a photographer reads them: exposure in stops (green), white balance as the red and
    blue gains over green; the largest and the median deviation over the views."""
    stops = np.log2(gains[:, 1])
    tint = np.abs(np.log(gains[:, [0, 2]] / gains[:, [1]]))
    return {"exposure_stops_max": round(float(np.abs(stops).max()), 3),
            "exposure_stops_median": round(float(np.median(np.abs(stops))), 3),
            "white_balance_max": round(float(np.expm1(tint.max())), 4),
            "white_balance_median": round(float(np.expm1(np.median(tint))), 4)}
