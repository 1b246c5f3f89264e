"""A candidate simulated in MuJoCo under the evaluation's protocol, against a Drake reference.

The candidate starts from the reference's first sample and, with equation error, is reset to the
reference's state every ``reset_interval_s`` (object pose and velocity, and the pusher's or table's
joints), exactly as :mod:`real2sim.evaluate.simulate` resets a Drake candidate. The trajectory is a
:class:`~real2sim.formats.trajectory.Trajectory` sampled at the scene's steps, so the same scoring code
scores it.

Frames: Drake's free-body state is (qw qx qy qz, p; omega_W, v_W), MuJoCo's free joint (p, qw qx qy qz;
v_W, omega_B) with omega in the body frame; :func:`mujoco_state` and :func:`drake_velocity` convert.

As in Drake each simulation runs twice on the same model: the timed run (``mj_step`` from reset to
reset, the actuators' set point written before each scene step, as a controller would; ``sim_time_s``
is its wall time) and the instrumented run (the state read at every scene step, and the object's
contacts of that sample's state, as Drake's unsampled port gives them: those ``mj_step`` found when it
stepped from the sample, at a reset those of the prediction, by one ``mj_forward`` before the reset, and
at the last sample by one more). MuJoCo is deterministic: both end in the same state (a RuntimeWarning
if not).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from real2sim.formats.contact import MujocoConfig
from real2sim.evaluate.mujoco.scene import MujocoScene, build_mujoco_scene
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import RunSpec, run_steps
from real2sim.evaluate.simulate import CHUNK_STEPS, Deadline, SimulationError, SimulationTimeout
from real2sim.formats.rotations import quaternions_to_matrices
from real2sim.formats.trajectory import Trajectory


def _rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    q = np.asarray(quat_wxyz, dtype=float)
    return quaternions_to_matrices((q / np.linalg.norm(q))[None, :])[0]


def mujoco_state(traj: Trajectory, step: int) -> tuple[np.ndarray, np.ndarray]:
    """The object's MuJoCo free-joint (qpos (7,), qvel (6,)) at sample ``step`` of a Drake trajectory."""
    q = traj.object_quaternion_wxyz[step]
    omega_w, v_w = traj.object_spatial_velocity[step, :3], traj.object_spatial_velocity[step, 3:]
    qpos = np.concatenate([traj.object_position_m[step], q])
    return qpos, np.concatenate([v_w, _rotation(q).T @ omega_w])


