"""Fidelity metrics against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.geometry.fidelity import IOU_POINTS_IN_UNION, chamfer_distance_mm, measure_fidelity


def _geometry(*shapes: CollisionShape) -> CollisionGeometry:
    return CollisionGeometry("test", "test", tuple(shapes))


def test_required_union_count_for_half_a_percent():
    # 1.96 * 0.5 / sqrt(n) <= 0.005
    assert 38_000 < IOU_POINTS_IN_UNION <= 38_416
    assert 1.96 * 0.5 / np.sqrt(IOU_POINTS_IN_UNION) == pytest.approx(0.005, rel=1e-3)


def test_identical_geometry():
    box = trimesh.creation.box(extents=(0.05, 0.08, 0.12))
    result = measure_fidelity(box, _geometry(CollisionShape("box", (0.05, 0.08, 0.12))), None)
    assert result["iou"] > 0.999
    assert result["chamfer_mm"] < 1e-6
    assert result["num_pieces"] == 1
    assert result["iou_ci95"] <= 0.005


def test_shifted_box_matches_closed_form_iou():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    shifted = _geometry(CollisionShape("box", (0.1, 0.1, 0.1), (0.02, 0.0, 0.0)))
    result = measure_fidelity(box, shifted, None, seed=1)
    assert result["iou"] == pytest.approx(0.08 / 0.12, abs=0.01)  # +-0.005 at 95 %; 0.01 is ~4 sigma
    assert result["iou_ci95"] <= 0.0051
    assert result["chamfer_mm"] > 1.0


def test_concentric_spheres_closed_form():
    # reference r = 5 cm, collision r = 5.5 cm: every point is 5 mm from the other surface
    reference = trimesh.creation.icosphere(subdivisions=5, radius=0.05)
    result = measure_fidelity(reference, _geometry(CollisionShape("sphere", (0.055,))), None, seed=2)
    assert result["iou"] == pytest.approx((0.05 / 0.055) ** 3, abs=0.01)
    assert result["chamfer_mm"] == pytest.approx(5.0, abs=0.1)


def test_mesh_baseline_and_two_pieces(tmp_path):
    reference = trimesh.creation.torus(major_radius=0.05, minor_radius=0.015)
    reference.export(tmp_path / "mesh.obj")
    same = measure_fidelity(reference, _geometry(CollisionShape("mesh", (), mesh_file="mesh.obj")), tmp_path, iou_samples=50_000)
    assert same["iou"] > 0.995
    assert same["chamfer_mm"] < 0.01
    assert same["iou_samples"] == 50_000
    # two overlapping boxes against their own union: the union mesh has no buried faces
    union = trimesh.boolean.union(
        [trimesh.creation.box(extents=(0.1, 0.02, 0.02)), trimesh.creation.box(extents=(0.02, 0.1, 0.02))], engine="manifold"
    )
    two = _geometry(CollisionShape("box", (0.1, 0.02, 0.02)), CollisionShape("box", (0.02, 0.1, 0.02)))
    result = measure_fidelity(union, two, None)
    assert result["iou"] > 0.999 and result["chamfer_mm"] < 1e-6 and result["num_pieces"] == 2


def test_chamfer_is_symmetric_in_its_definition():
    a = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    b = trimesh.creation.box(extents=(0.1, 0.1, 0.12))
    assert chamfer_distance_mm(a, b) == pytest.approx(chamfer_distance_mm(b, a), rel=0.05)
