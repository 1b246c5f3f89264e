"""Simulate the paper's ground truth and candidate assets in the evaluation scenes.

The ground truth (paper V-C) is the full visual mesh as a rigid hydroelastic body
against the compliant floor/table/pusher (:func:`simulate_reference`). A candidate is a
URDF from ``ASSETDIR/<representation>/model.urdf`` simulated with point or hydroelastic
contact (:func:`simulate_candidate`). Equation error: every ``reset_interval_s`` the
candidate's state (object pose + spatial velocity, and the pusher's / table's joint
state) is set to the reference's state at that step, then one interval is simulated.

A candidate's simulation runs twice on the same diagram:
1. the timed run: bare ``Simulator.AdvanceTo`` from reset to reset (in chunks of
   :data:`CHUNK_STEPS` steps), with no Python per step; ``sim_time_s`` is its wall time
   (resets included: they cost microseconds);
2. the instrumented run: one ``AdvanceTo`` per step, reading the state and the plant's
   contact results; its wall time is ``instrumented_time_s``.
Both runs execute the same discrete updates on the same states; their final states agree
bit for bit (checked on every run: a RuntimeWarning if not). The reference runs the
instrumented run only: nothing scores its speed, and on a big mesh its timed run was half
of the sweep's longest job (its ``sim_time_s`` is NaN).

Wall-clock limit: with ``timeout_s`` both runs advance in chunks of at most
:data:`CHUNK_STEPS` steps and check the clock between chunks; past the limit the simulation
stops with :class:`SimulationTimeout` (the sweep records the row as a "timeout" failure and
goes on). Chunking does not change the result: the plant is discrete, and the instrumented
run already advances one step at a time to the same states.

Times: sample n is at n * time_step_s, n = 0..num_steps. At a reset step the logged
candidate state is the *prediction* (before the reset), so equation error measures one
interval's drift; sample 0 is the shared initial state.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.formats.physical import read_physical_properties
from real2sim.formats.trajectory import Trajectory
from real2sim.evaluate.scene.placement import StablePoseCache, initial_object_pose
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import RunSpec, run_steps
from real2sim.evaluate.scene.world import Scene, build_scene, reference_object_adder, urdf_object_adder


class SimulationError(RuntimeError):
    """A simulation failed (solver failure, non-finite or exploded state); the message
    names the task, run, contact model, representation and simulated time."""


class SimulationTimeout(SimulationError):
    """A simulation ran past its wall-clock limit; the message starts with "timeout:"."""


#: Steps advanced between two looks at the clock (a box's step is ~0.1 ms, a big mesh's ~10 ms).
CHUNK_STEPS = 25


class Deadline:
    """The wall-clock limit of one simulation (both runs together); None: no limit."""

    def __init__(self, timeout_s: float | None) -> None:
        self.timeout_s = timeout_s
        self._end = None if timeout_s is None else time.monotonic() + float(timeout_s)

    def check(self, label: str, t_s: float) -> None:
        if self._end is not None and time.monotonic() > self._end:
            raise SimulationTimeout(f"timeout: {label} ran past its {self.timeout_s:g} s wall-clock limit "
                                    f"(sim_timeout_s) at simulated t = {t_s:.3f} s")


@dataclass(frozen=True)
class _State:
    """Object and actuator state at one step, in Drake's own layouts."""

    object_q: np.ndarray   # (7,) qw qx qy qz px py pz
    object_v: np.ndarray   # (6,) wx wy wz vx vy vz (world)
    actuated_q: np.ndarray
    actuated_v: np.ndarray


def _state_at(traj: Trajectory, step: int) -> _State:
    return _State(np.concatenate([traj.object_quaternion_wxyz[step], traj.object_position_m[step]]),
                  traj.object_spatial_velocity[step].copy(),
                  traj.actuated_positions[step].copy(), traj.actuated_velocities[step].copy())


