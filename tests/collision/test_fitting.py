"""Primitive fitting on analytic targets (no sampler needed), conversion to the asset frame."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from real2sim.formats.rotations import quaternion_to_matrix
from real2sim.geometry.collision_mesh import inside_collision
from real2sim.collision.fit.config import FitConfig, FitResult
from real2sim.collision.fit.convert import result_sdf, to_collision_geometry
from real2sim.collision.fit.loop import fit_primitives
from real2sim.collision.fit.losses import rotation_penalty, sdf_loss

# Small and fast: few samples, small batches, few iterations; direct parameters unless tested.
FAST = FitConfig(parameterization="direct", batch_size=2048, max_iterations=250, min_iterations=250, revive_dead=False)


def _near_surface(sdf_fn, surface_pts: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Samples like the sampler's: surface points jittered at two scales, plus uniform ones."""
    rng = np.random.default_rng(seed)
    n = len(surface_pts)
    sigma = np.where(np.arange(n) % 2 == 0, 0.005, 0.04)[:, None]
    pts = surface_pts + rng.normal(size=surface_pts.shape) * sigma
    pts = np.vstack([pts, rng.uniform(-1, 1, size=(300, 3))])
    return pts.astype(np.float32), sdf_fn(pts).astype(np.float32)


def _box_sdf_np(pts: np.ndarray, centre, half) -> np.ndarray:
    q = np.abs(pts - np.asarray(centre)) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)


def _box_surface(centre, half, n: int, rng) -> np.ndarray:
    """Points spread on a box surface (area-weighted faces)."""
    half = np.asarray(half, dtype=float)
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]).repeat(2)
    face = rng.choice(6, size=n, p=areas / areas.sum())
    p = rng.uniform(-1, 1, size=(n, 3)) * half
    axis = face // 2
    p[np.arange(n), axis] = np.where(face % 2 == 0, -1, 1) * half[axis]
    return p + np.asarray(centre)


@pytest.fixture(scope="module")
def sphere_samples():
    rng = np.random.default_rng(1)
    c, r = np.array([0.1, -0.2, 0.05]), 0.45
    d = rng.normal(size=(12_000, 3))
    surf = c + r * d / np.linalg.norm(d, axis=1, keepdims=True)
    return (*_near_surface(lambda p: np.linalg.norm(p - c, axis=1) - r, surf), c, r)


@pytest.fixture(scope="module")
def box_samples():
    rng = np.random.default_rng(2)
    c, h = np.array([-0.1, 0.05, 0.1]), np.array([0.3, 0.2, 0.5])
    return (*_near_surface(lambda p: _box_sdf_np(p, c, h), _box_surface(c, h, 12_000, rng)), c, h)


@pytest.fixture(scope="module")
def l_shape_samples():
    rng = np.random.default_rng(3)
    boxes = [(np.array([-0.2, 0.0, -0.3]), np.array([0.4, 0.2, 0.15])), (np.array([-0.45, 0.0, 0.15]), np.array([0.15, 0.2, 0.35]))]

    def sdf(p):
        return np.minimum(*(_box_sdf_np(p, c, h) for c, h in boxes))

    surf = np.vstack([_box_surface(c, h, 8_000, rng) for c, h in boxes])
    surf = surf[np.abs(sdf(surf)) < 1e-9]  # drop the faces buried inside the other box
    return _near_surface(sdf, surf)


def test_one_sphere_recovers_centre_and_radius(sphere_samples):
    pts, sdf, c, r = sphere_samples
    res = fit_primitives(pts, sdf, (("spheres", 1),), FAST)
    assert res.kinds == ("sphere",) and res.effective_count == 1
    p = np.asarray(res.parameters[0])
    np.testing.assert_allclose(p[:3], c, atol=0.02)
    assert abs(p[3] - r) < 0.02
    assert res.final_loss < 1e-4


def test_one_box_recovers_box(box_samples):
    pts, sdf, c, h = box_samples
    res = fit_primitives(pts, sdf, (("boxes", 1),), FAST)
    p = np.asarray(res.parameters[0])
    np.testing.assert_allclose(p[:3], c, atol=0.02)
    np.testing.assert_allclose(p[3:6], h, atol=0.02)


