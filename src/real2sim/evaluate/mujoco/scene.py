"""The evaluation's two scenes in MuJoCo, built around a representation's ``model.xml``.

The same world as :mod:`real2sim.evaluate.scene.world` and :mod:`~real2sim.evaluate.scene.tasks`, in
MuJoCo's terms (world z up, gravity -9.81 m/s^2, metres, kg):

* the object: ``model.xml`` as the asset wrote it (one free body ``object`` whose frame is the asset
  frame, inertia written explicitly); its non-colliding visual geoms and their mesh, texture and
  material are dropped (they cost compile time, never simulation time);
* the floor: a plane whose top is z = 0 (Drake's is a compliant slab, top at z = 0);
* push: a sphere of ``pusher_radius_m`` on two slide joints (world -x-> carriage -y-> sphere), its centre
  ``pusher_clearance_m`` above its radius, each joint driven by a PD actuator with Drake's gains;
* ramp: the box table on a hinge about world x at ``hinge_height_m``, extending towards -y, its mass
  centred on the hinge, driven by a PD actuator with Drake's gains along the same minimum-jerk tilt.

A PD actuator is MuJoCo's affine ``general`` actuator ``kp * ctrl - kp * q - kd * qdot`` with the set point
``ctrl = q_d + (kd / kp) * qdot_d``, which is Drake's ``kp (q_d - q) + kd (qdot_d - qdot)`` exactly.

Friction: Drake combines a pair's coefficients as ``2 a b / (a + b)``, MuJoCo takes the larger; the
environment's geoms carry the Drake-combined coefficient with a higher ``priority``, so every contact
has Drake's coefficient. Every touching geom gets :class:`~real2sim.formats.contact.MujocoConfig`'s
condim, solref and solimp.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.formats.contact import MujocoConfig
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import RunSpec, pusher_start_xy, run_steps, task_named, tilt_angle_rad

OBJECT_BODY = "object"  # real2sim.asset.export.mjcf.BODY_NAME, the body model.xml names


@dataclass
class MujocoScene:
    """A compiled scene and what the simulation needs to read and set its state.

    model, data: MuJoCo's MjModel and an MjData of it. object_qpos, object_dof: the free joint's 7
    positions (x y z qw qx qy qz) and 6 velocities (v world, then omega in the body frame) as index
    arrays. actuated_qpos, actuated_dof: the pusher's two slide joints (x, y, m) or the table's hinge (rad),
    in the order of Drake's actuated state. object_geoms: ids of the object's collision geoms.
    set_points: (steps + 1, nu) the actuators' ``ctrl`` at every scene step. task: as built.
    """

    model: object
    data: object
    object_qpos: np.ndarray
    object_dof: np.ndarray
    actuated_qpos: np.ndarray
    actuated_dof: np.ndarray
    object_geoms: np.ndarray
    set_points: np.ndarray
    task: str


def combined_friction(a: float, b: float) -> float:
    """Drake's combination of two Coulomb coefficients, ``2 a b / (a + b)`` (0 when both are 0)."""
    return 0.0 if a + b == 0 else 2.0 * a * b / (a + b)


def _drop_visuals(spec) -> None:
    """Remove the object's non-colliding geoms and the assets only they use."""
    used = set()
    for geom in list(spec.geoms):
        if geom.contype == 0 and geom.conaffinity == 0:
            used.update({geom.meshname, geom.material})
            spec.delete(geom)
        else:
            used.discard(geom.meshname)
    for mesh in list(spec.meshes):
        if mesh.name in used:
            spec.delete(mesh)
    textures = set()
    for material in list(spec.materials):
        if material.name in used:
            textures.update(t for t in material.textures if t)
            spec.delete(material)
    for texture in list(spec.textures):
        if texture.name in textures:
            spec.delete(texture)


def _contact_settings(geom, cfg: MujocoConfig) -> None:
    geom.condim = cfg.condim
    geom.solref = [cfg.solref_timeconst_s, cfg.solref_dampratio]
    geom.solimp = list(cfg.solimp)


def _environment_geom(body, mujoco, cfg: MujocoConfig, mu: float, **attrs):
    geom = body.add_geom(**attrs)
    _contact_settings(geom, cfg)
    geom.friction = [mu, 0.0, 0.0]
    geom.priority = 1  # its friction (Drake's combined coefficient) wins over the object's
    return geom


def _pd_actuator(spec, mujoco, joint: str, kp: float, kd: float) -> None:
    spec.add_actuator(name=f"{joint}_motor", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                      gaintype=mujoco.mjtGain.mjGAIN_FIXED, biastype=mujoco.mjtBias.mjBIAS_AFFINE,
                      gainprm=[kp] + [0.0] * 9, biasprm=[0.0, -kp, -kd] + [0.0] * 7)


def _add_pusher(spec, mujoco, run_spec: RunSpec, cfg: SceneConfig, mj: MujocoConfig, mu: float) -> None:
    carriage = spec.worldbody.add_body(name="pusher_carriage", mass=0.1, inertia=[1e-4, 1e-4, 1e-4], ipos=[0.0] * 3,
                                          explicitinertial=True)
    carriage.add_joint(name="pusher_x", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0, 0.0, 0.0])
    r = cfg.pusher_radius_m
    inertia = 0.4 * cfg.pusher_mass_kg * r * r
    sphere = carriage.add_body(name="pusher_sphere", pos=[0.0, 0.0, r + cfg.pusher_clearance_m],
                               mass=cfg.pusher_mass_kg, inertia=[inertia] * 3, ipos=[0.0] * 3,
                               explicitinertial=True)
    sphere.add_joint(name="pusher_y", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0.0, 1.0, 0.0])
    _environment_geom(sphere, mujoco, mj, mu, name="pusher_sphere", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                      size=[r, 0.0, 0.0])
    for joint in ("pusher_x", "pusher_y"):
        _pd_actuator(spec, mujoco, joint, cfg.pusher_kp_n_per_m, cfg.pusher_kd_n_s_per_m)


