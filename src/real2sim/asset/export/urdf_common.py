"""What every URDF real2sim writes shares: numbers as text, origins, the shapes URDF itself has, and
the one link with its inertial and visual (:mod:`real2sim.asset.export.writers` for Drake,
:mod:`real2sim.asset.export.portable_urdf` for every other URDF consumer).

Numbers are written with ``repr`` (shortest round-trip float text), so a file read back gives the
same doubles that were written.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from real2sim.formats.collision import CollisionShape
from real2sim.formats.physical import PhysicalProperties


def num(x: float) -> str:
    """``x`` as attribute or element text: the shortest text that reads back as the same double."""
    return repr(float(x))


def nums(values) -> str:
    """``values`` as space-separated :func:`num` texts (a URDF ``xyz``, a box's ``size``)."""
    return " ".join(num(v) for v in values)


def urdf_origin(parent: ET.Element, xyz, rpy) -> None:
    """An ``<origin xyz rpy>`` in ``parent`` (metres; roll-pitch-yaw in radians, Drake's convention)."""
    ET.SubElement(parent, "origin", xyz=nums(xyz), rpy=nums(rpy))


def standard_urdf_geometry(geom: ET.Element, shape: CollisionShape) -> bool:
    """Write ``shape`` into ``<geometry>`` ``geom`` if URDF itself has it (box, sphere, cylinder);
    whether it did."""
    s = shape.size_m
    if shape.kind == "box":
        ET.SubElement(geom, "box", size=nums(s))
    elif shape.kind == "sphere":
        ET.SubElement(geom, "sphere", radius=num(s[0]))
    elif shape.kind == "cylinder":
        ET.SubElement(geom, "cylinder", radius=num(s[0]), length=num(s[1]))
    else:
        return False
    return True


def urdf_link(props: PhysicalProperties, visual_mesh_relpath: str | None, model_name: str,
              link_name: str) -> tuple[ET.Element, ET.Element]:
    """``(<robot>, <link>)``: the one link with its inertial (mass, the CoM as the inertial frame's
    origin, the inertia about the CoM in the link's axes) and, given a path, the visual mesh;
    collision elements are the caller's."""
    robot = ET.Element("robot", name=model_name)
    link = ET.SubElement(robot, "link", name=link_name)
    inertial = ET.SubElement(link, "inertial")
    urdf_origin(inertial, props.com_m, (0.0, 0.0, 0.0))
    ET.SubElement(inertial, "mass", value=num(props.mass_kg))
    i = props.inertia
    ET.SubElement(
        inertial,
        "inertia",
        ixx=num(i[0, 0]), ixy=num(i[0, 1]), ixz=num(i[0, 2]),
        iyy=num(i[1, 1]), iyz=num(i[1, 2]), izz=num(i[2, 2]),
    )  # fmt: skip
    if visual_mesh_relpath:
        visual = ET.SubElement(link, "visual", name="visual")
        urdf_origin(visual, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        vgeom = ET.SubElement(visual, "geometry")
        ET.SubElement(vgeom, "mesh", filename=visual_mesh_relpath)
    return robot, link
