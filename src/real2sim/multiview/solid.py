"""The object's solid from trusted depth, and each view's mask as that solid's outline: masks from geometry.

The solid lives on a voxel grid in the *table frame* of a :class:`~real2sim.multiview.support.SupportScene`
(the support plane z = 0, z towards the cameras, the object's footprint centre on the z axis; world units)
over the object's points' box. A voxel is free space when some view's trusted depth, at the voxel's
projection (the deepest within a pixel of it), lies beyond the voxel by more than two pixel footprints and
half a voxel: that view sees past it (the table behind the object carves around it, so a textureless side
with no depth of its own still gets its outline). The solid is the part of what is left that holds the
object's points. A view's mask is the solid's surface drawn into it (every triangle filled, so the part of
the object a close view sees is the part its mask holds and the border cuts it where it cuts the view),
then snapped to the image's colour edges (:func:`real2sim.geometry.silhouettes.colour_refined_mask`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.geometry.silhouettes import colour_refined_mask, edge_band_px, filled_triangles
from real2sim.multiview.fusion import DensePoints, back_projected
from real2sim.multiview.stereo import DepthMaps
from real2sim.multiview.support import SupportScene
from real2sim.multiview.views import project_torch
from real2sim.multiview.voxel_grid import VoxelGrid, surface_from_grid, voxel_parts


@dataclass(frozen=True)
class SolidConfig:
    """How :func:`object_solid` carves the object's solid."""

    voxels: int = 64
    """Voxels along the longest side of the object's box (>= 8)."""
    margin_voxels: int = 3
    """The box reaches this many voxels beyond the object's points on every side but the table (>= 1)."""
    see_through_footprints: float = 2.0
    """A view sees past a voxel when its depth there is beyond it by this many pixel footprints (> 0), plus
    half a voxel."""
    above_top_reach_voxels: int = 2
    """Above the object's top (:attr:`SupportScene.height`, a high percentile of its points' heights) the solid
    keeps only the voxels within this many voxels of an object point (>= 0): nothing carves the space over a
    textureless lid or a mug's opening, where the grid's margin otherwise stands as a cap, while a thin top
    with few points (a nozzle) keeps its points' neighbourhood
    (docs/design-notes/capture.md#solid-above-the-top)."""


@dataclass(frozen=True)
class ObjectSolid:
    """The object's solid: ``occupied`` (bool, ``grid.shape``) on ``grid`` (the table frame, world units);
    ``world_from_table``: (4, 4) rigid map of the table frame into the world."""

    grid: VoxelGrid
    occupied: np.ndarray
    world_from_table: np.ndarray


def table_frame(scene: SupportScene) -> np.ndarray:
    """(4, 4) world_from_table: the support plane z = 0, z along its normal, the origin the object's footprint
    centre (module docstring)."""
    n = scene.normal
    x = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = np.cross(x, n)
    x /= np.linalg.norm(x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, np.cross(n, x), n], axis=1)
    out[:3, 3] = scene.centre
    return out


def object_solid(maps: DepthMaps, trusted: np.ndarray, scene: SupportScene, dense: DensePoints,
                 config: SolidConfig = SolidConfig(), device: str | torch.device = "cpu") -> ObjectSolid:
    """The object's solid (module docstring). ``trusted``: (V, h, w) bool, the depths to carve with
    (:func:`real2sim.multiview.fusion.consistent_depth` at its threshold); a depth whose point lies on the
    support plane (within its band) carves too, trusted or not: a wrong depth seldom lands on the plane, and
    the table is what a view sees around the object."""
    on_plane = np.abs(scene.heights(back_projected(maps).reshape(-1, 3))).reshape(maps.depth.shape) <= scene.band
    trusted = trusted | (on_plane & (maps.depth > 0))
    world_from_table = table_frame(scene)
    table_from_world = np.linalg.inv(world_from_table)
    pts = dense.points[scene.object_index] @ table_from_world[:3, :3].T + table_from_world[:3, 3]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    hi[2] = max(hi[2], scene.height)
    voxel = float((hi - lo).max()) / config.voxels
    lo, hi = lo - config.margin_voxels * voxel, hi + config.margin_voxels * voxel
    lo[2] = 0.0
    grid = VoxelGrid.covering(lo, hi, int(round(float((hi - lo).max()) / voxel)), table_z_m=0.0)
    centres = grid.centres() @ world_from_table[:3, :3].T + world_from_table[:3, 3]
    free = _seen_through(maps, trusted, centres, grid.voxel_m, config, device).reshape(grid.shape)
    labels, _ = voxel_parts(~free)
    cells = np.floor((pts - (grid.origin_m - 0.5 * grid.voxel_m)) / grid.voxel_m).astype(int)
    inside = np.all((cells >= 0) & (cells < np.asarray(grid.shape)), axis=1)
    held = np.bincount(labels[tuple(cells[inside].T)], minlength=labels.max() + 1)
    held[0] = 0
    # the parts holding at least a tenth of the points the best-held part holds
    occupied = np.isin(labels, np.nonzero(held >= 0.1 * max(held.max(), 1))[0]) & (labels > 0)
    return ObjectSolid(grid, occupied & ~above_the_points(grid, pts[inside], cells[inside], scene.height,
                                                           config.above_top_reach_voxels), world_from_table)


