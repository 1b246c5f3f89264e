"""MJCF assets, checked in real MuJoCo: they load, hold the geoms of collision.json with the
right sizes and poses, carry the asset's mass properties, and stand on a floor."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is a dependency (pip install mujoco)")

from real2sim.asset.build import AssetConfig, build_asset  # noqa: E402
from real2sim.asset.export.mjcf import lowest_collision_z, mjcf_size, write_model_mjcf_string  # noqa: E402
from real2sim.formats.collision import CollisionGeometry, CollisionShape, read_collision_json  # noqa: E402
from real2sim.formats.contact import ContactProperties  # noqa: E402
from real2sim.formats.physical import PhysicalProperties, read_physical_properties  # noqa: E402
from real2sim.formats.rotations import quaternion_to_matrix  # noqa: E402
from real2sim.formats.spec import parse_spec  # noqa: E402

PRIMITIVE_AND_CONVEX_SPECS = ("cylinders:1", "rotated_boxes:2", "spheres:16", "ellipsoids:2", "capsules:2",
                              "superquadrics:1", "coacd", "mesh")
# Representations whose bottom is flat (or many-pointed) enough to stand upright: a can of 2 capsules
# or 2 ellipsoids rests on a rounded bottom and rolls over, and one superquadric's 128-vertex polytope
# has a fan of shallow facets for a bottom (it settles 1.7 degrees tilted; measured).
STANDING = ("cylinders_1", "rotated_boxes_2", "spheres_16", "coacd", "mesh")


def _build(tmp_path_factory, name: str, specs, pca_up: bool = True) -> Path:
    from real2sim.collision.fit import FitConfig
    from real2sim.geometry.objects import OBJECTS, export_object

    mesh = export_object(name, tmp_path_factory.mktemp(name) / f"{name}.obj")
    config = AssetConfig(mass_kg=OBJECTS[name].mass_kg, specs=tuple(parse_spec(s) for s in specs),
                         flat_bottom=True, pca_up=pca_up, formats=("urdf", "mjcf"),
                         fit_config=FitConfig(max_iterations=150, min_iterations=50))
    return build_asset(mesh, tmp_path_factory.mktemp(f"{name}_asset") / "asset", config).asset_dir


@pytest.fixture(scope="module")
def can_asset(tmp_path_factory) -> Path:
    return _build(tmp_path_factory, "can", PRIMITIVE_AND_CONVEX_SPECS)


def _load(xml_path: Path, floor: bool = False):
    spec = mujoco.MjSpec.from_file(str(xml_path))
    if floor:
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.0, 1.0, 0.01])
    model = spec.compile()
    return model, mujoco.MjData(model)


def _collision_geoms(model) -> list[int]:
    return [g for g in range(model.ngeom) if model.geom_contype[g] or model.geom_conaffinity[g]
            if model.geom_bodyid[g] != 0]


def test_every_representation_loads_with_its_geoms_and_mass_properties(can_asset):
    props = read_physical_properties(can_asset / "physical_properties.json")
    reps = sorted(p.parent for p in can_asset.glob("*/collision.json"))
    assert len(reps) == len(PRIMITIVE_AND_CONVEX_SPECS)
    for rep in reps:
        model, data = _load(rep / "model.xml")
        geometry = read_collision_json(rep / "collision.json")
        geoms = _collision_geoms(model)
        assert len(geoms) == len(geometry.shapes), rep.name
        for g, shape in zip(geoms, geometry.shapes):
            if shape.kind in ("convex", "mesh"):
                assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
            else:
                kind, size = mjcf_size(shape)
                assert mujoco.mjtGeom(model.geom_type[g]).name == f"mjGEOM_{kind.upper()}"
                np.testing.assert_allclose(model.geom_size[g][:len(size)], size, rtol=1e-12)
        body = model.body("object").id
        assert model.body_mass[body] == pytest.approx(props.mass_kg, rel=1e-12)
        np.testing.assert_allclose(model.body_ipos[body], props.com_m, atol=1e-12)
        # MuJoCo stores the principal moments and the principal axes' orientation.
        axes = np.zeros(9)
        mujoco.mju_quat2Mat(axes, model.body_iquat[body])
        axes = axes.reshape(3, 3)
        inertia = axes @ np.diag(model.body_inertia[body]) @ axes.T
        np.testing.assert_allclose(inertia, props.inertia, rtol=1e-6, atol=1e-12)
        # The visual mesh is there, textured, and takes part in no contact.
        visual = model.geom("visual").id
        assert model.geom_contype[visual] == 0 and model.geom_conaffinity[visual] == 0
        assert model.geom_matid[visual] >= 0 and model.ntex == 1
        # Relative paths only.
        for element in ET.parse(rep / "model.xml").getroot().iter():
            assert not Path(element.get("file", "x")).is_absolute()


def test_mesh_pieces_sit_where_collision_json_puts_them(can_asset):
    """MuJoCo re-centres mesh assets on their centroid and moves the geom frame to match: the
    vertices in the world must be the convex hull of the file's vertices, posed by collision.json."""
    import trimesh

    for rep_name in ("coacd", "superquadrics_1"):
        rep = can_asset / rep_name
        model, data = _load(rep / "model.xml")
        mujoco.mj_forward(model, data)
        shapes = read_collision_json(rep / "collision.json").shapes
        for g, shape in zip(_collision_geoms(model), shapes):
            mesh_id = model.geom_dataid[g]
            start, count = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
            world = data.geom_xpos[g] + model.mesh_vert[start:start + count] @ data.geom_xmat[g].reshape(3, 3).T
            local = trimesh.load(rep / shape.mesh_file, process=False).convex_hull.vertices
            expected = np.asarray(shape.position_m) + local @ quaternion_to_matrix(shape.quaternion_wxyz).T
            np.testing.assert_allclose(np.sort(world, axis=0)[[0, -1]], np.sort(expected, axis=0)[[0, -1]], atol=1e-5)