def _set_state(scene: Scene, plant_context, state: _State, label: str = "", t_s: float = 0.0) -> None:
    plant = scene.plant
    if not all(np.all(np.isfinite(x)) for x in (state.object_q, state.object_v, state.actuated_q,
                                                 state.actuated_v)):
        # Drake would abort the process on a non-finite state; say which sample was bad instead.
        raise SimulationError(f"{label}: the state to set at t = {t_s:.3f} s is not finite")
    plant.SetPositions(plant_context, scene.object_instance, state.object_q)
    plant.SetVelocities(plant_context, scene.object_instance, state.object_v)
    plant.SetPositions(plant_context, scene.actuated_instance, state.actuated_q)
    plant.SetVelocities(plant_context, scene.actuated_instance, state.actuated_v)


def _check_object_instance(scene: Scene) -> None:
    plant = scene.plant
    nq = plant.num_positions(scene.object_instance)
    nv = plant.num_velocities(scene.object_instance)
    if (nq, nv) != (7, 6):
        raise ValueError(f"the object model must be one free rigid body (7 positions, 6 "
                         f"velocities); got {nq} positions, {nv} velocities")


def _initial_state(scene: Scene, X_WO) -> _State:
    q = np.concatenate([X_WO.rotation().ToQuaternion().wxyz(), X_WO.translation()])
    na = len(scene.actuated_initial_positions)
    return _State(q, np.zeros(6), np.asarray(scene.actuated_initial_positions, float), np.zeros(na))


def _check_finite(scene: Scene, plant_context, label: str, t_s: float) -> None:
    q = scene.plant.GetPositions(plant_context, scene.object_instance)
    v = scene.plant.GetVelocities(plant_context, scene.object_instance)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
        raise SimulationError(f"{label}: non-finite object state at t = {t_s:.3f} s")
    if np.abs(q[4:]).max() > 1e3 or np.abs(v).max() > 1e3:
        raise SimulationError(f"{label}: object state exploded at t = {t_s:.3f} s "
                              f"(|position| {np.abs(q[4:]).max():.3g} m, |velocity| "
                              f"{np.abs(v).max():.3g}); the contact solver diverged")


