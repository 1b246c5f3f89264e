"""The hydroelastic scenes' floor: the box slab as graded tetrahedra, with the box's pressure field."""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from real2sim.evaluate.scene.floor import FINE_CELL_M, floor_mesh_path, grid_lines, slab_tetrahedra
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import make_run_specs
from real2sim.evaluate.simulate import simulate_reference
from real2sim.formats.physical import PhysicalProperties


def test_the_tetrahedra_fill_the_slab_exactly_and_are_fine_near_the_object():
    vertices, tets = slab_tetrahedra(40.0, 0.5)
    a, b, c, d = (vertices[tets[:, m]] for m in range(4))
    volumes = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0
    assert volumes.min() > 0 and np.isclose(volumes.sum(), 40.0 * 40.0 * 1.0)
    assert np.allclose(vertices.min(axis=0), (-20, -20, -1)) and np.allclose(vertices.max(axis=0), (20, 20, 0))
    lines = grid_lines(20.0)
    assert np.all(np.diff(lines) > 0) and np.isclose(np.diff(lines)[len(lines) // 2], FINE_CELL_M)
    # no tetrahedron crosses the mid-plane, where the box's field has its ridge
    z = vertices[tets][:, :, 2]
    assert np.all((z.max(axis=1) <= -0.5 + 1e-12) | (z.min(axis=1) >= -0.5 - 1e-12))
    assert floor_mesh_path(40.0, 0.5) == floor_mesh_path(40.0, 0.5) and floor_mesh_path(40.0, 0.5).is_file()


def test_a_resting_rigid_block_sinks_as_the_box_field_says(tmp_path):
    """Pressure E * depth / h under the whole base (h the slab's half-thickness) carries the weight:
    a rigid cube of side s and mass m rests m g h / (E s^2) deep."""
    side, mass_kg = 0.1, 1.0
    block = trimesh.creation.box((side, side, side)).subdivide().subdivide()
    path = tmp_path / "block.obj"
    block.export(path)
    inertia = mass_kg * side**2 / 6
    props = PhysicalProperties(mass_kg, (0.0, 0.0, 0.0),
                               ((inertia, 0, 0), (0, inertia, 0), (0, 0, inertia)))
    cfg = dataclasses.replace(SceneConfig(), settle_s=0.6, push_duration_s=0.0)
    traj = simulate_reference(path, props, make_run_specs("push", 1, 0)[0], cfg)
    sunk_m = side / 2 - traj.object_position_m[-1, 2]
    expected_m = mass_kg * 9.81 * cfg.floor_slab_thickness_m / (cfg.environment_hydroelastic_modulus_pa * side**2)
    assert abs(sunk_m - expected_m) < 0.05 * expected_m, (sunk_m, expected_m)
    assert np.abs(traj.object_spatial_velocity[-1]).max() < 1e-3
