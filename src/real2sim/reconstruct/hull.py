"""Visual hull: the region every mask agrees is object, on a voxel grid, and its surface.

A voxel's *silhouette score* is the mask value (bilinear, so the surface falls
between pixels) at its projection in each view; views it projects outside of, or
lies behind, cast no vote. The score kept is a low order statistic of the votes
rather than their minimum, so that a few bad masks or pose errors
(``outlier_fraction`` of the views that see the voxel) cannot cut the object. The
fraction is of the voxels' own voters, not of all views: counted over all views, a
point only a few cameras see kept the non-voters' "inside" whatever those few said,
and a wide bowl's search box never closed (its corners, seen by three close-up views,
all counted as object). The hull is where the score is >= 0.5.

World frame, metres; the table top is z = 0 and nothing is kept below it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from real2sim.formats.errors import UserInputError
from real2sim.reconstruct.views import PosedViews, common_look_at_point, project_torch


MIN_VOTES = 3


@dataclass(frozen=True)
class VoxelGrid:
    """An axis-aligned grid: voxel (i, j, k) has its centre at ``origin_m + (i, j, k) * voxel_m``."""

    origin_m: np.ndarray
    voxel_m: float
    shape: tuple[int, int, int]

    def centres(self) -> np.ndarray:
        """(nx * ny * nz, 3) voxel centres in C order (x slowest)."""
        axes = [self.origin_m[a] + self.voxel_m * np.arange(n) for a, n in enumerate(self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)

    @property
    def bounds_m(self) -> np.ndarray:
        """(2, 3) lower and upper corners of the voxels' cells."""
        lo = self.origin_m - 0.5 * self.voxel_m
        return np.stack([lo, lo + self.voxel_m * np.asarray(self.shape)])

    @staticmethod
    def covering(lo_m: np.ndarray, hi_m: np.ndarray, longest_side_voxels: int, table_z_m: float | None = 0.0) -> "VoxelGrid":
        """A grid over the box [lo, hi] with ``longest_side_voxels`` along its longest side.

        With ``table_z_m``, the lowest layer of cells starts exactly at the table plane.
        """
        lo, hi = np.asarray(lo_m, dtype=float), np.asarray(hi_m, dtype=float)
        voxel = float((hi - lo).max()) / longest_side_voxels
        if table_z_m is not None:
            lo = lo.copy()
            lo[2] = max(lo[2], table_z_m)
        shape = tuple(int(n) for n in np.maximum(np.ceil((hi - lo) / voxel), 2))
        return VoxelGrid(lo + 0.5 * voxel, voxel, shape)


def voxel_footprint_px(views: PosedViews, grid: VoxelGrid) -> float:
    """How many pixels one voxel of ``grid`` spans in a typical view (at the median camera distance
    from the grid's centre)."""
    centre = grid.origin_m + 0.5 * grid.voxel_m * (np.asarray(grid.shape) - 1)
    distance = float(np.median(np.linalg.norm(views.c2w_cv[:, :3, 3] - centre, axis=1)))
    return grid.voxel_m * views.intrinsics.fl_x / distance


def silhouette_scores(views: PosedViews, points_m: np.ndarray, outlier_fraction: float,
                      chunk: int = 100_000, min_votes: int = MIN_VOTES) -> np.ndarray:
    """(P,) float32 silhouette score of world points: see the module docstring.

    A point fewer than ``min_votes`` cameras see scores 0: nothing constrains it, and
    counting it as inside would let the hull run off where the views are sparse.
    """
    k = views.intrinsics
    masks = torch.from_numpy(views.mask[:, None])  # (V, 1, H, W)
    w2c = torch.from_numpy(np.linalg.inv(views.c2w_cv)).float()
    out = np.empty(len(points_m), dtype=np.float32)
    with torch.no_grad():
        for start in range(0, len(points_m), chunk):
            pts = torch.from_numpy(np.asarray(points_m[start:start + chunk], dtype=np.float32))
            u, v, z = project_torch(k, w2c, pts)
            grid = torch.stack([u * (2.0 / k.width) - 1.0, v * (2.0 / k.height) - 1.0], dim=-1)
            vals = torch.nn.functional.grid_sample(masks, grid[:, None], mode="bilinear", align_corners=False)[:, 0, 0]
            no_vote = (z <= 0) | (grid.abs() > 1).any(dim=-1)
            seen = (~no_vote).sum(dim=0)
            ordered = vals.masked_fill(no_vote, 2.0).sort(dim=0).values  # the votes first, in order
            rank = torch.clamp(torch.floor(outlier_fraction * seen).long(), max=torch.clamp(seen - 1, min=0))
            score = ordered.gather(0, rank[None])[0]
            out[start:start + chunk] = torch.where(seen >= min_votes, score, torch.zeros_like(score)).numpy()
    return out


