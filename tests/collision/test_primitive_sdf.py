"""Primitive SDFs against brute-force distances to dense meshes of the same shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from real2sim.formats.rotations import quaternion_to_matrix as np_quat_to_matrix
from real2sim.geometry.inside import signed_distance
from real2sim.collision.primitive_sdf import (
    EXPONENT_DIM,
    HAS_ROTATION,
    PARAM_DIM,
    SIZE_DIM,
    box_sdf,
    capsule_sdf,
    cylinder_sdf,
    ellipsoid_sdf,
    primitive_sdf,
    quaternion_to_matrix,
    rotated_box_sdf,
    sphere_sdf,
    union_sdf,
)

RNG = np.random.default_rng(7)
CENTRE = np.array([0.1, -0.2, 0.05])
Q = np.array([math.cos(0.35), math.sin(0.35) * 0.6, math.sin(0.35) * 0.0, math.sin(0.35) * 0.8])  # unit


def _pose(mesh: trimesh.Trimesh, quat=None) -> trimesh.Trimesh:
    t = np.eye(4)
    if quat is not None:
        t[:3, :3] = np_quat_to_matrix(quat)
    t[:3, 3] = CENTRE
    return mesh.copy().apply_transform(t)


def _brute(mesh: trimesh.Trimesh, pts: np.ndarray) -> np.ndarray:
    """Signed distance to the nearest triangle of a dense mesh (libigl), sign by winding number."""
    return signed_distance(mesh, pts)


def _queries(n: int = 400, spread: float = 0.6) -> np.ndarray:
    return CENTRE + RNG.uniform(-spread, spread, size=(n, 3))


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float64))


def _check(pred: torch.Tensor, mesh: trimesh.Trimesh, pts: np.ndarray, tol: float) -> None:
    expected = _brute(mesh, pts)
    got = pred.detach().numpy().reshape(-1)
    np.testing.assert_allclose(got, expected, atol=tol)
    far = np.abs(expected) > tol
    assert np.all(np.sign(got[far]) == np.sign(expected[far]))


def test_sphere_matches_mesh_distance():
    mesh = _pose(trimesh.creation.icosphere(subdivisions=5, radius=0.3))
    pts = _queries()
    d = sphere_sdf(_t(pts), _t([CENTRE]), _t([0.3]))
    assert d.shape == (1, len(pts))
    _check(d, mesh, pts, tol=2e-3)  # faceting of the icosphere


def test_axis_aligned_box_exact():
    half = np.array([0.2, 0.1, 0.3])
    mesh = _pose(trimesh.creation.box(extents=2 * half))
    pts = _queries()
    _check(box_sdf(_t(pts), _t([CENTRE]), _t([half])), mesh, pts, tol=1e-9)


def test_rotated_box_exact():
    half = np.array([0.2, 0.1, 0.3])
    mesh = _pose(trimesh.creation.box(extents=2 * half), Q)
    pts = _queries()
    _check(rotated_box_sdf(_t(pts), _t([CENTRE]), _t([half]), _t([Q])), mesh, pts, tol=1e-9)


def test_cylinder_exact_axis_along_rotated_z():
    mesh = _pose(trimesh.creation.cylinder(radius=0.15, height=0.5, sections=512), Q)
    pts = _queries()
    d = cylinder_sdf(_t(pts), _t([CENTRE]), _t([0.15]), _t([0.25]), _t([Q]))
    _check(d, mesh, pts, tol=2e-5 + 0.15 * (1 - math.cos(math.pi / 512)))


def test_capsule_exact():
    # trimesh's capsule: ``height`` is the distance between the two hemisphere centres.
    mesh = _pose(trimesh.creation.capsule(height=0.4, radius=0.12, count=[128, 128]), Q)
    pts = _queries()
    d = capsule_sdf(_t(pts), _t([CENTRE]), _t([0.12]), _t([0.2]), _t([Q]))
    _check(d, mesh, pts, tol=5e-4)


def check_estimate(d: np.ndarray, exact: np.ndarray, sign_tol: float, band: float, min_near: int,
                   rel: float, atol: float) -> None:
    """An estimated (not exact) signed distance ``d`` against brute force ``exact``: the right sign
    wherever |exact| > sign_tol, and, within ``band`` of the surface (at least ``min_near``
    points), an error below ``rel * |exact| + atol``."""
    far = np.abs(exact) > sign_tol
    assert np.all(np.sign(d[far]) == np.sign(exact[far]))
    near = np.abs(exact) < band
    assert near.sum() > min_near
    assert np.all(np.abs(d[near] - exact[near]) < rel * np.abs(exact[near]) + atol)


def test_ellipsoid_bound_sign_everywhere_and_close_near_surface():
    axes = np.array([0.3, 0.15, 0.2])
    sphere = trimesh.creation.icosphere(subdivisions=6)
    sphere.apply_scale(axes)
    mesh = _pose(sphere, Q)
    pts = _queries(600)
    d = ellipsoid_sdf(_t(pts), _t([CENTRE]), _t([axes]), _t([Q])).numpy()[0]
    check_estimate(d, _brute(mesh, pts), sign_tol=2e-3, band=0.03, min_near=10, rel=0.2, atol=2e-3)


def test_dense_and_paired_agree_for_every_kind():
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(50, 3, generator=gen, dtype=torch.float64) - 0.5
    for kind, dim in PARAM_DIM.items():
        packed = torch.rand(7, dim, generator=gen, dtype=torch.float64) * 0.3 + 0.05
        packed[:, :3] -= 0.2
        dense = primitive_sdf(kind, x, packed)
        assert dense.shape == (7, 50)
        for j in range(7):
            paired = primitive_sdf(kind, x, packed[j].expand(50, dim), paired=True)
            torch.testing.assert_close(paired, dense[j])


def test_union_is_minimum_and_gradients_finite_at_singular_points():
    # Points at a sphere centre, on box edges/corners and on a cylinder axis: sqrt/abs kinks.
    x = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.1, 0.3], [0.2, 0.0, 0.0], [0.0, 0.0, 0.25]], dtype=torch.float64)
    for kind in PARAM_DIM:
        packed = torch.tensor([[0.0, 0.0, 0.0] + [0.2, 0.1, 0.3][: SIZE_DIM[kind]] + [0.02, 1.0][: EXPONENT_DIM[kind]]
                               + ([1.0, 0.0, 0.0, 0.0] if HAS_ROTATION[kind] else [])], dtype=torch.float64)
        if kind in ("cylinder", "capsule"):
            packed[0, 3:5] = torch.tensor([0.1, 0.25])
        packed.requires_grad_(True)
        d = primitive_sdf(kind, x, packed)
        (g,) = torch.autograd.grad(d.sum(), packed)
        assert torch.isfinite(d).all() and torch.isfinite(g).all(), kind
    d = torch.tensor([[0.3, -0.1, 2.0], [0.1, 0.2, -0.5]])
    torch.testing.assert_close(union_sdf(d), torch.tensor([0.1, -0.1, -0.5]))


def test_quaternion_matrix_matches_numpy_and_normalises():
    r = quaternion_to_matrix(_t(2.5 * Q)).numpy()
    np.testing.assert_allclose(r, np_quat_to_matrix(Q), atol=1e-12)


@pytest.mark.parametrize("kind", sorted(PARAM_DIM))
def test_unknown_size_layout_round_trip(kind):
    # Sign sanity for every kind: the centre is inside, a far point outside.
    packed = torch.zeros(1, PARAM_DIM[kind], dtype=torch.float64)
    packed[0, 3:] = 0.2
    if HAS_ROTATION[kind]:
        packed[0, -4:] = torch.tensor([1.0, 0, 0, 0])
    d = primitive_sdf(kind, torch.tensor([[0.0, 0, 0], [3.0, 0, 0]], dtype=torch.float64), packed)[0]
    assert d[0] < 0 < d[1]
