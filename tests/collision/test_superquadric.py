"""Superquadrics: their SDF estimate, their convex polytope, their fit, and Drake resting on them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from real2sim.formats.collision import CollisionGeometry
from real2sim.formats.rotations import quaternion_to_matrix
from real2sim.geometry.collision_mesh import union_mesh
from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.convert import to_collision_geometry
from real2sim.collision.fit.loop import fit_primitives
from real2sim.geometry.inside import signed_distance
from real2sim.collision.primitive_sdf import ellipsoid_sdf, primitive_sdf, superquadric_sdf
from real2sim.formats.spec import parse_spec
from real2sim.collision.superquadric import inside_outside, superquadric_hull, volume
from tests.collision.test_fitting import _box_sdf_np, _box_surface, _near_surface, cylinder_samples
from tests.collision.test_primitive_sdf import check_estimate

CENTRE = np.array([0.1, -0.2, 0.05])
Q = np.array([math.cos(0.35), math.sin(0.35) * 0.6, 0.0, math.sin(0.35) * 0.8])
AXES = np.array([0.3, 0.15, 0.2])
SHAPES = [(1.0, 1.0), (0.5, 1.5), (1.0, 0.3), (0.2, 1.0), (0.1, 0.1)]


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float64))


def _posed(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    t = np.eye(4)
    t[:3, :3] = quaternion_to_matrix(Q)
    t[:3, 3] = CENTRE
    return mesh.copy().apply_transform(t)


@pytest.mark.parametrize("exponents", SHAPES)
def test_sdf_sign_everywhere_and_close_near_surface(exponents):
    # Brute force: distance to a dense polytope of the same superquadric (20k vertices).
    dense = _posed(superquadric_hull(AXES, exponents, num_vertices=20_000))
    rng = np.random.default_rng(0)
    pts = CENTRE + rng.uniform(-0.45, 0.45, size=(1500, 3))
    exact = signed_distance(dense, pts)
    d = superquadric_sdf(_t(pts), _t([CENTRE]), _t([AXES]), _t([exponents]), _t([Q])).numpy()[0]
    # First-order estimate: exact on the surface, error growing with the distance from it
    # (and, for sharp shapes, bounded by the L-infinity-like behaviour at edges).
    check_estimate(d, exact, sign_tol=3e-3, band=0.02, min_near=30, rel=0.5, atol=3e-3)


def test_exponents_one_give_the_ellipsoid_estimate_exactly():
    pts = _t(np.random.default_rng(1).normal(size=(500, 3)) * 0.4)
    a = superquadric_sdf(pts, _t([CENTRE]), _t([AXES]), _t([[1.0, 1.0]]), _t([Q]))
    b = ellipsoid_sdf(pts, _t([CENTRE]), _t([AXES]), _t([Q]))
    torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def test_float32_stays_finite_for_sharp_small_primitives_far_away():
    # |x/a|^(2/e) would overflow float32 here without the log-space evaluation.
    pts = torch.tensor([[1.3, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.3], [1.0, 1.0, 1.0]])
    packed = torch.tensor([[0.0, 0.0, 0.0, 0.004, 0.004, 0.004, 0.02, 0.02, 1.0, 0.0, 0.0, 0.0]], requires_grad=True)
    d = primitive_sdf("superquadric", pts, packed)
    (g,) = torch.autograd.grad(d.sum(), packed)
    assert torch.isfinite(d).all() and torch.isfinite(g).all()
    assert d[0, 1] < 0 < d[0, 0] and d[0, 2] > 1.2


@pytest.mark.parametrize("exponents", SHAPES + [(2.0, 2.0), (0.02, 1.0)])
def test_volume_formula_and_volume_matched_convex_hull(exponents):
    rng = np.random.default_rng(2)
    pts = (rng.random((300_000, 3)) * 2 - 1) * AXES
    inside = inside_outside(pts, AXES, exponents) < 1
    box_volume = 8 * np.prod(AXES)
    mc = inside.mean() * box_volume
    assert volume(AXES, exponents) == pytest.approx(mc, abs=4 * box_volume * math.sqrt(0.25 / len(pts)))
    hull = superquadric_hull(AXES, exponents)
    assert len(hull.vertices) <= 128 and hull.is_watertight and hull.is_convex
    assert hull.volume == pytest.approx(volume(AXES, exponents), rel=1e-9)
    in_hull = hull.contains(pts)
    assert (inside & in_hull).sum() / (inside | in_hull).sum() > 0.96


def test_sphere_closed_form_and_bad_parameters():
    assert volume((1, 1, 1), (1, 1)) == pytest.approx(4 / 3 * math.pi)
    assert volume((1, 2, 3), (1e-9, 1e-9)) == pytest.approx(48.0, rel=1e-6)  # the box limit
    with pytest.raises(ValueError, match="convex"):
        superquadric_hull(AXES, (2.5, 1.0))
    with pytest.raises(ValueError, match="positive"):
        superquadric_hull((0.1, -0.1, 0.1), (1.0, 1.0))


FAST = FitConfig(batch_size=4096, max_iterations=400, min_iterations=400, revive_dead=False)


def test_fit_finds_a_box_and_a_cylinder_by_their_exponents():
    rng = np.random.default_rng(2)
    c, half = np.array([-0.1, 0.05, 0.1]), np.array([0.3, 0.2, 0.5])
    pts, sdf = _near_surface(lambda p: _box_sdf_np(p, c, half), _box_surface(c, half, 12_000, rng))
    box = np.asarray(fit_primitives(pts, sdf, (("superquadrics", 1),), FAST).parameters[0])
    assert box[6] < 0.25 and box[7] < 0.25  # square profile and square section
    np.testing.assert_allclose(box[:3], c, atol=0.02)
    # The box's axes in some order (the fit may rotate the superquadric by quarter turns).
    axes_world = np.abs(quaternion_to_matrix(box[8:12])) @ box[3:6]
    np.testing.assert_allclose(axes_world, half, atol=0.03)

    pts, sdf = cylinder_samples(np.array([0.05, -0.1, 0.0]), 0.3, 0.6)
    cyl = np.asarray(fit_primitives(pts, sdf, (("superquadrics", 1),), FAST).parameters[0])
    # Round section (e2 = 1) around the axis, flat profile (e1 small) along it.
    axis = int(np.argmax(np.abs(quaternion_to_matrix(cyl[8:12])[2, :])))
    assert axis == 2, "the cylinder's axis should be the superquadric's own z"
    assert cyl[6] < 0.25 and 0.8 < cyl[7] < 1.25


def test_conversion_writes_posed_convex_pieces_in_metres(tmp_path):
    from real2sim.collision.fit.config import FitResult

    row = (0.1, 0.0, -0.2, 0.2, 0.1, 0.3, 0.3, 1.0) + tuple(Q)
    res = FitResult(kinds=("superquadric", "sphere"), parameters=(row, (0.0, 0.0, 0.0, 0.1)), final_loss=0.0,
                    iterations=1, fit_seconds=0.0, effective_count=2, requested_count=2, device="cpu")
    with pytest.raises(ValueError, match="rep_dir"):
        to_collision_geometry(res, (1.0, 2.0, 3.0), 0.5, "superquadrics:1+spheres:1")
    geo = to_collision_geometry(res, (1.0, 2.0, 3.0), 0.5, "superquadrics:1+spheres:1", tmp_path)
    piece = geo.shapes[0]
    assert piece.kind == "convex" and (tmp_path / piece.mesh_file).exists()
    np.testing.assert_allclose(piece.position_m, (1.05, 2.0, 2.9))
    np.testing.assert_allclose(piece.quaternion_wxyz, Q, atol=1e-12)
    hull = trimesh.load(tmp_path / piece.mesh_file, force="mesh")
    assert hull.volume == pytest.approx(volume((0.1, 0.05, 0.15), (0.3, 1.0)), rel=1e-3)
    # The union the fidelity metrics see: the posed polytope plus the sphere.
    union = union_mesh(CollisionGeometry(geo.name, geo.spec, geo.shapes[:1]), tmp_path)
    assert union.volume == pytest.approx(hull.volume, rel=1e-6)
    np.testing.assert_allclose(union.centroid, piece.position_m, atol=1e-6)


def test_spec_family():
    spec = parse_spec("superquadrics:2+cylinders:1")
    assert spec.parts == (("superquadrics", 2), ("cylinders", 1)) and spec.name == "superquadrics_2_cylinders_1"


def test_asset_cli_writes_a_drake_loadable_superquadric_representation(tmp_path, capsys):
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    from real2sim.cli import main
    from real2sim.geometry.objects import OBJECTS, make_object

    mesh_path = tmp_path / "can.obj"
    make_object("can").export(mesh_path)
    out = tmp_path / "asset"
    code = main(["asset", str(mesh_path), "--mass-kg", str(OBJECTS["can"].mass_kg), "--out", str(out),
                 "--collision", "superquadrics:2", "--iterations", "200"])
    assert code == 0, capsys.readouterr().err
    rep = out / "superquadrics_2"
    shapes = json.loads((rep / "collision.json").read_text())["shapes"]
    assert {s["type"] for s in shapes} == {"convex"} and 1 <= len(shapes) <= 2
    report = json.loads((rep / "fit_report.json").read_text())
    assert report["iou"] > 0.8
    assert len(report["superquadrics"]) == len(shapes)
    assert all(0.02 <= e <= 2.0 for sq in report["superquadrics"] for e in sq["exponents"])
    plant = MultibodyPlant(0.001)
    Parser(plant).AddModels(str(rep / "model.urdf"))
    plant.Finalize()
    assert plant.num_bodies() == 2  # world + the object


@pytest.mark.parametrize("contact_model", ["point", "hydroelastic"])
def test_a_box_of_two_superquadrics_rests_on_the_floor_in_drake(tmp_path, contact_model):
    """Two box-like superquadric pieces, one turned a quarter about z, resting in Drake: the
    pieces' poses and volume-matched polytopes reach the simulator as written."""
    from tests.asset.test_drake_rest import CHATTER_M_PER_S, RestObject, check_rest, simulate_drop

    from real2sim.asset.export.writers import write_representation
    from real2sim.formats.contact import ContactProperties
    from real2sim.collision.fit.config import FitResult
    from real2sim.formats.physical import PhysicalProperties

    quarter_z = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    rows = (
        (0.0, 0.0, -0.03, 0.025, 0.035, 0.03, 0.05, 0.05, 1.0, 0.0, 0.0, 0.0),
        (0.0, 0.0, 0.03, 0.035, 0.025, 0.03, 0.05, 0.05) + quarter_z,  # same box, axes swapped by the turn
    )
    res = FitResult(kinds=("superquadric",) * 2, parameters=rows, final_loss=0.0, iterations=1, fit_seconds=0.0,
                    effective_count=2, requested_count=2, device="cpu")
    rep = tmp_path / "superquadrics_2"
    geo = to_collision_geometry(res, (0.0, 0.0, 0.0), 1.0, "superquadrics:2", rep)
    mesh = union_mesh(geo, rep)
    (tmp_path / "visual").mkdir()
    mesh.export(tmp_path / "visual" / "model.obj")  # the writer links the asset's visual mesh
    assert mesh.extents == pytest.approx((0.05, 0.07, 0.12), rel=0.02)
    m = 0.3
    inertia = m / 12 * np.diag([0.07**2 + 0.12**2, 0.05**2 + 0.12**2, 0.05**2 + 0.07**2])
    props = PhysicalProperties(m, (0.0, 0.0, 0.0), tuple(map(tuple, inertia)), method="closed form")
    write_representation(rep, geo, props, ContactProperties(), formats=("urdf",))
    obj = RestObject("superquadric box", mesh, props, geo)
    drop = simulate_drop(rep / "model.urdf", obj, contact_model)
    check_rest(obj, drop, CHATTER_M_PER_S if contact_model == "point" else 1e-3)
    if contact_model == "hydroelastic":
        assert drop.num_surfaces >= 1 and drop.num_point_pairs == 0


def test_exponents_stay_in_the_convex_range_whatever_the_raw_parameters():
    from real2sim.collision.fit.params import constrain

    raw = torch.tensor([[0.0, 0.0, 0.0, 0.1, 0.1, 0.1, -50.0, 50.0, 1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    packed = constrain("superquadric", raw, 0.004, FitConfig().superquadric_exponent_gain)
    assert 0.02 <= float(packed[0, 6]) < 0.021 and 1.99 < float(packed[0, 7]) <= 2.0
