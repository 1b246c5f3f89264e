"""Rays walked through a voxel solid (real2sim.reconstruct.carving.voxel_rays), against geometry worked by hand."""

import numpy as np
import torch

from real2sim.multiview.voxel_grid import VoxelGrid
from real2sim.reconstruct.carving.voxel_rays import flat_samples, segments_clear

VOXEL_M = 0.01


def _cube_grid():
    """A 20-voxel grid of 1 cm voxels (centres at 0.5 cm ... 19.5 cm) holding a solid cube over
    voxels 8..11 on each axis: the cube spans 8 cm to 12 cm."""
    grid = VoxelGrid.covering(np.zeros(3), np.full(3, 0.2), 20, 0.0)
    assert grid.shape == (20, 20, 20) and np.isclose(grid.voxel_m, VOXEL_M)
    solid = np.zeros(grid.shape, bool)
    solid[8:12, 8:12, 8:12] = True
    return grid, solid


def test_segments_meet_the_cube_only_where_they_reach_it():
    grid, solid = _cube_grid()
    x = np.array([1.0, 0.0, 0.0])
    origins = np.array([[-0.5, 0.1, 0.1],    # through the cube's middle, 60 cm long: reaches past it
                        [-0.5, 0.1, 0.1],    # the same line, stopping 2 mm short of its face at 8 cm
                        [-0.5, 0.1, 0.1],    # the same line, stopping 2 mm inside it
                        [-0.5, 0.15, 0.1],   # beside the cube (y = 15 cm): nothing to meet
                        [0.1, 0.1, 0.1]])    # starting inside the cube
    lengths = np.array([0.6, 0.578, 0.582, 0.6, 0.05])
    clear = segments_clear(solid, grid, origins, np.tile(x, (5, 1)), lengths)
    assert clear.tolist() == [False, True, False, True, False]


def test_diagonal_segments_and_empty_input():
    grid, solid = _cube_grid()
    d = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    start = np.array([[0.0, 0.0, 0.0]])
    # the trilinear level-0.5 surface cuts the cube's corner, as marching cubes does: along the diagonal
    # it lies where each axis's weight w has w**3 = 0.5 (w = 0.794), 2.94 mm past the corner on each
    # axis, 5.09 mm along the diagonal
    to_corner = np.linalg.norm(np.full(3, 0.08))
    assert not segments_clear(solid, grid, start, d[None], np.array([to_corner + 0.0055]))[0]
    assert segments_clear(solid, grid, start, d[None], np.array([to_corner + 0.0045]))[0]
    assert segments_clear(solid, grid, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)).shape == (0,)
    assert segments_clear(np.zeros_like(solid), grid, start, d[None], np.array([1.0]))[0]


def test_flat_samples_hold_every_ray_s_samples_in_chunks():
    start = torch.tensor([0.0, 5.0, 10.0, 20.0], dtype=torch.float64)
    count = torch.tensor([3, 0, 2, 4])
    seen = {}
    for rays, ray_of, t in flat_samples(start, count, 0.5, samples_per_chunk=4):
        assert len(t) <= 4 or len(rays) == 1  # whole rays: more only when one ray alone has more
        for r, value in zip(rays[ray_of].tolist(), t.tolist()):
            seen.setdefault(r, []).append(value)
    assert seen == {0: [0.0, 0.5, 1.0], 2: [10.0, 10.5], 3: [20.0, 20.5, 21.0, 21.5]}
