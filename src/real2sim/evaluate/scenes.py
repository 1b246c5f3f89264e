"""Drake scenes of the paper's evaluation (section V-C): planar pushing and actuated ramp.

Both tasks share one world layout, built around an object body whose frame is the
asset (canonical) frame of ``ASSETDIR`` (metres, z = the object's longest axis):

* world frame: z up, gravity -9.81 m/s^2 along z.
* floor: a compliant hydroelastic box slab whose top is z = 0, ``floor_size_m`` wide
  (large, so a rolling object never falls off the world).
* push task: a sphere of radius ``pusher_radius_m`` on two prismatic joints
  (world -x-> carriage -y-> sphere), PD-controlled along a straight line towards the
  object's initial centre at constant speed, its centre ``pusher_clearance_m`` above
  ``pusher_radius_m`` so it never rubs on the floor.
* ramp task: a compliant box table (``table_size_m`` = x width along the hinge,
  y length down-slope, thickness) on a revolute joint about world x at
  (0, 0, ``hinge_height_m``). The hinge lies on the table's top face at its +y edge;
  the table extends towards -y, and tilting by +theta lowers the -y end, so the
  object, placed just down-slope of the hinge, rolls towards -y. The table's mass is
  centred on the hinge (a counterweight), so the PD actuator only fights the object.

The object lies on its side in both tasks by default, so that a bottle or can rolls:
in a statically stable resting pose of the reference mesh (so nothing rolls away before
the task starts), its long axis turned along world x (the hinge) before the run's yaw.
The initial pose comes from :class:`RunSpec` and the reference mesh's vertices
(:func:`initial_object_pose`), and reference and candidates start from the very same
state (candidates take the reference trajectory's first sample).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from real2sim.formats.contact import CONTACT_MODELS

TASKS = ("push", "ramp")


@dataclass(frozen=True)
class SceneConfig:
    """Every physical parameter of the evaluation scenes; shared by reference and candidates.

    Simulation:
        time_step_s: the plant's discrete step, s (the paper: 0.001).
        discrete_contact_approximation: "lagged" (default), "sap" or "similar" (SAP family;
            TAMSI is deprecated in Drake and does not drive PD actuators).
        reset_interval_s: equation error resets every this many seconds (paper: 0.1); None
            or 0 -> simulation error (one rollout without resets). Must be a whole number
            of steps.
    Environment material (floor, table, pusher):
        environment_hydroelastic_modulus_pa: compliant modulus of floor, table and pusher, Pa.
        floor_slab_thickness_m: half the floor slab's thickness (depth of its pressure maximum), m;
            floor_size_m: the floor slab's width and length, m.
        environment_dissipation_s_per_m: Hunt-Crossley dissipation, s/m (lagged/similar).
        environment_relaxation_time_s: linear Kelvin-Voigt relaxation time, s ("sap").
        floor_mu, table_mu, pusher_mu: Coulomb friction (static = dynamic) of each body.
        pusher_resolution_hint_m: compliant sphere mesh resolution, m.
    Object placement:
        object_lying: object on its side (asset z horizontal) when True, upright otherwise.
        drop_clearance_m: gap between the object's lowest vertex and the support at t=0, m.
    Push:
        pusher_radius_m, pusher_clearance_m (sphere bottom above the floor), pusher_mass_kg,
        pusher_start_distance_m (sphere centre to object centre, horizontal, at t=0),
        pusher_speed_m_per_s, settle_s (pusher waits while the object settles),
        push_duration_s (motion after settling), pusher_kp_n_per_m, pusher_kd_n_s_per_m.
    Ramp:
        table_size_m (x along hinge, y down-slope, z thickness), table_mass_kg,
        hinge_height_m (hinge above the floor), hold_s (flat before tilting),
        tilt_deg, tilt_time_s (minimum-jerk 0 -> tilt_deg), total_duration_s,
        ramp_object_gap_m (object's up-slope edge to the hinge line, along -y),
        table_kp_n_m_per_rad, table_kd_n_m_s_per_rad (Drake's implicit PD actuator;
        no integral term is needed: the table's mass is centred on the hinge).
    """

    time_step_s: float = 1e-3
    discrete_contact_approximation: str = "lagged"
    reset_interval_s: float | None = 0.1

    environment_hydroelastic_modulus_pa: float = 1.0e7
    floor_slab_thickness_m: float = 0.5
    floor_size_m: float = 40.0
    environment_dissipation_s_per_m: float = 1.0
    environment_relaxation_time_s: float = 0.01
    floor_mu: float = 0.5
    table_mu: float = 0.5
    pusher_mu: float = 0.5
    pusher_resolution_hint_m: float = 0.01

    object_lying: bool = True
    drop_clearance_m: float = 0.001

    pusher_radius_m: float = 0.05
    pusher_clearance_m: float = 0.002
    pusher_mass_kg: float = 1.0
    pusher_start_distance_m: float = 0.2
    pusher_speed_m_per_s: float = 0.2
    settle_s: float = 0.2
    push_duration_s: float = 1.3
    pusher_kp_n_per_m: float = 5.0e3
    pusher_kd_n_s_per_m: float = 2.0e2

    table_size_m: tuple[float, float, float] = (0.8, 1.6, 0.05)
    table_mass_kg: float = 10.0
    hinge_height_m: float = 1.3
    hold_s: float = 0.3
    tilt_deg: float = 45.0
    tilt_time_s: float = 0.5
    total_duration_s: float = 2.0
    ramp_object_gap_m: float = 0.02
    table_kp_n_m_per_rad: float = 2.0e4
    table_kd_n_m_s_per_rad: float = 5.0e2

    def __post_init__(self) -> None:
        if not (self.time_step_s > 0 and np.isfinite(self.time_step_s)):
            raise ValueError("time_step_s must be positive")
        if self.discrete_contact_approximation not in ("lagged", "sap", "similar"):
            raise ValueError("discrete_contact_approximation must be lagged, sap or similar")
        if self.reset_interval_s:
            k = self.reset_interval_s / self.time_step_s
            if abs(k - round(k)) > 1e-6 or round(k) < 1:
                raise ValueError("reset_interval_s must be a whole number of time steps")

    def duration_s(self, task: str) -> float:
        """Simulated seconds of one run of ``task``."""
        check_task(task)
        return self.settle_s + self.push_duration_s if task == "push" else self.total_duration_s

    def num_steps(self, task: str) -> int:
        """Number of plant steps of one run of ``task`` (integer; times are step * time_step_s)."""
        return int(round(self.duration_s(task) / self.time_step_s))

    def reset_interval_steps(self) -> int | None:
        """Steps between equation-error resets, or None for simulation error."""
        if not self.reset_interval_s:
            return None
        return int(round(self.reset_interval_s / self.time_step_s))


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


def check_task(task: str) -> None:
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; expected one of {TASKS}")


def make_run_specs(task: str, runs: int, seed: int) -> list[RunSpec]:
    """``runs`` seeded initial conditions for ``task``; the same list for every representation.

    Push: yaw and roll uniform in [-pi, pi), offset uniform in +-0.05 m, approach uniform
    in [-pi, pi). Ramp: yaw within +-10 degrees of "long axis along the hinge" (so the
    object rolls rather than slides off sideways), roll uniform, offset x (along the
    hinge) +-0.1 m, y in [-0.02, 0] m (down-slope).
    """
    check_task(task)
    if runs < 0:
        raise ValueError("runs must be >= 0")
    # One stream per (seed, task): adding runs appends specs, never changes earlier ones.
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), TASKS.index(task)]))
    specs = []
    for run in range(runs):
        u = rng.random(6)
        roll = float(-np.pi + 2 * np.pi * u[0])
        if task == "push":
            specs.append(RunSpec(task=task, run=run, seed=int(seed),
                                 object_yaw_rad=float(-np.pi + 2 * np.pi * u[1]),
                                 object_offset_m=(float(0.1 * u[2] - 0.05), float(0.1 * u[3] - 0.05)),
                                 pusher_approach_rad=float(-np.pi + 2 * np.pi * u[4]),
                                 object_roll_rad=roll))
        else:
            specs.append(RunSpec(task=task, run=run, seed=int(seed),
                                 object_yaw_rad=float(np.deg2rad(10.0) * (2 * u[1] - 1)),
                                 object_offset_m=(float(0.2 * u[2] - 0.1), float(-0.02 * u[3])),
                                 pusher_approach_rad=0.0,
                                 object_roll_rad=roll))
    return specs


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


_STABLE_CACHE: dict[bytes, list[tuple[np.ndarray, float]]] = {}


def stable_rotations(vertices_m: np.ndarray, com_m=None) -> list[tuple[np.ndarray, float]]:
    """Statically stable resting orientations of a rigid object on a plane: (R_WO, probability)
    pairs, most probable first (trimesh's quasi-static analysis of the vertices' convex hull
    about ``com_m``, default the hull's centroid). Cached per (vertices, com): the hull of a
    6k-vertex mesh takes seconds."""
    import trimesh

    v = np.ascontiguousarray(vertices_m, dtype=float)
    c = None if com_m is None else np.asarray(com_m, dtype=float).reshape(3)
    key = v.tobytes() + (b"" if c is None else c.tobytes())
    if key not in _STABLE_CACHE:
        hull = trimesh.convex.convex_hull(v)
        transforms, probs = trimesh.poses.compute_stable_poses(
            hull, center_mass=hull.center_mass if c is None else c, n_samples=1)
        _STABLE_CACHE.clear()  # one object at a time: keep memory flat in long sweeps
        _STABLE_CACHE[key] = [(np.asarray(T)[:3, :3].copy(), float(pr)) for T, pr in zip(transforms, probs)]
    return _STABLE_CACHE[key]


def initial_object_rotation(vertices_m: np.ndarray, run_spec: RunSpec, scene_config: SceneConfig,
                            com_m=None) -> np.ndarray:
    """R_WO (3x3) of the object at t = 0: a statically stable resting orientation (so the
    object does not roll away before the task starts), then yaw about world z.

    Lying (``object_lying``): among the stable poses whose asset z axis is within ~45 degrees
    of horizontal, the one whose downward direction, seen about the asset z axis, is
    nearest ``run_spec.object_roll_rad`` (among those at least a quarter as probable as the
    likeliest lying one); it is turned about world z so that the long axis's
    horizontal projection points along world +x (parallel to the ramp's hinge) before the
    yaw. Upright: the most probable stable pose with asset z within 45 degrees of vertical.
    Falls back to the most probable stable pose, and to the plain axis-aligned pose when
    the analysis finds none.
    """
    poses = stable_rotations(vertices_m, com_m)
    lay = _rot_y(np.pi / 2) if scene_config.object_lying else np.eye(3)
    if not poses:
        return _rot_z(run_spec.object_yaw_rad) @ lay @ _rot_z(run_spec.object_roll_rad)
    up = np.array([R[2, 2] for R, _ in poses])  # world z component of the asset z axis
    if scene_config.object_lying:
        candidates = [k for k in range(len(poses)) if abs(up[k]) < np.sqrt(0.5)]
    else:
        candidates = [k for k in range(len(poses)) if up[k] >= np.sqrt(0.5)]
    if not candidates:
        candidates = [0]
    # Marginal poses (tiny basin of attraction) tip over at the first disturbance; keep those
    # at least a quarter as likely as the likeliest candidate.
    top = max(poses[k][1] for k in candidates)
    candidates = [k for k in candidates if poses[k][1] >= 0.25 * top]
    if scene_config.object_lying:
        def roll_gap(k: int) -> float:
            down = poses[k][0].T @ np.array([0.0, 0.0, -1.0])  # in the asset frame
            a = np.arctan2(down[1], down[0]) - run_spec.object_roll_rad
            return abs(np.arctan2(np.sin(a), np.cos(a)))

        best = min(candidates, key=lambda k: (round(roll_gap(k), 9), k))
    else:
        best = candidates[0]
    R = poses[best][0]
    axis = R[:, 2]
    heading = np.arctan2(axis[1], axis[0]) if np.hypot(axis[0], axis[1]) > 1e-6 else 0.0
    return _rot_z(run_spec.object_yaw_rad - heading) @ R


def initial_object_pose(vertices_m: np.ndarray, run_spec: RunSpec, scene_config: SceneConfig,
                        com_m=None):
    """World pose (pydrake RigidTransform) of the object's asset frame at t = 0.

    vertices_m: (n, 3) reference-mesh vertices in the asset frame, m; they set the
    resting orientation (:func:`initial_object_rotation`, about ``com_m``, the object's CoM
    in the asset frame), the height (lowest vertex ``drop_clearance_m`` above the support)
    and, on the ramp, the distance from the hinge (up-slope edge ``ramp_object_gap_m``
    below it). Push: the asset origin is at ``object_offset_m``.
    """
    from pydrake.math import RigidTransform, RotationMatrix

    check_task(run_spec.task)
    v = np.asarray(vertices_m, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise ValueError("vertices_m must be a non-empty (n, 3) array")
    R = initial_object_rotation(v, run_spec, scene_config, com_m)
    w = v @ R.T
    ox, oy = run_spec.object_offset_m
    if run_spec.task == "push":
        p = np.array([ox, oy, scene_config.drop_clearance_m - w[:, 2].min()])
    else:
        p = np.array([ox, oy - scene_config.ramp_object_gap_m - w[:, 1].max(),
                      scene_config.hinge_height_m + scene_config.drop_clearance_m - w[:, 2].min()])
    return RigidTransform(RotationMatrix(R), p)


@dataclass
class Scene:
    """A built, finalized scene: the diagram and the handles the simulator needs.

    diagram: pydrake Diagram (plant + scene graph + desired-state source).
    plant: the MultibodyPlant inside ``diagram``.
    object_instance: the object's model instance (one free body, its frame = asset frame).
    object_body: that free body.
    actuated_instance: the pusher's (push) or table's (ramp) model instance.
    actuated_initial_positions: the pusher's (x, y) in m or the table's angle in rad at t = 0.
    task, contact_model: as built.
    """

    diagram: object
    plant: object
    scene_graph: object
    object_instance: object
    object_body: object
    actuated_instance: object
    actuated_initial_positions: np.ndarray
    task: str
    contact_model: str
    extra: dict = field(default_factory=dict)

    @property
    def object_geometry_ids(self) -> set:
        return set(self.plant.GetCollisionGeometriesForBody(self.object_body))


ObjectAdder = Callable[[object], object]
"""Adds the object to a plant before Finalize and returns its model instance."""


def _material(props, dissipation_s_per_m: float, relaxation_time_s: float | None, mu_static: float,
              mu_dynamic: float) -> None:
    from pydrake.geometry import AddContactMaterial
    from pydrake.multibody.plant import CoulombFriction

    AddContactMaterial(props, dissipation=dissipation_s_per_m,
                       friction=CoulombFriction(mu_static, mu_dynamic))
    if relaxation_time_s is not None:
        # The "sap" approximation's linear model reads a relaxation time instead of H-C dissipation.
        props.AddProperty("material", "relaxation_time", relaxation_time_s)


def reference_object_adder(mesh_path: Path, physical_properties, object_contact=None) -> ObjectAdder:
    """An :data:`ObjectAdder` for the ground truth: one body with ``physical_properties``
    and the mesh at ``mesh_path`` (asset frame, m) as a *rigid* hydroelastic collision
    (non-convex surface kept) plus its visual; friction/dissipation from ``object_contact``
    (a ContactProperties, defaults when None)."""
    from real2sim.formats.contact import ContactProperties

    mesh_path = Path(mesh_path)
    if not mesh_path.is_file():
        raise FileNotFoundError(f"reference mesh not found: {mesh_path}")
    if mesh_path.suffix.lower() != ".obj":
        # Drake's rigid hydroelastic Mesh reads Wavefront .obj surfaces only.
        raise ValueError(f"reference mesh must be a .obj file (asset frame, metres): {mesh_path}")
    contact = object_contact or ContactProperties()

    def add(plant):
        from pydrake.geometry import AddRigidHydroelasticProperties, Mesh, ProximityProperties
        from pydrake.math import RigidTransform
        from pydrake.multibody.tree import RotationalInertia, SpatialInertia

        pp = physical_properties
        I = np.asarray(pp.inertia_kg_m2, dtype=float)
        instance = plant.AddModelInstance("reference_object")
        M = SpatialInertia.MakeFromCentralInertia(
            float(pp.mass_kg), np.asarray(pp.com_m, dtype=float),
            RotationalInertia(I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]))
        body = plant.AddRigidBody("reference_object", instance, M)
        props = ProximityProperties()
        AddRigidHydroelasticProperties(props)
        # No relaxation time: the candidates' URDFs carry none either, so both get Drake's default.
        _material(props, contact.hunt_crossley_dissipation_s_per_m, None,
                  contact.mu_static, contact.mu_dynamic)
        plant.RegisterCollisionGeometry(body, RigidTransform(), Mesh(str(mesh_path.resolve())),
                                        "reference_collision", props)
        return instance

    return add


def urdf_object_adder(urdf_path: Path) -> ObjectAdder:
    """An :data:`ObjectAdder` that parses a candidate's URDF from its file (relative mesh
    paths resolve next to it); the URDF must hold one free body whose frame is the asset frame."""
    urdf_path = Path(urdf_path)
    if not urdf_path.is_file():
        raise FileNotFoundError(f"candidate URDF not found: {urdf_path}")

    def add(plant):
        from pydrake.multibody.parsing import Parser

        instances = Parser(plant).AddModels(str(urdf_path.resolve()))
        if len(instances) != 1:
            raise ValueError(f"{urdf_path}: expected one model, got {len(instances)}")
        return instances[0]

    return add


def _add_floor(plant, cfg: SceneConfig) -> None:
    # A compliant *box*, not a half-space: Drake 1.51 gives a compliant half-space no
    # hydroelastic contact with compliant shapes and silently falls back to point
    # contact for those pairs, which would make every "hydroelastic" candidate a point
    # contact one. A slab 2 * floor_slab_thickness_m thick has its pressure field's
    # maximum at the same depth as the half-space's slab would.
    from pydrake.geometry import AddCompliantHydroelasticProperties, Box, ProximityProperties
    from pydrake.math import RigidTransform

    props = ProximityProperties()
    AddCompliantHydroelasticProperties(1.0, cfg.environment_hydroelastic_modulus_pa, props)
    _material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
              cfg.floor_mu, cfg.floor_mu)
    thickness = 2.0 * cfg.floor_slab_thickness_m
    plant.RegisterCollisionGeometry(
        plant.world_body(), RigidTransform([0.0, 0.0, -thickness / 2]),
        Box(cfg.floor_size_m, cfg.floor_size_m, thickness), "floor", props,
    )


def _pd_actuator(plant, name: str, joint, kp: float, kd: float) -> None:
    from pydrake.multibody.tree import PdControllerGains

    actuator = plant.AddJointActuator(name, joint)
    actuator.set_controller_gains(PdControllerGains(p=kp, d=kd))


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
    _pd_actuator(plant, "pusher_x_motor", jx, cfg.pusher_kp_n_per_m, cfg.pusher_kd_n_s_per_m)
    _pd_actuator(plant, "pusher_y_motor", jy, cfg.pusher_kp_n_per_m, cfg.pusher_kd_n_s_per_m)
    props = ProximityProperties()
    AddCompliantHydroelasticProperties(cfg.pusher_resolution_hint_m,
                                       cfg.environment_hydroelastic_modulus_pa, props)
    _material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
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
    _pd_actuator(plant, "ramp_motor", hinge, cfg.table_kp_n_m_per_rad, cfg.table_kd_n_m_s_per_rad)
    props = ProximityProperties()
    AddCompliantHydroelasticProperties(0.05, cfg.environment_hydroelastic_modulus_pa, props)
    _material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
              cfg.table_mu, cfg.table_mu)
    plant.RegisterCollisionGeometry(table, RigidTransform(c), Box(lx, ly, lz), "table", props)
    return instance, table, np.array([0.0])


def build_scene(task: str, contact_model: str, add_object: ObjectAdder, run_spec: RunSpec,
                scene_config: SceneConfig) -> Scene:
    """Build and finalize the ``task`` scene with ``contact_model`` ("point" or
    "hydroelastic", the latter meaning Drake's hydroelastic_with_fallback) around the
    object that ``add_object`` adds; the actuator's desired trajectory depends on
    ``run_spec`` (push approach line) and ``scene_config``."""
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource

    check_task(task)
    if contact_model not in CONTACT_MODELS:
        raise ValueError(f"unknown contact model {contact_model!r}; expected one of {CONTACT_MODELS}")
    if run_spec.task != task:
        raise ValueError(f"run spec is for task {run_spec.task!r}, scene is {task!r}")
    cfg = scene_config
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(MultibodyPlantConfig(
        time_step=cfg.time_step_s,
        discrete_contact_approximation=cfg.discrete_contact_approximation,
        contact_model="point" if contact_model == "point" else "hydroelastic_with_fallback",
        # Output ports (contact results) computed from the context's current state, so the
        # contacts logged at a sample belong to that sample's pose; sampled ports would report
        # the previous step's (off by v * dt, 4 mm at 4 m/s). Dynamics are unaffected.
        use_sampled_output_ports=False), builder)
    object_instance = add_object(plant)
    _add_floor(plant, cfg)
    extra = {}
    if task == "push":
        actuated, q0 = _add_pusher(plant, run_spec, cfg)
        desired = _pusher_desired(run_spec, cfg)
    else:
        actuated, table, q0 = _add_table(plant, cfg)
        extra["table"] = table
        desired = _table_desired(cfg)
    plant.Finalize()
    find_body = getattr(plant, "GetUniqueFloatingBaseBodyOrThrow", None) or plant.GetUniqueFreeBaseBodyOrThrow
    object_body = find_body(object_instance)
    source = builder.AddSystem(TrajectorySource(desired, output_derivative_order=1))
    # PD-controlled actuators read their set points from this port; it exists only after Finalize.
    builder.Connect(source.get_output_port(), plant.get_desired_state_input_port(actuated))
    diagram = builder.Build()
    return Scene(diagram=diagram, plant=plant, scene_graph=scene_graph,
                 object_instance=object_instance, object_body=object_body,
                 actuated_instance=actuated, actuated_initial_positions=q0, task=task,
                 contact_model=contact_model, extra=extra)
