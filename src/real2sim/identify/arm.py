"""The arm holding a payload, as a Drake MultibodyPlant, and the payload's inertial parameters.

Inertial parameters ``phi`` (10,), in the payload's (the object's own) frame O, about its origin:
``[m, m cx, m cy, m cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]``: mass (kg), first moments (kg m) and the
rotational inertia about O (kg m^2). Joint torques are linear in ``phi``, which is what makes
identification a least-squares problem.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError

PAYLOAD_BODY = "payload"


def default_arm_urdf() -> Path:
    """Our own iiwa 14-like arm (``real2sim/data/robots/iiwa14_like.urdf``, sources in the file)."""
    return Path(str(resources.files("real2sim").joinpath("data/robots/iiwa14_like.urdf")))


@dataclass(frozen=True)
class ArmWithPayload:
    """A finalized plant: the arm's base welded at the world origin, the payload body welded to the
    flange at ``flange_from_object``. ``plant``, ``context`` and ``payload`` are Drake objects;
    ``joint_names`` are in the order of the log's columns."""

    plant: object
    context: object
    payload: object
    joint_names: tuple[str, ...]
    position_lower_rad: np.ndarray
    position_upper_rad: np.ndarray
    velocity_limit_rad_per_s: np.ndarray
    effort_limit_n_m: np.ndarray
    flange_frame: str = "flange"

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)


def load_arm(urdf: Path, flange_frame: str, flange_from_object: np.ndarray, time_step_s: float = 0.0) -> ArmWithPayload:
    """Parse ``urdf`` (UserInputError when Drake cannot) and add the payload."""
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant
    from pydrake.multibody.tree import SpatialInertia

    plant = MultibodyPlant(time_step_s)
    try:
        (instance,) = Parser(plant).AddModels(str(urdf))
    except Exception as exc:  # Drake raises RuntimeError/ValueError with the parser's message
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
        raise UserInputError(f"the robot model {urdf} does not load in Drake: {first}") from None
    bodies = plant.GetBodyIndices(instance)
    base = plant.get_body(bodies[0])
    plant.WeldFrames(plant.world_frame(), base.body_frame())
    try:
        flange = plant.GetFrameByName(flange_frame, instance)
    except RuntimeError:
        raise UserInputError(f"the robot model {urdf} has no frame {flange_frame!r} (the grasp's flange_frame)") from None
    payload = plant.AddRigidBody(PAYLOAD_BODY, instance, SpatialInertia.Zero())
    plant.WeldFrames(flange, payload.body_frame(), RigidTransform(np.asarray(flange_from_object, dtype=float)))
    plant.Finalize()
    joints = [plant.get_joint(j) for j in plant.GetJointIndices(instance)]
    moving = [j for j in joints if j.num_velocities() == 1]
    if len(moving) != plant.num_velocities() or plant.num_velocities() == 0:
        raise UserInputError(f"the robot model {urdf} must be a chain of 1-DoF joints (revolute or prismatic)")
    return ArmWithPayload(
        plant=plant, context=plant.CreateDefaultContext(), payload=payload,
        joint_names=tuple(j.name() for j in moving),
        position_lower_rad=plant.GetPositionLowerLimits(), position_upper_rad=plant.GetPositionUpperLimits(),
        velocity_limit_rad_per_s=plant.GetVelocityUpperLimits(),
        effort_limit_n_m=_effort_limits(urdf, [j.name() for j in moving]), flange_frame=flange_frame,
    )


def _effort_limits(urdf: Path, names: list[str]) -> np.ndarray:
    """Each joint's ``<limit effort>`` (N m) from the URDF, infinity where none is given: Drake keeps
    effort limits on actuators, which a model without transmissions does not have."""
    import xml.etree.ElementTree as ET

    efforts = {}
    for joint in ET.parse(urdf).getroot().iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("effort"):
            efforts[joint.get("name")] = float(limit.get("effort"))
    return np.array([efforts.get(n, np.inf) for n in names])


def spatial_inertia(phi: np.ndarray):
    """Drake's SpatialInertia of ``phi`` about the payload origin, without a validity check: the
    regressor needs non-physical basis elements. ``phi[0]`` must not be zero."""
    from pydrake.multibody.tree import SpatialInertia, UnitInertia

    m, h, inertia = float(phi[0]), np.asarray(phi[1:4], dtype=float), inertia_matrix(phi)
    g = inertia / m
    return SpatialInertia(m, h / m, UnitInertia(g[0, 0], g[1, 1], g[2, 2], g[0, 1], g[0, 2], g[1, 2]),
                          skip_validity_check=True)


def inertia_matrix(phi: np.ndarray) -> np.ndarray:
    """The 3x3 rotational inertia about the payload origin held in ``phi``."""
    ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in phi[4:10])
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def phi_from_properties(mass_kg: float, com_m: np.ndarray, inertia_about_com_kg_m2: np.ndarray) -> np.ndarray:
    """``phi`` of a body with the given mass, CoM (payload frame) and inertia about its CoM."""
    c = np.asarray(com_m, dtype=float)
    about_origin = np.asarray(inertia_about_com_kg_m2, dtype=float) + mass_kg * (c @ c * np.eye(3) - np.outer(c, c))
    i = about_origin
    return np.array([mass_kg, *(mass_kg * c), i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])


def properties_from_phi(phi: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, CoM m, inertia about the CoM kg m^2) of ``phi``."""
    m = float(phi[0])
    c = np.asarray(phi[1:4], dtype=float) / m
    return m, c, inertia_matrix(phi) - m * (c @ c * np.eye(3) - np.outer(c, c))


def pseudo_inertia(phi: np.ndarray) -> np.ndarray:
    """The 4x4 pseudo-inertia ``[[Sigma, h], [h^T, m]]``, ``Sigma = tr(I)/2 * 1 - I``: positive
    semidefinite exactly when some mass distribution has these parameters (Wensing et al., 2017)."""
    inertia = inertia_matrix(phi)
    out = np.zeros((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = phi[1:4]
    out[3, 3] = phi[0]
    return out
