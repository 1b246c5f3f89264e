"""Every physical parameter of the evaluation scenes (:class:`SceneConfig`), shared by reference and candidates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.evaluate.scene.tasks import task_named


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
        return task_named(task).duration_s(self)

    def num_steps(self, task: str) -> int:
        """Number of plant steps of one run of ``task`` (integer; times are step * time_step_s)."""
        return int(round(self.duration_s(task) / self.time_step_s))

    def reset_interval_steps(self) -> int | None:
        """Steps between equation-error resets, or None for simulation error."""
        if not self.reset_interval_s:
            return None
        return int(round(self.reset_interval_s / self.time_step_s))
