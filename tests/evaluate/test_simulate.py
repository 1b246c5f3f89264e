"""Simulation of reference and candidates: pushing, ramp, equation-error resets, failures.

Short scenes (0.3-0.5 simulated seconds) with a can made of one cylinder primitive.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import make_run_specs, run_steps
from real2sim.evaluate.simulate import SimulationError, simulate_candidate, simulate_reference

from tests.evaluate.test_world import CAN_H, CAN_R, write_can_asset

# A RuntimeWarning (e.g. the timed and the logged run ending apart) fails the test.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

# Pusher starts 0.12 m from the can's centre (surfaces 2-4 cm apart), 0.2 m/s.
SHORT_PUSH = SceneConfig(settle_s=0.05, push_duration_s=0.25, pusher_start_distance_m=0.12)
# 45 degrees in 0.3 s after 0.05 s flat; 0.45 s in all.
SHORT_RAMP = SceneConfig(hold_s=0.05, tilt_time_s=0.3, total_duration_s=0.45)


@pytest.fixture(scope="module")
def can_asset(tmp_path_factory):
    return write_can_asset(tmp_path_factory.mktemp("can"))


def _ate(a, b) -> float:
    return float(np.linalg.norm(a.object_position_m - b.object_position_m, axis=1).mean())


def test_push_moves_the_object_along_the_approach(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    traj = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    n = run_steps("push", SHORT_PUSH)
    assert traj.times_s.shape == (n + 1,) and traj.times_s[-1] == pytest.approx(0.3)
    assert traj.object_position_m.shape == (n + 1, 3) and traj.object_quaternion_wxyz.shape == (n + 1, 4)
    assert len(traj.contact_points_object_m) == n + 1 and len(traj.reset_steps) == 0
    u = np.array([np.cos(spec.pusher_approach_rad), np.sin(spec.pusher_approach_rad)])
    moved = traj.object_position_m[-1, :2] - traj.object_position_m[0, :2]
    assert moved @ u > 0.01  # pushed at least a centimetre forward
    # The pusher tracked its line: it travelled speed * push duration along u.
    travel = traj.actuated_positions[-1] - traj.actuated_positions[0]
    assert travel @ u == pytest.approx(0.2 * 0.25, abs=0.005)
    # Contact with floor only before the pusher arrives (at 0.1 s: the 1 mm drop's one
    # small bounce on the soft point contact is over by 0.06 s), floor + pusher at the end.
    assert len(traj.contact_points_object_m[100]) == 1
    assert len(traj.contact_points_object_m[-1]) == 2
    assert traj.sim_time_s > 0 and traj.sim_duration_s == pytest.approx(0.3)


@pytest.mark.parametrize("contact_model", ["point", "hydroelastic"])
def test_contact_points_are_in_the_object_frame(can_asset, contact_model):
    mesh_path, urdf, props = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    # Resting can, floor contact only (settled after about 0.25 s).
    cfg = dataclasses.replace(SHORT_PUSH, settle_s=0.35, push_duration_s=0.0)
    traj = simulate_candidate(urdf, contact_model, spec, cfg, initial_mesh_path=mesh_path)
    steps = [i for i in range(20, len(traj.times_s)) if len(traj.contact_points_object_m[i])]
    assert len(steps) > 100
    pts = np.concatenate([traj.contact_points_object_m[i] for i in steps])
    # The can lies on its side: the floor touches its curved face, at radius r from the
    # axis (z), within the length.
    radial = np.linalg.norm(pts[:, :2], axis=1)
    assert np.allclose(radial, CAN_R, atol=1.5e-3)
    assert np.all(np.abs(pts[:, 2]) <= CAN_H / 2 + 1e-3)
    # Mapped back to the world with the logged pose, they lie on the floor (z = 0).
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RotationMatrix

    for i in steps[::10]:
        q = traj.object_quaternion_wxyz[i]
        R = RotationMatrix(Quaternion(q / np.linalg.norm(q))).matrix()
        p_w = traj.contact_points_object_m[i] @ R.T + traj.object_position_m[i]
        assert np.all(np.abs(p_w[:, 2]) < 1.5e-3)
    # One force per contact point; at rest the floor carries the weight: the mean net
    # contact force on the object, back in the world, is m g upward.
    assert [len(f) for f in traj.contact_forces_object_n] == [len(p) for p in traj.contact_points_object_m]
    # which of them are hydroelastic surfaces (the paper's CPD picks one kind): all or none here
    surfaces = np.asarray(traj.contact_surface_counts)
    counts = np.array([len(p) for p in traj.contact_points_object_m])
    assert np.array_equal(surfaces, counts if contact_model == "hydroelastic" else np.zeros_like(counts))
    late = [i for i in steps if i >= 250]
    net_w = []
    for i in late:
        q = traj.object_quaternion_wxyz[i]
        R = RotationMatrix(Quaternion(q / np.linalg.norm(q))).matrix()
        net_w.append((traj.contact_forces_object_n[i] @ R.T).sum(axis=0))
    mean_net_w = np.mean(net_w, axis=0)
    assert mean_net_w[2] == pytest.approx(props.mass_kg * 9.81, rel=0.02)
    assert np.linalg.norm(mean_net_w[:2]) < 0.05 * mean_net_w[2]


def test_contact_points_belong_to_the_logged_pose_of_a_fast_rolling_can(can_asset):
    """A can rolling at 3 m/s: each logged contact point is directly below its axis in the
    pose logged at the same sample (a one-step lag would put it v * dt = 3 mm behind)."""
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RotationMatrix

    mesh_path, urdf, _ = can_asset
    spec = dataclasses.replace(make_run_specs("push", 1, seed=0)[0], pusher_approach_rad=0.0,
                               object_offset_m=(3.0, 0.0))  # pusher far behind, never touches
    cfg = dataclasses.replace(SHORT_PUSH, settle_s=0.05, push_duration_s=0.0, reset_interval_s=None)
    rest = simulate_candidate(urdf, "point", spec, cfg, initial_mesh_path=mesh_path)
    # Start rolling without slip across its axis, from the rested state.
    q = rest.object_quaternion_wxyz[-1]
    R0 = RotationMatrix(Quaternion(q / np.linalg.norm(q))).matrix()
    axis = R0[:, 2]
    across = np.cross([0.0, 0.0, 1.0], axis)
    v = 3.0 * across / np.linalg.norm(across)
    w = np.cross([0.0, 0.0, 1.0], v) / CAN_R  # v = w x (r up): rolling without slip
    vel = rest.object_spatial_velocity.copy()
    vel[0] = np.concatenate([w, v])
    start = dataclasses.replace(rest, object_position_m=np.repeat(rest.object_position_m[-1:], len(rest.times_s), 0),
                                object_quaternion_wxyz=np.repeat(rest.object_quaternion_wxyz[-1:], len(rest.times_s), 0),
                                object_spatial_velocity=vel)
    for contact_model in ("point", "hydroelastic"):
        roll = simulate_candidate(urdf, contact_model, spec, cfg, reference=start)
        speed = np.linalg.norm(roll.object_spatial_velocity[:, 3:], axis=1)
        checked = 0
        along = []
        for i in range(1, len(roll.times_s)):
            pts = roll.contact_points_object_m[i]
            if len(pts) != 1 or speed[i] < 2.5:
                continue
            q = roll.object_quaternion_wxyz[i]
            R = RotationMatrix(Quaternion(q / np.linalg.norm(q))).matrix()
            offset = pts[0] @ R.T  # from the can's centre, in world axes
            along.append(offset @ (v / 3.0))
            if contact_model == "point":
                assert abs(along[-1]) < 3e-4, (contact_model, i, offset)
            checked += 1
        # A compliant rolling contact's pressure centroid wanders about a millimetre around
        # the axis (dissipation, settling after the start); a one-step lag would shift it 3 mm.
        assert abs(np.median(along)) < 1.5e-3, (contact_model, np.median(along))
        assert checked > 20


def test_an_untimed_candidate_is_the_same_trajectory_without_a_time(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    timed = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    shown = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path, timed=False)
    assert np.isfinite(timed.sim_time_s) and timed.sim_time_s > 0 and np.isnan(shown.sim_time_s)
    assert np.array_equal(timed.object_position_m, shown.object_position_m)
    assert np.array_equal(timed.object_quaternion_wxyz, shown.object_quaternion_wxyz)


def test_ramp_tilts_to_45_degrees_and_object_moves_down_slope(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("ramp", 1, seed=0)[0]
    traj = simulate_candidate(urdf, "hydroelastic", spec, SHORT_RAMP, initial_mesh_path=mesh_path)
    angle = traj.actuated_positions[:, 0]
    assert angle[0] == 0.0
    assert np.rad2deg(angle[-1]) == pytest.approx(45.0, abs=1.0)
    d = traj.object_position_m[-1] - traj.object_position_m[0]
    assert d[1] < -0.02 and d[2] < -0.02  # down-slope is -y and down
    assert abs(d[0]) < abs(d[1])  # rolls down the slope, not sideways


def test_equation_error_against_itself_is_exact_and_resets_on_step_multiples(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 2, seed=0)[1]
    ref = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    again = simulate_candidate(urdf, "point", spec, SHORT_PUSH, reference=ref)
    assert _ate(ref, again) < 1e-6
    assert np.array_equal(ref.object_position_m, again.object_position_m)  # deterministic
    # 300 steps, reset every 100: resets at steps 100 and 200 (the start is not one).
    assert again.reset_steps.tolist() == [100, 200]
    # A duration that is not a multiple of the interval: the last partial interval is simulated.
    cfg = dataclasses.replace(SHORT_PUSH, push_duration_s=0.3)  # 350 steps
    ref = simulate_candidate(urdf, "point", spec, cfg, initial_mesh_path=mesh_path)
    again = simulate_candidate(urdf, "point", spec, cfg, reference=ref)
    assert again.reset_steps.tolist() == [100, 200, 300]
    assert len(again.times_s) == 351 and _ate(ref, again) < 1e-6
    assert len(again.reset_steps) == int(np.floor((350 - 1) / 100))


def test_equation_error_resets_candidate_to_reference(can_asset):
    """Point contact vs the hydroelastic mesh reference: the candidate drifts within an
    interval, and right after each reset it is one step away from the reference again."""
    mesh_path, urdf, props = can_asset
    spec = make_run_specs("ramp", 1, seed=0)[0]
    ref = simulate_reference(mesh_path, props, spec, SHORT_RAMP)
    assert ref.representation == "reference" and ref.contact_model == "hydroelastic"
    eq = simulate_candidate(urdf, "point", spec, SHORT_RAMP, reference=ref)
    free = simulate_candidate(urdf, "point", spec, dataclasses.replace(SHORT_RAMP, reset_interval_s=None),
                              reference=ref)
    assert len(free.reset_steps) == 0 and eq.reset_steps.tolist() == [100, 200, 300, 400]
    assert np.array_equal(eq.object_position_m[0], ref.object_position_m[0])
    err = np.linalg.norm(eq.object_position_m - ref.object_position_m, axis=1)
    for r in eq.reset_steps:
        assert err[r + 1] < 2e-3  # one step (1 ms) after a reset
    # Drift accumulates within each interval, so resets keep the error bounded.
    assert _ate(eq, ref) <= _ate(free, ref) + 1e-9
    # The same geometry, hydroelastic: equation error of a few millimetres at most.
    hydro = simulate_candidate(urdf, "hydroelastic", spec, SHORT_RAMP, reference=ref)
    assert _ate(hydro, ref) < 5e-3


def test_a_reset_fully_determines_what_follows(can_asset):
    """No hidden memory besides the state that is reset: two references that agree at the
    reset at step 200 but differ at step 100 give the same candidate after step 200."""
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    ref = simulate_candidate(urdf, "hydroelastic", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    pos = ref.object_position_m.copy()
    pos[100] += [0.0, 0.0, 0.002]  # dropped from 2 mm higher at t = 0.1 s
    other = dataclasses.replace(ref, object_position_m=pos)
    a = simulate_candidate(urdf, "point", spec, SHORT_PUSH, reference=ref)
    b = simulate_candidate(urdf, "point", spec, SHORT_PUSH, reference=other)
    assert not np.array_equal(a.object_position_m[101:200], b.object_position_m[101:200])
    assert np.array_equal(a.object_position_m[201:], b.object_position_m[201:])
    assert np.array_equal(a.object_quaternion_wxyz[201:], b.object_quaternion_wxyz[201:])


def test_reference_and_candidate_start_from_the_same_state(can_asset):
    mesh_path, urdf, props = can_asset
    spec = make_run_specs("push", 3, seed=5)[2]
    cfg = dataclasses.replace(SHORT_PUSH, push_duration_s=0.05)
    ref = simulate_reference(mesh_path, props, spec, cfg)
    cand = simulate_candidate(urdf, "hydroelastic", spec, cfg)  # finds ../visual/model.obj itself
    assert np.array_equal(ref.object_position_m[0], cand.object_position_m[0])
    assert np.array_equal(ref.object_quaternion_wxyz[0], cand.object_quaternion_wxyz[0])
    assert np.array_equal(ref.actuated_positions[0], cand.actuated_positions[0])


def test_a_resting_block_stays_put(tmp_path):
    """The initial pose is a stable rest: a block on the floor does not tip during settling."""
    import trimesh
    from real2sim.formats.physical import PhysicalProperties

    block = trimesh.creation.box((0.06, 0.04, 0.12))
    mesh_path = tmp_path / "block.obj"
    block.export(mesh_path)
    m = 0.3
    inertia = m / 12 * np.diag([0.04**2 + 0.12**2, 0.06**2 + 0.12**2, 0.06**2 + 0.04**2])
    props = PhysicalProperties(m, (0.0, 0.0, 0.0), tuple(map(tuple, inertia)))
    cfg = dataclasses.replace(SHORT_PUSH, settle_s=0.2, push_duration_s=0.0)
    for spec in make_run_specs("push", 2, seed=7):
        traj = simulate_reference(mesh_path, props, spec, cfg)
        assert np.abs(traj.object_position_m[-1, :2] - traj.object_position_m[0, :2]).max() < 5e-4
        q0, q1 = traj.object_quaternion_wxyz[0], traj.object_quaternion_wxyz[-1]
        assert abs(abs(q0 @ q1) - 1) < 1e-4  # no rotation


def test_reference_mismatch_is_rejected(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    ref = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    with pytest.raises(ValueError, match="samples"):
        simulate_candidate(urdf, "point", spec, dataclasses.replace(SHORT_PUSH, push_duration_s=0.35),
                           reference=ref)


def test_a_diverging_run_raises_an_informative_error(can_asset):
    mesh_path, urdf, _ = can_asset
    spec = make_run_specs("push", 1, seed=0)[0]
    ref = simulate_candidate(urdf, "point", spec, SHORT_PUSH, initial_mesh_path=mesh_path)
    # A reset to an absurd state (the object flung at 5 km/s at t = 0.2 s) makes the run
    # leave the world: the error names the run and the time instead of writing garbage.
    fast_v = ref.object_spatial_velocity.copy()
    fast_v[200, 3:] = [5000.0, 0.0, 0.0]
    flung = dataclasses.replace(ref, object_spatial_velocity=fast_v)
    with pytest.raises(SimulationError, match=r"cylinders_1 point push run 0: .*exploded at t = 0\.300"):
        simulate_candidate(urdf, "point", spec, SHORT_PUSH, reference=flung)
    # A non-finite reference sample is refused before Drake sees it (Drake would abort).
    nan_v = ref.object_spatial_velocity.copy()
    nan_v[100] = np.nan
    with pytest.raises(SimulationError, match=r"not finite.*t = 0\.100|t = 0\.100.*not finite"):
        simulate_candidate(urdf, "point", spec, SHORT_PUSH,
                           reference=dataclasses.replace(ref, object_spatial_velocity=nan_v))


@pytest.mark.slow
@pytest.mark.parametrize("task", ["push", "ramp"])
def test_bottle_full_scenes_mesh_candidate_matches_reference(tmp_path, task):
    """End to end at the default scene lengths: the bundled bottle as reference and, as
    candidate, the same mesh (rigid hydroelastic: identical; point contact: close)."""
    from real2sim.asset.export.writers import write_representation
    from real2sim.asset.canonical import canonicalize
    from real2sim.formats.collision import CollisionGeometry, CollisionShape
    from real2sim.formats.contact import ContactProperties
    from real2sim.geometry.objects import OBJECTS, make_object
    from real2sim.formats.physical import PhysicalProperties

    mesh, _ = canonicalize(make_object("bottle"))
    (tmp_path / "visual").mkdir()
    mesh_path = tmp_path / "visual" / "model.obj"
    mesh.export(mesh_path)
    dense = mesh.copy()
    dense.density = OBJECTS["bottle"].mass_kg / mesh.volume
    props = PhysicalProperties(OBJECTS["bottle"].mass_kg, tuple(dense.center_mass),
                               tuple(map(tuple, dense.moment_inertia)))
    rep = tmp_path / "mesh"
    rep.mkdir()
    mesh.export(rep / "mesh.obj")
    write_representation(rep, CollisionGeometry("mesh", "mesh", (
        CollisionShape("mesh", (), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), "mesh.obj"),)), props,
        ContactProperties())
    cfg = SceneConfig()
    spec = make_run_specs(task, 1, seed=0)[0]
    ref = simulate_reference(mesh_path, props, spec, cfg)
    travel = np.linalg.norm(ref.object_position_m[-1, :2] - ref.object_position_m[0, :2])
    assert travel > (0.1 if task == "push" else 1.0)
    same = simulate_candidate(rep / "model.urdf", "hydroelastic", spec, cfg, reference=ref)
    assert _ate(same, ref) < 1e-6
    point = simulate_candidate(rep / "model.urdf", "point", spec, cfg, reference=ref)
    assert _ate(point, ref) < 0.02
