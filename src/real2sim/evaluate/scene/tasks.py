"""The evaluation's tasks (paper V-C): planar pushing and the actuated ramp, one small object each.

A task says how long one run lasts, how its seeded initial conditions are drawn
(:class:`RunSpec`), where the object starts, which actuated body it adds to the
plant (a pusher sphere on two prismatic joints, or a table on a hinge) and that
body's desired trajectory. :mod:`real2sim.evaluate.scene.world` builds the same world
around either; adding a task means adding one object here.

* push: a sphere of radius ``pusher_radius_m`` on two prismatic joints
  (world -x-> carriage -y-> sphere), PD-controlled along a straight line towards the
  object's initial centre at constant speed, its centre ``pusher_clearance_m`` above
  ``pusher_radius_m`` so it never rubs on the floor.
* ramp: a compliant box table (``table_size_m`` = x width along the hinge,
  y length down-slope, thickness) on a revolute joint about world x at
  (0, 0, ``hinge_height_m``). The hinge lies on the table's top face at its +y edge;
  the table extends towards -y, and tilting by +theta lowers the -y end, so the
  object, placed just down-slope of the hinge, rolls towards -y. The table's mass is
  centred on the hinge (a counterweight), so the PD actuator only fights the object.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from real2sim.evaluate.scene.plant_parts import contact_material, pd_actuator
from real2sim.evaluate.scene.scene_config import SceneConfig


@dataclass(frozen=True)
class RunSpec:
    """Initial conditions of one simulation; identical for every representation.

    task: "push" or "ramp". run: index within the task's list. seed: the seed the list was
        drawn from (:func:`make_run_specs`), kept for the record.
    object_yaw_rad: rotation about world z of the placed object, rad.
    object_roll_rad: which side a lying object rests on: the stable resting pose whose
        downward direction, as an angle about the asset z axis, is nearest this, rad.
    object_offset_m: (x, y) offset of the object's asset-frame origin from the task's
        nominal place, m (push: from the world origin; ramp: x along the hinge, y down-slope
        is negative).
    pusher_approach_rad: push only: direction of the pusher's motion in the floor plane
        (the pusher starts at centre - d (cos a, sin a)), rad.
    """

    task: str
    run: int
    seed: int
    object_yaw_rad: float
    object_offset_m: tuple[float, float]
    pusher_approach_rad: float = 0.0
    object_roll_rad: float = 0.0


def make_run_specs(task: str, runs: int, seed: int) -> list[RunSpec]:
    """``runs`` seeded initial conditions for ``task``; the same list for every representation
    (each task's :meth:`run_spec` says how one is drawn)."""
    chosen = task_named(task)
    if runs < 0:
        raise ValueError("runs must be >= 0")
    # One stream per (seed, task): adding runs appends specs, never changes earlier ones.
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), TASKS.index(task)]))
    return [chosen.run_spec(run, int(seed), rng.random(6)) for run in range(runs)]


def pusher_start_xy(run_spec: RunSpec, cfg: SceneConfig) -> np.ndarray:
    """(x, y) of the pusher's centre at t = 0, m."""
    u = np.array([np.cos(run_spec.pusher_approach_rad), np.sin(run_spec.pusher_approach_rad)])
    return np.asarray(run_spec.object_offset_m, dtype=float) - cfg.pusher_start_distance_m * u


def _add_pusher(plant, run_spec: RunSpec, cfg: SceneConfig):
    from pydrake.geometry import AddCompliantHydroelasticProperties, ProximityProperties, Sphere
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import (FixedOffsetFrame, PrismaticJoint, RotationalInertia,
                                       SpatialInertia)

    instance = plant.AddModelInstance("pusher")
    carriage = plant.AddRigidBody("pusher_carriage", instance, SpatialInertia.MakeFromCentralInertia(
        0.1, np.zeros(3), RotationalInertia(1e-4, 1e-4, 1e-4)))
    sphere = plant.AddRigidBody("pusher_sphere", instance, SpatialInertia.SolidSphereWithMass(
        cfg.pusher_mass_kg, cfg.pusher_radius_m))
    height_m = cfg.pusher_radius_m + cfg.pusher_clearance_m
    jx = plant.AddJoint(PrismaticJoint("pusher_x", plant.world_frame(), carriage.body_frame(),
                                       [1.0, 0.0, 0.0]))
    # The height lives in the y joint's parent offset so the carriage frame sits at z = 0.
    y_parent = plant.AddFrame(FixedOffsetFrame("pusher_y_parent", carriage.body_frame(),
                                               RigidTransform([0.0, 0.0, height_m])))
    jy = plant.AddJoint(PrismaticJoint("pusher_y", y_parent, sphere.body_frame(), [0.0, 1.0, 0.0]))
    x0, y0 = pusher_start_xy(run_spec, cfg)
    jx.set_default_translation(float(x0))
    jy.set_default_translation(float(y0))
    pd_actuator(plant, "pusher_x_motor", jx, cfg.pusher_kp_n_per_m, cfg.pusher_kd_n_s_per_m)
    pd_actuator(plant, "pusher_y_motor", jy, cfg.pusher_kp_n_per_m, cfg.pusher_kd_n_s_per_m)
    props = ProximityProperties()
    AddCompliantHydroelasticProperties(cfg.pusher_resolution_hint_m,
                                       cfg.environment_hydroelastic_modulus_pa, props)
    contact_material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
              cfg.pusher_mu, cfg.pusher_mu)
    plant.RegisterCollisionGeometry(sphere, RigidTransform(), Sphere(cfg.pusher_radius_m),
                                    "pusher_sphere", props)
    return instance, np.array([x0, y0])


