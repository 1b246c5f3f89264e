"""Collision shapes as meshes, their union, and the exact inside test."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.rotations import matrix_to_quaternion
from real2sim.geometry.collision_mesh import inside_collision, shape_mesh, union_mesh
from real2sim.geometry.inside import inside_mask

Q_X90 = matrix_to_quaternion(Rotation.from_euler("x", 90, degrees=True).as_matrix())


@pytest.mark.parametrize(
    "shape, volume_m3",
    [
        (CollisionShape("sphere", (0.05,), (0.1, 0.0, 0.0)), 4 / 3 * np.pi * 0.05**3),
        (CollisionShape("box", (0.02, 0.04, 0.08), (0.0, 0.1, 0.0), Q_X90), 0.02 * 0.04 * 0.08),
        (CollisionShape("cylinder", (0.03, 0.1), (0.0, 0.0, 0.1), Q_X90), np.pi * 0.03**2 * 0.1),
        (CollisionShape("ellipsoid", (0.01, 0.02, 0.03), (0.05, 0.05, 0.0)), 4 / 3 * np.pi * 0.01 * 0.02 * 0.03),
        (CollisionShape("capsule", (0.02, 0.06), (0.0, -0.1, 0.0), Q_X90), np.pi * 0.02**2 * 0.06 + 4 / 3 * np.pi * 0.02**3),
    ],
)
def test_primitive_meshes_closed_posed_and_sized(shape, volume_m3):
    mesh = shape_mesh(shape)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(volume_m3, rel=0.01)
    np.testing.assert_allclose(mesh.center_mass, shape.position_m, atol=1e-9)
    # the pose's rotation is applied: the shape's own z axis ends up along asset -y for Q_X90
    if shape.quaternion_wxyz == Q_X90 and shape.kind != "sphere":
        ext = mesh.extents
        expected_y = {"box": 0.08, "cylinder": 0.1, "capsule": 0.06 + 2 * 0.02}[shape.kind]
        assert ext[1] == pytest.approx(expected_y, rel=1e-6)


def test_convex_and_mesh_pieces_load_from_rep_dir(tmp_path):
    hull = trimesh.creation.icosphere(subdivisions=1, radius=0.03)
    hull.export(tmp_path / "hull_0.obj")
    torus = trimesh.creation.torus(major_radius=0.05, minor_radius=0.015)
    torus.export(tmp_path / "mesh.obj")
    convex = CollisionShape("convex", (), (0.1, 0.0, 0.0), mesh_file="hull_0.obj")
    nonconvex = CollisionShape("mesh", (), (0.0, 0.0, 0.0), Q_X90, mesh_file="mesh.obj")
    m = shape_mesh(convex, tmp_path)
    np.testing.assert_allclose(m.bounds.mean(axis=0), (0.1, 0, 0), atol=1e-9)
    assert m.volume == pytest.approx(hull.volume, rel=1e-6)
    t = shape_mesh(nonconvex, tmp_path)
    assert t.extents[1] == pytest.approx(0.03, rel=1e-6)  # torus axis turned from z to -y
    with pytest.raises(ValueError):
        shape_mesh(convex, None)


def test_union_of_overlapping_boxes_is_closed_with_exact_volume():
    geometry = CollisionGeometry(
        "boxes_2",
        "boxes:2",
        (CollisionShape("box", (0.1, 0.1, 0.1)), CollisionShape("box", (0.1, 0.1, 0.1), (0.05, 0.0, 0.0))),
    )
    union = union_mesh(geometry)
    assert union.is_watertight
    assert union.volume == pytest.approx(0.15 * 0.1 * 0.1, rel=1e-9)
    # no internal faces: the area is that of the outer boundary only
    assert union.area == pytest.approx(2 * (0.15 * 0.1 * 2 + 0.1 * 0.1), rel=1e-9)


def test_union_of_500_rotated_boxes():
    rng = np.random.default_rng(0)
    quats = [matrix_to_quaternion(m) for m in Rotation.random(500, random_state=5).as_matrix()]
    shapes = tuple(
        CollisionShape("box", tuple(map(float, e)), tuple(map(float, c)), q)
        for c, e, q in zip(rng.uniform(-0.1, 0.1, (500, 3)), rng.uniform(0.01, 0.04, (500, 3)), quats)
    )
    geometry = CollisionGeometry("rotated_boxes_500", "rotated_boxes:500", shapes)
    union = union_mesh(geometry)
    assert union.is_watertight and union.volume > 0
    pts = rng.uniform(-0.13, 0.13, (20_000, 3))
    exact = inside_collision(geometry, None, pts)
    assert 0.1 < exact.mean() < 0.9
    assert np.mean(inside_mask(union, pts) == exact) > 0.999  # boxes have no tessellation error


def test_union_of_spheres():
    rng = np.random.default_rng(0)
    shapes = tuple(CollisionShape("sphere", (float(r),), tuple(map(float, c))) for c, r in zip(rng.uniform(-0.05, 0.05, (40, 3)), rng.uniform(0.01, 0.03, 40)))
    geometry = CollisionGeometry("spheres_40", "spheres:40", shapes)
    union = union_mesh(geometry)
    assert union.is_watertight
    pts = rng.uniform(-0.08, 0.08, (20_000, 3))
    assert np.mean(inside_mask(union, pts) == inside_collision(geometry, None, pts)) > 0.995  # tessellation error only


def test_inside_collision_matches_union_mesh(tmp_path):
    rng = np.random.default_rng(1)
    trimesh.creation.box(extents=(0.03, 0.03, 0.03)).export(tmp_path / "hull.obj")
    rot = matrix_to_quaternion(Rotation.random(random_state=4).as_matrix())
    shapes = (
        CollisionShape("sphere", (0.03,), (0.05, 0.0, 0.0)),
        CollisionShape("box", (0.02, 0.05, 0.03), (-0.04, 0.02, 0.0), rot),
        CollisionShape("cylinder", (0.02, 0.06), (0.0, -0.04, 0.02), rot),
        CollisionShape("ellipsoid", (0.01, 0.03, 0.02), (0.0, 0.05, -0.03), rot),
        CollisionShape("capsule", (0.015, 0.04), (0.0, 0.0, 0.05), Q_X90),
        CollisionShape("convex", (), (0.05, 0.05, 0.05), rot, mesh_file="hull.obj"),
        CollisionShape("mesh", (), (-0.05, -0.05, -0.05), mesh_file="hull.obj"),
    )
    geometry = CollisionGeometry("mix", "mix", shapes)
    pts = rng.uniform(-0.1, 0.1, (40_000, 3))
    exact = inside_collision(geometry, tmp_path, pts)
    by_mesh = inside_mask(union_mesh(geometry, tmp_path), pts)
    assert exact.sum() > 1000
    assert np.mean(exact == by_mesh) > 0.998
    # a point at each shape's centre is inside; a far point is not
    centres = np.array([s.position_m for s in shapes] + [[1.0, 1.0, 1.0]])
    assert inside_collision(geometry, tmp_path, centres).tolist() == [True] * len(shapes) + [False]