@pytest.mark.parametrize("rep_name", STANDING)
def test_dropped_1mm_onto_a_floor_it_rests_upright(can_asset, rep_name):
    model, data = _load(can_asset / rep_name / "model.xml", floor=True)
    mujoco.mj_forward(model, data)
    data.qpos[2] += 0.001 - lowest_collision_z(model, data)
    mujoco.mj_forward(model, data)
    start = data.qpos[:3].copy()
    while data.time < 1.0:
        mujoco.mj_step(model, data)
    up = data.xmat[model.body("object").id].reshape(3, 3)[:, 2]
    tilt_deg = np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0)))
    penetration_m = -min([c.dist for c in data.contact[:data.ncon]] or [0.0])
    assert data.ncon >= 3  # standing on a face, not on an edge or a point
    assert tilt_deg < 1.0
    assert penetration_m < 1e-3
    assert np.linalg.norm(data.qpos[:2] - start[:2]) < 1e-3  # no drift
    assert np.linalg.norm(data.qvel[:3]) < 5e-3  # at rest


def test_mesh_representation_says_mujoco_makes_it_convex(can_asset):
    report = json.loads((can_asset / "mesh" / "fit_report.json").read_text())
    assert any("convex hull" in note for note in report["mjcf_notes"])
    assert "mjcf_notes" not in json.loads((can_asset / "cylinders_1" / "fit_report.json").read_text())