def _add_table(spec, mujoco, cfg: SceneConfig, mj: MujocoConfig, mu: float) -> None:
    lx, ly, lz = cfg.table_size_m
    m = cfg.table_mass_kg
    # The slab's inertia about the hinge with its mass put on the hinge, as the Drake table's.
    c = np.array([0.0, -ly / 2, -lz / 2])
    Ic = m / 12 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    Ih = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    table = spec.worldbody.add_body(name="table", pos=[0.0, 0.0, cfg.hinge_height_m], mass=m, ipos=[0.0] * 3,
                                    explicitinertial=True,
                                    fullinertia=[Ih[0, 0], Ih[1, 1], Ih[2, 2], Ih[0, 1], Ih[0, 2], Ih[1, 2]])
    table.add_joint(name="ramp_hinge", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1.0, 0.0, 0.0])
    _environment_geom(table, mujoco, mj, mu, name="table", type=mujoco.mjtGeom.mjGEOM_BOX,
                      size=[lx / 2, ly / 2, lz / 2], pos=c.tolist())
    _pd_actuator(spec, mujoco, "ramp_hinge", cfg.table_kp_n_m_per_rad, cfg.table_kd_n_m_s_per_rad)


def _set_points(task: str, run_spec: RunSpec, cfg: SceneConfig) -> np.ndarray:
    """(steps + 1, nu) actuator set points ``q_d + (kd / kp) qdot_d`` at every scene step."""
    t = np.arange(run_steps(task, cfg) + 1) * cfg.time_step_s
    if task == "push":
        u = np.array([np.cos(run_spec.pusher_approach_rad), np.sin(run_spec.pusher_approach_rad)])
        moving = (t >= cfg.settle_s) & (t < cfg.settle_s + cfg.push_duration_s)
        travel = cfg.pusher_speed_m_per_s * np.clip(t - cfg.settle_s, 0.0, cfg.push_duration_s)
        q = pusher_start_xy(run_spec, cfg)[None, :] + travel[:, None] * u[None, :]
        qd = np.where(moving[:, None], cfg.pusher_speed_m_per_s * u[None, :], 0.0)
        return q + (cfg.pusher_kd_n_s_per_m / cfg.pusher_kp_n_per_m) * qd
    q, qd = tilt_angle_rad(t, cfg)
    return (q + (cfg.table_kd_n_m_s_per_rad / cfg.table_kp_n_m_per_rad) * qd)[:, None]


def load_object_spec(model_xml: Path):
    """The representation's model.xml as an MjSpec, its visual geoms dropped; ValueError when it holds
    no free body named ``object``."""
    import mujoco

    model_xml = Path(model_xml)
    if not model_xml.is_file():
        raise FileNotFoundError(f"no MuJoCo model at {model_xml} (build the asset with --format mjcf)")
    spec = mujoco.MjSpec.from_file(str(model_xml.resolve()))
    body = spec.body(OBJECT_BODY)
    if body is None or not any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints):
        raise ValueError(f"{model_xml}: expected a free body named {OBJECT_BODY!r}")
    _drop_visuals(spec)
    return spec


def build_mujoco_scene(model_xml: Path, run_spec: RunSpec, cfg: SceneConfig, mj: MujocoConfig) -> MujocoScene:
    """The ``run_spec.task`` scene around the object of ``model_xml`` (see the module docstring)."""
    import mujoco

    task_named(run_spec.task)
    spec = load_object_spec(model_xml)
    spec.option.timestep = mj.timestep_s
    spec.option.gravity = [0.0, 0.0, -9.81]
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{mj.integrator.upper()}")
    spec.option.cone = getattr(mujoco.mjtCone, f"mjCONE_{mj.cone.upper()}")
    spec.option.impratio = mj.impratio
    object_mu = []
    for geom in spec.body(OBJECT_BODY).geoms:
        _contact_settings(geom, mj)
        object_mu.append(float(geom.friction[0]))
    mu_object = float(np.mean(object_mu)) if object_mu else 0.5  # the writer gives every geom the same
    half = cfg.floor_size_m / 2
    _environment_geom(spec.worldbody, mujoco, mj, combined_friction(mu_object, cfg.floor_mu), name="floor",
                      type=mujoco.mjtGeom.mjGEOM_PLANE, size=[half, half, 0.1])
    if run_spec.task == "push":
        _add_pusher(spec, mujoco, run_spec, cfg, mj, combined_friction(mu_object, cfg.pusher_mu))
        joints = ("pusher_x", "pusher_y")
    else:
        _add_table(spec, mujoco, cfg, mj, combined_friction(mu_object, cfg.table_mu))
        joints = ("ramp_hinge",)
    model = spec.compile()
    body = model.body(OBJECT_BODY).id
    free = model.body_jntadr[body]
    qa, da = model.jnt_qposadr[free], model.jnt_dofadr[free]
    actuated = [model.joint(j).id for j in joints]
    geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] == body
                      and (model.geom_contype[g] or model.geom_conaffinity[g])], dtype=int)
    return MujocoScene(model=model, data=mujoco.MjData(model), object_qpos=np.arange(qa, qa + 7),
                       object_dof=np.arange(da, da + 6),
                       actuated_qpos=np.array([model.jnt_qposadr[j] for j in actuated]),
                       actuated_dof=np.array([model.jnt_dofadr[j] for j in actuated]),
                       object_geoms=geoms, set_points=_set_points(run_spec.task, run_spec, cfg), task=run_spec.task)