def object_region(views: PosedViews, *, outlier_fraction: float = 0.03, coarse_voxels: int = 64,
                  table_z_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) world box (metres) holding the visual hull, found on a coarse grid around the cameras' common point.

    The search box grows until the hull no longer touches its sides. UserInputError
    when the masks agree on no region at all.
    """
    centre = common_look_at_point(views)
    radius = 0.5 * float(np.median(np.linalg.norm(views.c2w_cv[:, :3, 3] - centre, axis=1)))
    for _ in range(4):
        grid = VoxelGrid.covering(centre - radius, centre + radius, coarse_voxels, table_z_m)
        inside = silhouette_scores(views, grid.centres(), outlier_fraction).reshape(grid.shape) >= 0.5
        if not inside.any():
            raise UserInputError("the masks agree on no region of space: check the masks and the camera poses")
        idx = np.argwhere(inside)
        lo_i, hi_i = idx.min(axis=0), idx.max(axis=0)
        touches = (lo_i[:2] == 0).any() or (hi_i >= np.asarray(grid.shape) - 1).any()
        lo = grid.origin_m + (lo_i - 1.5) * grid.voxel_m
        hi = grid.origin_m + (hi_i + 1.5) * grid.voxel_m
        if not touches:
            lo[2] = max(lo[2], table_z_m)
            return lo, hi
        radius *= 2.0
    raise UserInputError("the visual hull does not close: the masks leave the object unbounded (too few views "
                         "from different directions?)")


def carve(views: PosedViews, grid: VoxelGrid, outlier_fraction: float = 0.03, block: int = 3) -> np.ndarray:
    """Silhouette scores on ``grid`` (shape ``grid.shape``), float32 in [0, 1].

    Scores are computed exactly only near the hull's surface: first at the centres
    of ``block``^3 blocks; a block whose 26 neighbours all agree with it (all
    inside or all outside) takes its centre's verdict for every voxel in it.
    """
    shape = np.asarray(grid.shape)
    coarse_shape = tuple(int(n) for n in np.ceil(shape / block))
    coarse = VoxelGrid(grid.origin_m + 0.5 * (block - 1) * grid.voxel_m, grid.voxel_m * block, coarse_shape)
    coarse_in = silhouette_scores(views, coarse.centres(), outlier_fraction).reshape(coarse_shape) >= 0.5
    from scipy.ndimage import binary_dilation, binary_erosion

    cube = np.ones((3, 3, 3), bool)
    certain_in = binary_erosion(coarse_in, cube, border_value=0)
    certain_out = ~binary_dilation(coarse_in, cube)
    expand = lambda a: np.repeat(np.repeat(np.repeat(a, block, 0), block, 1), block, 2)[: shape[0], : shape[1], : shape[2]]
    scores = np.where(expand(certain_in), 1.0, 0.0).astype(np.float32)
    band = ~(expand(certain_in) | expand(certain_out))
    scores[band] = silhouette_scores(views, grid.centres().reshape(*grid.shape, 3)[band], outlier_fraction)
    return scores


def surface_from_grid(values: np.ndarray, grid: VoxelGrid, level: float, table_z_m: float = 0.0) -> trimesh.Trimesh:
    """Marching cubes of ``values`` at ``level``, closed by padding below ``level``; vertices in metres.

    The padding closes the surface where it reaches the grid's sides; the bottom cap,
    half a voxel below the lowest layer, is moved up onto the table plane.
    """
    from skimage.measure import marching_cubes

    lo_value = min(float(values.min()), level) - 1.0
    padded = np.pad(values.astype(np.float32), 1, constant_values=lo_value)
    if not (padded.max() > level):
        raise UserInputError("reconstruction is empty: nothing is above the surface level")
    verts, faces, _, _ = marching_cubes(padded, level=level, spacing=(grid.voxel_m,) * 3)
    verts = verts + (grid.origin_m - grid.voxel_m)
    verts[:, 2] = np.maximum(verts[:, 2], table_z_m)
    # skimage orients faces for rising values; our inside is high, so flip to outward normals
    return trimesh.Trimesh(verts, faces[:, ::-1], process=True)


def largest_parts(mesh: trimesh.Trimesh, min_volume_fraction: float = 0.05) -> trimesh.Trimesh:
    """The connected components holding at least ``min_volume_fraction`` of the largest one's volume (floaters go).

    When any component is open, areas stand in for volumes.
    """
    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    if all(p.is_watertight for p in parts):
        size = np.array([abs(p.volume) for p in parts])
    else:  # an open surface (a TSDF mesh) has no volume: compare areas, or a closed speck would win
        size = np.array([p.area for p in parts])
    keep = [p for p, s in zip(parts, size) if s >= min_volume_fraction * size.max()]
    return trimesh.util.concatenate(keep) if len(keep) > 1 else keep[0]


def simplified(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """The mesh reduced to at most ``max_faces`` by quadric edge collapse (Open3D); unchanged when smaller."""
    if len(mesh.faces) <= max_faces:
        return mesh
    import open3d as o3d

    o3d_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, dtype=np.float64)),
                                         o3d.utility.Vector3iVector(np.asarray(mesh.faces, dtype=np.int32)))
    reduced = o3d_mesh.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    return trimesh.Trimesh(np.asarray(reduced.vertices), np.asarray(reduced.triangles), process=True)


def visual_hull_mesh(views: PosedViews, *, longest_side_voxels: int = 192, outlier_fraction: float = 0.03,
                     table_z_m: float = 0.0) -> tuple[trimesh.Trimesh, VoxelGrid, np.ndarray]:
    """The visual hull's surface (metres, world frame), its grid and the scores on it."""
    lo, hi = object_region(views, outlier_fraction=outlier_fraction, table_z_m=table_z_m)
    grid = VoxelGrid.covering(lo, hi, longest_side_voxels, table_z_m)
    scores = carve(views, grid, outlier_fraction)
    mesh = largest_parts(surface_from_grid(scores, grid, 0.5, table_z_m))
    return mesh, grid, scores
