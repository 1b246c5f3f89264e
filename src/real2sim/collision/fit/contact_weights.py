"""Per-sample weights that favour the surfaces an object touches things with (beyond the paper).

A rigid body meets a floor, a ramp or a wall only on its convex hull: the bottom it stands on,
the sides it rolls on and the edges it tips over are all on the hull, and a concave region (a
bottle's waist, a mug's cavity, a dented base) touches nothing flat. So the samples within a band
around the hull's surface get weight ``1 + gain`` in the fit and all others weight 1; the
support plane needs no rule of its own, it is a hull face.

The hull is computed from the samples alone: the convex hull of the interior samples near the
surface (``-band <= sdf <= 0``), which lies inside the object's hull by about the spacing of the
samples there (docs/design-notes/collision.md#contact-hull).
"""

from __future__ import annotations

import numpy as np

# Points x distinct planes per block of the signed-distance pass: bounds its memory (~64 MB).
_CHUNK_ELEMENTS = 8_000_000
# The samples scatter around the surface, so their exact hull has ~10^4 sliver facets; qhull's
# pre-merge of facets whose centrums lie within 0.002 (unit sphere) of their neighbours' planes
# leaves a few hundred, at about the exact hull's accuracy (docs/design-notes/collision.md#contact-hull).
_QHULL_OPTIONS = "Qc C-0.002"
# qhull triangulates a merged face into simplices with the same equation: one plane.
_PLANE_DECIMALS = 5


def hull_planes(points_unit: np.ndarray, sdf: np.ndarray, band: float) -> np.ndarray:
    """Distinct facet planes (F, 4) ``[n, b]`` of the convex hull of the near-surface interior
    samples (``-band <= sdf <= 0``), unit outward normals, ``n . x + b <= 0`` inside.

    Empty (0, 4) when fewer than four such samples span a volume (the weights are then all 1).
    """
    from scipy.spatial import ConvexHull, QhullError

    pts = np.asarray(points_unit, dtype=np.float64)
    d = np.asarray(sdf, dtype=np.float64).reshape(-1)
    near = pts[(d <= 0) & (d >= -band)]
    if len(near) < 4:
        return np.zeros((0, 4))
    try:
        hull = ConvexHull(near, qhull_options=_QHULL_OPTIONS)
    except QhullError:  # flat or degenerate: no volume, no hull to weight
        return np.zeros((0, 4))
    return np.unique(np.round(hull.equations, _PLANE_DECIMALS), axis=0)


def hull_signed_distance(points_unit: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """Signed distance (N,) of points to the convex polytope ``planes`` (F, 4) (negative inside).

    The largest plane value ``max_f n_f . x + b_f``: exact inside the polytope and outside in
    front of a face; beyond an edge or a vertex it underestimates the distance (a lower bound).
    Chunked so that the (points x planes) block stays small; float32.
    """
    # float32: the samples are float32 already, and the band is thousands of ulps wide
    pts = np.asarray(points_unit, dtype=np.float32).reshape(-1, 3)
    out = np.empty(len(pts), dtype=np.float32)
    step = max(1, _CHUNK_ELEMENTS // max(1, len(planes)))
    normals = np.ascontiguousarray(planes[:, :3], dtype=np.float32)
    offsets = planes[:, 3:].astype(np.float32)
    for start in range(0, len(pts), step):
        # (planes x points) and a max down the columns: twice as fast as the row-wise max
        block = normals @ pts[start : start + step].T
        block += offsets
        out[start : start + step] = block.max(axis=0)
    return out


def contact_weights(points_unit, sdf, band: float, gain: float, *, planes: np.ndarray | None = None) -> np.ndarray:
    """Weight (N,) float32 of each sample: ``1 + gain`` within ``band`` of the hull's surface, else 1.

    ``points_unit`` (N, 3) and ``sdf`` (N,) are samples in unit-sphere coordinates; ``band`` is
    a distance in the same units, on both sides of the hull's surface (the outside samples near
    the hull keep the union from bulging past it, the inside ones make it reach it). Beyond
    an edge of the hull the distance is underestimated (:func:`hull_signed_distance`), so the
    band is a little wider there. ``planes`` (from :func:`hull_planes` of these or other
    samples) skips computing the hull from ``points_unit`` and ``sdf`` (``sdf`` is then unused),
    e.g. to weight extra points (the fitter's interior fill) by the hull of the samples.
    """
    if not gain >= 0 or not band > 0:
        raise ValueError(f"gain must be >= 0 and band > 0, got gain={gain}, band={band}")
    pts = np.asarray(points_unit, dtype=np.float64).reshape(-1, 3)
    weights = np.ones(len(pts), dtype=np.float32)
    if gain == 0:
        return weights
    if planes is None:
        planes = hull_planes(pts, sdf, band)
    if len(planes) == 0 or len(pts) == 0:
        return weights
    weights[np.abs(hull_signed_distance(pts, planes)) <= band] += np.float32(gain)
    return weights
