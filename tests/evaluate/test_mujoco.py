"""The evaluation in MuJoCo (``evaluate --simulator mujoco``): the same tasks and equation-error protocol,
judged against the same Drake reference. Real MuJoCo and Drake simulations of a tiny box asset."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from real2sim.formats.contact import MujocoConfig
from real2sim.evaluate.mujoco.simulate import simulate_candidate_mujoco
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import make_run_specs, pusher_start_xy, run_steps
from real2sim.evaluate.scoring import score
from real2sim.evaluate.simulate import simulate_candidate, simulate_reference
from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.formats.physical import read_physical_properties
from real2sim.formats.results import read_runs_csv, read_summary_csv
from real2sim.formats.trajectory import Trajectory
from real2sim.plumbing.errors import UserInputError
from tests.cli_helpers import run_cli
from tests.evaluate.test_sweep import SHORT_SCENE, make_box_asset

G = 9.81


@pytest.fixture(scope="module")
def mj_asset(tmp_path_factory) -> Path:
    """The sweep tests' box asset, each representation with its MuJoCo model.xml too."""
    from real2sim.asset.export.writers import write_representation
    from real2sim.formats.collision import CollisionGeometry, CollisionShape
    from real2sim.formats.contact import ContactProperties
    from tests.evaluate.test_sweep import BOX_EXTENTS_M

    root = make_box_asset(tmp_path_factory.mktemp("mj") / "box", reps=("boxes_1",))
    props = read_physical_properties(root / "physical_properties.json")
    for name, scale in (("boxes_1", 1.0), ("boxes_1_x1p2", 1.2)):
        shape = CollisionShape("box", tuple(float(v) for v in BOX_EXTENTS_M * scale))
        write_representation(root / name, CollisionGeometry(name, name, (shape,)), props, ContactProperties(),
                             formats=("urdf", "mjcf"))
    return root


def _ballistic_reference(scene: SceneConfig, p0, v0, task: str = "push") -> Trajectory:
    """A hand-made reference: a free body far above the floor in exact ballistic flight, not rotating,
    the pusher held at its start."""
    spec = make_run_specs(task, 1, 0)[0]
    n = run_steps(task, scene)
    t = np.arange(n + 1) * scene.time_step_s
    p = np.asarray(p0)[None, :] + np.outer(t, v0) - 0.5 * G * np.outer(t * t, [0.0, 0.0, 1.0])
    v = np.asarray(v0)[None, :] - G * np.outer(t, [0.0, 0.0, 1.0])
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n + 1, 1))
    velocity = np.concatenate([np.zeros((n + 1, 3)), v], axis=1)
    pusher = np.tile(pusher_start_xy(spec, scene), (n + 1, 1))
    return Trajectory(times_s=t, object_position_m=p, object_quaternion_wxyz=quat, object_spatial_velocity=velocity,
                      actuated_positions=pusher, actuated_velocities=np.zeros_like(pusher),
                      contact_points_object_m=[np.zeros((0, 3))] * (n + 1), sim_time_s=0.0,
                      sim_duration_s=n * scene.time_step_s, instrumented_time_s=0.0, reset_steps=np.zeros(0, int),
                      task=task, contact_model="reference", representation="hand", run=0)


