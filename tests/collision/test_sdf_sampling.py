"""Signed-distance sampling: magnitudes and signs against analytic shapes, robustness to
holes and internal faces, seeds, the cache, and the unit-sphere transform."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.inside import signed_distance
from tests.progress_check import Recorder
from real2sim.collision.sdf_sampling import SdfSamplingConfig, default_cache_dir, sample_sdf, unit_sphere_transform

SMALL = SdfSamplingConfig(num_surface_samples=20_000, num_uniform_samples=500, seed=3)
# Wider noise puts many samples clearly (> 0.05 unit) inside or outside, where signs are checked.
WIDE = SdfSamplingConfig(num_surface_samples=20_000, num_uniform_samples=2000, surface_sigmas=(0.0025, 0.08), seed=3)
BOX_EXTENTS_M = np.array([0.20, 0.10, 0.06])
BOX_CENTRE_M = np.array([0.3, -0.1, 0.05])


def _box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=BOX_EXTENTS_M)
    box = box.subdivide().subdivide()  # more, smaller faces: holes can be cut without opening a whole side
    box.apply_translation(BOX_CENTRE_M)
    return box


def _box_sdf_m(points_m: np.ndarray) -> np.ndarray:
    q = np.abs(points_m - BOX_CENTRE_M) - BOX_EXTENTS_M / 2
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def _sphere(radius_m: float = 0.05, centre_m=(0.1, 0.2, 0.3), subdivisions: int = 4) -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_m)
    sphere.apply_translation(centre_m)
    return sphere


def _clear_sign_accuracy(samples, truth_m: np.ndarray) -> float:
    """Fraction of clearly inside/outside samples (|d| > 0.05 unit) whose sign matches the truth."""
    clear = np.abs(truth_m) > 0.05 * samples.scale_m
    assert clear.sum() > 1000
    return float(np.mean(np.sign(samples.sdf[clear]) == np.sign(truth_m[clear])))


def test_box_magnitudes_and_signs_match_analytic():
    box = _box()
    samples = sample_sdf(box, SMALL, cache_dir=None)
    truth = _box_sdf_m(samples.points_m())
    # Exact planar faces: the only error is float32 storage of the unit-sphere points.
    np.testing.assert_allclose(samples.sdf_m(), truth, atol=1e-6 * samples.scale_m * 10)
    assert (samples.sdf < 0).mean() == pytest.approx((truth < 0).mean(), abs=1e-3)


def test_sphere_matches_analytic_within_faceting():
    radius, centre = 0.05, np.array([0.1, 0.2, 0.3])
    samples = sample_sdf(_sphere(radius, centre), SMALL, cache_dir=None)
    truth = np.linalg.norm(samples.points_m() - centre, axis=1) - radius
    faceting_m = 2e-3 * radius  # sagitta of a 5120-face icosphere is ~1.2e-3 of its radius
    assert np.abs(samples.sdf_m() - truth).max() < faceting_m
    clear = np.abs(truth) > faceting_m
    assert np.all(np.sign(samples.sdf_m()[clear]) == np.sign(truth[clear]))


def test_unit_sphere_transform_and_back_to_asset_frame():
    box = _box()
    centre, scale = unit_sphere_transform(box)
    np.testing.assert_allclose(centre, BOX_CENTRE_M, atol=1e-12)
    assert scale == pytest.approx(np.linalg.norm(BOX_EXTENTS_M) / 2, rel=1e-12)
    unit_vertices = (box.vertices - centre) / scale
    assert np.linalg.norm(unit_vertices, axis=1).max() == pytest.approx(1.0, abs=1e-12)

    samples = sample_sdf(box, SMALL, cache_dir=None)
    assert samples.scale == samples.scale_m == scale
    np.testing.assert_array_equal(samples.points_m(), centre + scale * samples.points.astype(np.float64))
    np.testing.assert_allclose(samples.to_unit(samples.to_asset(samples.points)), samples.points, atol=1e-12)
    np.testing.assert_allclose(samples.to_asset(unit_vertices), box.vertices, atol=1e-15)
    # The stored distances are the mesh's own signed distances, rescaled to metres.
    sub = slice(0, 2000)
    np.testing.assert_allclose(samples.sdf_m()[sub], signed_distance(box, samples.points_m()[sub]), atol=1e-6 * scale)


def test_counts_noise_scales_and_uniform_ball():
    cfg = SdfSamplingConfig(num_surface_samples=12_000, num_uniform_samples=700, surface_sigmas=(0.0025, 0.025), seed=1)
    samples = sample_sdf(_box(), cfg, cache_dir=None)
    assert samples.points.shape == (12_700, 3) and samples.sdf.shape == (12_700,)
    assert samples.points.dtype == np.float32 and samples.sdf.dtype == np.float32
    assert samples.num_surface == 12_000
    # Near a large flat face the sdf is the normal component of the noise: median |N(0, s)| = 0.674 s.
    fine, coarse = np.abs(samples.sdf[:6000]), np.abs(samples.sdf[6000:12_000])
    assert np.median(fine) == pytest.approx(0.674 * 0.0025, rel=0.25)
    assert np.median(coarse) == pytest.approx(0.674 * 0.025, rel=0.25)
    radii = np.linalg.norm(samples.points[12_000:], axis=1)
    assert radii.max() <= 1.3 + 1e-6
    # Uniform in the ball: (r / R)^3 is uniform on [0, 1].
    assert np.mean((radii / 1.3) ** 3) == pytest.approx(0.5, abs=0.05)


def test_seed_reproducible_and_different_seeds_differ():
    box = _box()
    a = sample_sdf(box, SMALL, cache_dir=None)
    b = sample_sdf(box, SMALL, cache_dir=None)
    c = sample_sdf(box, SdfSamplingConfig(num_surface_samples=20_000, seed=4), cache_dir=None)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.sdf, b.sdf)
    assert not np.array_equal(a.points, c.points)


def test_signs_robust_to_holes():
    box = _box()
    # Cut a hole: drop the faces of a patch on the top face (z max).
    top = box.triangles_center[:, 2] > BOX_CENTRE_M[2] + BOX_EXTENTS_M[2] / 2 - 1e-9
    near_centre = np.linalg.norm(box.triangles_center[:, :2] - BOX_CENTRE_M[:2], axis=1) < 0.03
    holey = box.copy()
    holey.update_faces(~(top & near_centre))
    assert not holey.is_watertight and len(holey.faces) < len(box.faces)
    samples = sample_sdf(holey, WIDE, cache_dir=None)
    assert _clear_sign_accuracy(samples, _box_sdf_m(samples.points_m())) > 0.99

    sphere = _sphere()
    keep = np.ones(len(sphere.faces), dtype=bool)
    keep[np.argsort(sphere.triangles_center[:, 2])[-60:]] = False  # an open cap at the top
    sphere.update_faces(keep)
    samples = sample_sdf(sphere, WIDE, cache_dir=None)
    truth = np.linalg.norm(samples.points_m() - np.array([0.1, 0.2, 0.3]), axis=1) - 0.05
    assert _clear_sign_accuracy(samples, truth) > 0.99


def test_signs_robust_to_internal_faces():
    centre = np.array([0.1, 0.2, 0.3])
    outer = _sphere(0.05, centre)
    inner_shell = _sphere(0.025, centre, subdivisions=3)  # a closed duplicated shell inside
    sheet = trimesh.creation.box(extents=(0.06, 0.06, 1e-4)).subdivide().subdivide()
    sheet = trimesh.Trimesh(sheet.vertices[:, :] + centre + [0.0, 0.0, 0.01], sheet.faces)  # a thin internal slab
    open_sheet = trimesh.Trimesh(
        vertices=centre + np.array([[-0.03, -0.03, -0.02], [0.03, -0.03, -0.02], [0.03, 0.03, -0.02], [-0.03, 0.03, -0.02]]),
        faces=[[0, 1, 2], [0, 2, 3]],
    ).subdivide().subdivide()  # an open one-sided sheet
    messy = trimesh.util.concatenate([outer, inner_shell, sheet, open_sheet])
    samples = sample_sdf(messy, WIDE, cache_dir=None)
    truth = np.linalg.norm(samples.points_m() - centre, axis=1) - 0.05
    assert _clear_sign_accuracy(samples, truth) > 0.99


def test_fast_signs_agree_with_exact_winding_numbers(mug_mesh):
    fast = sample_sdf(mug_mesh, SdfSamplingConfig(num_surface_samples=30_000, seed=2), cache_dir=None)
    exact = sample_sdf(mug_mesh, SdfSamplingConfig(num_surface_samples=30_000, seed=2, sign_method="exact"), cache_dir=None)
    np.testing.assert_array_equal(np.abs(fast.sdf), np.abs(exact.sdf))
    disagree = np.sign(fast.sdf) != np.sign(exact.sdf)
    assert disagree.mean() < 1e-3
    assert np.all(np.abs(exact.sdf[disagree]) < 1e-3)
    # The cavity (radius 0.037 m above a 6 mm floor) is outside; ray stabbing would fill it.
    p = fast.points_m()
    in_cavity = (np.linalg.norm(p[:, :2], axis=1) < 0.035) & (p[:, 2] > 0.009) & (p[:, 2] < 0.09)
    assert in_cavity.sum() > 50
    assert np.all(fast.sdf[in_cavity] > 0)


def test_fast_signs_agree_with_exact_on_holes_and_stray_triangles():
    # Many holes, plus stray randomly oriented triangles in and around the surface: the
    # per-face inference must hand every point near a rim back to the exact winding number.
    rng = np.random.default_rng(5)
    sphere = _sphere(subdivisions=4)
    sphere.update_faces(rng.random(len(sphere.faces)) > 0.05)
    centres = sphere.vertices[rng.integers(0, len(sphere.vertices), 400)] * 1.0
    stray = centres[:, None, :] + rng.normal(size=(400, 3, 3)) * 0.004
    messy = trimesh.util.concatenate([sphere, trimesh.Trimesh(stray.reshape(-1, 3), np.arange(1200).reshape(-1, 3))])
    cfg = dict(num_surface_samples=20_000, surface_sigmas=(0.0025, 0.08), seed=1)
    fast = sample_sdf(messy, SdfSamplingConfig(**cfg), cache_dir=None)
    exact = sample_sdf(messy, SdfSamplingConfig(**cfg, sign_method="exact"), cache_dir=None)
    disagree = np.sign(fast.sdf) != np.sign(exact.sdf)
    assert np.all(np.abs(exact.sdf[disagree]) < 1e-6)


def test_cache_hit_returns_identical_arrays(tmp_path):
    box = _box()
    first = sample_sdf(box, SMALL, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1 and not first.from_cache
    second = sample_sdf(box, SMALL, cache_dir=tmp_path)
    assert second.from_cache
    np.testing.assert_array_equal(first.points, second.points)
    np.testing.assert_array_equal(first.sdf, second.sdf)
    np.testing.assert_array_equal(first.centre_m, second.centre_m)
    assert first.scale_m == second.scale_m and first.num_surface == second.num_surface
    # A different configuration or a different mesh is a different entry.
    sample_sdf(box, SdfSamplingConfig(num_surface_samples=20_000, seed=9), cache_dir=tmp_path)
    moved = box.copy()
    moved.apply_translation([0.0, 0.0, 1e-3])
    assert not sample_sdf(moved, SMALL, cache_dir=tmp_path).from_cache
    assert len(list(tmp_path.glob("*.npz"))) == 3
    # A corrupt cache file is recomputed, not trusted.
    files[0].write_bytes(b"not an npz")
    again = sample_sdf(box, SMALL, cache_dir=tmp_path)
    assert not again.from_cache
    np.testing.assert_array_equal(again.sdf, first.sdf)


def test_default_cache_dir_follows_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("REAL2SIM_CACHE", str(tmp_path))
    assert default_cache_dir() == tmp_path / "sdf"
    progress = Recorder()
    samples = sample_sdf(_box(), SdfSamplingConfig(num_surface_samples=2000), progress=progress)
    assert not samples.from_cache
    assert progress.check()[-1] == ("sdf: sampled", 3, 3)
    assert len(list((tmp_path / "sdf").glob("*.npz"))) == 1
    monkeypatch.delenv("REAL2SIM_CACHE")
    assert default_cache_dir().parts[-3:] == (".cache", "real2sim", "sdf")


def test_open_surface_is_rejected():
    # A wavy open sheet (not flat, so it passes the mesh checks) bounds no volume.
    x, y = np.meshgrid(np.linspace(-0.1, 0.1, 30), np.linspace(-0.1, 0.1, 30))
    z = 0.02 * np.sin(30 * x) * np.cos(20 * y)
    verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    idx = np.arange(900).reshape(30, 30)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    sheet = trimesh.Trimesh(verts, faces)
    with pytest.raises(UserInputError, match="encloses no volume"):
        sample_sdf(sheet, SMALL, cache_dir=None)


def test_closed_but_paper_thin_mesh_is_rejected():
    foil = trimesh.creation.box(extents=(0.2, 0.2, 1e-6))  # closed, but no sample fits inside
    with pytest.raises(UserInputError, match="encloses no volume"):
        sample_sdf(foil, SMALL, cache_dir=None)
    plate = trimesh.creation.box(extents=(0.2, 0.2, 0.004))  # thin but real: accepted
    assert (sample_sdf(plate, SMALL, cache_dir=None).sdf < 0).mean() > 0.05


def test_empty_mesh_is_rejected():
    with pytest.raises(UserInputError):
        sample_sdf(trimesh.Trimesh(), SMALL, cache_dir=None)


def test_bad_config_is_rejected():
    with pytest.raises(ValueError):
        SdfSamplingConfig(surface_sigmas=(0.0,))
    with pytest.raises(ValueError):
        SdfSamplingConfig(sign_method="rays")