def above_the_points(grid: VoxelGrid, pts: np.ndarray, cells: np.ndarray, top: float, reach: int) -> np.ndarray:
    """(``grid.shape``) bool: voxels wholly above ``top`` (table frame) farther than ``reach`` voxels from every
    object point above it (``pts`` (P, 3) table frame, in their grid ``cells`` (P, 3))."""
    from scipy.ndimage import binary_dilation

    z = grid.origin_m[2] + np.arange(grid.shape[2]) * grid.voxel_m
    above = np.broadcast_to(z - 0.5 * grid.voxel_m > top, grid.shape)
    near = np.zeros(grid.shape, bool)
    near[tuple(cells[pts[:, 2] > top].T)] = True
    if reach > 0 and near.any():
        near = binary_dilation(near, np.ones((3, 3, 3), bool), iterations=reach)
    return above & ~near


def _seen_through(maps: DepthMaps, trusted: np.ndarray, centres: np.ndarray, voxel: float, config: SolidConfig,
                  device: str | torch.device) -> np.ndarray:
    """(P,) bool: whether some view's trusted depth lies beyond each of ``centres`` (P, 3, world)."""
    k = maps.intrinsics
    h, w = maps.depth.shape[1:]
    # the deepest trusted depth within a pixel: the table seen between sparse trusted pixels still carves
    depth = torch.from_numpy(np.where(trusted, maps.depth, 0.0).astype(np.float32)).to(device)
    depth = torch.nn.functional.max_pool2d(depth[:, None], 3, stride=1, padding=1)[:, 0]
    w2c = torch.from_numpy(np.linalg.inv(maps.c2w_cv)).float().to(device)
    free = torch.zeros(len(centres), dtype=torch.bool, device=device)
    pts = torch.from_numpy(centres.astype(np.float32)).to(device)
    with torch.no_grad():
        for i in range(len(depth)):
            u, v, z = project_torch(k, w2c[i:i + 1], pts)
            col, row = torch.floor(u[0]).long(), torch.floor(v[0]).long()
            inside = (z[0] > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
            seen = depth[i, row.clamp(0, h - 1), col.clamp(0, w - 1)]
            margin = config.see_through_footprints * z[0] / k.fl_x + 0.5 * voxel
            free |= inside & (seen > 0) & (seen > z[0] + margin)
    return free.cpu().numpy()


def solid_masks(solid: ObjectSolid, k: CameraIntrinsics, c2w_cv: np.ndarray, rgb: np.ndarray | None = None,
                device: str | torch.device = "cpu") -> np.ndarray:
    """(V, H, W) float32 masks (1 = object) of cameras ``c2w_cv`` (V, 4, 4) of size ``k``: the solid's outline
    (module docstring), snapped to the colour edges of ``rgb`` (V, H, W, 3, 0-1) when given."""
    mesh = surface_from_grid(solid.occupied.astype(np.float32), solid.grid, 0.5, 0.0)
    verts = np.asarray(mesh.vertices) @ solid.world_from_table[:3, :3].T + solid.world_from_table[:3, 3]
    w2c = torch.from_numpy(np.linalg.inv(c2w_cv)).float().to(device)
    u, v, z = (t.cpu().numpy() for t in project_torch(k, w2c, torch.from_numpy(verts.astype(np.float32)).to(device)))
    faces = np.asarray(mesh.faces)
    masks = np.zeros((len(c2w_cv), k.height, k.width), np.float32)
    band = edge_band_px(k.width, k.height)
    for i in range(len(c2w_cv)):
        front = (z[i][faces] > 0).all(axis=1)
        drawn = filled_triangles(k.height, k.width, np.stack([u[i][faces[front]], v[i][faces[front]]], axis=-1),
                                 closed=bool(front.all()))  # marching cubes on a padded grid: a closed surface
        masks[i] = drawn
        if rgb is not None and drawn.any():
            masks[i] = colour_refined_mask(rgb[i], masks[i], band)
    return masks