def test_equation_error_against_a_hand_computed_ballistic_reference(mj_asset):
    """Reset every 0.1 s onto an exact parabola, MuJoCo's semi-implicit Euler step falls behind it by
    g dt^2 k / 2 after k steps (v_k = v_r - g k dt, p_k = p_r + v_r k dt - g dt^2 k (k + 1) / 2), so with
    300 samples after the start in three intervals of 100 the ATE is g dt^2 (3 * 100 * 101 / 2) / 2 / 301;
    nothing rotates, so OCAE equals it, and nothing touches, so no CPD."""
    scene = SHORT_SCENE  # a 0.3 s push: 300 steps of 1 ms, resets at 100 and 200
    reference = _ballistic_reference(scene, (0.0, 0.0, 20.0), (0.3, -0.2, 1.0))
    spec = make_run_specs("push", 1, 0)[0]
    traj = simulate_candidate_mujoco(mj_asset / "boxes_1" / "model.xml", spec, scene, reference,
                                     MujocoConfig(integrator="Euler"))
    assert list(traj.reset_steps) == [100, 200]
    dt = scene.time_step_s
    expected = G * dt * dt * (3 * 100 * 101 / 2) / 2 / 301
    values = score(reference, traj)
    assert values["ate_m"] == pytest.approx(expected, rel=1e-6)
    assert values["ocae_m"] == pytest.approx(expected, rel=1e-6)
    assert math.isnan(values["cpd_m_per_s"]) and math.isnan(values["cpd_paper"])
    # the sample at a reset is the prediction, 100 steps behind: g dt^2 100 / 2 below the parabola
    assert reference.object_position_m[100, 2] - traj.object_position_m[100, 2] == pytest.approx(
        G * dt * dt * 50, rel=1e-6)
    # the evaluation's own setting: the same semi-implicit step for an undamped free body, h at a time
    # (k scene steps are k dt / h MuJoCo steps, so the lag is g h dt k / 2)
    chosen = MujocoConfig()
    lag = score(reference, simulate_candidate_mujoco(mj_asset / "boxes_1" / "model.xml", spec, scene, reference,
                                                     chosen))["ate_m"]
    if chosen.integrator == "RK4":  # exact on a parabola
        assert lag < 1e-9
    else:
        assert lag == pytest.approx(expected * chosen.timestep_s / dt, rel=1e-6)


def test_mujoco_and_drake_agree_on_a_falling_and_a_resting_body(mj_asset):
    """Free fall (no contact, one roll-out from the same state): the two agree to 1 micrometre. Resting
    on the floor (the pusher parked 1 m away): MuJoCo's soft contact and Drake's hydroelastic reference
    agree to 1 mm in position and 1 degree in orientation, and MuJoCo's contact forces carry the weight
    to 5 %."""
    free = dataclasses.replace(SHORT_SCENE, reset_interval_s=None)
    reference = _ballistic_reference(free, (0.0, 0.0, 20.0), (0.3, -0.2, 1.0))
    spec = make_run_specs("push", 1, 0)[0]
    mj = simulate_candidate_mujoco(mj_asset / "boxes_1" / "model.xml", spec, free, reference)
    drake = simulate_candidate(mj_asset / "boxes_1" / "model.urdf", "point", spec, free, reference)
    assert np.abs(mj.object_position_m - drake.object_position_m).max() < 1e-6
    assert np.abs(mj.object_spatial_velocity - drake.object_spatial_velocity).max() < 1e-6

    parked = dataclasses.replace(free, pusher_start_distance_m=1.0, pusher_speed_m_per_s=0.0)
    props = read_physical_properties(mj_asset / "physical_properties.json")
    resting = simulate_reference(mj_asset / "visual" / "model.obj", props, spec, parked)
    mj = simulate_candidate_mujoco(mj_asset / "boxes_1" / "model.xml", spec, parked, resting)
    assert np.abs(mj.object_position_m[-1] - resting.object_position_m[-1]).max() < 1e-3
    q1, q2 = mj.object_quaternion_wxyz[-1], resting.object_quaternion_wxyz[-1]
    angle = 2 * np.degrees(np.arccos(min(1.0, abs(float(np.dot(q1 / np.linalg.norm(q1), q2 / np.linalg.norm(q2)))))))
    assert angle < 1.0
    weight = np.sum(mj.contact_forces_object_n[-1], axis=0)
    R = _matrix(q1)
    assert np.linalg.norm(R @ weight - [0.0, 0.0, props.mass_kg * G]) < 0.05 * props.mass_kg * G
    assert np.abs(mj.object_spatial_velocity[-1]).max() < 1e-2


def _matrix(q):
    from real2sim.formats.rotations import quaternions_to_matrices

    q = np.asarray(q, float)
    return quaternions_to_matrices((q / np.linalg.norm(q))[None])[0]


