"""Axis-aligned boxes (boxes:N) start from a greedy cover of the solid by maximal boxes
(fit/box_cover.py): on meshes the project makes, the cover itself and the fits it starts."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from real2sim.asset.canonical import canonical_transform
from real2sim.collision.fit.box_cover import greedy_box_cover
from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.convert import to_collision_geometry
from real2sim.collision.fit.initialization import interior_fill_points
from real2sim.collision.fit.loop import fit_primitives
from real2sim.collision.sdf_sampling import SdfSamplingConfig, sample_sdf
from real2sim.geometry.collision_mesh import inside_collision
from real2sim.geometry.fidelity import measure_fidelity
from real2sim.geometry.objects import make_object

# Small: 200k near-surface samples (fewer leave the fill's voxel shell open), 200 steps of 2048 (a few seconds per fit).
SAMPLING = SdfSamplingConfig(num_surface_samples=200_000)
FAST = FitConfig(max_iterations=200, min_iterations=200, batch_size=2048)


def _canonical(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_transform(canonical_transform(mesh))
    return mesh


@pytest.fixture(scope="module")
def can():
    mesh = _canonical(make_object("can"))  # r 34 mm, 100 mm long: the axis is the canonical z
    return mesh, sample_sdf(mesh, SAMPLING)


@pytest.fixture(scope="module")
def carton():
    mesh = _canonical(trimesh.creation.box(extents=(0.06, 0.1, 0.2)))
    return mesh, sample_sdf(mesh, SAMPLING)


def _with_fill(samples) -> tuple[np.ndarray, np.ndarray]:
    """The samples as the fitter hands them to the cover: with its labelled-inside fill points."""
    points, sdf = samples.points.astype(np.float32), samples.sdf.astype(np.float32)
    fill = interior_fill_points(points, sdf)
    return np.concatenate((points, fill)), np.concatenate((sdf, np.full(len(fill), -1e-3, np.float32)))


def _corners_m(geometry) -> np.ndarray:
    """Every corner of every (axis-aligned) box, metres, asset frame."""
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)])
    return np.concatenate([np.asarray(s.position_m) + signs * np.asarray(s.size_m) / 2 for s in geometry.shapes])


def _rolling_profile_error_mm(mesh: trimesh.Trimesh, geometry) -> float:
    """Mean |support-function difference| over directions about the long axis z, mm: how far the
    surface the object rolls on lies from the true one (what a lying can rolls on)."""
    a = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    u = np.stack([np.cos(a), np.sin(a), 0 * a], 1)
    diff = (u @ _corners_m(geometry).T).max(1) - (u @ mesh.vertices.T).max(1)
    return float(1e3 * np.abs(diff).mean())


def test_cover_of_a_carton_starts_with_the_carton(carton):
    mesh, samples = carton
    centres, half = greedy_box_cover(*_with_fill(samples), 10)
    # The first box is the carton, to the voxels wholly inside it (the rest pick up the ragged
    # outermost layer of voxels).
    true_half = (mesh.bounds[1] - mesh.bounds[0]) / 2 / samples.scale_m
    voxel = 2 * true_half.max() / 64
    np.testing.assert_allclose(half[0], true_half, atol=1.5 * voxel)
    np.testing.assert_allclose(samples.centre_m + samples.scale_m * centres[0], mesh.bounds.mean(0),
                               atol=1.5 * voxel * samples.scale_m)


def test_cover_of_a_can_is_full_length_slabs_with_corners_on_the_circle(can):
    mesh, samples = can
    centres, half = greedy_box_cover(*_with_fill(samples), 6)
    assert len(centres) == 6
    height = (mesh.bounds[1, 2] - mesh.bounds[0, 2]) / samples.scale_m
    radius = 0.034 / samples.scale_m
    voxel = height / 64
    # The first slabs run the whole length (k-means patches spanned a third to a half of it) ...
    assert np.all(2 * half[:4, 2] >= height - 3 * voxel)
    # ... and are as wide as the circle lets them: corners on it, never outside.
    corner_radius = np.hypot(np.abs(centres[:, 0]) + half[:, 0], np.abs(centres[:, 1]) + half[:, 1])
    assert np.all(corner_radius <= radius + voxel) and np.all(corner_radius >= radius - 3 * voxel)
    # Different slabs, not one repeated: the cover counts only voxels no earlier box covers.
    assert len({tuple(np.round(h, 4)) for h in half}) == 6


def test_boxes_10_on_the_can_follow_its_round_side_and_flat_ends(can):
    """Reverting the cover (box_init="kmeans") gave IoU 0.896 and a rolling profile 3.6 mm off at
    this size; the cover gives ~0.95 and ~1.7 mm."""
    mesh, samples = can
    result = fit_primitives(samples.points, samples.sdf, (("boxes", 10),), FAST)
    geometry = to_collision_geometry(result, samples.centre_m, samples.scale_m, "boxes:10")
    fidelity = measure_fidelity(mesh, geometry, None, iou_samples=20_000, chamfer_samples=5_000)
    assert fidelity["iou"] >= 0.93
    assert _rolling_profile_error_mm(mesh, geometry) <= 2.5
    # Flat ends at the support planes: no box pokes past an end, and the boxes that reach the
    # bottom cover its disc (the can stands level on them).
    corners = _corners_m(geometry)
    assert corners[:, 2].min() >= mesh.bounds[0, 2] - 3e-4 and corners[:, 2].max() <= mesh.bounds[1, 2] + 3e-4
    rng = np.random.default_rng(0)
    disc = rng.uniform(-0.033, 0.033, size=(4000, 2))
    disc = disc[np.hypot(disc[:, 0], disc[:, 1]) < 0.032]
    bottom = np.column_stack([disc, np.full(len(disc), mesh.bounds[0, 2] + 3e-4)])
    assert inside_collision(geometry, None, bottom).mean() >= 0.9


def test_boxes_on_a_carton_fit_it_exactly(carton):
    """k-means patches gave a carton 10 boxes, faces up to 0.24 mm off (Chamfer 0.1 mm); the cover
    starts one box on it and the boxes it had no use for are dropped: one box, faces within 0.02 mm."""
    mesh, samples = carton
    result = fit_primitives(samples.points, samples.sdf, (("boxes", 10),), FAST)
    geometry = to_collision_geometry(result, samples.centre_m, samples.scale_m, "boxes:10")
    fidelity = measure_fidelity(mesh, geometry, None, iou_samples=20_000, chamfer_samples=5_000)
    assert len(geometry.shapes) <= 2 and fidelity["iou"] >= 0.995 and fidelity["chamfer_mm"] <= 0.02
    corners = _corners_m(geometry)
    np.testing.assert_allclose(corners.min(0), mesh.bounds[0], atol=5e-5)
    np.testing.assert_allclose(corners.max(0), mesh.bounds[1], atol=5e-5)


def test_cover_only_starts_boxes_alone(can):
    """Other families, mixes and rotated boxes keep the k-means start: same fit with either setting."""
    _, samples = can
    cfg = FitConfig(max_iterations=5, min_iterations=5, batch_size=256)
    for parts in ((("cylinders", 2),), (("boxes", 2), ("cylinders", 1)), (("rotated_boxes", 2),)):
        a = fit_primitives(samples.points, samples.sdf, parts, cfg)
        b = fit_primitives(samples.points, samples.sdf, parts, FitConfig(**{**cfg.__dict__, "box_init": "kmeans"}))
        assert a.parameters == b.parameters
    boxes = [fit_primitives(samples.points, samples.sdf, (("boxes", 2),), FitConfig(**{**cfg.__dict__, "box_init": b}))
             for b in ("cover", "kmeans")]
    assert boxes[0].parameters != boxes[1].parameters


def test_box_init_is_checked():
    with pytest.raises(ValueError, match="box_init"):
        FitConfig(box_init="voxels")

