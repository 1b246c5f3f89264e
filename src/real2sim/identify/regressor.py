"""Joint torques as a linear function of the payload's parameters: ``tau = tau_arm + Y phi``.

``Y`` comes from Drake's inverse dynamics itself, not from a hand-written Newton-Euler: inverse
dynamics is exactly linear in the payload's ten inertial parameters (:mod:`real2sim.identify.arm`),
so each column of ``Y`` is the difference of two inverse-dynamics solutions whose payloads differ
by one parameter.
"""

from __future__ import annotations

import numpy as np

from real2sim.identify.arm import ArmWithPayload, spatial_inertia

#: A payload the columns are differenced around: 1 kg at the origin, a small inertia (any phi with a
#: non-zero mass would do; inverse dynamics is linear in phi).
_BASE_PHI = np.array([1.0, 0.0, 0.0, 0.0, 0.01, 0.01, 0.01, 0.0, 0.0, 0.0])


def joint_torques(plant, context, vdot: np.ndarray, forces=None) -> np.ndarray:
    """Inverse dynamics at the context's state, gravity included: Drake's CalcInverseDynamics counts
    only the forces it is given, so the force elements (gravity) are added first. ``forces``: a
    MultibodyForces of ``plant`` to reuse (overwritten) in a loop, where making one per call and the
    import's lookup were a third of the time."""
    if forces is None:
        from pydrake.multibody.tree import MultibodyForces

        forces = MultibodyForces(plant)
    plant.CalcForceElementsContribution(context, forces)
    return plant.CalcInverseDynamics(context, vdot, forces)


def _inverse_dynamics(arm: ArmWithPayload, q: np.ndarray, v: np.ndarray, a: np.ndarray, inertia) -> np.ndarray:
    from pydrake.multibody.tree import MultibodyForces

    plant, ctx = arm.plant, arm.context
    arm.payload.SetSpatialInertiaInBodyFrame(ctx, inertia)
    forces = MultibodyForces(plant)
    out = np.empty_like(q)
    for t in range(len(q)):
        plant.SetPositions(ctx, q[t])
        plant.SetVelocities(ctx, v[t])
        out[t] = joint_torques(plant, ctx, a[t], forces)
    return out


def payload_regressor(arm: ArmWithPayload, q_rad: np.ndarray, v_rad_per_s: np.ndarray,
                      a_rad_per_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(tau_arm (T, n) N m, Y (T, n, 10)) at the samples: the arm's own inverse dynamics (gravity
    included, no payload) and the payload regressor, ``tau = tau_arm + Y @ phi``."""
    from pydrake.multibody.tree import SpatialInertia

    q, v, a = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q_rad, v_rad_per_s, a_rad_per_s2))
    tau_arm = _inverse_dynamics(arm, q, v, a, SpatialInertia.Zero())
    tau_base = _inverse_dynamics(arm, q, v, a, spatial_inertia(_BASE_PHI))
    columns = []
    for k in range(10):
        phi = _BASE_PHI.copy()
        phi[k] += 1.0
        columns.append(_inverse_dynamics(arm, q, v, a, spatial_inertia(phi)) - tau_base)
    arm.payload.SetSpatialInertiaInBodyFrame(arm.context, SpatialInertia.Zero())
    return tau_arm, np.stack(columns, axis=-1)


def friction_regressor(v_rad_per_s: np.ndarray, stiction_band_rad_per_s: float = 0.01) -> np.ndarray:
    """(T, n, 2n): each joint's Coulomb (``tanh(v / band)``, a smoothed sign) and viscous (``v``)
    friction columns; parameters ``[Fc_1..Fc_n, Fv_1..Fv_n]`` in N m and N m s/rad."""
    v = np.atleast_2d(np.asarray(v_rad_per_s, dtype=float))
    t, n = v.shape
    out = np.zeros((t, n, 2 * n))
    idx = np.arange(n)
    out[:, idx, idx] = np.tanh(v / stiction_band_rad_per_s)
    out[:, idx, n + idx] = v
    return out