def test_evaluate_in_mujoco_then_both_simulators(mj_asset, tmp_path):
    """``simulators=("mujoco",)`` writes MuJoCo rows with the simulator column; resumed with both, the
    MuJoCo rows are kept and Drake's added, each labelled apart in summary.csv."""
    out = tmp_path / "results"
    config = EvaluationConfig(tasks=("push",), contact_models=("point", "hydroelastic"), simulators=("mujoco",),
                              runs=1, jobs=1, scene=SHORT_SCENE)
    first = evaluate([mj_asset], out, config)
    assert first.failed == 0 and first.simulated == 2
    rows = read_runs_csv(out / "runs.csv")
    assert {(r["representation"], r["contact_model"], r["simulator"]) for r in rows} == {
        ("boxes_1", "point", "mujoco"), ("boxes_1_x1p2", "point", "mujoco")}
    by_rep = {r["representation"]: r for r in rows}
    assert by_rep["boxes_1"]["ocae_m"] < by_rep["boxes_1_x1p2"]["ocae_m"]  # the wrong size is worse in MuJoCo too
    with open(out / "runs.csv", newline="") as fh:
        assert "simulator" in next(csv.reader(fh))

    both = evaluate([mj_asset], out, dataclasses.replace(config, simulators=("drake", "mujoco"),
                                                          contact_models=("point",)))
    assert both.skipped == 2 and both.simulated == 2 and both.failed == 0
    summary = {r["representation"]: r for r in read_summary_csv(out / "summary.csv")}
    assert set(summary) == {"boxes_1_point", "boxes_1_x1p2_point", "boxes_1_point_mujoco", "boxes_1_x1p2_point_mujoco"}
    assert summary["boxes_1_point_mujoco"]["simulator"] == "mujoco"
    assert summary["boxes_1_point"]["simulator"] == "drake"
    html = (out / "report.html").read_text()
    assert "mujoco, point contact" in html
    # MuJoCo's settings are part of what its rows mean: a resume with others is refused, nothing changed
    before = (out / "runs.csv").read_bytes()
    softer = dataclasses.replace(config, mujoco=dataclasses.replace(MujocoConfig(), solref_timeconst_s=0.08))
    with pytest.raises(UserInputError, match="different mujoco"):
        evaluate([mj_asset], out, softer)
    assert (out / "runs.csv").read_bytes() == before


def test_cli_evaluate_simulator_mujoco(mj_asset, tmp_path, capsys):
    code, out, err = run_cli(capsys, "evaluate", mj_asset, "--out", tmp_path / "r", "--simulator", "mujoco",
                             "--tasks", "push", "--runs", "1", "--jobs", "1", "--duration-scale", "0.1",
                             "--no-animations")
    assert code == 0, err
    assert {r["simulator"] for r in read_runs_csv(tmp_path / "r" / "runs.csv")} == {"mujoco"}
    assert "mujoco: hydroelastic contact is not a mujoco contact model" in out


@pytest.mark.parametrize("extra, needle", [
    (("--simulator", "bullet"), "unknown simulator"),
    (("--simulator", "mujoco", "--contact", "hydroelastic"), "mujoco has no contact model"),
])
def test_cli_bad_simulator_is_one_line_exit_2(mj_asset, tmp_path, capsys, extra, needle):
    code, _out, err = run_cli(capsys, "evaluate", mj_asset, "--out", tmp_path / "r", *extra)
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and needle in lines[0]
    assert not (tmp_path / "r").exists()


def test_missing_model_xml_is_refused_before_anything_is_written(tmp_path):
    asset = make_box_asset(tmp_path / "box", reps=("boxes_1",))  # URDF only
    with pytest.raises(UserInputError, match="model.xml"):
        evaluate([asset], tmp_path / "r", EvaluationConfig(simulators=("mujoco",), runs=1, jobs=1, scene=SHORT_SCENE))
    assert not (tmp_path / "r").exists()
