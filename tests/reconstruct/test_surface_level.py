"""Where the surface of a trained field is put: the level chosen by the masks' edges
(``extract.silhouette_surface_level``) against a field whose density is known, and in the stage."""

from __future__ import annotations

import numpy as np
import pytest

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.reconstruct.field.extract import SURFACE_DENSITY_PER_VOXEL, density_mesh, silhouette_surface_level
from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.voxel_grid import VoxelGrid
from real2sim.multiview.views import PosedViews, pixel_rays

RADIUS_M = 0.02
CENTRE_M = np.array([0.0, 0.0, 0.03])
VOXEL_M = 0.002


def _soft_ball(level_at_radius: float, slope_per_m: float) -> VoxelRadianceField:
    """A ball whose density falls linearly with the distance from its centre and equals
    ``level_at_radius`` (per voxel) at ``RADIUS_M``: a surface layer several voxels thick."""
    shape = (30, 30, 30)
    grid = VoxelGrid(CENTRE_M - 0.5 * VOXEL_M * (np.asarray(shape) - 1), VOXEL_M, shape)
    r = np.linalg.norm(grid.centres() - CENTRE_M, axis=1)
    density = np.clip(level_at_radius + slope_per_m * (RADIUS_M - r), 1e-4, 6.0).reshape(shape)
    return VoxelRadianceField(grid, np.ones(shape, bool), feature_channels=4, hidden=8, init_density=density)


def _ball_views(count: int = 24) -> PosedViews:
    """Cameras on two rings looking at the ball; each mask is the ball's exact silhouette at pixel centres."""
    k = CameraIntrinsics(width=160, height=120, fl_x=300.0, fl_y=300.0, cx=80.0, cy=60.0)
    poses, masks = [], []
    for i in range(count):
        azimuth = 2 * np.pi * i / (count // 2)
        elevation = np.deg2rad(20.0 if i < count // 2 else 55.0)
        eye = CENTRE_M + 0.25 * np.array([np.cos(elevation) * np.cos(azimuth),
                                          np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        forward = (CENTRE_M - eye) / np.linalg.norm(CENTRE_M - eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)  # OpenCV: x right, y down
        c2w[:3, 3] = eye
        v, u = np.mgrid[0:k.height, 0:k.width]
        o, d = pixel_rays(k, c2w, u.ravel() + 0.5, v.ravel() + 0.5)
        to_centre = CENTRE_M - o
        miss = np.linalg.norm(to_centre - np.sum(to_centre * d, axis=1)[:, None] * d, axis=1)
        poses.append(c2w)
        masks.append((miss < RADIUS_M).reshape(k.height, k.width).astype(np.float32))
    masks = np.stack(masks)
    return PosedViews(np.zeros((*masks.shape, 3), np.float32), masks, np.stack(poses), k,
                      tuple(f"view_{i}" for i in range(count)))


def _mean_radius_m(mesh) -> float:
    return float(np.mean(np.linalg.norm(mesh.vertices - CENTRE_M, axis=1)))


def test_the_masks_put_the_surface_where_the_silhouettes_are():
    """The density at the silhouettes' radius is 0.2 per voxel: the ln 2 surface lies 0.7 voxel inside
    the ball the masks show; the level the masks choose puts it within a tenth of a voxel."""
    field = _soft_ball(level_at_radius=0.2, slope_per_m=0.35 / 0.001)
    views = _ball_views()
    chosen = silhouette_surface_level(field, views, seed=0)
    assert chosen["edge_pixels"] > 1000
    assert chosen["level_per_voxel"] == pytest.approx(0.2, rel=0.25)
    assert chosen["disagreement"] < chosen["disagreement_ln2"]
    r_ln2 = _mean_radius_m(density_mesh(field, table_z_m=-1.0))
    r_chosen = _mean_radius_m(density_mesh(field, table_z_m=-1.0, level_per_voxel=chosen["level_per_voxel"]))
    assert RADIUS_M - r_ln2 > 0.6 * VOXEL_M  # the ln 2 surface: (0.693 - 0.2) / 0.35 per mm = 1.4 mm inside
    assert abs(r_chosen - RADIUS_M) < 0.1 * VOXEL_M


def test_a_level_outside_the_search_is_not_chosen():
    """Masks of a ball whose silhouette density is far below the searched range: the bottom of the range
    (the middle of the best stretch of levels, which starts at the range's lowest)."""
    field = _soft_ball(level_at_radius=0.001, slope_per_m=0.35 / 0.001)
    chosen = silhouette_surface_level(field, _ball_views(), search=(0.25, 2.0))
    lowest = 0.25 * SURFACE_DENSITY_PER_VOXEL
    assert lowest <= chosen["level_per_voxel"] <= 1.05 * lowest


def test_masks_without_edges_leave_the_level_at_half_light():
    """Empty masks (the object out of view) have no edge to judge by: ln 2 per voxel, no shares."""
    views = _ball_views()
    empty = PosedViews(views.rgb, np.zeros_like(views.mask), views.c2w_cv, views.intrinsics, views.names)
    chosen = silhouette_surface_level(_soft_ball(level_at_radius=0.2, slope_per_m=350.0), empty)
    assert chosen == {"level_per_voxel": SURFACE_DENSITY_PER_VOXEL, "edge_pixels": 0,
                      "disagreement": None, "disagreement_ln2": None}
