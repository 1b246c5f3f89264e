"""Voxel-particle baseline: counts, placement, fidelity against resolution, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from real2sim.formats.collision import read_collision_json, write_collision_json
from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.inside import inside_mask
from real2sim.collision.particles import COVERING, particle_spheres, particles_for_count, voxel_centres_inside


def _sampled_iou(mesh: trimesh.Trimesh, geometry, n: int = 60_000, seed: int = 0) -> float:
    """IoU of the mesh's solid and the union of spheres, by uniform samples in the padded bounding box."""
    lo, hi = mesh.bounds
    pad = 0.1 * (hi - lo).max()
    pts = (lo - pad) + (hi - lo + 2 * pad) * np.random.default_rng(seed).random((n, 3))
    in_mesh = inside_mask(mesh, pts)
    centres = np.array([s.position_m for s in geometry.shapes])
    radius = geometry.shapes[0].size_m[0]
    dist, _ = cKDTree(centres).query(pts)
    in_spheres = dist <= radius
    return float((in_mesh & in_spheres).sum() / (in_mesh | in_spheres).sum())


def test_count_scales_with_inverse_voxel_volume(can_mesh):
    coarse = particle_spheres(can_mesh, 0.012)
    fine = particle_spheres(can_mesh, 0.006)
    ratio = len(fine.shapes) / len(coarse.shapes)
    assert 6.0 < ratio < 10.0  # 8 in the limit; boundary voxels make it noisy at coarse sizes
    volume = can_mesh.volume
    assert len(fine.shapes) * 0.006**3 == pytest.approx(volume, rel=0.15)


def test_particles_are_spheres_inside_with_half_voxel_radius(bottle_mesh):
    voxel = 0.01
    geometry = particle_spheres(bottle_mesh, voxel)
    assert geometry.spec == f"particles:{len(geometry.shapes)}"
    assert geometry.name == f"particles_{len(geometry.shapes)}"
    assert all(s.kind == "sphere" and s.size_m == (voxel / 2,) for s in geometry.shapes)
    centres = np.array([s.position_m for s in geometry.shapes])
    assert inside_mask(bottle_mesh, centres).all()
    # Centres sit on one grid of pitch ``voxel``.
    offsets = (centres - centres[0]) / voxel
    np.testing.assert_allclose(offsets, np.round(offsets), atol=1e-9)
    # Every grid voxel whose centre is inside got a particle: none missing next to kept ones.
    assert len(voxel_centres_inside(bottle_mesh, voxel)) == len(geometry.shapes)


def test_fidelity_grows_with_resolution(bottle_mesh):
    ious = [_sampled_iou(bottle_mesh, particle_spheres(bottle_mesh, v)) for v in (0.02, 0.01, 0.005)]
    assert ious[0] < ious[1] < ious[2]
    # Touching spheres fill at most pi/6 of the voxels they sit in.
    assert ious[2] < np.pi / 6 + 0.02
    covering = [_sampled_iou(bottle_mesh, particle_spheres(bottle_mesh, v, radius_fraction=COVERING)) for v in (0.02, 0.01, 0.005)]
    assert covering[0] < covering[1] < covering[2]
    assert covering[2] > 0.8


def test_particles_for_count_hits_target(bottle_mesh):
    geometry = particles_for_count(bottle_mesh, 300)
    assert geometry.spec == "particles:300" and geometry.name == "particles_300"
    assert 250 <= len(geometry.shapes) <= 350


def test_round_trips_through_collision_json(can_mesh, tmp_path):
    geometry = particle_spheres(can_mesh, 0.015)
    write_collision_json(geometry, tmp_path / "collision.json")
    back = read_collision_json(tmp_path / "collision.json")
    assert back.spec == geometry.spec and len(back.shapes) == len(geometry.shapes)
    np.testing.assert_allclose([s.position_m for s in back.shapes], [s.position_m for s in geometry.shapes])


def test_bad_voxel_sizes_are_rejected(can_mesh, mug_mesh):
    with pytest.raises(UserInputError, match="no voxel centre"):
        particle_spheres(mug_mesh, 1.0)  # a single voxel, centred in the mug's (empty) cavity
    with pytest.raises(UserInputError, match="positive"):
        particle_spheres(can_mesh, 0.0)
    with pytest.raises(UserInputError, match="too fine"):
        particle_spheres(can_mesh, 1e-5)
    with pytest.raises(UserInputError):
        particles_for_count(can_mesh, 0)
