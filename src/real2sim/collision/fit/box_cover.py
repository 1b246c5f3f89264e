"""Where axis-aligned boxes start: a greedy cover of the solid by maximal inscribed boxes.

k-means clusters of interior samples hug the surface, so boxes started there are tiles of the
shell, and the sides the object rolls on become a lumpy staircase that changes from one height
to the next (docs/design-notes/collision.md#box-cover). Gradient steps do not undo that: a box
that would have to grow through its neighbours gains nothing until it has.

Here the solid is voxelised (a voxel is solid when the sample nearest its centre is inside and
it holds no outside sample; the interior fill points count as inside), and each box in turn is
the maximal box of solid voxels, grown from one of several seeds, that covers the most voxels no
earlier box covers. Growth adds one voxel layer at a time on the side whose layer holds the most
uncovered voxels weighted by their depth in the solid (ties: the most solid ones), until no side
can grow without leaving the solid; box sums are O(1) from 3-D prefix sums, and all seeds grow
at once. On a cylinder this gives nested full-length slabs whose corners lie on the circle, on a
carton one box. The fit then moves the faces out to the surface.

Lengths are in unit-sphere coordinates, like the samples.
"""

from __future__ import annotations

import numpy as np

#: Seeds tried per box: the deepest uncovered solid voxels first, then random uncovered ones.
SEEDS_PER_BOX = 24

# Faces of a box [lo, hi) in voxel indices: (axis, side) with side 0 = lo, 1 = hi.
_FACES = tuple((a, s) for a in range(3) for s in range(2))


def solid_voxels(points: np.ndarray, sdf: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(solid (X, Y, Z) bool, origin (3,), voxel edge): voxels over the interior samples' bounds
    (one spare layer each side) whose centre's nearest sample is inside (sdf < 0) and that hold
    no outside sample.

    The nearest sample, not the samples within the voxel: near-surface samples leave most voxels
    of the deep interior (and, when sparse, some of the shell) without a sample of their own."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    inside = points[sdf < 0]
    lo, hi = inside.min(0), inside.max(0)
    voxel = float((hi - lo).max()) / resolution
    origin = lo - voxel
    shape = np.ceil((hi + voxel - origin) / voxel).astype(int) + 1
    centres = origin + (np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), -1).reshape(-1, 3) + 0.5) * voxel
    _, nearest = cKDTree(points).query(centres, k=1)
    solid = (sdf[nearest] < 0).reshape(shape)
    # Deep in a sparsely sampled interior the nearest sample can be an outside one across the
    # surface: such voxels, enclosed by solid ones, are solid too.
    ijk = np.floor((points[sdf >= 0] - origin) / voxel).astype(int)
    ok = np.all((ijk >= 0) & (ijk < shape), axis=1)
    has_outside = np.zeros(shape, dtype=bool)
    has_outside[tuple(ijk[ok].T)] = True
    # A voxel holding an outside sample straddles the surface (near-surface samples lie within a
    # fraction of a voxel of it): its centre's sign is a coin toss, and one wrong voxel in a layer
    # stops a box growing across it, so the cover keeps to voxels wholly inside; the fit then
    # moves the faces out to the surface.
    return (solid | ndimage.binary_fill_holes(solid)) & ~has_outside, origin, voxel


def _prefix(grid: np.ndarray) -> np.ndarray:
    """Summed-volume table with a zero layer in front: S[i, j, k] = grid[:i, :j, :k].sum()."""
    s = np.zeros(tuple(n + 1 for n in grid.shape), dtype=np.int64)
    s[1:, 1:, 1:] = grid.astype(np.int64).cumsum(0).cumsum(1).cumsum(2)
    return s


