"""`excite`: a simulated arm holds the object, follows the exciting trajectory, and logs its joints.

Drake simulates the arm (a continuous plant, error-controlled integration) with the payload welded to
the flange at the grasp.
A computed-torque controller tracks the trajectory with the arm's nominal model, which knows
nothing of the payload (the tracking error absorbs it, as on a real robot). The joints feel
Coulomb and viscous friction. What is logged is what a
torque-sensing arm reports: encoder positions (quantised), velocities differenced from them, and
the motor torques with white noise. The controller compensates 80 % of the friction; the rest
shows up as tracking error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.formats.joint_log import JointLog
from real2sim.identify.arm import ArmWithPayload, phi_from_properties, spatial_inertia
from real2sim.identify.excitation import FourierTrajectory

DEFAULT_COULOMB_N_M = (1.0, 1.0, 0.6, 0.6, 0.4, 0.2, 0.2)
DEFAULT_VISCOUS_N_M_S = (0.8, 0.8, 0.5, 0.5, 0.3, 0.2, 0.2)


@dataclass(frozen=True)
class Measurement:
    """How the simulated arm measures its joints, and the friction they feel."""

    torque_noise_n_m: float = 0.05
    """RMS of the white noise on each joint's logged torque, N m, >= 0."""
    encoder_resolution_rad: float = 2.0 * np.pi / 2**20
    """Quantisation step of the logged joint positions, rad, >= 0 (a 2^20-count encoder)."""
    coulomb_n_m: tuple[float, ...] = DEFAULT_COULOMB_N_M
    """Coulomb friction of each joint, shoulder to wrist, N m, >= 0 (repeated when shorter)."""
    viscous_n_m_s: tuple[float, ...] = DEFAULT_VISCOUS_N_M_S
    """Viscous friction of each joint, shoulder to wrist, N m s/rad, >= 0 (repeated when shorter)."""
    stiction_band_rad_per_s: float = 0.01
    """Speed scale of the tanh that smooths the Coulomb part through zero speed, rad/s, > 0."""


@dataclass(frozen=True)
class PayloadTruth:
    """The payload's true mass (kg), CoM (m) and inertia about the CoM (kg m^2), object frame."""

    mass_kg: float
    com_m: np.ndarray
    inertia_kg_m2: np.ndarray

    def to_json(self) -> dict:
        return {"mass_kg": self.mass_kg, "com_m": np.asarray(self.com_m).tolist(),
                "inertia_kg_m2": np.asarray(self.inertia_kg_m2).tolist(), "frame": "the object's mesh frame"}


def closed_solid(mesh):
    """A copy of ``mesh`` (trimesh) as bare geometry with coincident vertices merged whatever their texture
    coordinates and normals: OBJ files split vertices at UV seams and STL files share none, which leaves
    a closed surface open to trimesh's watertightness test. The vertices keep their coordinates."""
    import trimesh

    solid = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=float).copy(), np.asarray(mesh.faces).copy(),
                            process=False)
    solid.merge_vertices(merge_tex=True, merge_norm=True)
    return solid


def payload_truth(mesh, mass_kg: float, extra_mass_kg: float = 0.0, extra_mass_at_m=None) -> PayloadTruth:
    """A body of ``mass_kg`` at uniform density over the closed ``mesh`` (trimesh, metres), plus a point
    mass ``extra_mass_kg`` at ``extra_mass_at_m`` (mesh frame)."""
    mesh = closed_solid(mesh)
    volume = float(mesh.volume)
    if not (mesh.is_watertight and volume > 0):
        raise ValueError("the payload's mesh must be a closed solid")
    com = np.asarray(mesh.center_mass, dtype=float)
    inertia = np.asarray(mesh.moment_inertia, dtype=float) * (mass_kg / volume)  # trimesh: unit density, about com
    phi = phi_from_properties(mass_kg, com, inertia)
    if extra_mass_kg > 0:
        p = np.asarray(extra_mass_at_m, dtype=float)
        phi = phi + phi_from_properties(extra_mass_kg, p, np.zeros((3, 3)))
    from real2sim.identify.arm import properties_from_phi

    m, c, i = properties_from_phi(phi)
    return PayloadTruth(m, c, i)


