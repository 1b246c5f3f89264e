"""Every physical parameter of the evaluation scenes (:class:`SceneConfig`), shared by reference and candidates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SceneConfig:
    """Every physical parameter of the evaluation scenes (the pushing floor and the tilting ramp);
    the reference and every candidate are simulated with the same one."""

    time_step_s: float = 1e-3
    """The plant's discrete time step, s; > 0 (the paper: 0.001)."""
    discrete_contact_approximation: str = "lagged"
    """Drake's discrete contact approximation: "lagged", "sap" or "similar" (the SAP family)
    (why not TAMSI: docs/design-notes/evaluate.md#contact-approximation)."""
    reset_interval_s: float | None = 0.1
    """Equation error: the candidate is reset to the reference state every this many seconds, s
    (the paper: 0.1); a whole number of time steps. None or 0: simulation error (one rollout, no resets)."""

    environment_hydroelastic_modulus_pa: float = 1.0e7
    """Compliant hydroelastic modulus of the floor, the table and the pusher, Pa; > 0."""
    floor_slab_thickness_m: float = 0.5
    """Half the floor slab's thickness, the depth of its pressure field's maximum below z = 0, m; > 0."""
    floor_size_m: float = 40.0
    """Width and length of the floor slab, m; large, so a rolling object never falls off the world."""
    environment_dissipation_s_per_m: float = 1.0
    """Hunt-Crossley dissipation of the floor, table and pusher, s/m; >= 0 (read by "lagged" and "similar")."""
    environment_relaxation_time_s: float = 0.01
    """Linear Kelvin-Voigt relaxation time of the floor, table and pusher, s; >= 0 (read by "sap")."""
    floor_mu: float = 0.5
    """Coulomb friction of the floor (static = dynamic); >= 0."""
    table_mu: float = 0.5
    """Coulomb friction of the ramp's table (static = dynamic); >= 0."""
    pusher_mu: float = 0.5
    """Coulomb friction of the pusher sphere (static = dynamic); >= 0."""
    pusher_resolution_hint_m: float = 0.01
    """Resolution hint of the pusher sphere's compliant mesh, m; > 0."""

    object_lying: bool = True
    """True: the object starts on its side (asset z horizontal), so a bottle or can rolls; False: upright."""
    drop_clearance_m: float = 0.001
    """Gap between the object's lowest vertex and its support (floor or table) at t = 0, m; >= 0."""

    pusher_radius_m: float = 0.05
    """Radius of the pusher sphere, m; > 0."""
    pusher_clearance_m: float = 0.002
    """Height of the pusher sphere's bottom above the floor, m; >= 0 (so it never rubs on the floor)."""
    pusher_mass_kg: float = 1.0
    """Mass of the pusher sphere, kg; > 0."""
    pusher_start_distance_m: float = 0.2
    """Horizontal distance from the pusher's centre to the object's centre at t = 0, m."""
    pusher_speed_m_per_s: float = 0.2
    """The pusher's commanded speed along its line once the object has settled, m/s."""
    settle_s: float = 0.2
    """Time the pusher waits at its start while the object settles, s; >= 0."""
    push_duration_s: float = 1.3
    """Time the pusher moves after settling, s; >= 0 (a push run lasts ``settle_s + push_duration_s``)."""
    pusher_kp_n_per_m: float = 5.0e3
    """Proportional gain of each of the pusher's two prismatic PD actuators, N/m."""
    pusher_kd_n_s_per_m: float = 2.0e2
    """Derivative gain of each of the pusher's two prismatic PD actuators, N s/m."""

    table_size_m: tuple[float, float, float] = (0.8, 1.6, 0.05)
    """The ramp's table: x width along the hinge, y length down-slope, z thickness, m."""
    table_mass_kg: float = 10.0
    """Mass of the ramp's table, kg; > 0 (centred on the hinge, a counterweight, so its PD fights only the object)."""
    hinge_height_m: float = 1.3
    """Height of the hinge (on the table's top face, at its +y edge) above the floor, m."""
    hold_s: float = 0.3
    """Time the table stays flat before tilting, s; >= 0."""
    tilt_deg: float = 45.0
    """The table's final tilt about the hinge, degrees (tilting lowers its -y end)."""
    tilt_time_s: float = 0.5
    """Duration of the minimum-jerk tilt from 0 to ``tilt_deg``, s; > 0."""
    total_duration_s: float = 2.0
    """Length of one ramp run, s; > 0."""
    ramp_object_gap_m: float = 0.02
    """Distance along -y from the hinge line to the object's up-slope edge at t = 0, m; >= 0."""
    table_kp_n_m_per_rad: float = 2.0e4
    """Proportional gain of the hinge's PD actuator, N m/rad (Drake's implicit PD; no integral term needed)."""
    table_kd_n_m_s_per_rad: float = 5.0e2
    """Derivative gain of the hinge's PD actuator, N m s/rad."""

    def __post_init__(self) -> None:
        if not (self.time_step_s > 0 and np.isfinite(self.time_step_s)):
            raise ValueError("time_step_s must be positive")
        if self.discrete_contact_approximation not in ("lagged", "sap", "similar"):
            raise ValueError("discrete_contact_approximation must be lagged, sap or similar")
        if self.reset_interval_s:
            k = self.reset_interval_s / self.time_step_s
            if abs(k - round(k)) > 1e-6 or round(k) < 1:
                raise ValueError("reset_interval_s must be a whole number of time steps")

    def reset_interval_steps(self) -> int | None:
        """Steps between equation-error resets, or None for simulation error."""
        if not self.reset_interval_s:
            return None
        return int(round(self.reset_interval_s / self.time_step_s))