def drake_velocity(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Drake's spatial velocity (omega_W, v_W) (6,) of a MuJoCo free joint's state."""
    return np.concatenate([_rotation(qpos[3:7]) @ qvel[3:6], qvel[:3]])


def _set_state(scene: MujocoScene, traj: Trajectory, step: int, dt: float, label: str) -> None:
    qpos, qvel = mujoco_state(traj, step)
    act_q, act_v = traj.actuated_positions[step], traj.actuated_velocities[step]
    if not all(np.all(np.isfinite(x)) for x in (qpos, qvel, act_q, act_v)):
        raise SimulationError(f"{label}: the state to set at t = {step * dt:.3f} s is not finite")
    d = scene.data
    d.qpos[scene.object_qpos] = qpos
    d.qvel[scene.object_dof] = qvel
    d.qpos[scene.actuated_qpos] = act_q
    d.qvel[scene.actuated_dof] = act_v
    d.time = step * dt


def _check(scene: MujocoScene, label: str, t_s: float) -> None:
    q, v = scene.data.qpos[scene.object_qpos], scene.data.qvel[scene.object_dof]
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
        raise SimulationError(f"{label}: non-finite object state at t = {t_s:.3f} s")
    if np.abs(q[:3]).max() > 1e3 or np.abs(v).max() > 1e3:
        raise SimulationError(f"{label}: object state exploded at t = {t_s:.3f} s (|position| "
                              f"{np.abs(q[:3]).max():.3g} m, |velocity| {np.abs(v).max():.3g})")


def _spans(num_steps: int, interval: int | None) -> list[tuple[int, int]]:
    if not interval:
        return [(0, num_steps)]
    return [(a, min(a + interval, num_steps)) for a in range(0, num_steps, interval)]


def _reset(scene: MujocoScene, reference: Trajectory, step: int, dt: float, label: str) -> None:
    import mujoco

    mujoco.mj_resetData(scene.model, scene.data)
    _set_state(scene, reference, step, dt, label)


def _timed_run(scene: MujocoScene, reference: Trajectory, spans, dt: float, substeps: int, label: str,
               deadline: Deadline) -> tuple[float, np.ndarray]:
    import mujoco

    m, d = scene.model, scene.data
    _reset(scene, reference, 0, dt, label)
    set_points = scene.set_points
    wall = 0.0
    for a, b in spans:
        if a > 0:
            _set_state(scene, reference, a, dt, label)
        step = a
        while step < b:
            end = min(step + CHUNK_STEPS, b)
            t0 = time.perf_counter()
            for i in range(step, end):
                d.ctrl[:] = set_points[i]
                mujoco.mj_step(m, d, substeps)
            wall += time.perf_counter() - t0
            step = end
            deadline.check(label, step * dt)
        _check(scene, label, b * dt)
    return wall, d.qpos.copy()


def _contacts(scene: MujocoScene, force6: np.ndarray, is_object: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The object's contact points (K, 3) and the forces it feels there (K, 3), world frame
    (``is_object``: (ngeom,) True for the object's collision geoms)."""
    import mujoco

    m, d = scene.model, scene.data
    n = d.ncon
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    geoms = d.contact.geom[:n]
    ours1 = is_object[geoms[:, 0]]
    ours2 = is_object[geoms[:, 1]]
    active = (ours1 | ours2) & (d.contact.efc_address[:n] >= 0)
    pts, forces = [], []
    for k in np.flatnonzero(active):
        mujoco.mj_contactForce(m, d, int(k), force6)
        # force6 is in the contact frame (rows of frame: normal first) and acts on geom2 (the normal points
        # from geom1 to geom2); the object feels minus that when it is geom1.
        f_w = d.contact.frame[k].reshape(3, 3).T @ force6[:3]
        pts.append(d.contact.pos[k].copy())
        forces.append(f_w if ours2[k] else -f_w)
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.asarray(pts), np.asarray(forces)


def simulate_candidate_mujoco(model_xml: Path, run_spec: RunSpec, scene_config: SceneConfig, reference: Trajectory,
                              mujoco_config: MujocoConfig = MujocoConfig(), timeout_s: float | None = None,
                              representation: str | None = None) -> Trajectory:
    """Simulate the representation of ``model_xml`` in MuJoCo on ``run_spec`` from ``reference``'s first
    sample, reset to it every ``scene_config.reset_interval_s`` (None/0: one free roll-out). Its
    contact model is "point" (MuJoCo's contacts are points). ``timeout_s``: wall-clock limit of the call
    (:class:`SimulationTimeout` past it); None: none."""
    import mujoco

    deadline = Deadline(timeout_s)
    model_xml = Path(model_xml)
    name = representation or model_xml.resolve().parent.name
    label = f"{name} mujoco {run_spec.task} run {run_spec.run}"
    dt = scene_config.time_step_s
    n = run_steps(run_spec.task, scene_config)
    if len(reference.times_s) != n + 1 or reference.task != run_spec.task or reference.run != run_spec.run:
        raise ValueError(f"{label}: the reference has {len(reference.times_s)} samples of task {reference.task!r} "
                         f"run {reference.run}; expected {n + 1} of {run_spec.task!r} run {run_spec.run}")
    substeps = mujoco_config.substeps(dt)
    try:
        scene = build_mujoco_scene(model_xml, run_spec, scene_config, mujoco_config)
    except (ValueError, FileNotFoundError):
        raise
    except Exception as exc:  # MuJoCo's compiler raises its own errors, one line each
        raise SimulationError(f"{label}: MuJoCo could not load the model: {str(exc).splitlines()[0]}") from exc
    interval = scene_config.reset_interval_steps()
    spans = _spans(n, interval)
    reset_steps = np.array([a for a, _ in spans if a > 0], dtype=int)
    deadline.check(label, 0.0)

    sim_time_s, timed_final = _timed_run(scene, reference, spans, dt, substeps, label, deadline)

    m, d = scene.model, scene.data
    na = len(scene.actuated_qpos)
    oq, ov = np.empty((n + 1, 7)), np.empty((n + 1, 6))
    aq, av = np.empty((n + 1, na)), np.empty((n + 1, na))
    mq, mv = np.empty((n + 1, 7)), np.empty((n + 1, 6))  # MuJoCo's free-joint state, converted after the loop
    contacts_w, forces_w = [], []
    force6 = np.zeros(6)
    resets = set(int(r) for r in reset_steps)
    is_object = np.zeros(m.ngeom, dtype=bool)
    is_object[scene.object_geoms] = True

    def log(i: int) -> None:
        mq[i] = d.qpos[scene.object_qpos]
        mv[i] = d.qvel[scene.object_dof]
        aq[i] = d.qpos[scene.actuated_qpos]
        av[i] = d.qvel[scene.actuated_dof]

    def log_contacts() -> None:
        pts, forces = _contacts(scene, force6, is_object)
        contacts_w.append(pts)
        forces_w.append(forces)

    _reset(scene, reference, 0, dt, label)
    log(0)
    t0 = time.perf_counter()
    for i in range(n):
        d.ctrl[:] = scene.set_points[i]
        # One step from the sample: mj_step's contacts are those of the state it stepped from. At a reset
        # (the prediction's contacts) or with several MuJoCo steps per sample: one mj_forward first.
        cheap = substeps == 1 and i not in resets
        if not cheap:
            mujoco.mj_forward(m, d)
            log_contacts()
        if i in resets:
            _set_state(scene, reference, i, dt, label)
        mujoco.mj_step(m, d, substeps)
        if cheap:
            log_contacts()
        log(i + 1)
        if (i + 1) % 100 == 0 or i + 1 == n:
            _check(scene, label, (i + 1) * dt)
        if (i + 1) % CHUNK_STEPS == 0:
            deadline.check(label, (i + 1) * dt)
    mujoco.mj_forward(m, d)
    log_contacts()  # the last sample's
    instrumented_time_s = time.perf_counter() - t0
    if not np.array_equal(d.qpos, timed_final):
        warnings.warn(f"{label}: timed and instrumented runs ended apart (max |dq| "
                      f"{np.abs(d.qpos - timed_final).max():.3g}); sim_time_s timed a different rollout",
                      RuntimeWarning, stacklevel=2)
    oq[:, :4], oq[:, 4:] = mq[:, 3:7], mq[:, :3]
    rotations = quaternions_to_matrices(mq[:, 3:7] / np.linalg.norm(mq[:, 3:7], axis=1, keepdims=True))
    ov[:, :3] = np.einsum("tij,tj->ti", rotations, mv[:, 3:6])  # omega from the body frame into the world's
    ov[:, 3:] = mv[:, :3]
    contacts_o = [(pw - oq[i, 4:]) @ rotations[i] for i, pw in enumerate(contacts_w)]
    forces_o = [fw @ rotations[i] for i, fw in enumerate(forces_w)]
    return Trajectory(times_s=np.arange(n + 1) * dt, object_position_m=oq[:, 4:].copy(),
                      object_quaternion_wxyz=oq[:, :4].copy(), object_spatial_velocity=ov,
                      actuated_positions=aq, actuated_velocities=av, contact_points_object_m=contacts_o,
                      contact_forces_object_n=forces_o, contact_surface_counts=np.zeros(n + 1, dtype=np.int64),
                      sim_time_s=sim_time_s, sim_duration_s=n * dt, instrumented_time_s=instrumented_time_s,
                      reset_steps=reset_steps, task=run_spec.task, contact_model="point", representation=name,
                      run=run_spec.run)
