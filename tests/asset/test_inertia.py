"""Inertia from interior samples: closed forms, floaters, bad masses."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from real2sim.asset.inertia import estimate_physical_properties

SAMPLES = 150_000  # enough for < 0.3 % error on these shapes, fast on a loaded 2-core machine


def _pose(mesh: trimesh.Trimesh, rotation: np.ndarray, offset) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_transform(np.vstack([np.hstack([rotation, np.reshape(offset, (3, 1))]), [0, 0, 0, 1]]))
    return out


def _check(props, mass_kg, com_m, principal_moments, rotation, scale_m):
    assert props.mass_kg == mass_kg
    assert np.linalg.norm(np.subtract(props.com_m, com_m)) < 0.01 * scale_m
    expected = rotation @ np.diag(principal_moments) @ rotation.T
    # each principal moment within 1 %, and the tensor's axes where they should be
    assert np.sort(np.linalg.eigvalsh(props.inertia)) == pytest.approx(np.sort(principal_moments), rel=0.01)
    assert np.abs(props.inertia - expected).max() < 0.01 * max(principal_moments)


def test_box():
    a, b, c, m = 0.06, 0.1, 0.2, 0.8
    rot = Rotation.from_euler("xyz", (10, 20, 30), degrees=True).as_matrix()
    mesh = _pose(trimesh.creation.box(extents=(a, b, c)), rot, (0.3, -0.2, 0.1))
    props = estimate_physical_properties(mesh, m, num_samples=SAMPLES)
    moments = m / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    _check(props, m, (0.3, -0.2, 0.1), moments, rot, c)
    assert props.samples_kept > 0.2 * SAMPLES


def test_cylinder():
    r, h, m = 0.034, 0.1, 0.35
    rot = Rotation.from_euler("y", 50, degrees=True).as_matrix()
    # libigl's fast winding number is ~10x slower on the long slivers of a fan-capped
    # cylinder; subdividing keeps the geometry and makes the triangles compact
    cylinder = trimesh.creation.cylinder(radius=r, height=h, sections=256).subdivide_to_size(0.01)
    mesh = _pose(cylinder, rot, (0.0, 0.05, 0.0))
    props = estimate_physical_properties(mesh, m, num_samples=SAMPLES, seed=3)
    side = m * (3 * r * r + h * h) / 12
    _check(props, m, (0.0, 0.05, 0.0), np.array([side, side, m * r * r / 2]), rot, h)


def test_torus_with_its_hole():
    big, small, m = 0.05, 0.015, 0.2
    mesh = trimesh.creation.torus(major_radius=big, minor_radius=small, major_sections=128, minor_sections=64)
    props = estimate_physical_properties(mesh, m, num_samples=SAMPLES)
    across = m * (big * big / 2 + 5 * small * small / 8)
    _check(props, m, (0.0, 0.0, 0.0), np.array([across, across, m * (big * big + 0.75 * small * small)]), np.eye(3), 2 * big)


def test_detached_floater_is_ignored():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    floater = trimesh.creation.icosphere(subdivisions=2, radius=0.01)
    floater.apply_translation((0.15, 0.0, 0.0))  # 10 cm beyond the box's face
    speck = trimesh.creation.box(extents=(0.001, 0.001, 0.001))
    speck.apply_translation((-0.1, 0.05, 0.0))
    clean = estimate_physical_properties(box, 1.0, num_samples=SAMPLES)
    dirty = estimate_physical_properties(trimesh.util.concatenate([box, floater, speck]), 1.0, num_samples=SAMPLES)
    assert np.linalg.norm(np.subtract(dirty.com_m, clean.com_m)) < 0.01 * 0.1
    assert dirty.inertia == pytest.approx(clean.inertia, rel=0.01, abs=1e-3 * clean.inertia.max())
    # without the rejection the floater would have moved the result by far more than 1 %
    raw = estimate_physical_properties(
        trimesh.util.concatenate([box, floater]), 1.0, num_samples=SAMPLES, outlier_min_neighbours=0, min_cluster_fraction=0
    )
    assert abs(raw.inertia[1, 1] - clean.inertia[1, 1]) > 0.03 * clean.inertia[1, 1]


def test_thin_attached_fin_is_kept():
    # a box with a thin fin (3 cells thick) attached: the fin is part of the object
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    fin = trimesh.creation.box(extents=(0.1, 0.006, 0.05))
    fin.apply_translation((0.1, 0.0, 0.0))
    solid = trimesh.boolean.union([box, fin], engine="manifold")
    props = estimate_physical_properties(solid, 1.0, num_samples=SAMPLES)
    expected_com_x = (0.1 * 0.006 * 0.05 * 0.1) / solid.volume
    assert props.com_m[0] == pytest.approx(expected_com_x, rel=0.05)


def test_seeded_and_deterministic():
    mesh = trimesh.creation.box(extents=(0.05, 0.05, 0.1))
    a = estimate_physical_properties(mesh, 1.0, num_samples=20_000, seed=7)
    b = estimate_physical_properties(mesh, 1.0, num_samples=20_000, seed=7)
    assert a == b


@pytest.mark.parametrize("mass", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_mass(mass):
    with pytest.raises(ValueError):
        estimate_physical_properties(trimesh.creation.box(), mass, num_samples=10_000)
