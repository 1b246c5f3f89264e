"""The field's unseen inside: voids that open to the outside only through a pinhole are filled when the
mesh is made (``extract.unseen_voids``), while a cup's cavity and a wide dent stay open."""

from __future__ import annotations

import numpy as np

from real2sim.reconstruct.field.extract import density_mesh, unseen_voids
from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.voxel_grid import VoxelGrid

SHAPE = (40, 40, 40)


def _block() -> np.ndarray:
    """A solid block standing on the table (the grid's lowest layer), air around it and above."""
    solid = np.zeros(SHAPE, bool)
    solid[5:35, 5:35, 0:30] = True
    return solid


def _cave(opening_voxels: int) -> tuple[np.ndarray, np.ndarray]:
    """The block with a cave inside (16 x 16 x 14 voxels, 13 % of it) reached from its +x side
    through a square tunnel ``opening_voxels`` wide; the solid and the cave with its tunnel."""
    solid = _block()
    cave = np.zeros(SHAPE, bool)
    cave[12:28, 12:28, 8:22] = True
    half = opening_voxels // 2
    cave[28:35, 20 - half:20 - half + opening_voxels, 15 - half:15 - half + opening_voxels] = True
    return solid & ~cave, cave


def test_a_cave_behind_a_pinhole_is_filled():
    solid, cave = _cave(opening_voxels=1)
    voids = unseen_voids(solid, gap_voxels=1)
    inner = np.zeros(SHAPE, bool)
    inner[12:28, 12:28, 8:22] = True
    assert voids[inner].all()  # the whole cave
    assert not voids[~cave].any()  # and nothing outside it
    # a two-voxel opening is shut as well (openings at most 2 * gap_voxels wide)
    assert unseen_voids(_cave(opening_voxels=2)[0], gap_voxels=1)[inner].all()


def test_a_wide_opening_a_cup_and_a_small_crevice_stay_open():
    wide, _ = _cave(opening_voxels=4)
    assert not unseen_voids(wide, gap_voxels=1).any()  # a view can look into it
    cup = _block()
    cup[12:28, 12:28, 5:30] = False  # its cavity opens at the top
    assert not unseen_voids(cup, gap_voxels=1).any()
    crevice = _block()
    crevice[34, 20, 10:14] = False  # 4 voxels, 0.015 % of the block: left as the field has it
    crevice[33, 20, 11:13] = False
    assert not unseen_voids(crevice, gap_voxels=1).any()
    assert unseen_voids(crevice, gap_voxels=1, min_fraction=0.0)[33, 20, 11:13].all()


def test_the_mesh_has_no_walls_inside_and_the_report_says_what_was_filled():
    """A field whose density is the block with a cave behind a pinhole: its mesh encloses the whole block,
    and the report gives the voxels and the volume filled; with the fill off (0) the cave stays."""
    solid, cave = _cave(opening_voxels=1)
    voxel_m = 0.002
    grid = VoxelGrid(np.zeros(3), voxel_m, SHAPE)
    field = VoxelRadianceField(grid, np.ones(SHAPE, bool), feature_channels=4, hidden=8,
                               init_density=np.where(solid, 8.0, 1e-4))
    report: dict = {}
    mesh = density_mesh(field, table_z_m=0.0, report=report)
    block_m3 = (30 * voxel_m) ** 2 * 30 * voxel_m
    assert mesh.is_watertight
    assert abs(mesh.volume - block_m3) < 0.06 * block_m3
    assert report["unseen_voids_filled_voxels"] >= 16 * 16 * 14
    assert report["unseen_voids_filled_ml"] > 0.9 * 16 * 16 * 14 * voxel_m ** 3 * 1e6
    hollow = density_mesh(field, table_z_m=0.0, void_gap_voxels=0)
    assert hollow.is_watertight and mesh.volume - hollow.volume > 0.7 * cave.sum() * voxel_m ** 3