def _pusher_desired(run_spec: RunSpec, cfg: SceneConfig):
    from pydrake.trajectories import PiecewisePolynomial

    start = pusher_start_xy(run_spec, cfg)
    u = np.array([np.cos(run_spec.pusher_approach_rad), np.sin(run_spec.pusher_approach_rad)])
    end = start + u * cfg.pusher_speed_m_per_s * cfg.push_duration_s
    breaks, knots = [0.0], [start]
    if cfg.settle_s > 0:
        breaks.append(cfg.settle_s)
        knots.append(start)
    if cfg.push_duration_s > 0:
        breaks.append(cfg.settle_s + cfg.push_duration_s)
        knots.append(end)
    if len(breaks) == 1:  # neither settling nor pushing: hold the start
        breaks.append(1.0)
        knots.append(start)
    return PiecewisePolynomial.FirstOrderHold(breaks, np.column_stack(knots))


def tilt_angle_rad(t_s: np.ndarray, cfg: SceneConfig) -> tuple[np.ndarray, np.ndarray]:
    """The table's commanded angle (rad) and rate (rad/s) at times ``t_s``: flat for
    ``hold_s``, then a minimum-jerk 0 -> ``tilt_deg`` over ``tilt_time_s``, then held."""
    t = np.asarray(t_s, dtype=float)
    T = cfg.tilt_time_s
    tau = np.clip((t - cfg.hold_s) / T, 0.0, 1.0)
    theta = np.deg2rad(cfg.tilt_deg)
    q = theta * tau**3 * (10 - 15 * tau + 6 * tau**2)
    qd = theta * 30 * tau**2 * (1 - tau) ** 2 / T
    return q, qd


def _table_desired(cfg: SceneConfig):
    from pydrake.trajectories import PiecewisePolynomial

    # Cubic Hermite through exact samples of the quintic: 40 knots keep it within ~1e-6 rad.
    knots = cfg.hold_s + np.linspace(0.0, cfg.tilt_time_s, 41)
    breaks = np.concatenate([[0.0], knots, [max(cfg.total_duration_s, knots[-1]) + 1.0]])
    q, qd = tilt_angle_rad(breaks, cfg)
    return PiecewisePolynomial.CubicHermite(breaks, q.reshape(1, -1), qd.reshape(1, -1))


def _add_table(plant, cfg: SceneConfig):
    from pydrake.geometry import AddCompliantHydroelasticProperties, Box, ProximityProperties
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import (FixedOffsetFrame, RevoluteJoint, RotationalInertia,
                                       SpatialInertia)

    lx, ly, lz = cfg.table_size_m
    m = cfg.table_mass_kg
    instance = plant.AddModelInstance("ramp")
    # Inertia of the slab about the hinge, with the CoM put on the hinge (a counterweight):
    # gravity then exerts no torque and the PD actuator only has to track the profile.
    c = np.array([0.0, -ly / 2, -lz / 2])
    Ic = m / 12 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    Ih = Ic + m * (c @ c * np.eye(3) - np.outer(c, c))
    table = plant.AddRigidBody("table", instance, SpatialInertia.MakeFromCentralInertia(
        m, np.zeros(3), RotationalInertia(Ih[0, 0], Ih[1, 1], Ih[2, 2], Ih[0, 1], Ih[0, 2], Ih[1, 2])))
    hinge_frame = plant.AddFrame(FixedOffsetFrame("ramp_hinge_frame", plant.world_frame(),
                                                  RigidTransform([0.0, 0.0, cfg.hinge_height_m])))
    hinge = plant.AddJoint(RevoluteJoint("ramp_hinge", hinge_frame, table.body_frame(),
                                         [1.0, 0.0, 0.0]))
    hinge.set_default_angle(0.0)
    pd_actuator(plant, "ramp_motor", hinge, cfg.table_kp_n_m_per_rad, cfg.table_kd_n_m_s_per_rad)
    props = ProximityProperties()
    AddCompliantHydroelasticProperties(0.05, cfg.environment_hydroelastic_modulus_pa, props)
    contact_material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
              cfg.table_mu, cfg.table_mu)
    plant.RegisterCollisionGeometry(table, RigidTransform(c), Box(lx, ly, lz), "table", props)
    return instance, table, np.array([0.0])


