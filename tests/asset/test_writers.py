"""URDF/SDFormat writer: every shape kind read back by Drake's own parser.

The poses are the part that goes wrong silently (roll-pitch-yaw conventions), so
each collision element's pose in the body frame is compared, as a rotation matrix
and a translation, with the intended quaternion and position.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

from real2sim.asset.export.writers import LINK_NAME, write_model_urdf_string, write_representation
from real2sim.formats.rotations import quaternion_to_rpy, rpy_to_matrix
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.rotations import quaternion_to_matrix
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties

pydrake = pytest.importorskip("pydrake")
from pydrake.geometry import (  # noqa: E402
    AddRigidHydroelasticProperties,
    Box,
    Capsule,
    Convex,
    Cylinder,
    Ellipsoid,
    HalfSpace,
    HydroelasticContactRepresentation,
    Mesh,
    ProximityProperties,
    Sphere,
)
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix  # noqa: E402
from pydrake.common.eigen_geometry import Quaternion  # noqa: E402
from pydrake.multibody.parsing import Parser  # noqa: E402
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction  # noqa: E402
from pydrake.systems.framework import DiagramBuilder  # noqa: E402


def _unit(q) -> tuple[float, float, float, float]:
    q = np.asarray(q, dtype=float)
    return tuple(float(v) for v in q / np.linalg.norm(q))


QUATS = [
    _unit([0.9, 0.2, -0.3, 0.25]),
    _unit([0.3, -0.7, 0.1, 0.6]),
    _unit([0.1, 0.5, 0.8, -0.3]),
    _unit([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]),  # pitch = +90 deg: gimbal lock
    _unit([0.5, 0.5, -0.5, 0.5]),
    _unit([0.2, -0.1, 0.3, -0.9]),
    _unit([-0.4, 0.3, 0.6, 0.62]),  # w < 0 on purpose
]


def _piece_vertices() -> np.ndarray:
    """An irregular convex polyhedron, off-centre in its own frame."""
    rng = np.random.default_rng(3)
    return rng.normal(size=(24, 3)) * np.array([0.01, 0.015, 0.02]) + np.array([0.004, -0.002, 0.003])


def _make_asset(root: Path) -> tuple[Path, CollisionGeometry]:
    """ASSET/visual/model.obj (with normals) and ASSET/rep/pieces/piece_000.obj; returns (rep_dir, geometry)."""
    (root / "visual").mkdir(parents=True)
    visual = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    visual.export(root / "visual" / "model.obj", include_normals=True)
    rep = root / "rep"
    (rep / "pieces").mkdir(parents=True)
    trimesh.convex.convex_hull(_piece_vertices()).export(rep / "pieces" / "piece_000.obj")
    shapes = (
        CollisionShape("box", (0.01, 0.02, 0.035), (0.03, -0.01, 0.02), QUATS[0]),
        CollisionShape("sphere", (0.012,), (-0.02, 0.015, 0.04), QUATS[1]),
        CollisionShape("cylinder", (0.011, 0.05), (0.005, 0.025, -0.03), QUATS[2]),
        CollisionShape("ellipsoid", (0.01, 0.02, 0.03), (-0.015, -0.02, 0.01), QUATS[3]),
        CollisionShape("capsule", (0.008, 0.03), (0.02, 0.02, -0.01), QUATS[4]),
        CollisionShape("convex", (), (0.01, -0.03, 0.015), QUATS[5], "pieces/piece_000.obj"),
        CollisionShape("mesh", (), (-0.01, 0.0, -0.02), QUATS[6], "pieces/piece_000.obj"),
    )
    return rep, CollisionGeometry(name="test", spec="test", shapes=shapes)


def _props() -> PhysicalProperties:
    rot = quaternion_to_matrix(QUATS[2])
    inertia = rot @ np.diag([2.0e-4, 3.0e-4, 4.5e-4]) @ rot.T  # off-diagonal terms on purpose
    inertia = 0.5 * (inertia + inertia.T)
    return PhysicalProperties(
        mass_kg=0.437, com_m=(0.004, -0.003, 0.011), inertia_kg_m2=tuple(tuple(float(v) for v in r) for r in inertia)
    )


CONTACT = ContactProperties(
    hydroelastic="compliant",
    hydroelastic_modulus_pa=3.5e6,
    hunt_crossley_dissipation_s_per_m=2.5,
    point_contact_stiffness_n_per_m=2.0e4,
    point_stiffness_per_piece=False,  # each piece reads back the stiffness as given (the share: test_point_contact)
    mu_static=0.7,
    mu_dynamic=0.45,
    resolution_hint_m=0.004,
)


def _load(model_file: Path, time_step: float = 1e-3):
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step)
    Parser(plant).AddModels(str(model_file))
    return builder, plant, scene_graph


def _collision_by_index(plant, scene_graph) -> dict[int, object]:
    inspector = scene_graph.model_inspector()
    out = {}
    for gid in plant.GetCollisionGeometriesForBody(plant.GetBodyByName(LINK_NAME)):
        name = inspector.GetName(gid)
        out[int(name.rsplit("collision_", 1)[1])] = gid
    return out


@pytest.fixture()
def asset(tmp_path):
    rep, geometry = _make_asset(tmp_path / "ASSET")
    write_representation(rep, geometry, _props(), CONTACT, formats=("urdf", "sdf"))
    return rep, geometry


def test_rpy_matches_drake_convention():
    rng = np.random.default_rng(0)
    quats = [_unit(q) for q in rng.normal(size=(200, 4))] + QUATS
    for q in quats:
        rpy = quaternion_to_rpy(q)
        drake_rot = RotationMatrix(RollPitchYaw(rpy)).matrix()
        np.testing.assert_allclose(drake_rot, quaternion_to_matrix(q), atol=1e-12)
        np.testing.assert_allclose(rpy_to_matrix(rpy), quaternion_to_matrix(q), atol=1e-12)
        # and the other way: Drake's own conversion gives the same rotation
        w, x, y, z = q
        drake_rpy = RollPitchYaw(RotationMatrix(Quaternion(w, x, y, z))).vector()
        np.testing.assert_allclose(rpy_to_matrix(drake_rpy), quaternion_to_matrix(q), atol=1e-12)


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_collision_poses_and_shapes_read_back(asset, fmt):
    rep, geometry = asset
    _, plant, scene_graph = _load(rep / f"model.{fmt}")
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    by_index = _collision_by_index(plant, scene_graph)
    assert sorted(by_index) == list(range(len(geometry.shapes)))
    piece_file = (rep / "pieces" / "piece_000.obj").resolve()
    for k, shape in enumerate(geometry.shapes):
        gid = by_index[k]
        pose = inspector.GetPoseInFrame(gid)  # X_BG, body frame = asset frame
        np.testing.assert_allclose(pose.rotation().matrix(), quaternion_to_matrix(shape.quaternion_wxyz), atol=1e-12)
        np.testing.assert_allclose(pose.translation(), shape.position_m, atol=1e-15)
        drake_shape = inspector.GetShape(gid)
        s = shape.size_m
        if shape.kind == "box":
            assert isinstance(drake_shape, Box)
            np.testing.assert_allclose([drake_shape.width(), drake_shape.depth(), drake_shape.height()], s)
        elif shape.kind == "sphere":
            assert isinstance(drake_shape, Sphere) and drake_shape.radius() == pytest.approx(s[0], rel=1e-15)
        elif shape.kind == "cylinder":
            assert isinstance(drake_shape, Cylinder)
            np.testing.assert_allclose([drake_shape.radius(), drake_shape.length()], s)
        elif shape.kind == "ellipsoid":
            assert isinstance(drake_shape, Ellipsoid)
            np.testing.assert_allclose([drake_shape.a(), drake_shape.b(), drake_shape.c()], s)
        elif shape.kind == "capsule":
            assert isinstance(drake_shape, Capsule)
            np.testing.assert_allclose([drake_shape.radius(), drake_shape.length()], s)
        elif shape.kind == "convex":
            assert isinstance(drake_shape, Convex)
            assert Path(drake_shape.source().path()).resolve() == piece_file
            np.testing.assert_allclose(drake_shape.scale3(), [1, 1, 1])
            hull = drake_shape.GetConvexHull()  # in the geometry frame: the piece's own vertices
            hull_vertices = np.array([hull.vertex(i) for i in range(hull.num_vertices())])
            expected = trimesh.convex.convex_hull(_piece_vertices()).vertices
            assert len(hull_vertices) == len(expected)
            np.testing.assert_allclose(np.sort(hull_vertices, axis=0), np.sort(expected, axis=0), atol=1e-7)
        else:
            assert isinstance(drake_shape, Mesh) and not isinstance(drake_shape, Convex)
            assert Path(drake_shape.source().path()).resolve() == piece_file


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_inertial_read_back(asset, fmt):
    rep, _ = asset
    props = _props()
    _, plant, _ = _load(rep / f"model.{fmt}")
    plant.Finalize()
    body = plant.GetBodyByName(LINK_NAME)
    spatial = body.default_spatial_inertia()  # about the body origin, in body axes
    assert spatial.get_mass() == pytest.approx(props.mass_kg, rel=1e-14)
    np.testing.assert_allclose(spatial.get_com(), props.com_m, atol=1e-15)
    about_com = spatial.Shift(spatial.get_com()).CalcRotationalInertia().CopyToFullMatrix3()
    np.testing.assert_allclose(about_com, props.inertia, rtol=1e-10, atol=1e-14)
    # the off-diagonal terms are really there (sign conventions of ixy & co. checked above)
    assert abs(props.inertia[0, 1]) > 1e-6 and abs(props.inertia[1, 2]) > 1e-6


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_proximity_properties_read_back(asset, fmt):
    rep, geometry = asset
    _, plant, scene_graph = _load(rep / f"model.{fmt}")
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    for k, gid in _collision_by_index(plant, scene_graph).items():
        props = inspector.GetProximityProperties(gid)
        friction = props.GetProperty("material", "coulomb_friction")
        assert friction.static_friction() == pytest.approx(CONTACT.mu_static)
        assert friction.dynamic_friction() == pytest.approx(CONTACT.mu_dynamic)
        assert props.GetProperty("material", "hunt_crossley_dissipation") == pytest.approx(2.5)
        assert props.GetProperty("material", "point_contact_stiffness") == pytest.approx(2.0e4)
        assert props.GetProperty("hydroelastic", "resolution_hint") == pytest.approx(0.004)
        if geometry.shapes[k].kind == "mesh":  # written rigid: a compliant .obj would become its hull
            assert not props.HasProperty("hydroelastic", "hydroelastic_modulus")
        else:
            assert props.GetProperty("hydroelastic", "hydroelastic_modulus") == pytest.approx(3.5e6)


def _contact_kinds(model_file: Path) -> tuple[set[str], set[str]]:
    """Names of the object's geometries in hydroelastic surfaces and in point pairs against a rigid ground.

    The body sits at the identity pose, so the plane z = 0 cuts every shape placed at z = 0.
    Compliant shapes against the rigid hydroelastic half-space give contact surfaces;
    rigid ones fall back to point contact.
    """
    builder, plant, scene_graph = _load(model_file)
    ground = ProximityProperties()
    AddRigidHydroelasticProperties(ground)
    ground.AddProperty("material", "coulomb_friction", CoulombFriction(0.5, 0.5))
    plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "ground", ground)
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    inspector = query.inspector()
    surfaces, pairs = query.ComputeContactSurfacesWithFallback(HydroelasticContactRepresentation.kPolygon)
    in_surfaces = {inspector.GetName(g) for s in surfaces for g in (s.id_M(), s.id_N())}
    in_pairs = {inspector.GetName(g) for p in pairs for g in (p.id_A, p.id_B)}
    return in_surfaces - {"ground"}, in_pairs - {"ground"}


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_hydroelastic_type_behaves_as_written(tmp_path, fmt):
    rep, geometry = _make_asset(tmp_path / "ASSET")
    # every shape straddles z = 0 (its centre is on the plane), rotated as before
    flat = tuple(
        CollisionShape(s.kind, s.size_m, (s.position_m[0], s.position_m[1], 0.0), s.quaternion_wxyz, s.mesh_file)
        for s in geometry.shapes
    )
    geometry = CollisionGeometry("flat", "flat", flat)
    names = [f"collision_{k:04d}" for k in range(len(flat))]
    mesh_name = names[[s.kind for s in flat].index("mesh")]

    write_representation(rep, geometry, _props(), CONTACT, formats=(fmt,))
    surfaces, pairs = _contact_kinds(rep / f"model.{fmt}")
    assert {n.rsplit("::", 1)[-1] for n in surfaces} == set(names) - {mesh_name}
    assert {n.rsplit("::", 1)[-1] for n in pairs} == {mesh_name}

    write_representation(rep, geometry, _props(), ContactProperties(hydroelastic="rigid"), formats=(fmt,))
    surfaces, pairs = _contact_kinds(rep / f"model.{fmt}")
    assert not surfaces and {n.rsplit("::", 1)[-1] for n in pairs} == set(names)


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_relative_visual_mesh_loads(asset, fmt):
    rep, _ = asset
    text = (rep / f"model.{fmt}").read_text()
    assert "../visual/model.obj" in text and str(rep.parent) not in text  # relative paths only
    _, plant, scene_graph = _load(rep / f"model.{fmt}")
    plant.Finalize()
    visuals = plant.GetVisualGeometriesForBody(plant.GetBodyByName(LINK_NAME))
    assert len(visuals) == 1
    shape = scene_graph.model_inspector().GetShape(visuals[0])
    assert isinstance(shape, Mesh)
    assert Path(shape.source().path()).resolve() == (rep.parent / "visual" / "model.obj").resolve()


def test_urdf_text_is_plain_xml_with_drake_namespace(asset):
    rep, geometry = asset
    text = write_model_urdf_string(geometry, _props(), CONTACT)
    root = ET.fromstring(text)
    assert root.tag == "robot" and root.get("name") == "object"
    assert text == (rep / "model.urdf").read_text()
    assert 'xmlns:drake="http://drake.mit.edu"' in text
    collisions = root.findall("./link/collision")
    assert len(collisions) == len(geometry.shapes)
    # numbers round-trip exactly
    xyz = [float(v) for v in collisions[0].find("origin").get("xyz").split()]
    assert xyz == list(geometry.shapes[0].position_m)


def test_bad_inputs_raise(tmp_path):
    rep, geometry = _make_asset(tmp_path / "ASSET")
    with pytest.raises(ValueError, match="format"):
        write_representation(rep, geometry, _props(), CONTACT, formats=("stl",))
    missing = CollisionGeometry("m", "m", (CollisionShape("convex", (), mesh_file="pieces/nope.obj"),))
    with pytest.raises(ValueError, match="not found"):
        write_representation(rep, missing, _props(), CONTACT)
    with pytest.raises(ValueError, match="mass"):
        bad = PhysicalProperties(0.0, (0.0, 0.0, 0.0), ((1e-4, 0, 0), (0, 1e-4, 0), (0, 0, 1e-4)))
        write_representation(rep, geometry, bad, CONTACT)
    assert not (rep / "model.urdf").exists()


@pytest.mark.parametrize("fmt", ["urdf", "sdf"])
def test_cylinder_flat_depth_gives_cylinders_their_own_finer_hint(tmp_path, fmt):
    import dataclasses
    import math

    from real2sim.geometry.tessellation import sections_for

    rep, geometry = _make_asset(tmp_path / "ASSET")
    contact = dataclasses.replace(CONTACT, cylinder_flat_depth_m=1e-5)
    write_representation(rep, geometry, _props(), contact, formats=(fmt,))
    _, plant, scene_graph = _load(rep / f"model.{fmt}")
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    for k, gid in _collision_by_index(plant, scene_graph).items():
        hint = inspector.GetProximityProperties(gid).GetProperty("hydroelastic", "resolution_hint")
        shape = geometry.shapes[k]
        if shape.kind != "cylinder":
            assert hint == pytest.approx(0.004)
            continue
        radius = shape.size_m[0]
        # Drake cuts the circle into ceil(2 pi r / hint) sections; their flats must be within 10 um.
        sections = math.ceil(2 * math.pi * radius / hint)
        assert sections == sections_for(radius, 1e-5) and radius * (1 - math.cos(math.pi / sections)) <= 1e-5
        assert hint < 0.004
    with pytest.raises(ValueError):
        ContactProperties(cylinder_flat_depth_m=0.0)
