"""The Drake world of the evaluation (paper V-C): floor, object, and the task's actuated body.

Both tasks share one world layout, built around an object body whose frame is the
asset (canonical) frame of ``ASSETDIR`` (metres, z = the object's longest axis):

* world frame: z up, gravity -9.81 m/s^2 along z.
* floor: a compliant hydroelastic box slab whose top is z = 0, ``floor_size_m`` wide
  (large, so a rolling object never falls off the world); in the hydroelastic scenes the
  same slab as a graded tetrahedral mesh (:mod:`real2sim.evaluate.scene.floor`).
* the task's actuated body (pusher or tilting table) and its desired trajectory come
  from the task object (:mod:`real2sim.evaluate.scene.tasks`); the object's initial pose from
  :mod:`real2sim.evaluate.scene.placement`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from real2sim.evaluate.scene.floor import floor_mesh_path
from real2sim.evaluate.scene.plant_parts import contact_material
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import RunSpec, task_named
from real2sim.formats.contact import CONTACT_MODELS


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
        contact_material(props, contact.hunt_crossley_dissipation_s_per_m, None,
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


def _add_floor(plant, cfg: SceneConfig, contact_model: str) -> None:
    # A compliant *box*, not a half-space: Drake 1.51 gives a compliant half-space no
    # hydroelastic contact with compliant shapes and silently falls back to point
    # contact for those pairs, which would make every "hydroelastic" candidate a point
    # contact one. A slab 2 * floor_slab_thickness_m thick has its pressure field's
    # maximum at the same depth as the half-space's slab would.
    from pydrake.geometry import AddCompliantHydroelasticProperties, Box, Mesh, ProximityProperties
    from pydrake.math import RigidTransform

    props = ProximityProperties()
    AddCompliantHydroelasticProperties(1.0, cfg.environment_hydroelastic_modulus_pa, props)
    contact_material(props, cfg.environment_dissipation_s_per_m, cfg.environment_relaxation_time_s,
              cfg.floor_mu, cfg.floor_mu)
    if contact_model == "hydroelastic":
        # the same slab and pressure field, in tetrahedra that let Drake cull (floor.py)
        plant.RegisterCollisionGeometry(
            plant.world_body(), RigidTransform(),
            Mesh(str(floor_mesh_path(cfg.floor_size_m, cfg.floor_slab_thickness_m))), "floor", props)
        return
    thickness = 2.0 * cfg.floor_slab_thickness_m
    plant.RegisterCollisionGeometry(
        plant.world_body(), RigidTransform([0.0, 0.0, -thickness / 2]),
        Box(cfg.floor_size_m, cfg.floor_size_m, thickness), "floor", props,
    )


def build_scene(task: str, contact_model: str, add_object: ObjectAdder, run_spec: RunSpec,
                scene_config: SceneConfig) -> Scene:
    """Build and finalize the ``task`` scene with ``contact_model`` ("point" or
    "hydroelastic", the latter meaning Drake's hydroelastic_with_fallback) around the
    object that ``add_object`` adds; the actuator's desired trajectory depends on
    ``run_spec`` (push approach line) and ``scene_config``."""
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import TrajectorySource

    chosen = task_named(task)
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
    _add_floor(plant, cfg, contact_model)
    actuated, q0, extra = chosen.add_actuated(plant, run_spec, cfg)
    desired = chosen.desired(run_spec, cfg)
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