@dataclass(frozen=True)
class PushTask:
    """Planar pushing: the object rests on the floor; a PD-driven sphere pushes it along a line."""

    name: str = "push"

    def duration_s(self, cfg: SceneConfig) -> float:
        return cfg.settle_s + cfg.push_duration_s

    def run_spec(self, run: int, seed: int, u: np.ndarray) -> RunSpec:
        """Yaw and roll uniform in [-pi, pi), offset uniform in +-0.05 m, approach uniform in [-pi, pi)."""
        return RunSpec(task=self.name, run=run, seed=seed,
                       object_yaw_rad=float(-np.pi + 2 * np.pi * u[1]),
                       object_offset_m=(float(0.1 * u[2] - 0.05), float(0.1 * u[3] - 0.05)),
                       pusher_approach_rad=float(-np.pi + 2 * np.pi * u[4]),
                       object_roll_rad=float(-np.pi + 2 * np.pi * u[0]))

    def object_position(self, world_vertices: np.ndarray, run_spec: RunSpec, cfg: SceneConfig) -> np.ndarray:
        """Asset origin at ``object_offset_m``, lowest vertex ``drop_clearance_m`` above the floor."""
        ox, oy = run_spec.object_offset_m
        return np.array([ox, oy, cfg.drop_clearance_m - world_vertices[:, 2].min()])

    def add_actuated(self, plant, run_spec: RunSpec, cfg: SceneConfig) -> tuple[object, np.ndarray, dict]:
        instance, q0 = _add_pusher(plant, run_spec, cfg)
        return instance, q0, {}

    def desired(self, run_spec: RunSpec, cfg: SceneConfig):
        return _pusher_desired(run_spec, cfg)


@dataclass(frozen=True)
class RampTask:
    """Actuated ramp: the object rests on a table that a PD-driven hinge tilts until it rolls off."""

    name: str = "ramp"

    def duration_s(self, cfg: SceneConfig) -> float:
        return cfg.total_duration_s

    def run_spec(self, run: int, seed: int, u: np.ndarray) -> RunSpec:
        """Yaw within +-10 degrees of "long axis along the hinge" (so the object rolls rather than
        slides off sideways), roll uniform, offset x (along the hinge) +-0.1 m, y in [-0.02, 0] m."""
        return RunSpec(task=self.name, run=run, seed=seed,
                       object_yaw_rad=float(np.deg2rad(10.0) * (2 * u[1] - 1)),
                       object_offset_m=(float(0.2 * u[2] - 0.1), float(-0.02 * u[3])),
                       pusher_approach_rad=0.0,
                       object_roll_rad=float(-np.pi + 2 * np.pi * u[0]))

    def object_position(self, world_vertices: np.ndarray, run_spec: RunSpec, cfg: SceneConfig) -> np.ndarray:
        """Up-slope edge ``ramp_object_gap_m`` down-slope of the hinge, lowest vertex
        ``drop_clearance_m`` above the table's top."""
        ox, oy = run_spec.object_offset_m
        return np.array([ox, oy - cfg.ramp_object_gap_m - world_vertices[:, 1].max(),
                         cfg.hinge_height_m + cfg.drop_clearance_m - world_vertices[:, 2].min()])

    def add_actuated(self, plant, run_spec: RunSpec, cfg: SceneConfig) -> tuple[object, np.ndarray, dict]:
        instance, table, q0 = _add_table(plant, cfg)
        return instance, q0, {"table": table}

    def desired(self, run_spec: RunSpec, cfg: SceneConfig):
        return _table_desired(cfg)


_TASKS = {task.name: task for task in (PushTask(), RampTask())}
TASKS = tuple(_TASKS)  # ("push", "ramp"): the order seeds each task's run stream


def task_named(task: str) -> PushTask | RampTask:
    """The task object called ``task``; ValueError for an unknown name."""
    try:
        return _TASKS[task]
    except KeyError:
        raise ValueError(f"unknown task {task!r}; expected one of {TASKS}") from None


def check_task(task: str) -> None:
    task_named(task)


def run_duration_s(task: str, cfg: SceneConfig) -> float:
    """Simulated seconds of one run of ``task`` in the scenes ``cfg``."""
    return task_named(task).duration_s(cfg)


def run_steps(task: str, cfg: SceneConfig) -> int:
    """Number of plant steps of one run of ``task`` (integer; times are step * ``cfg.time_step_s``)."""
    return int(round(run_duration_s(task, cfg) / cfg.time_step_s))