def simulate_excitation(arm: ArmWithPayload, nominal: ArmWithPayload, traj: FourierTrajectory, truth: PayloadTruth,
                        measurement: Measurement = Measurement(), *, seed: int = 0, log_period_s: float = 1e-3,
                        control_period_s: float = 5e-4, progress=None) -> JointLog:
    """Run ``traj`` on ``arm`` (a continuous plant: ``time_step_s`` 0) carrying ``truth``; ``nominal`` is
    the controller's model (same arm, no payload). Returns the measured log, sampled every
    ``log_period_s``.

    The controller updates every ``control_period_s`` (an even fraction of the log period: 2 kHz by
    default, as fast as a torque-controlled arm's joint loop; faster costs time for no better result:
    docs/design-notes/identify.md#controller-rate) and holds its torque
    in between, as a real joint controller does; a log sample's torque is the mean of
    what was applied over the log period centred on it (what a torque reading averaged over one
    period gives), so that it goes with the motion at that instant.
    """
    from pydrake.multibody.tree import MultibodyForces
    from pydrake.systems.analysis import Simulator

    from real2sim.identify.regressor import joint_torques

    sub = int(round(log_period_s / control_period_s))
    if sub < 2 or sub % 2 or abs(sub * control_period_s - log_period_s) > 1e-12:
        raise ValueError("control_period_s must divide log_period_s an even number of times")
    rng = np.random.default_rng(seed)
    plant, ctx = arm.plant, arm.context
    arm.payload.SetSpatialInertiaInBodyFrame(ctx, spatial_inertia(phi_from_properties(
        truth.mass_kg, truth.com_m, truth.inertia_kg_m2)))
    n = arm.num_joints
    coulomb = np.resize(np.asarray(measurement.coulomb_n_m, float), n)
    viscous = np.resize(np.asarray(measurement.viscous_n_m_s, float), n)
    samples = int(round(traj.duration_s / log_period_s))
    steps = samples * sub
    times = np.arange(steps + 1) * control_period_s
    q_d, v_d, a_d = traj.sample(times)
    plant.SetPositions(ctx, q_d[0])
    plant.SetVelocities(ctx, v_d[0])
    simulator = Simulator(plant, ctx)
    simulator.Initialize()
    port = plant.get_applied_generalized_force_input_port()
    # stiff joint-level tracking, as an industrial arm has; the controller compensates 80 % of the
    # friction it was told about (a real one never knows it exactly)
    kp, kd = 2500.0, 100.0
    q_log = np.empty((samples + 1, n))
    tau_applied = np.empty((steps + 1, n))
    v_before = v_d[0]  # the arm starts at the trajectory's velocity: the first period's rate is 0
    forces = MultibodyForces(nominal.plant)
    for i in range(steps + 1):
        q, v = plant.GetPositions(ctx), plant.GetVelocities(ctx)
        if i % sub == 0:
            q_log[i // sub] = q
        nominal.plant.SetPositions(nominal.context, q)
        nominal.plant.SetVelocities(nominal.context, v)
        command = a_d[i] + kp * (q_d[i] - q) + kd * (v_d[i] - v)
        friction = _friction(v, coulomb, viscous, measurement.stiction_band_rad_per_s)
        tau_applied[i] = joint_torques(nominal.plant, nominal.context, command, forces) + 0.8 * friction
        if i == steps:
            break
        # The joints' friction acts all the time, not only at the controller's ticks: held over a control
        # period it is the friction at the period's middle (the velocity carried half a period on at the
        # last period's rate). Held at the tick's velocity it would lag the motion by half a period, a
        # torque that looks like inertia (docs/design-notes/identify.md#friction-at-mid-period).
        v_mid = v + 0.5 * (v - v_before)
        port.FixValue(ctx, tau_applied[i] - _friction(v_mid, coulomb, viscous, measurement.stiction_band_rad_per_s))
        v_before = v
        simulator.AdvanceTo(times[i + 1])
        if progress is not None and i % (500 * sub) == 0:
            progress(i, steps)
    if progress is not None:
        progress(steps, steps)
    res = measurement.encoder_resolution_rad
    q_meas = np.round(q_log / res) * res if res > 0 else q_log
    v_meas = np.gradient(q_meas, log_period_s, axis=0)
    # the torque over [t - T/2, t + T/2): control steps i*sub - sub/2 ... i*sub + sub/2 - 1
    padded = np.concatenate([np.repeat(tau_applied[:1], sub // 2, axis=0), tau_applied[:-1],
                             np.repeat(tau_applied[-1:], sub // 2 + 1, axis=0)])
    windows = padded[: (samples + 1) * sub].reshape(samples + 1, sub, n)
    tau_meas = windows.mean(axis=1) + rng.normal(scale=measurement.torque_noise_n_m, size=(samples + 1, n))
    return JointLog(time_s=np.arange(samples + 1) * log_period_s, q_rad=q_meas, v_rad_per_s=v_meas,
                    tau_n_m=tau_meas, a_rad_per_s2=None, flange_from_object=_grasp_of(arm),
                    flange_frame=arm.flange_frame)


def _friction(v: np.ndarray, coulomb: np.ndarray, viscous: np.ndarray, band: float) -> np.ndarray:
    """Joint friction torques, N m: Coulomb smoothed over ``band`` rad/s, plus viscous."""
    return coulomb * np.tanh(v / band) + viscous * v


def _grasp_of(arm: ArmWithPayload) -> np.ndarray:
    """The payload body's pose in the flange frame (the weld's transform)."""
    plant, ctx = arm.plant, arm.context
    flange = plant.GetFrameByName(arm.flange_frame)
    return plant.CalcRelativeTransform(ctx, flange, arm.payload.body_frame()).GetAsMatrix4()

