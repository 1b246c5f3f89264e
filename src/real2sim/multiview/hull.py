"""Visual hull: the region every mask agrees is object, on a voxel grid, and its surface.

A voxel's *silhouette score* is the mask value (bilinear, so the surface falls
between pixels) at its projection in each view. A view it projects outside of votes 0
when its mask stays clear of that image edge (the view holds the object's whole
outline there: a long lens's narrow view of a ring is bounded this way), and not at all
when the mask reaches that edge (the object is cut by the border: the view cannot tell)
or the point lies behind it. The score kept is a low order statistic of the votes
rather than their minimum, so that a few bad masks or pose errors
(``outlier_fraction`` of the views that see the voxel) cannot cut the object. The
fraction is of the voxels' own voters, not of all views: counted over all views, a
point only a few cameras see would keep the non-voters' "inside" whatever those few said
(docs/design-notes/reconstruct.md#visual-hull). The hull is where the score is >= 0.5.

A point is *constrained* only when at least ``MIN_VOTES`` views see it from directions
at least ``MIN_SPREAD_DEG`` apart (:func:`view_spread_deg`). A few neighbouring
cameras of a ring, or of a long lens, see a thin, long cone together: their masks
cannot say where along it the object is, and counting such points as inside lets the
region run off far past the object (docs/design-notes/reconstruct.md#visual-hull). Points not constrained
score 0, whatever their masks say; the same rule bounds the region the views see
together (:func:`seen_together`), which no result may leave.

No view is trusted alone until its mask has shown it agrees with the others: a point is
carved by one mask only when too few views see it for a second to agree (``MIN_AGREEING``);
otherwise the lowest mask value is skipped, so one wrong mask (a real threshold that ate part
of the object) cannot cut it. That leaves a skin where one view alone bounds the object (a
ring over part of a circle has no opposite views), so :func:`carve` then lets the views whose
masks remove only a sliver of that robust hull (:func:`consistent_views`) carve alone where a
point lies more than ``TRUSTED_MARGIN_PX`` outside their mask.

World frame, metres; the table top is z = 0 and nothing is kept below it.
"""

from __future__ import annotations


import numpy as np
import torch
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.multiview.views import PosedViews, common_look_at_point, project_torch
from real2sim.multiview.voxel_grid import VoxelGrid, largest_parts, surface_from_grid


MIN_VOTES = 3
#: the widest angle between two views that see a point must reach this for the point to count (degrees)
MIN_SPREAD_DEG = 25.0
#: a point is carved only when this many of the views that see it put it outside their masks
#: (when at least 2 * MIN_VOTES views see it; fewer views are all needed)
MIN_AGREEING = 2
#: a view whose mask alone would remove at most this share of the robust hull's skin carves alone
TRUSTED_SKIN_FRACTION = 0.5
#: ... but only where a point lies more than this far outside its mask (pixels): closer in, the
#: silhouettes of many views with poses a fraction of a pixel off disagree, and the strictest of
#: them would erode the object (why: docs/design-notes/reconstruct.md#visual-hull)
TRUSTED_MARGIN_PX = 1.5


