"""Scenes of the Drake evaluation: run specs, initial poses, diagrams that build."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from real2sim.asset.export.writers import write_representation
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties, write_physical_properties
from real2sim.evaluate.scene.placement import initial_object_pose
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import make_run_specs, run_steps, tilt_angle_rad
from real2sim.evaluate.scene.world import build_scene, reference_object_adder, urdf_object_adder

CAN_R, CAN_H, CAN_KG = 0.034, 0.10, 0.35


def write_can_asset(root: Path) -> tuple[Path, Path, PhysicalProperties]:
    """A can asset: visual/model.obj (48-sided cylinder) and cylinders_1/model.urdf (one
    cylinder primitive); the asset frame is the can's centre with z along its axis."""
    (root / "visual").mkdir(parents=True, exist_ok=True)
    mesh = trimesh.creation.cylinder(radius=CAN_R, height=CAN_H, sections=48)
    mesh_path = root / "visual" / "model.obj"
    mesh.export(mesh_path)
    ixx = CAN_KG * (3 * CAN_R**2 + CAN_H**2) / 12
    props = PhysicalProperties(CAN_KG, (0.0, 0.0, 0.0),
                               ((ixx, 0.0, 0.0), (0.0, ixx, 0.0), (0.0, 0.0, CAN_KG * CAN_R**2 / 2)))
    geometry = CollisionGeometry("cylinders_1", "cylinders:1", (
        CollisionShape("cylinder", (CAN_R, CAN_H), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), None),))
    write_representation(root / "cylinders_1", geometry, props, ContactProperties())
    write_physical_properties(props, root / "physical_properties.json")
    return mesh_path, root / "cylinders_1" / "model.urdf", props


@pytest.fixture(scope="module")
def can_asset(tmp_path_factory):
    return write_can_asset(tmp_path_factory.mktemp("can"))


def test_run_specs_are_seeded_prefix_stable_and_in_range():
    a = make_run_specs("push", 5, seed=3)
    assert a == make_run_specs("push", 5, seed=3)
    assert make_run_specs("push", 8, seed=3)[:5] == a  # more runs never change earlier ones
    assert a != make_run_specs("push", 5, seed=4)
    assert [s.run for s in a] == list(range(5))
    assert len({s.pusher_approach_rad for s in a}) == 5
    for s in a:
        assert s.task == "push" and max(abs(v) for v in s.object_offset_m) <= 0.05
    for s in make_run_specs("ramp", 20, seed=0):
        assert abs(s.object_yaw_rad) <= np.deg2rad(10) + 1e-12
        assert -0.02 <= s.object_offset_m[1] <= 0.0
    with pytest.raises(ValueError):
        make_run_specs("fly", 1, 0)


def test_scene_config_rejects_fractional_reset_interval():
    with pytest.raises(ValueError):
        SceneConfig(time_step_s=1e-3, reset_interval_s=0.00025)
    cfg = SceneConfig(settle_s=0.1, push_duration_s=0.25)
    assert run_steps("push", cfg) == 350 and cfg.reset_interval_steps() == 100
    assert SceneConfig(reset_interval_s=None).reset_interval_steps() is None


def test_initial_pose_rests_lowest_vertex_just_above_support():
    mesh = trimesh.creation.cylinder(radius=CAN_R, height=CAN_H, sections=48)
    cfg = SceneConfig()
    for task in ("push", "ramp"):
        for spec in make_run_specs(task, 3, seed=1):
            X = initial_object_pose(mesh.vertices, spec, cfg)
            w = mesh.vertices @ X.rotation().matrix().T + X.translation()
            support = 0.0 if task == "push" else cfg.hinge_height_m
            assert w[:, 2].min() == pytest.approx(support + cfg.drop_clearance_m, abs=1e-9)
            # Lying: the can's axis is horizontal.
            assert abs(X.rotation().matrix()[2, 2]) < 1e-6
            if task == "ramp":  # up-slope edge just down-slope of the hinge line y = 0
                assert w[:, 1].max() == pytest.approx(-cfg.ramp_object_gap_m + spec.object_offset_m[1])
            else:
                assert X.translation()[:2] == pytest.approx(spec.object_offset_m)


