"""``model_portable.urdf``: the same rigid body in plain URDF, for simulators other than Drake.

``model.urdf`` is written for Drake: its ellipsoids and capsules are ``drake:ellipsoid`` and
``drake:capsule`` elements, which PyBullet, Isaac's URDF importer, Gazebo and ROS parsers
(urdfdom, yourdfpy) do not know (PyBullet refuses the whole file). ``model.urdf`` keeps
them because Drake then simulates the smooth shape that was fitted, which a polytope of it is not
(why: docs/design-notes/asset.md#native-and-portable-shapes-in-drake). This second file, written for every
representation beside ``model.urdf``, holds only standard URDF:

* box, sphere and cylinder as themselves;
* ellipsoids and capsules as convex ``<mesh>`` pieces of the shape's exact volume
  (:mod:`real2sim.asset.export.round_pieces`), written to ``portable/<kind>_NNN.obj`` in the
  shape's frame and posed by the collision element's origin;
* convex pieces (CoACD, V-HACD, superquadrics) as the same OBJ files ``model.urdf`` uses,
  one convex piece per file: PyBullet, like every URDF consumer we know, collides a mesh
  file as the convex hull of *all* its vertices, so pieces must never share a file;
* the ``mesh`` representation's non-convex mesh as it is; every URDF consumer of dynamic
  bodies collides it as its convex hull (PyBullet, Isaac without a decomposition, MuJoCo);
* no ``drake:`` element and no namespace declaration. The one extension present is
  PyBullet's ``<contact><lateral_friction value=.../></contact>`` in the link, which carries
  the asset's dynamic friction to PyBullet and which other URDF parsers skip.

Inertial: mass, the CoM and the full tensor about it, as ``model.urdf``. PyBullet *ignores*
it unless ``loadURDF(..., flags=pybullet.URDF_USE_INERTIA_FROM_FILE)``: without the flag it
computes the inertia from the collision shapes' bounding box (docs/formats.md).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from real2sim.asset.export.round_pieces import round_polytope
from real2sim.asset.export.urdf_common import num, nums, standard_urdf_geometry, urdf_link
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties
from real2sim.formats.rotations import quaternion_to_rpy

PORTABLE_URDF_NAME = "model_portable.urdf"
PORTABLE_PIECES_DIR = "portable"

#: Elements (tag -> allowed parents) a portable URDF may contain: the URDF specification's
#: link-level vocabulary plus PyBullet's <contact> block. Tests check every file against it.
PORTABLE_ELEMENTS = {
    "robot": (None,), "link": ("robot",), "inertial": ("link",), "origin": ("inertial", "visual", "collision"),
    "mass": ("inertial",), "inertia": ("inertial",), "visual": ("link",), "collision": ("link",),
    "geometry": ("visual", "collision"), "box": ("geometry",), "sphere": ("geometry",),
    "cylinder": ("geometry",), "mesh": ("geometry",), "contact": ("link",), "lateral_friction": ("contact",),
}


def portable_mesh_file(shape: CollisionShape, index: int) -> str | None:
    """The mesh file (relative to the representation folder) the portable URDF uses for shape
    number ``index``; None for shapes URDF has (box, sphere, cylinder)."""
    if shape.kind in ("ellipsoid", "capsule"):
        return f"{PORTABLE_PIECES_DIR}/{shape.kind}_{index:03d}.obj"
    if shape.kind in ("convex", "mesh"):
        return str(shape.mesh_file)
    return None


def write_round_pieces(geometry: CollisionGeometry, rep_dir: Path) -> None:
    """Write the polytope of every ellipsoid and capsule to ``rep_dir/portable/`` (stale files go)."""
    pieces = Path(rep_dir) / PORTABLE_PIECES_DIR
    for stale in pieces.glob("*.obj"):
        stale.unlink()
    for k, shape in enumerate(geometry.shapes):
        if shape.kind in ("ellipsoid", "capsule"):
            pieces.mkdir(parents=True, exist_ok=True)
            round_polytope(shape).export(Path(rep_dir) / portable_mesh_file(shape, k), include_normals=False)
    if pieces.is_dir() and not any(pieces.iterdir()):
        pieces.rmdir()


def build_portable_urdf(geometry: CollisionGeometry, props: PhysicalProperties, contact: ContactProperties,
                        visual_mesh_relpath: str = "../visual/model.obj", model_name: str = "object",
                        link_name: str = "base_link") -> ET.Element:
    """The ``<robot>`` element of the portable URDF (module docstring); mesh files are named,
    not written (:func:`write_round_pieces` writes the round ones)."""
    robot, link = urdf_link(props, visual_mesh_relpath, model_name, link_name)
    for k, shape in enumerate(geometry.shapes):
        col = ET.SubElement(link, "collision", name=f"collision_{k:04d}")
        ET.SubElement(col, "origin", xyz=nums(shape.position_m), rpy=nums(quaternion_to_rpy(shape.quaternion_wxyz)))
        geom = ET.SubElement(col, "geometry")
        if not standard_urdf_geometry(geom, shape):
            ET.SubElement(geom, "mesh", filename=portable_mesh_file(shape, k))
    contact_el = ET.SubElement(link, "contact")
    ET.SubElement(contact_el, "lateral_friction", value=num(contact.mu_dynamic))
    return robot


def write_portable_urdf(rep_dir: Path, geometry: CollisionGeometry, props: PhysicalProperties,
                        contact: ContactProperties, visual_mesh_relpath: str = "../visual/model.obj",
                        model_name: str = "object", link_name: str = "base_link") -> Path:
    """Write ``rep_dir/model_portable.urdf`` and its round pieces; returns the URDF's path."""
    write_round_pieces(geometry, rep_dir)
    root = build_portable_urdf(geometry, props, contact, visual_mesh_relpath, model_name, link_name)
    ET.indent(root, space=" ")
    path = Path(rep_dir) / PORTABLE_URDF_NAME
    path.write_text('<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n")
    return path