def _advance(simulator, step: int, dt: float, label: str) -> None:
    try:
        simulator.AdvanceTo(step * dt)
    except Exception as e:  # Drake raises RuntimeError (and sometimes others) from C++
        t = simulator.get_context().get_time()
        raise SimulationError(f"{label}: Drake failed near t = {t:.3f} s: "
                              f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from e


def _intervals(num_steps: int, interval: int | None) -> list[tuple[int, int]]:
    """[start, end) step ranges between resets; every interval simulated, the last included."""
    if not interval:
        return [(0, num_steps)]
    starts = list(range(0, num_steps, interval))
    return [(a, min(a + interval, num_steps)) for a in starts]


def _simulate(scene: Scene, initial: _State, reference: Trajectory | None, cfg: SceneConfig,
              label: str, representation: str, run: int, deadline: Deadline | None = None,
              timed: bool = True) -> Trajectory:
    _check_object_instance(scene)
    plant = scene.plant
    dt = cfg.time_step_s
    n = run_steps(scene.task, cfg)
    interval = cfg.reset_interval_steps() if reference is not None else None
    if reference is not None:
        if len(reference.times_s) != n + 1 or reference.task != scene.task:
            raise ValueError(f"{label}: the reference has {len(reference.times_s)} samples of task "
                             f"{reference.task!r}; expected {n + 1} of {scene.task!r} "
                             "(same SceneConfig and task)")
    spans = _intervals(n, interval)
    reset_steps = np.array([a for a, _ in spans if a > 0], dtype=int)
    deadline = deadline or Deadline(None)
    deadline.check(label, 0.0)  # building the scene may already have used the time

    # 1. The timed rollout (``timed``); 2. the same rollout again, instrumented.
    sim_time_s, timed_final_q = (_timed_run(scene, initial, reference, spans, dt, label, deadline) if timed
                                 else (float("nan"), None))

    # one AdvanceTo per step, logging state and contacts
    simulator, pctx = _started(scene, initial, label)
    na = plant.num_positions(scene.actuated_instance)
    oq = np.empty((n + 1, 7))
    ov = np.empty((n + 1, 6))
    aq = np.empty((n + 1, na))
    av = np.empty((n + 1, na))
    contacts_w: list[np.ndarray] = []
    forces_w: list[np.ndarray] = []
    surface_counts = np.zeros(n + 1, dtype=np.int64)
    reset_set = set(int(r) for r in reset_steps)
    read_contacts = _contact_reader(scene)

    def log(i: int) -> None:
        oq[i] = plant.GetPositions(pctx, scene.object_instance)
        ov[i] = plant.GetVelocities(pctx, scene.object_instance)
        aq[i] = plant.GetPositions(pctx, scene.actuated_instance)
        av[i] = plant.GetVelocities(pctx, scene.actuated_instance)

    def log_contacts() -> None:
        pts, forces, surfaces = read_contacts(pctx)
        surface_counts[len(contacts_w)] = surfaces
        contacts_w.append(pts)
        forces_w.append(forces)

    log(0)
    log_contacts()
    t0 = time.perf_counter()
    for i in range(n):
        if i in reset_set:
            _set_state(scene, pctx, _state_at(reference, i), label, i * dt)
        _advance(simulator, i + 1, dt, label)
        log(i + 1)
        log_contacts()
        if (i + 1) % 100 == 0 or i + 1 == n:
            _check_finite(scene, pctx, label, (i + 1) * dt)
        if (i + 1) % CHUNK_STEPS == 0:
            deadline.check(label, (i + 1) * dt)
    instrumented_time_s = time.perf_counter() - t0
    if timed_final_q is not None and not np.array_equal(plant.GetPositions(pctx), timed_final_q):
        # Same diagram, same states, same discrete updates: they should agree bit for bit.
        # The logged run is still valid; only sim_time_s timed a (slightly) different rollout.
        warnings.warn(f"{label}: timed and instrumented runs ended apart (max |dq| "
                      f"{np.abs(plant.GetPositions(pctx) - timed_final_q).max():.3g}); "
                      "sim_time_s timed a different rollout", RuntimeWarning, stacklevel=3)

    contacts_o, forces_o = _in_object_frame(contacts_w, forces_w, oq)
    return Trajectory(times_s=np.arange(n + 1) * dt, object_position_m=oq[:, 4:].copy(),
                      object_quaternion_wxyz=oq[:, :4].copy(), object_spatial_velocity=ov,
                      actuated_positions=aq, actuated_velocities=av,
                      contact_points_object_m=contacts_o, contact_forces_object_n=forces_o,
                      contact_surface_counts=surface_counts, sim_time_s=sim_time_s,
                      sim_duration_s=n * dt, instrumented_time_s=instrumented_time_s,
                      reset_steps=reset_steps, task=scene.task, contact_model=scene.contact_model,
                      representation=representation, run=run)


def _timed_run(scene: Scene, initial: _State, reference: Trajectory | None, spans, dt: float, label: str,
               deadline: Deadline) -> tuple[float, np.ndarray]:
    """The rollout that is timed: bare AdvanceTo between resets, in chunks so that the wall-clock
    limit is looked at in between. (wall seconds spent advancing, final plant positions)."""
    simulator, pctx = _started(scene, initial, label)
    sim_time_s = 0.0
    for a, b in spans:
        if a > 0:
            _set_state(scene, pctx, _state_at(reference, a), label, a * dt)
        step = a
        while step < b:
            step = min(step + CHUNK_STEPS, b)
            t0 = time.perf_counter()
            _advance(simulator, step, dt, label)
            sim_time_s += time.perf_counter() - t0
            deadline.check(label, step * dt)
        _check_finite(scene, pctx, label, b * dt)
    return sim_time_s, scene.plant.GetPositions(pctx).copy()


def _started(scene: Scene, initial: _State, label: str):
    """(a Simulator of the scene's diagram, initialised at ``initial``, and the plant's context in it)."""
    from pydrake.systems.analysis import Simulator

    simulator = Simulator(scene.diagram)
    pctx = scene.plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    _set_state(scene, pctx, initial, label, 0.0)
    simulator.Initialize()
    return simulator, pctx


def _contact_reader(scene: Scene):
    """A function of the plant's context: the object's contact points (K, 3) and the forces it feels
    there (K, 3), world frame, point contacts first and then hydroelastic contact surfaces (at their
    centroids), and how many of the K are surfaces. The port and the object's ids are looked up
    once: it is called every step."""
    port = scene.plant.get_contact_results_output_port()
    obj_index, obj_geoms = scene.object_body.index(), scene.object_geometry_ids

    def read(pctx) -> tuple[np.ndarray, np.ndarray, int]:
        results = port.Eval(pctx)
        pts, forces = [], []
        surfaces = 0
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            # contact_force() acts on body B; the object feels minus that when it is body A.
            if info.bodyB_index() == obj_index:
                pts.append(info.contact_point())
                forces.append(info.contact_force())
            elif info.bodyA_index() == obj_index:
                pts.append(info.contact_point())
                forces.append(-info.contact_force())
        for k in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(k)
            surface = info.contact_surface()
            # F_Ac_W acts on the body of geometry M at the centroid; N's body feels minus it.
            if surface.id_M() in obj_geoms:
                pts.append(surface.centroid())
                forces.append(info.F_Ac_W().translational())
                surfaces += 1
            elif surface.id_N() in obj_geoms:
                pts.append(surface.centroid())
                forces.append(-info.F_Ac_W().translational())
                surfaces += 1
        return (np.asarray(pts, dtype=float).reshape(-1, 3), np.asarray(forces, dtype=float).reshape(-1, 3),
                surfaces)

    return read


def _in_object_frame(contacts_w: list[np.ndarray], forces_w: list[np.ndarray],
                     object_q: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per step, contact points and forces from the world frame into the object's body frame
    (``object_q``: (N, 7) quaternion wxyz then position, per step)."""
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RotationMatrix

    contacts_o, forces_o = [], []
    for i, (pw, fw) in enumerate(zip(contacts_w, forces_w)):
        if len(pw) == 0:
            contacts_o.append(np.zeros((0, 3)))
            forces_o.append(np.zeros((0, 3)))
            continue
        R = RotationMatrix(Quaternion(object_q[i, :4] / np.linalg.norm(object_q[i, :4]))).matrix()
        contacts_o.append((pw - object_q[i, 4:]) @ R)
        forces_o.append(fw @ R)
    return contacts_o, forces_o


def _mesh_vertices(mesh_path: Path) -> np.ndarray:
    from real2sim.geometry.mesh_io import load_mesh

    return np.asarray(load_mesh(Path(mesh_path)).vertices, dtype=float)


def simulate_reference(reference_mesh_path: Path, physical_properties, run_spec: RunSpec,
                       scene_config: SceneConfig, object_contact=None, timeout_s: float | None = None,
                       stable_poses: StablePoseCache | None = None) -> Trajectory:
    """The ground truth: the mesh at ``reference_mesh_path`` (asset frame, m; usually
    ``ASSETDIR/visual/model.obj``) as a rigid hydroelastic body with ``physical_properties``
    (a real2sim.formats.physical.PhysicalProperties), hydroelastic contact, no resets.
    ``object_contact``: real2sim.formats.contact.ContactProperties for friction/dissipation
    (defaults when None). ``timeout_s``: wall-clock limit of the whole call
    (:class:`SimulationTimeout` past it); None: none. ``stable_poses``: the object's resting
    poses kept by the caller (:class:`~real2sim.evaluate.scene.placement.StablePoseCache`; None: computed).
    Simulated once, instrumented: its ``sim_time_s`` is NaN, ``instrumented_time_s`` its wall time."""
    deadline = Deadline(timeout_s)
    scene = build_scene(run_spec.task, "hydroelastic",
                        reference_object_adder(reference_mesh_path, physical_properties, object_contact),
                        run_spec, scene_config)
    X_WO = initial_object_pose(_mesh_vertices(reference_mesh_path), run_spec, scene_config,
                               com_m=physical_properties.com_m, cache=stable_poses)
    label = f"reference {run_spec.task} run {run_spec.run}"
    return _simulate(scene, _initial_state(scene, X_WO), None, scene_config, label, "reference",
                     run_spec.run, deadline, timed=False)


def representation_name(urdf_path: Path) -> str:
    """The representation's canonical name: its folder under ASSETDIR."""
    return Path(urdf_path).resolve().parent.name


def simulate_candidate(representation_urdf_path: Path, contact_model: str, run_spec: RunSpec,
                       scene_config: SceneConfig, reference: Trajectory | None = None,
                       initial_mesh_path: Path | None = None, timeout_s: float | None = None,
                       timed: bool = True) -> Trajectory:
    """Simulate a candidate URDF with ``contact_model`` ("point" | "hydroelastic").

    With ``reference``: it starts from the reference's initial state and, when
    ``scene_config.reset_interval_s`` is set, is reset to the reference's state every
    interval (equation error); with ``reset_interval_s`` None/0 it is one rollout from the
    reference's start (simulation error). Without ``reference``: one rollout (simulation
    error) from the initial pose computed from ``initial_mesh_path`` (default: the asset's
    ``visual/model.obj`` two folders up from the URDF) and the CoM in the asset's
    ``physical_properties.json`` when present, so it matches :func:`simulate_reference`
    on that mesh. ``timeout_s``: wall-clock limit of the whole call (:class:`SimulationTimeout`
    past it); None: none. ``timed`` False: no separate timed roll-out, ``sim_time_s`` NaN (for a
    trajectory that is shown, not scored).
    """
    deadline = Deadline(timeout_s)
    urdf = Path(representation_urdf_path)
    scene = build_scene(run_spec.task, contact_model, urdf_object_adder(urdf), run_spec, scene_config)
    name = representation_name(urdf)
    label = f"{name} {contact_model} {run_spec.task} run {run_spec.run}"
    if reference is not None:
        if reference.run != run_spec.run:
            raise ValueError(f"{label}: reference is run {reference.run}")
        initial = _state_at(reference, 0)
    else:
        initial = candidate_initial_state(scene, urdf, run_spec, scene_config, initial_mesh_path, label)
    return _simulate(scene, initial, reference, scene_config, label, name, run_spec.run, deadline, timed=timed)


def candidate_initial_state(scene: Scene, urdf: Path, run_spec: RunSpec, scene_config: SceneConfig,
                            initial_mesh_path: Path | None = None, label: str = "candidate") -> _State:
    """A candidate's state at t = 0 without a reference: at rest, posed by :func:`initial_object_pose` from
    ``initial_mesh_path`` (default: the asset's ``visual/model.obj`` two folders up from ``urdf``) and the
    CoM in the asset's ``physical_properties.json`` when present, as :func:`simulate_reference` poses that
    mesh."""
    mesh = Path(initial_mesh_path) if initial_mesh_path else urdf.resolve().parent.parent / "visual" / "model.obj"
    if not mesh.is_file():
        raise FileNotFoundError(f"{label}: no reference given and no mesh for the initial pose at {mesh}")
    props_path = urdf.resolve().parent.parent / "physical_properties.json"
    com_m = read_physical_properties(props_path).com_m if props_path.is_file() else None
    return _initial_state(scene, initial_object_pose(_mesh_vertices(mesh), run_spec, scene_config, com_m=com_m))