def cylinder_samples(c, r: float, h: float, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Near-surface samples of a capped cylinder (axis z, radius r, half-length h) centred at c."""
    rng = np.random.default_rng(seed)

    def sdf(p):
        q = p - c
        dr, dz = np.hypot(q[:, 0], q[:, 1]) - r, np.abs(q[:, 2]) - h
        return np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)) + np.minimum(np.maximum(dr, dz), 0)

    th, z = rng.uniform(0, 2 * np.pi, 8000), rng.uniform(-h, h, 8000)
    rr, t2 = r * np.sqrt(rng.uniform(0, 1, 3000)), rng.uniform(0, 2 * np.pi, 3000)
    surf = np.vstack([
        np.stack([r * np.cos(th), r * np.sin(th), z], 1),
        np.stack([rr * np.cos(t2), rr * np.sin(t2), np.where(np.arange(3000) % 2 == 0, -h, h)], 1),
    ]) + c  # fmt: skip
    return _near_surface(sdf, surf, seed=seed)


def test_one_cylinder_recovers_radius_length_and_axis():
    c, r, h = np.array([0.05, -0.1, 0.0]), 0.3, 0.6
    pts, target = cylinder_samples(c, r, h)
    p = np.asarray(fit_primitives(pts, target, (("cylinders", 1),), FAST).parameters[0])
    np.testing.assert_allclose(p[:3], c, atol=0.02)
    assert abs(p[3] - r) < 0.02 and abs(p[4] - h) < 0.02
    axis = quaternion_to_matrix(p[5:9])[:, 2]
    assert abs(axis[2]) > 0.99


def test_two_boxes_beat_one_on_an_l_shape(l_shape_samples):
    pts, sdf = l_shape_samples
    one = fit_primitives(pts, sdf, (("boxes", 1),), FAST)
    two = fit_primitives(pts, sdf, (("boxes", 2),), FAST)
    assert two.final_loss < 0.5 * one.final_loss


@pytest.mark.parametrize("parameterization", ["network", "direct"])
def test_network_and_direct_both_reduce_the_loss(l_shape_samples, parameterization):
    pts, sdf = l_shape_samples
    cfg = dataclasses.replace(FAST, parameterization=parameterization, init="random", max_iterations=150, min_iterations=150)
    res = fit_primitives(pts, sdf, (("rotated_boxes", 3),), cfg)
    start = np.mean(res.history[:2])
    end = np.mean(res.history[-2:])
    assert end < 0.3 * start
    assert np.all(np.isfinite(res.parameters))


def test_fit_is_repeatable_for_a_seed(l_shape_samples):
    pts, sdf = l_shape_samples
    # A batch large enough for torch's multi-threaded kernels, where bit-level nondeterminism lives.
    cfg = dataclasses.replace(
        FAST, parameterization="network", batch_size=8192, max_iterations=40, min_iterations=40, revive_dead=True, revive_every=20
    )
    a = fit_primitives(pts, sdf, (("boxes", 3), ("cylinders", 2)), cfg, seed=5)
    b = fit_primitives(pts, sdf, (("boxes", 3), ("cylinders", 2)), cfg, seed=5)
    assert a.parameters == b.parameters and a.kinds == b.kinds and a.final_loss == b.final_loss
    c = fit_primitives(pts, sdf, (("boxes", 3), ("cylinders", 2)), cfg, seed=6)
    assert c.parameters != a.parameters


def test_fit_reports_effective_count_after_removal(sphere_samples):
    pts, sdf, _, _ = sphere_samples
    res = fit_primitives(pts, sdf, (("spheres", 6),), dataclasses.replace(FAST, max_iterations=80, min_iterations=80))
    assert res.requested_count == 6 and 1 <= res.effective_count == len(res.parameters) <= 6
    kept = fit_primitives(pts, sdf, (("spheres", 6),), dataclasses.replace(FAST, max_iterations=80, min_iterations=80, remove_dead=False))
    assert kept.effective_count == 6


def test_rotation_penalty_eq13_zero_inside_quarter_pi_positive_outside():
    axis = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    axis = axis / axis.norm()

    def q(angle):
        return torch.cat((torch.tensor([math.cos(angle / 2)], dtype=torch.float64), math.sin(angle / 2) * axis))

    for angle in (0.0, 0.3, -0.7, math.pi / 4 - 1e-6):
        assert float(rotation_penalty(q(angle))) == pytest.approx(0.0, abs=1e-9)
        assert float(rotation_penalty(-2.0 * q(angle))) == pytest.approx(0.0, abs=1e-9)  # scale and sign free
    for angle in (1.0, -1.2, 2.5):
        assert float(rotation_penalty(q(angle))) == pytest.approx(abs(angle) - math.pi / 4, abs=1e-9)
    x = q(1.0).clone().requires_grad_(True)
    (g,) = torch.autograd.grad(rotation_penalty(x), x)
    assert torch.isfinite(g).all() and g.abs().sum() > 0
    x0 = q(0.0).clone().requires_grad_(True)
    (g0,) = torch.autograd.grad(rotation_penalty(x0), x0)
    assert torch.isfinite(g0).all()


def test_conversion_to_asset_frame_known_pose():
    qz30 = (math.cos(math.pi / 12), 0.0, 0.0, math.sin(math.pi / 12))
    res = FitResult(
        kinds=("box", "rotated_box", "cylinder", "sphere", "capsule", "ellipsoid"),
        parameters=(
            (0.1, 0.2, 0.3, 0.1, 0.2, 0.3),
            (0.0, 0.0, 0.0, 0.1, 0.2, 0.3, *qz30),
            (0.0, 0.0, -0.5, 0.2, 0.25, 1.0, 0.0, 0.0, 0.0),
            (0.5, 0.0, 0.0, 0.1),
            (0.0, 0.5, 0.0, 0.1, 0.2, 1.0, 0.0, 0.0, 0.0),
            (0.0, -0.5, 0.0, 0.1, 0.2, 0.3, *qz30),
        ),
        final_loss=0.0, iterations=0, fit_seconds=0.0, effective_count=6, requested_count=6, device="cpu",
    )  # fmt: skip
    geo = to_collision_geometry(res, centre_m=(1.0, 2.0, 3.0), scale_m=0.5, spec="boxes:1+rotated_boxes:1+cylinders:1+spheres:1+capsules:1+ellipsoids:1")
    box, rbox, cyl, sph, cap, ell = geo.shapes
    assert geo.name == "boxes_1_rotated_boxes_1_cylinders_1_spheres_1_capsules_1_ellipsoids_1"
    assert box.kind == "box" and box.quaternion_wxyz == (1.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(box.position_m, (1.05, 2.1, 3.15))
    np.testing.assert_allclose(box.size_m, (0.1, 0.2, 0.3))  # full edges = 2 * half * scale
    assert rbox.kind == "box"
    np.testing.assert_allclose(rbox.quaternion_wxyz, qz30)
    assert cyl.kind == "cylinder"
    np.testing.assert_allclose(cyl.size_m, (0.1, 0.25))  # radius, full length
    np.testing.assert_allclose(cyl.position_m, (1.0, 2.0, 2.75))
    assert sph.size_m == pytest.approx((0.05,))
    assert cap.kind == "capsule" and cap.size_m == pytest.approx((0.05, 0.2))
    assert ell.kind == "ellipsoid" and ell.size_m == pytest.approx((0.05, 0.1, 0.15))

    # The same points are inside in unit coordinates and, mapped, inside the collision shapes.
    rng = np.random.default_rng(0)
    unit = rng.uniform(-1.0, 1.0, size=(20_000, 3))
    inside_unit = result_sdf(res, unit) < 0
    inside_m = inside_collision(geo, None, np.array([1.0, 2.0, 3.0]) + 0.5 * unit)
    assert inside_unit.sum() > 500
    assert np.mean(inside_unit == inside_m) > 0.999


def test_mix_fits_both_kinds_jointly(l_shape_samples):
    pts, sdf = l_shape_samples
    cfg = dataclasses.replace(FAST, max_iterations=60, min_iterations=60, remove_dead=False)
    res = fit_primitives(pts, sdf, (("boxes", 2), ("cylinders", 2)), cfg)
    assert res.kinds == ("box", "box", "cylinder", "cylinder")
    geo = to_collision_geometry(res, np.zeros(3), 0.1, "boxes:2+cylinders:2")
    assert {s.kind for s in geo.shapes} == {"box", "cylinder"}
    assert geo.spec == "boxes:2+cylinders:2"


def test_fit_collision_on_a_mesh_gives_metres_in_the_asset_frame():
    import trimesh

    from real2sim.collision.sdf_sampling import SdfSamplingConfig
    from real2sim.collision.fit.stage import fit_collision
    from real2sim.formats.spec import parse_spec

    from tests.progress_check import Recorder

    mesh = trimesh.creation.box(extents=(0.04, 0.06, 0.1))
    mesh.apply_translation((0.01, 0.0, 0.02))
    progress = Recorder()
    geo, report = fit_collision(
        mesh,
        parse_spec("boxes:2"),
        fit_config=dataclasses.replace(FAST, max_iterations=150, min_iterations=150),
        sampling_config=SdfSamplingConfig(num_surface_samples=20_000, num_uniform_samples=200),
        cache_dir=None,
        progress=progress,
    )
    messages = {message for message, _, _ in progress.check()}
    assert "fit" in messages and any(m.startswith("sdf: ") for m in messages)
    assert geo.name == "boxes_2" and 1 <= len(geo.shapes) == report["effective_count"] <= 2
    assert set(report) >= {"final_loss", "fit_seconds", "effective_count", "iterations", "device"}
    lo = np.min([np.asarray(s.position_m) - 0.5 * np.asarray(s.size_m) for s in geo.shapes], axis=0)
    hi = np.max([np.asarray(s.position_m) + 0.5 * np.asarray(s.size_m) for s in geo.shapes], axis=0)
    np.testing.assert_allclose(lo, mesh.bounds[0], atol=0.004)  # metres, the box's own frame
    np.testing.assert_allclose(hi, mesh.bounds[1], atol=0.004)


def test_fit_leaves_torch_global_state_as_found(box_samples):
    pts, sdf, _, _ = box_samples
    torch.manual_seed(1234)
    rng_before = torch.get_rng_state().clone()
    threads_before = torch.get_num_threads()
    deterministic_before = torch.are_deterministic_algorithms_enabled()
    cuda_before = torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None
    config = dataclasses.replace(FAST, max_iterations=20, min_iterations=20)
    fit_primitives(pts, sdf, (("boxes", 2),), config, seed=7)
    assert torch.are_deterministic_algorithms_enabled() == deterministic_before
    assert torch.get_num_threads() == threads_before
    assert torch.equal(torch.get_rng_state(), rng_before)
    if cuda_before is not None:
        assert all(torch.equal(a, b) for a, b in zip(torch.cuda.get_rng_state_all(), cuda_before))


def test_protrusion_weight_scales_only_outside_samples_the_union_reaches_past():
    predicted = torch.tensor([0.05, 0.15, -0.02, 0.30, 0.10])
    target = torch.tensor([0.10, 0.10, -0.05, -0.10, 0.10])  # too near, too far, inside x2, exact
    plain = sdf_loss(predicted, target, "squared")
    # 0 is eq. 9 as before the option, bit for bit
    assert torch.equal(sdf_loss(predicted, target, "squared", 0.0), plain)
    weighted = sdf_loss(predicted, target, "squared", 4.0)
    assert weighted[0] == pytest.approx(5.0 * float(plain[0]))  # the union reaches past the surface
    assert torch.equal(weighted[1:], plain[1:])  # inset, inside and exact samples keep their loss
    with pytest.raises(ValueError):
        FitConfig(protrusion_weight=-1.0)


def _reach_past_cylinder(result, c, r: float, h: float) -> float:
    """How far (unit lengths) the fitted union reaches outside the capped cylinder: the largest
    cylinder signed distance among grid points inside the union."""
    g = np.linspace(-1.0, 1.0, 61)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    inside = pts[result_sdf(result, pts) < 0]
    q = inside - c
    dr, dz = np.hypot(q[:, 0], q[:, 1]) - r, np.abs(q[:, 2]) - h
    return float((np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)) + np.minimum(np.maximum(dr, dz), 0)).max())


def test_protrusion_weight_keeps_the_union_inside_the_object():
    # One ellipsoid cannot be a cylinder: eq. 9's symmetric square lets it bulge past the side
    # where the cylinder's corners pull it out; weighted, it stays nearer inside.
    c, r, h = np.zeros(3), 0.4, 0.6
    pts, target = cylinder_samples(c, r, h)
    reach = {}
    for w in (0.0, 16.0):
        result = fit_primitives(pts, target, (("ellipsoids", 1),), dataclasses.replace(FAST, protrusion_weight=w))
        reach[w] = _reach_past_cylinder(result, c, r, h)
    assert reach[0.0] > 0.02, reach  # the symmetric fit does reach past the side
    assert reach[16.0] < 0.5 * reach[0.0], reach


def test_bad_config_rejected():
    with pytest.raises(ValueError):
        FitConfig(parameterization="magic")
    with pytest.raises(ValueError):
        FitConfig(init="grid")
    with pytest.raises(ValueError):
        fit_primitives(np.zeros((5, 2)), np.zeros(5), (("boxes", 1),), FAST)


@pytest.mark.cuda
def test_cuda_matches_cpu(box_samples):
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    pts, sdf, _, _ = box_samples
    cfg = dataclasses.replace(FAST, max_iterations=100, min_iterations=100)
    cpu = fit_primitives(pts, sdf, (("boxes", 1),), cfg, device="cpu")
    gpu = fit_primitives(pts, sdf, (("boxes", 1),), cfg, device="cuda")
    assert gpu.device.startswith("cuda")
    np.testing.assert_allclose(np.asarray(gpu.parameters), np.asarray(cpu.parameters), atol=0.02)
    assert gpu.final_loss == pytest.approx(cpu.final_loss, rel=0.5, abs=1e-5)