def test_rotated_box_and_cylinder_have_the_same_world_pose_in_mujoco_and_drake(tmp_path):
    """Quaternion conventions differ between libraries (w-first or w-last, active or passive):
    compare MuJoCo's geom poses with Drake's reading of the URDF of the same shapes."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from real2sim.asset.export.writers import write_representation

    q_box = np.array([0.9, 0.3, -0.2, 0.25])
    q_cyl = np.array([0.6, -0.1, 0.7, 0.3])
    q_box, q_cyl = q_box / np.linalg.norm(q_box), q_cyl / np.linalg.norm(q_cyl)
    shapes = (CollisionShape("box", (0.04, 0.02, 0.01), (0.01, -0.02, 0.03), tuple(q_box)),
              CollisionShape("cylinder", (0.015, 0.05), (-0.02, 0.01, -0.01), tuple(q_cyl)))
    geometry = CollisionGeometry(name="rotated", spec="test", shapes=shapes)
    props = PhysicalProperties(mass_kg=0.2, com_m=(0.0, 0.0, 0.0),
                               inertia_kg_m2=((1e-4, 0, 0), (0, 2e-4, 0), (0, 0, 3e-4)))
    write_representation(tmp_path, geometry, props, ContactProperties(), visual_mesh_relpath="",
                         formats=("urdf", "mjcf"))

    model, data = _load(tmp_path / "model.xml")
    mujoco.mj_forward(model, data)
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    Parser(plant).AddModels(str(tmp_path / "model.urdf"))
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    inspector = scene_graph.model_inspector()
    body = plant.GetBodyByName("base_link")
    drake_poses = [inspector.GetPoseInFrame(gid) for gid in plant.GetCollisionGeometriesForBody(body)]
    del context
    for g, shape, drake_pose in zip(_collision_geoms(model), shapes, drake_poses):
        mj_rotation = data.geom_xmat[g].reshape(3, 3)
        np.testing.assert_allclose(data.geom_xpos[g], shape.position_m, atol=1e-12)
        np.testing.assert_allclose(mj_rotation, quaternion_to_matrix(shape.quaternion_wxyz), atol=1e-9)
        np.testing.assert_allclose(drake_pose.translation(), data.geom_xpos[g], atol=1e-9)
        np.testing.assert_allclose(drake_pose.rotation().matrix(), mj_rotation, atol=1e-9)


def test_handwritten_text_matches_the_writer(tmp_path):
    """Sizes are MuJoCo half-lengths: a 4 cm box is size 0.02, a 5 cm cylinder half-length 0.025."""
    shapes = (CollisionShape("box", (0.04, 0.02, 0.01)), CollisionShape("cylinder", (0.015, 0.05)),
              CollisionShape("capsule", (0.01, 0.03)))
    props = PhysicalProperties(mass_kg=0.2, com_m=(0.0, 0.0, 0.0),
                               inertia_kg_m2=((1e-4, 0, 0), (0, 2e-4, 0), (0, 0, 3e-4)))
    text = write_model_mjcf_string(CollisionGeometry(name="x", spec="test", shapes=shapes), props,
                                   ContactProperties(mu_dynamic=0.7), tmp_path, visual_mesh_relpath="")
    geoms = [g for g in ET.fromstring(text).iter("geom")]
    assert [g.get("size") for g in geoms] == ["0.02 0.01 0.005", "0.015 0.025", "0.01 0.015"]
    assert all(g.get("friction").split()[0] == "0.7" for g in geoms)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bottle", "can", "mug"])
def test_every_representation_of_every_bundled_object_loads(tmp_path_factory, name):
    specs = PRIMITIVE_AND_CONVEX_SPECS + ("vhacd", "boxes:8", "boxes:4+cylinders:2")
    asset = _build(tmp_path_factory, name, specs, pca_up=name != "mug")
    for rep in sorted(p.parent for p in asset.glob("*/collision.json")):
        model, data = _load(rep / "model.xml", floor=True)
        assert len(_collision_geoms(model)) == len(read_collision_json(rep / "collision.json").shapes)
        mujoco.mj_step(model, data)


def test_the_scene_carries_the_measured_contact_settings_and_the_model_keeps_mujocos(can_asset, tmp_path):
    """scene.xml simulates as the evaluation did (its options, every geom's contact); model.xml leaves a
    scene of the user's own to decide; asset_config.json records the settings and a rewrite keeps them."""
    import shutil

    from real2sim.asset.build import rewrite_models
    from real2sim.formats.contact import MujocoConfig

    settings = MujocoConfig()
    record = json.loads((can_asset / "asset_config.json").read_text())
    assert MujocoConfig.from_record(record["mujoco"]) == settings
    scene = mujoco.MjModel.from_xml_path(str(can_asset / "cylinders_1" / "scene.xml"))
    assert scene.opt.timestep == settings.timestep_s and scene.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    touching = [g for g in range(scene.ngeom) if scene.geom_contype[g] or scene.geom_conaffinity[g]]
    assert scene.geom("floor").id in touching and len(touching) >= 2
    for g in touching:
        assert tuple(scene.geom_solref[g]) == (settings.solref_timeconst_s, settings.solref_dampratio)
        assert tuple(scene.geom_solimp[g]) == settings.solimp and scene.geom_condim[g] == settings.condim
    model, _ = _load(can_asset / "cylinders_1" / "model.xml")
    default = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size="1"/></worldbody></mujoco>')
    assert all(tuple(model.geom_solref[g]) == tuple(default.geom_solref[0]) for g in range(model.ngeom))

    copy = shutil.copytree(can_asset, tmp_path / "copy")
    other = {**record, "mujoco": {**record["mujoco"], "solref_timeconst_s": 0.02}}
    (copy / "asset_config.json").write_text(json.dumps(other))
    rewrite_models(copy, ContactProperties(), formats=("urdf", "mjcf"))
    again = mujoco.MjModel.from_xml_path(str(copy / "cylinders_1" / "scene.xml"))
    assert again.geom_solref[again.geom("floor").id][0] == 0.02