def _box_sum(s: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sums over boxes [lo, hi) (K, 3) of the grid behind the table ``s``; empty boxes give 0."""
    hi = np.maximum(hi, lo)
    x0, y0, z0 = lo.T
    x1, y1, z1 = hi.T
    return (s[x1, y1, z1] - s[x0, y1, z1] - s[x1, y0, z1] - s[x1, y1, z0]
            + s[x0, y0, z1] + s[x0, y1, z0] + s[x1, y0, z0] - s[x0, y0, z0])


def _grow(solid_s: np.ndarray, weight_s: np.ndarray, shape: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grow unit boxes at ``seeds`` (K, 3) to maximal solid boxes, each step on the side whose layer
    has the largest weight (``weight_s``: table of uncovered voxels times their depth); returns
    (lo, hi) (K, 3) each."""
    k = len(seeds)
    lo, hi = seeds.copy(), seeds + 1
    active = np.ones(k, dtype=bool)
    rows = np.arange(k)
    axes = np.array([a for a, _ in _FACES])
    low_side = np.array([s == 0 for _, s in _FACES])
    while active.any():
        # The six one-voxel layers just outside each box, all boxes at once: (K, 6, 3).
        slo = np.repeat(lo[:, None, :], 6, 1)
        shi = np.repeat(hi[:, None, :], 6, 1)
        f = np.arange(6)
        edge = np.where(low_side, lo[:, axes], hi[:, axes])  # (K, 6): the face's coordinate
        slo[:, f, axes] = np.where(low_side, edge - 1, edge)
        shi[:, f, axes] = np.where(low_side, edge, edge + 1)
        inside = (slo[:, f, axes] >= 0) & (shi[:, f, axes] <= shape[axes])
        slo, shi = np.clip(slo, 0, shape).reshape(-1, 3), np.clip(shi, 0, shape).reshape(-1, 3)
        volume = np.prod(shi - slo, axis=1).reshape(k, 6)
        filled = _box_sum(solid_s, slo, shi).reshape(k, 6)
        ok = inside & (filled == volume) & active[:, None]
        # Deep uncovered voxels first: the outermost layer of solid voxels is ragged (it follows the
        # surface within a voxel), and a box that took part of it early could then grow no further
        # across it. Among equal weights the larger layer, so the box ends maximal.
        score = np.where(ok, _box_sum(weight_s, slo, shi).reshape(k, 6) * 1e6 + volume, -1.0)
        best = score.argmax(1)
        active &= score[rows, best] >= 0
        grow_lo = active & low_side[best]
        grow_hi = active & ~low_side[best]
        lo[rows[grow_lo], axes[best[grow_lo]]] -= 1
        hi[rows[grow_hi], axes[best[grow_hi]]] += 1
    return lo, hi


def greedy_box_cover(points: np.ndarray, sdf: np.ndarray, count: int, resolution: int = 64,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` axis-aligned boxes inside the solid the samples describe, each the
    maximal box (of the seeds tried) that covers the most voxels earlier boxes left uncovered.

    ``points`` (N, 3) and ``sdf`` (N,) in unit-sphere coordinates, negative inside, with the
    fitter's interior fill points among them (without them, a deep voxel's nearest sample may be
    an outside one across the surface). Returns
    (centres (M, 3), half-extents (M, 3)), M <= ``count``: the cover stops early when every solid
    voxel is covered (a carton is one box). Deterministic for a given ``seed``.
    """
    points = np.asarray(points, dtype=np.float64)
    sdf = np.asarray(sdf, dtype=np.float64).reshape(-1)
    if int((sdf < 0).sum()) == 0 or count < 1:
        return np.zeros((0, 3)), np.zeros((0, 3))
    solid, origin, voxel = solid_voxels(points, sdf, resolution)
    from scipy import ndimage

    depth = ndimage.distance_transform_edt(solid)
    depth_voxels = np.ceil(depth).astype(np.int64)
    shape = np.array(solid.shape)
    solid_s = _prefix(solid)
    free = solid.copy()
    rng = np.random.default_rng(seed)
    boxes = []
    for _ in range(count):
        free_idx = np.flatnonzero(free)
        if len(free_idx) == 0:
            break
        deep = free_idx[np.argsort(-depth.ravel()[free_idx], kind="stable")[: SEEDS_PER_BOX // 2]]
        rand = rng.choice(free_idx, size=min(len(free_idx), SEEDS_PER_BOX - len(deep)), replace=False)
        seeds = np.stack(np.unravel_index(np.concatenate((deep, rand)), solid.shape), 1)
        free_s = _prefix(free)
        lo, hi = _grow(solid_s, _prefix(np.where(free, depth_voxels, 0)), shape, seeds)
        gain = _box_sum(free_s, lo, hi)
        k = int(np.argmax(gain))
        if gain[k] <= 0:
            break
        free[lo[k, 0]:hi[k, 0], lo[k, 1]:hi[k, 1], lo[k, 2]:hi[k, 2]] = False
        boxes.append((lo[k], hi[k]))
    if not boxes:
        return np.zeros((0, 3)), np.zeros((0, 3))
    lo = np.array([b[0] for b in boxes], dtype=np.float64)
    hi = np.array([b[1] for b in boxes], dtype=np.float64)
    return origin + 0.5 * (lo + hi) * voxel, 0.5 * (hi - lo) * voxel
