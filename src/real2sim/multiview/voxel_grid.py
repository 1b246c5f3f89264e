"""Voxel grids and what is made on them: the grid itself, its surface (marching cubes), its connected
parts, the parts of a mesh worth keeping, a mesh reduced to a face budget, and the empty space a solid
closes off. Shared by the visual hull (:mod:`real2sim.multiview.hull`), photo carving, the parallax
masks and the radiance field. World frame, metres; the table top is z = 0 unless a grid says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.multiview.views import PosedViews


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


def voxel_parts(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(labels, voxels per label) of the connected parts (26-neighbours; 8 in an image) of the bool grid
    ``mask``; label 0 is the outside, its count set to 0."""
    from scipy.ndimage import label

    labels, count = label(mask, np.ones((3,) * mask.ndim, bool))
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    sizes[0] = 0
    return labels, sizes


def largest_parts(mesh: trimesh.Trimesh, min_volume_fraction: float = 0.05) -> trimesh.Trimesh:
    """The connected components holding at least ``min_volume_fraction`` of the largest one's volume (floaters go).

    When any component is open, areas stand in for volumes.
    """
    # one component (the usual case) is found from the face graph alone: splitting copies the mesh (seconds)
    if len(mesh.faces) == 0 or trimesh.graph.connected_component_labels(
            mesh.face_adjacency, node_count=len(mesh.faces)).max() == 0:
        return mesh
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


def closed_off(empty: np.ndarray, gap_voxels: int) -> np.ndarray:
    """The ``empty`` voxels with no way out (through faces) to the grid's sides or top once openings at
    most ``2 * gap_voxels`` wide are shut; the table below is no way out."""
    from scipy.ndimage import binary_dilation, label

    cube = np.ones((3, 3, 3), bool)
    shut = ~binary_dilation(~empty, cube, iterations=gap_voxels) if gap_voxels else empty
    padded = np.pad(shut, 1, constant_values=True)
    padded[:, :, 0] = False
    labels, _ = label(padded)
    border = np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(), labels[:, :, -1].ravel()])
    outside = np.isin(labels, np.unique(border[border > 0]))[1:-1, 1:-1, 1:-1]
    if gap_voxels:
        outside = binary_dilation(outside, cube, iterations=gap_voxels)
    return empty & ~outside