def view_spread_deg(directions: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """(P,) how widely the views that see each point surround it, degrees.

    ``directions``: (V, P, 3) unit vectors from the points to the cameras; ``seen``: (V, P) bool.
    The measure is ``2 asin(sqrt(lambda_2))`` of the directions' second moment matrix
    (lambda_2 its middle eigenvalue): two views ``a`` degrees apart give exactly ``a``, views
    spread along an arc of ``a`` degrees somewhat less, and a ring and a hemisphere alike
    count by their widest spread, so a ring level with the object is as good as a dome.
    """
    weight = seen.to(directions.dtype)
    moment = torch.einsum("vp,vpi,vpj->pij", weight, directions, directions)
    return _spread_deg((moment / weight.sum(dim=0).clamp_min(1.0)[:, None, None]).double())


def camera_spread_deg(centres: torch.Tensor, pts: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """(P,) :func:`view_spread_deg` of the directions from points ``pts`` (P, 3) to the cameras at ``centres``
    (V, 3) that see them (``seen``: (V, P) bool), without forming the (V, P, 3) directions: with
    ``s = seen / |c - p|^2``, the second moment is ``sum s c c^T - (sum s c) p^T - p (sum s c)^T + (sum s) p p^T``,
    three matrix products over the views. Coordinates are taken from the points' mean so that the terms stay
    of the size of the result (float32), and the moments are assembled in float64."""
    ref = pts.mean(dim=0)
    c, p = centres - ref, pts - ref
    dist2 = (p * p).sum(dim=1)[None].addmm(c, p.T, alpha=-2.0).add_((c * c).sum(dim=1)[:, None])  # (V, P)
    s_t = (seen.to(dist2.dtype) / dist2.clamp_min(1e-30)).T  # (P, V)
    outer_c = (c[:, :, None] * c[:, None, :]).reshape(-1, 9)
    sum_sc, p64 = (s_t @ c).double(), p.double()
    moment = ((s_t @ outer_c).view(-1, 3, 3).double() - sum_sc[:, :, None] * p64[:, None, :]
              - p64[:, :, None] * sum_sc[:, None, :] + s_t.sum(dim=1).double()[:, None, None] * p64[:, :, None] * p64[:, None, :])
    return _spread_deg(moment / seen.sum(dim=0).clamp_min(1).double()[:, None, None])


def _spread_deg(moment: torch.Tensor) -> torch.Tensor:
    """(P,) float32 ``2 asin(sqrt(lambda_2))`` in degrees of the (P, 3, 3) float64 second moments of unit
    directions (:func:`view_spread_deg`)."""
    middle = _middle_eigenvalue(moment).clamp(0.0, 1.0)
    return torch.rad2deg(2.0 * torch.asin(middle.sqrt())).float()


def _middle_eigenvalue(a: torch.Tensor) -> torch.Tensor:
    """(P,) middle eigenvalue of symmetric (P, 3, 3) matrices, in closed form (the trigonometric
    solution of the characteristic cubic): batched LAPACK calls on 3x3 matrices cost more than the
    whole rest of the silhouette scores."""
    q = torch.diagonal(a, dim1=1, dim2=2).sum(dim=1) / 3.0
    off = a[:, 0, 1] ** 2 + a[:, 0, 2] ** 2 + a[:, 1, 2] ** 2
    centred = a - q[:, None, None] * torch.eye(3, dtype=a.dtype, device=a.device)
    p = torch.sqrt((torch.diagonal(centred, dim1=1, dim2=2) ** 2).sum(dim=1) + 2.0 * off) / np.sqrt(6.0)
    b = centred / p.clamp_min(1e-30)[:, None, None]
    # the 3x3 determinant written out: torch.linalg.det on CUDA loads its solver library on first use
    det = (b[:, 0, 0] * (b[:, 1, 1] * b[:, 2, 2] - b[:, 1, 2] * b[:, 2, 1])
           - b[:, 0, 1] * (b[:, 1, 0] * b[:, 2, 2] - b[:, 1, 2] * b[:, 2, 0])
           + b[:, 0, 2] * (b[:, 1, 0] * b[:, 2, 1] - b[:, 1, 1] * b[:, 2, 0]))
    phi = torch.acos((det / 2.0).clamp(-1.0, 1.0)) / 3.0
    largest = q + 2.0 * p * torch.cos(phi)
    smallest = q + 2.0 * p * torch.cos(phi + 2.0 * np.pi / 3.0)
    return torch.where(p > 1e-15, 3.0 * q - largest - smallest, q)


def border_touched(mask: np.ndarray) -> np.ndarray:
    """(V, 4) bool: whether each view's mask (V, H, W) reaches its image's left, right, top and bottom edge."""
    m = np.asarray(mask) >= 0.5
    return np.stack([m[:, :, 0].any(1), m[:, :, -1].any(1), m[:, 0, :].any(1), m[:, -1, :].any(1)], axis=1)


def _votes(views: PosedViews, w2c: torch.Tensor, pts: torch.Tensor, touched: torch.Tensor | None = None):
    """Per view: where the points project (grid_sample coordinates), whether they are in its image,
    and whether the view votes on them.

    A view whose mask stays clear of an image edge holds the object's whole outline on that side,
    so a point beyond that edge is outside the object: a vote of 0. Beyond an edge the mask reaches
    (the object cut by the border), or behind the camera, the view cannot tell: no vote.
    ``touched``: (V, 4) :func:`border_touched`; None counts only points in the image.
    """
    k = views.intrinsics
    u, v, z = project_torch(k, w2c, pts)
    gx, gy = u.mul_(2.0 / k.width).sub_(1.0), v.mul_(2.0 / k.height).sub_(1.0)
    grid = torch.stack([gx, gy], dim=-1)
    front = z > 0
    left, right, top, bottom = gx < -1, gx > 1, gy < -1, gy > 1
    in_image = front & ~(left | right | top | bottom)
    if touched is None:
        return grid, in_image, in_image
    # (V, P) comparisons against each edge's (V, 1) flag: a (V, P, 4) stack of them took most of the scoring
    unknown = ((left & touched[:, 0:1]) | (right & touched[:, 1:2]) | (top & touched[:, 2:3])
               | (bottom & touched[:, 3:4]))
    return grid, in_image, front & ~unknown


def _constrained(centres: torch.Tensor, pts: torch.Tensor, seen: torch.Tensor, min_votes: int,
                 min_spread_deg: float) -> torch.Tensor:
    """(P,) bool: enough views see the point, from directions far enough apart (module docstring)."""
    ok = seen.sum(dim=0) >= min_votes
    if min_spread_deg > 0 and bool(ok.any()):
        idx = torch.nonzero(ok)[:, 0]
        ok[idx] = camera_spread_deg(centres, pts[idx], seen[:, idx]) >= min_spread_deg
    return ok


def mask_votes(views: PosedViews, points_m: np.ndarray, chunk: int, device: str | torch.device = "cpu"):
    """Per chunk of ``chunk`` world points (metres), a tuple: its first index, the points (tensor), their
    grid_sample coordinates in every view, which views vote on them (V, chunk bool; :func:`_votes`), and
    each view's bilinear mask value there (V, chunk). Callers hold ``torch.no_grad()``; the hull's scores
    and the others' hull of :mod:`real2sim.reconstruct.poses.others_hull` count their votes from it."""
    masks = torch.from_numpy(views.mask[:, None]).to(device)  # (V, 1, H, W)
    touched = torch.from_numpy(border_touched(views.mask)).to(device)
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float().to(device)
    for start in range(0, len(points_m), chunk):
        pts = torch.from_numpy(np.asarray(points_m[start:start + chunk], dtype=np.float32)).to(device)
        grid, _, seen = _votes(views, w2c, pts, touched)
        vals = torch.nn.functional.grid_sample(masks, grid[:, None], mode="bilinear", align_corners=False)[:, 0, 0]
        yield start, pts, grid, seen, vals


def silhouette_scores(views: PosedViews, points_m: np.ndarray, outlier_fraction: float,
                      chunk: int = 100_000, min_votes: int = MIN_VOTES,
                      min_spread_deg: float = MIN_SPREAD_DEG, trusted: np.ndarray | None = None,
                      device: str | torch.device = "cpu") -> np.ndarray:
    """(P,) float32 silhouette score of world points: see the module docstring.

    A point fewer than ``min_votes`` cameras see, or seen only from directions less than
    ``min_spread_deg`` apart, scores 0: nothing constrains it, and counting it as inside
    would let the hull run off where the views are sparse. ``trusted``: (V,) bool, views
    whose masks may carve alone (:func:`consistent_views`); the score is then at most
    their lowest vote. ``device``: where the votes are counted (the result is the same on any).
    """
    centres = torch.from_numpy(views.c2w_cv[:, :3, 3]).float().to(device)
    if trusted is not None:
        trusted_t = torch.from_numpy(np.asarray(trusted, bool)).to(device)
        outside_px = torch.from_numpy(_outside_distance_px(views.mask, trusted))[:, None].to(device)
    out = np.empty(len(points_m), dtype=np.float32)
    with torch.no_grad():
        for start, pts, grid, seen, vals in mask_votes(views, points_m, chunk, device):
            count = seen.sum(dim=0)
            floor = torch.where(count >= 2 * min_votes, MIN_AGREEING - 1, 0)
            rank = torch.maximum(torch.floor(outlier_fraction * count).long(), floor)
            rank = torch.clamp(rank, max=torch.clamp(count - 1, min=0))
            # the lowest rank + 1 votes in order (the unseen after them): a few of the views' votes, where a
            # full sort of all of them took a third of the scoring
            lowest = int(rank.max()) + 1 if len(rank) else 1
            ordered = vals.masked_fill(~seen, 2.0).topk(min(lowest, len(vals)), dim=0, largest=False).values
            score = ordered.gather(0, rank[None])[0]
            if trusted is not None:
                alone = seen & trusted_t[:, None]
                beyond_px = torch.nn.functional.grid_sample(outside_px, grid[:, None], mode="bilinear",
                                                            padding_mode="border", align_corners=False)[:, 0, 0]
                lone = (0.5 + TRUSTED_MARGIN_PX - beyond_px).clamp(0.0, 1.0).masked_fill(~alone, 2.0)
                score = torch.minimum(score, lone.min(dim=0).values)
            # Below 0.5 a point is outside whatever the spread; its score still places the surface
            # between voxels, so it keeps the score (the rule of min_votes alone). The spread is
            # computed only where the masks would keep a point.
            candidate = (score >= 0.5) & (count >= min_votes)
            keep = count >= min_votes
            if bool(candidate.any()):
                keep = keep & (~candidate | _constrained(centres, pts, seen & candidate[None], min_votes, min_spread_deg))
            out[start:start + chunk] = torch.where(keep, score, torch.zeros_like(score)).cpu().numpy()
    return out


def _outside_distance_px(mask: np.ndarray, which: np.ndarray) -> np.ndarray:
    """(V, H, W) float32: each pixel's distance to the nearest object pixel of its view's mask (0 on
    the object), for the views in ``which`` (others all 0)."""
    from scipy.ndimage import distance_transform_edt

    out = np.zeros(mask.shape, np.float32)
    for i in np.nonzero(which)[0]:
        out[i] = distance_transform_edt(mask[i] < 0.5)
    return out


def lone_carving(views: PosedViews, points_m: np.ndarray, chunk: int = 100_000,
                 device: str | torch.device = "cpu") -> np.ndarray:
    """(V,) how many of ``points_m`` (world, metres) each view alone puts outside its mask (a vote below 0.5)."""
    counts = torch.zeros(views.count, dtype=torch.long, device=device)
    with torch.no_grad():
        for _, _, _, seen, vals in mask_votes(views, points_m, chunk, device):
            counts += (seen & (vals < 0.5)).sum(dim=1)
    return counts.cpu().numpy()


def consistent_views(views: PosedViews, grid: VoxelGrid, inside: np.ndarray,
                     device: str | torch.device = "cpu") -> np.ndarray:
    """(V,) bool: views whose masks agree with the hull ``inside`` (bool, ``grid.shape``) found without
    trusting any one view, so that they may carve alone.

    A right mask on a right pose removes, alone, only a sliver of that hull: the skin where its
    neighbours' silhouettes, a few degrees away, are a little wider, and the gaps only it sees
    through. A mask that lost part of the object, or a pose that is off, removes a volume. A view is
    trusted when what it would remove alone is at most ``TRUSTED_SKIN_FRACTION`` of the hull's
    outer layer of voxels (a measure of the hull's size in voxels that does not depend on the grid).
    """
    from scipy.ndimage import binary_erosion

    skin = int((inside & ~binary_erosion(inside, border_value=0)).sum())
    if skin == 0:
        return np.zeros(views.count, bool)
    return lone_carving(views, grid.centres()[inside.reshape(-1)], device=device) <= TRUSTED_SKIN_FRACTION * skin


def seen_together(views: PosedViews, points_m: np.ndarray, *, min_votes: int = MIN_VOTES,
                  min_spread_deg: float = MIN_SPREAD_DEG, chunk: int = 100_000) -> np.ndarray:
    """(P,) bool: which world points lie where the views see together (module docstring), masks aside."""
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float()
    centres = torch.from_numpy(views.c2w_cv[:, :3, 3]).float()
    out = np.empty(len(points_m), dtype=bool)
    with torch.no_grad():
        for start in range(0, len(points_m), chunk):
            pts = torch.from_numpy(np.asarray(points_m[start:start + chunk], dtype=np.float32))
            _, seen, _ = _votes(views, w2c, pts)
            out[start:start + chunk] = _constrained(centres, pts, seen, min_votes, min_spread_deg).numpy()
    return out


def object_region(views: PosedViews, *, outlier_fraction: float = 0.03, coarse_voxels: int = 64,
                  table_z_m: float | None = 0.0, device: str | torch.device = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) world box (metres) holding the visual hull, found on a coarse grid around the cameras' common point;
    nothing below ``table_z_m`` (None: no table, the box is bounded below by the views alone).

    The search box grows until the hull no longer touches its sides. UserInputError
    when the masks agree on no region at all. ``device``: where the silhouettes are scored (the same box
    on any).
    """
    centre = common_look_at_point(views)
    radius = 0.5 * float(np.median(np.linalg.norm(views.c2w_cv[:, :3, 3] - centre, axis=1)))
    for _ in range(4):
        grid = VoxelGrid.covering(centre - radius, centre + radius, coarse_voxels, table_z_m)
        inside = silhouette_scores(views, grid.centres(), outlier_fraction,
                                   device=device).reshape(grid.shape) >= 0.5
        if not inside.any():
            raise UserInputError("the masks agree on no region of space: check the masks and the camera poses")
        idx = np.argwhere(inside)
        lo_i, hi_i = idx.min(axis=0), idx.max(axis=0)
        # on a table the hull may (must) touch the grid's floor; with none, every side counts
        sides = slice(0, 2) if table_z_m is not None else slice(0, 3)
        touches = (lo_i[sides] == 0).any() or (hi_i >= np.asarray(grid.shape) - 1).any()
        lo, hi = _padded_box(grid, inside)
        if not touches:
            if table_z_m is not None:
                lo[2] = max(lo[2], table_z_m)
            return _tightened(views, lo, hi, outlier_fraction, coarse_voxels, table_z_m, device)
        radius *= 2.0
    raise UserInputError("the visual hull does not close: the masks leave the object unbounded (too few views "
                         "from different directions?)")


def _tightened(views: PosedViews, lo: np.ndarray, hi: np.ndarray, outlier_fraction: float, voxels: int,
               table_z_m: float | None, device: str | torch.device = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The box ``[lo, hi]``, which holds the hull with room to spare, shrunk to the hull found on a grid
    of ``voxels`` across it, plus a voxel and a half: the search grid's cells are a camera distance over
    64, centimetres for a long lens, and every later grid spends its voxels across this box."""
    grid = VoxelGrid.covering(lo, hi, voxels, table_z_m)
    inside = silhouette_scores(views, grid.centres(), outlier_fraction, device=device).reshape(grid.shape) >= 0.5
    if not inside.any():
        return lo, hi
    new_lo, new_hi = _padded_box(grid, inside)
    return np.maximum(new_lo, lo), np.minimum(new_hi, hi)


def _padded_box(grid: VoxelGrid, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) metres: the centres of the outermost voxels of ``inside`` (a non-empty bool array of
    ``grid.shape``), a voxel and a half further out."""
    idx = np.argwhere(inside)
    return (grid.origin_m + (idx.min(axis=0) - 1.5) * grid.voxel_m,
            grid.origin_m + (idx.max(axis=0) + 1.5) * grid.voxel_m)


def carve(views: PosedViews, grid: VoxelGrid, outlier_fraction: float = 0.03, block: int = 3,
          trust_consistent: bool = True, device: str | torch.device = "cpu") -> np.ndarray:
    """Silhouette scores on ``grid`` (shape ``grid.shape``), float32 in [0, 1], counted on ``device``.

    Scores are computed exactly only near the hull's surface: first at the centres
    of ``block``^3 blocks; a block whose 26 neighbours all agree with it (all
    inside or all outside) takes its centre's verdict for every voxel in it.
    """
    shape = np.asarray(grid.shape)
    coarse_shape = tuple(int(n) for n in np.ceil(shape / block))
    coarse = VoxelGrid(grid.origin_m + 0.5 * (block - 1) * grid.voxel_m, grid.voxel_m * block, coarse_shape)
    coarse_in = silhouette_scores(views, coarse.centres(), outlier_fraction, device=device).reshape(coarse_shape) >= 0.5
    trusted = consistent_views(views, coarse, coarse_in, device) if trust_consistent and coarse_in.any() else None
    if trusted is not None and not trusted.any():
        trusted = None
    if trusted is not None:
        coarse_in = silhouette_scores(views, coarse.centres(), outlier_fraction,
                                      trusted=trusted, device=device).reshape(coarse_shape) >= 0.5
    from scipy.ndimage import binary_dilation, binary_erosion

    cube = np.ones((3, 3, 3), bool)
    certain_in = binary_erosion(coarse_in, cube, border_value=0)
    certain_out = ~binary_dilation(coarse_in, cube)
    expand = lambda a: np.repeat(np.repeat(np.repeat(a, block, 0), block, 1), block, 2)[: shape[0], : shape[1], : shape[2]]
    scores = np.where(expand(certain_in), 1.0, 0.0).astype(np.float32)
    band = ~(expand(certain_in) | expand(certain_out))
    scores[band] = silhouette_scores(views, grid.centres().reshape(*grid.shape, 3)[band], outlier_fraction,
                                     trusted=trusted, device=device)
    return scores


def visual_hull_mesh(views: PosedViews, *, longest_side_voxels: int = 192, outlier_fraction: float = 0.03,
                     table_z_m: float = 0.0, trust_consistent: bool = True) -> tuple[trimesh.Trimesh, VoxelGrid, np.ndarray]:
    """The visual hull's surface (metres, world frame), its grid and the scores on it
    (``trust_consistent``: see :func:`carve`; off for candidate masks that only bound the object)."""
    lo, hi = object_region(views, outlier_fraction=outlier_fraction, table_z_m=table_z_m)
    grid = VoxelGrid.covering(lo, hi, longest_side_voxels, table_z_m)
    scores = carve(views, grid, outlier_fraction, trust_consistent=trust_consistent)
    mesh = largest_parts(surface_from_grid(scores, grid, 0.5, table_z_m))
    return mesh, grid, scores


