"""model.usda read back with usd-core (issue 34, part 3): units and up axis, the rigid body's mass
properties, every collider's type, size and pose against collision.json (through usd-core's own
physics parser, UsdPhysicsLoadStageFromPrimRange), the physics material, the textured visual."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

pxr = pytest.importorskip("pxr", reason="usd-core is a dependency (pip install usd-core)")

from pxr import Usd, UsdGeom, UsdPhysics, UsdShade  # noqa: E402

from real2sim.asset.export.round_pieces import ellipsoid_polytope  # noqa: E402
from real2sim.asset.export.usd import USD_NAME  # noqa: E402
from real2sim.asset.export.writers import write_representation  # noqa: E402
from real2sim.formats.collision import CollisionGeometry, CollisionShape, read_collision_json, write_collision_json  # noqa: E402
from real2sim.formats.contact import ContactProperties  # noqa: E402
from real2sim.formats.physical import PhysicalProperties  # noqa: E402
from real2sim.formats.rotations import quaternion_to_matrix  # noqa: E402


def _unit(q) -> tuple[float, ...]:
    q = np.asarray(q, dtype=float)
    return tuple(q / np.linalg.norm(q))


ROTATED = _unit((0.9, 0.3, -0.2, 0.25))
TILTED = _unit((0.6, -0.1, 0.7, 0.3))
CONTACT = ContactProperties(mu_static=0.8, mu_dynamic=0.6)
# A full inertia tensor (off-diagonal terms) and a CoM off the origin: principal axes are not the body's.
PROPS = PhysicalProperties(0.42, (0.003, -0.002, 0.01),
                           ((2.0e-4, 1.5e-5, -1.0e-5), (1.5e-5, 3.0e-4, 2.0e-5), (-1.0e-5, 2.0e-5, 1.2e-4)))


@pytest.fixture(scope="module")
def usd_rep(tmp_path_factory) -> Path:
    """A representation with one shape of every kind, its textured visual, written with --format usd."""
    from real2sim.geometry.objects import export_object

    root = tmp_path_factory.mktemp("usd_asset")
    export_object("can", root / "visual" / "model.obj")
    rep = root / "every_kind"
    (rep / "pieces").mkdir(parents=True)
    trimesh.creation.icosphere(subdivisions=1, radius=0.01).export(rep / "pieces" / "piece_000.obj")
    trimesh.creation.annulus(r_min=0.005, r_max=0.012, height=0.01).export(rep / "pieces" / "mesh.obj")
    shapes = (
        CollisionShape("box", (0.04, 0.02, 0.01), (0.01, -0.02, 0.03), ROTATED),
        CollisionShape("sphere", (0.015,), (0.0, 0.01, -0.02)),
        CollisionShape("cylinder", (0.015, 0.05), (-0.02, 0.01, -0.01), TILTED),
        CollisionShape("capsule", (0.01, 0.03), (0.02, 0.0, 0.0), ROTATED),
        CollisionShape("ellipsoid", (0.03, 0.02, 0.01), (0.0, -0.01, 0.04), TILTED),
        CollisionShape("convex", (), (0.005, 0.0, -0.03), ROTATED, mesh_file="pieces/piece_000.obj"),
        CollisionShape("mesh", (), (0.0, 0.0, 0.05), mesh_file="pieces/mesh.obj"),
    )
    geometry = CollisionGeometry("every_kind", "test", shapes)
    write_collision_json(geometry, rep / "collision.json")
    write_representation(rep, geometry, PROPS, CONTACT, formats=("urdf", "usd"))
    return rep


def _physics(stage) -> dict:
    """usd-core's own parse of the stage's physics: {type name: [(path, desc), ...]}."""
    parsed = UsdPhysics.LoadUsdPhysicsFromRange(stage, ["/"]) if not hasattr(UsdPhysics, "UsdPhysicsLoadStageFromPrimRange") \
        else UsdPhysics.UsdPhysicsLoadStageFromPrimRange(stage, ["/"])
    return {str(kind).split(".")[-1]: list(zip(paths, descs)) for kind, (paths, descs) in parsed.items()}


def test_stage_is_in_metres_and_kilograms_with_z_up(usd_rep):
    stage = Usd.Stage.Open(str(usd_rep / USD_NAME))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert stage.GetDefaultPrim().GetPath() == "/object"


def test_rigid_body_carries_the_assets_mass_properties(usd_rep):
    stage = Usd.Stage.Open(str(usd_rep / USD_NAME))
    physics = _physics(stage)
    assert [str(path) for path, _ in physics["RigidBody"]] == ["/object"]
    body = UsdPhysics.RigidBodyAPI(stage.GetPrimAtPath("/object"))

    def from_colliders(prim):  # what a simulator would derive from a collider's density: unused when the body has mass
        info = UsdPhysics.RigidBodyAPI.MassInformation()
        info.volume = 1.0
        return info

    # usd-core's own mass computation, which the body's MassAPI values must override completely
    mass_kg, moments, com, q = body.ComputeMassProperties(from_colliders)
    assert mass_kg == pytest.approx(PROPS.mass_kg, rel=1e-7)
    np.testing.assert_allclose(np.array(com), PROPS.com_m, atol=1e-8)
    axes = quaternion_to_matrix((q.GetReal(), *q.GetImaginary()))
    inertia = axes @ np.diag(np.array(moments, dtype=float)) @ axes.T
    np.testing.assert_allclose(inertia, PROPS.inertia, rtol=1e-6, atol=1e-6 * np.abs(PROPS.inertia).max())


def _pose(desc) -> tuple[np.ndarray, np.ndarray]:
    rot = desc.localRot
    return np.array(desc.localPos), quaternion_to_matrix((rot.GetReal(), *rot.GetImaginary()))


def test_every_collider_has_the_type_size_and_pose_of_collision_json(usd_rep):
    stage = Usd.Stage.Open(str(usd_rep / USD_NAME))
    found = {str(path): (kind, desc) for kind, items in _physics(stage).items() for path, desc in items
             if kind.endswith("Shape")}
    shapes = read_collision_json(usd_rep / "collision.json").shapes
    assert len(found) == len(shapes)
    expected_type = {"box": "CubeShape", "sphere": "SphereShape", "cylinder": "CylinderShape",
                     "capsule": "CapsuleShape", "ellipsoid": "MeshShape", "convex": "MeshShape", "mesh": "MeshShape"}
    for k, shape in enumerate(shapes):
        kind, desc = found[f"/object/collisions/collision_{k:04d}"]
        assert kind == expected_type[shape.kind], (k, shape.kind, kind)
        pos, rot = _pose(desc)
        np.testing.assert_allclose(pos, shape.position_m, atol=1e-9)
        np.testing.assert_allclose(rot, quaternion_to_matrix(shape.quaternion_wxyz), atol=1e-6)
        s = shape.size_m
        if shape.kind == "box":
            np.testing.assert_allclose(np.array(desc.halfExtents), np.array(s) / 2, rtol=1e-6)
        elif shape.kind == "sphere":
            assert desc.radius == pytest.approx(s[0], rel=1e-6)
        elif shape.kind in ("cylinder", "capsule"):
            assert desc.radius == pytest.approx(s[0], rel=1e-6)
            assert desc.halfHeight == pytest.approx(s[1] / 2, rel=1e-6)
            assert str(desc.axis).endswith("Z")
        else:
            assert str(desc.approximation) == "convexHull"
            points = np.array(UsdGeom.Mesh(stage.GetPrimAtPath(desc.primPath)).GetPointsAttr().Get(), dtype=float)
            if shape.kind == "ellipsoid":
                hull = trimesh.Trimesh(points).convex_hull
                assert hull.volume == pytest.approx(4 / 3 * math.pi * np.prod(s), rel=1e-5)
                np.testing.assert_allclose(points, ellipsoid_polytope(s).vertices, atol=1e-7)
            else:
                np.testing.assert_allclose(points, trimesh.load(usd_rep / shape.mesh_file, process=False).vertices,
                                           atol=1e-7)
        assert [str(m) for m in desc.materials] == ["/object/physics_material"]


def test_friction_is_a_physics_material(usd_rep):
    stage = Usd.Stage.Open(str(usd_rep / USD_NAME))
    [(path, material)] = _physics(stage)["RigidBodyMaterial"]
    assert material.staticFriction == pytest.approx(CONTACT.mu_static, rel=1e-6)
    assert material.dynamicFriction == pytest.approx(CONTACT.mu_dynamic, rel=1e-6)


def test_visual_mesh_is_textured_and_takes_no_part_in_collision(usd_rep):
    stage = Usd.Stage.Open(str(usd_rep / USD_NAME))
    visual = stage.GetPrimAtPath("/object/visual")
    assert visual.IsA(UsdGeom.Mesh) and not visual.HasAPI(UsdPhysics.CollisionAPI)
    obj = trimesh.load(usd_rep.parent / "visual" / "model.obj", process=False)
    assert len(UsdGeom.Mesh(visual).GetPointsAttr().Get()) == len(obj.vertices)
    material, _ = UsdShade.MaterialBindingAPI(visual).ComputeBoundMaterial()
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    source = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    texture = UsdShade.Shader(source.GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture"
    file_path = texture.GetInput("file").Get()
    assert not Path(file_path.path).is_absolute() and Path(file_path.resolvedPath).is_file()
    assert UsdGeom.PrimvarsAPI(visual).GetPrimvar("st").GetInterpolation() == UsdGeom.Tokens.vertex
    for collider in stage.GetPrimAtPath("/object/collisions").GetChildren():
        assert UsdGeom.Imageable(collider).GetPurposeAttr().Get() == UsdGeom.Tokens.guide