def test_tilt_profile_reaches_target_smoothly():
    cfg = SceneConfig()
    t = np.linspace(0, cfg.total_duration_s, 2001)
    q, qd = tilt_angle_rad(t, cfg)
    assert q[0] == 0 and q[-1] == pytest.approx(np.deg2rad(45))
    assert np.all(np.diff(q) >= -1e-15)
    # Peak angular acceleration x 0.1 m from the hinge stays under 0.5 g (DESIGN.md pitfall).
    assert np.abs(np.gradient(qd, t)).max() * 0.1 < 0.5 * 9.81


@pytest.mark.parametrize("task", ["push", "ramp"])
@pytest.mark.parametrize("contact_model", ["point", "hydroelastic"])
def test_scenes_build_for_both_contact_models(can_asset, task, contact_model):
    from pydrake.multibody.plant import ContactModel

    _, urdf, _ = can_asset
    spec = make_run_specs(task, 1, seed=0)[0]
    scene = build_scene(task, contact_model, urdf_object_adder(urdf), spec, SceneConfig())
    plant = scene.plant
    expected = ContactModel.kPoint if contact_model == "point" else ContactModel.kHydroelasticWithFallback
    assert plant.get_contact_model() == expected
    assert plant.time_step() == 1e-3
    assert plant.num_positions(scene.object_instance) == 7
    assert plant.num_positions(scene.actuated_instance) == (2 if task == "push" else 1)
    assert plant.num_actuators() == plant.num_positions(scene.actuated_instance)
    # The desired-state port is connected: evaluating the plant's dynamics needs it.
    ctx = scene.diagram.CreateDefaultContext()
    pctx = plant.GetMyContextFromRoot(ctx)
    q0 = plant.GetPositions(pctx, scene.actuated_instance)
    assert q0 == pytest.approx(scene.actuated_initial_positions)
    plant.get_contact_results_output_port().Eval(pctx)


def test_reference_scene_has_rigid_mesh_on_a_body_with_asset_mass(can_asset):
    mesh_path, _, props = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    scene = build_scene("push", "hydroelastic", reference_object_adder(mesh_path, props), spec, SceneConfig())
    ctx = scene.diagram.CreateDefaultContext()
    pctx = scene.plant.GetMyContextFromRoot(ctx)
    assert scene.object_body.get_mass(pctx) == pytest.approx(CAN_KG)
    inspector = scene.scene_graph.model_inspector()
    (gid,) = scene.object_geometry_ids
    proximity = inspector.GetProximityProperties(gid)
    # Rigid hydroelastic: a compliance type but no modulus (a compliant one would carry one).
    assert proximity.HasProperty("hydroelastic", "compliance_type")
    assert not proximity.HasProperty("hydroelastic", "hydroelastic_modulus")
    assert inspector.GetShape(gid).__class__.__name__ == "Mesh"


def test_missing_files_are_reported(tmp_path):
    with pytest.raises(FileNotFoundError):
        urdf_object_adder(tmp_path / "nope.urdf")
    with pytest.raises(FileNotFoundError):
        reference_object_adder(tmp_path / "nope.obj", None)
    trimesh.creation.box().export(tmp_path / "box.stl")
    with pytest.raises(ValueError, match=".obj"):
        reference_object_adder(tmp_path / "box.stl", None)


def test_lying_pose_is_a_stable_rest_for_a_non_round_object():
    """A 6 x 4 x 12 cm block must lie on a face whatever the requested roll, not on an edge."""
    block = trimesh.creation.box((0.06, 0.04, 0.12))
    cfg = SceneConfig()
    for spec in make_run_specs("push", 6, seed=2):
        R = initial_object_pose(block.vertices, spec, cfg).rotation().matrix()
        w = block.vertices @ R.T
        assert np.sum(w[:, 2] < w[:, 2].min() + 1e-9) == 4  # a whole face down
        assert abs(R[2, 2]) < 1e-9  # long axis horizontal
        # long axis along the yaw direction (before yaw: along world x)
        assert abs(abs(R[:, 2] @ [np.cos(spec.object_yaw_rad), np.sin(spec.object_yaw_rad), 0]) - 1) < 1e-9


def test_upright_option_stands_the_can_on_an_end():
    mesh = trimesh.creation.cylinder(radius=CAN_R, height=CAN_H, sections=48)
    cfg = SceneConfig(object_lying=False)
    spec = make_run_specs("push", 1, seed=0)[0]
    X = initial_object_pose(mesh.vertices, spec, cfg)
    assert abs(X.rotation().matrix()[2, 2]) == pytest.approx(1.0)
    assert X.translation()[2] == pytest.approx(CAN_H / 2 + cfg.drop_clearance_m)
