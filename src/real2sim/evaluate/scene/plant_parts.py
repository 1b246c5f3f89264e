"""Small Drake building blocks shared by the world and the tasks."""

from __future__ import annotations


def contact_material(props, dissipation_s_per_m: float, relaxation_time_s: float | None, mu_static: float,
              mu_dynamic: float) -> None:
    from pydrake.geometry import AddContactMaterial
    from pydrake.multibody.plant import CoulombFriction

    AddContactMaterial(props, dissipation=dissipation_s_per_m,
                       friction=CoulombFriction(mu_static, mu_dynamic))
    if relaxation_time_s is not None:
        # The "sap" approximation's linear model reads a relaxation time instead of H-C dissipation.
        props.AddProperty("material", "relaxation_time", relaxation_time_s)


def pd_actuator(plant, name: str, joint, kp: float, kd: float) -> None:
    from pydrake.multibody.tree import PdControllerGains

    actuator = plant.AddJointActuator(name, joint)
    actuator.set_controller_gains(PdControllerGains(p=kp, d=kd))
