"""URDF and SDFormat files for one collision representation (paper IV-E), written for Drake.

Other simulators get their own files from the same data (docs/formats.md):
``model_portable.urdf`` (always; :mod:`real2sim.asset.export.portable_urdf`), ``model.xml`` and
``scene.xml`` (:mod:`real2sim.asset.export.mjcf`), ``model.usda`` (:mod:`real2sim.asset.export.usd`);
:func:`write_representation` writes them all.

An asset folder holds the textured visual mesh once (``visual/model.obj``) and one
folder per collision representation; this module writes that folder's
``model.urdf`` (always) and ``model.sdf`` (on request). Each file describes one
rigid link whose frame is the asset (canonical) frame:

* visual: the textured mesh, referenced by a path *relative* to the file
  (``../visual/model.obj`` by default), because Drake rejects absolute mesh paths
  in some flows and the asset must survive being moved;
* collision: every :class:`~real2sim.formats.collision.CollisionShape` as its own
  ``<collision>`` element, as the paper does (no triangle-mesh union of the
  primitives), posed by xyz + roll-pitch-yaw in Drake's convention (extrinsic
  x-y-z: R = Rz(yaw) Ry(pitch) Rx(roll));
* inertial: mass, the CoM as the inertial frame's origin, and the rotational
  inertia about the CoM in the link's axes (inertial frame not rotated);
* Drake proximity properties in every collision element, from
  :class:`~real2sim.formats.contact.ContactProperties`.

Shape kinds map to Drake geometry as follows (URDF / SDFormat):

=========  ===================================  =========================================
kind       URDF                                 SDFormat 1.9
=========  ===================================  =========================================
box        ``<box size>``                       ``<box><size>``
sphere     ``<sphere radius>``                  ``<sphere><radius>``
cylinder   ``<cylinder radius length>``         ``<cylinder><radius><length>``
ellipsoid  ``<drake:ellipsoid a b c>``          ``<ellipsoid><radii>``
capsule    ``<drake:capsule radius length>``    ``<capsule><radius><length>``
convex     ``<mesh>`` + ``<drake:declare_convex/>``  ``<mesh><uri>`` + ``<drake:declare_convex/>``
mesh       ``<mesh>`` (used as it is)           ``<mesh><uri>``
=========  ===================================  =========================================

Hydroelastic type of a non-convex ``mesh`` shape: Drake silently replaces a
*compliant* hydroelastic ``.obj`` by its convex hull, which would erase the very
concavities the ``mesh`` baseline exists to keep. Such a shape is therefore
written as *rigid* hydroelastic whenever the contact properties ask for
compliant (a rigid non-convex mesh against a compliant environment keeps its
shape). A tetrahedral ``.vtk`` mesh keeps its shape when compliant and is written
as asked. Point contact is different: Drake's point contact treats a non-convex
``.obj`` mesh as its convex hull (Drake 1.51; why: docs/design-notes/asset.md#drake-point-contact-and-meshes),
so the ``mesh`` representation is only non-convex under hydroelastic contact.

``drake:point_contact_stiffness`` is written from ContactProperties (see there why
it is softer than Drake's default); ``drake:relaxation_time`` (SAP's dissipation) is
not, so Drake's default applies.

Environment caveat (Drake 1.51): a *compliant* half-space has no hydroelastic
contact with *compliant* shapes of any kind; Drake silently falls back to point
contact for those pairs. Give a compliant object a compliant box (or rigid) floor.

Numbers are written with ``repr`` (shortest round-trip float text,
:mod:`real2sim.asset.export.urdf_common`), so a file read back gives the same doubles that were written.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from real2sim.asset.export.portable_urdf import write_portable_urdf
from real2sim.asset.export.urdf_common import num, nums, standard_urdf_geometry, urdf_link, urdf_origin
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import POINT_URDF_NAME, ContactProperties, MujocoConfig
from real2sim.formats.rotations import quaternion_to_rpy
from real2sim.formats.physical import PhysicalProperties
from real2sim.geometry.tessellation import sections_for


DRAKE_NS = "http://drake.mit.edu"


LINK_NAME = "base_link"


VISUAL_MESH_RELPATH = "../visual/model.obj"


SDF_VERSION = "1.9"


#: Model files an asset can hold per representation: model.urdf and model_portable.urdf (always),
#: model.sdf, model.xml + scene.xml (MuJoCo), model.usda (USD for Isaac).
ASSET_FORMATS = ("urdf", "sdf", "mjcf", "usd")

SIMULATOR_FILES: dict[str, tuple[str, str]] = {
    "drake": ("model.urdf", "urdf"),
    "drake_point": ("model_point.urdf", "urdf"),
    "mujoco": ("scene.xml", "mjcf"),
    "pybullet": ("model_portable.urdf", "urdf"),
    "isaac": ("model.usda", "usd"),
    "gazebo": ("model.sdf", "sdf"),
    "urdf": ("model_portable.urdf", "urdf"),
}
"""The file each simulator takes from a representation's folder, and the ``--format`` that writes it:
simulator -> (file name, format)."""

ET.register_namespace("drake", DRAKE_NS)


def _d(tag: str) -> str:
    """Qualified name of a Drake extension element."""
    return f"{{{DRAKE_NS}}}{tag}"


def _hydroelastic_type(shape: CollisionShape, contact: ContactProperties) -> str:
    """The hydroelastic type written for one shape ("compliant", "rigid" or "none")."""
    if (
        shape.kind == "mesh"
        and contact.hydroelastic == "compliant"
        and not str(shape.mesh_file).lower().endswith(".vtk")
    ):
        return "rigid"  # a compliant .obj would become its convex hull in Drake
    return contact.hydroelastic


def resolution_hint_m(shape: CollisionShape, contact: ContactProperties) -> float:
    """The mesh resolution hint (m) written for ``shape``: ``contact.resolution_hint_m``, or for a
    cylinder with ``contact.cylinder_flat_depth_m`` set, a hint small enough that Drake's polygon
    around its circle keeps its flats that shallow (Drake cuts it into ceil(2 pi r / hint) sections)."""
    depth = contact.cylinder_flat_depth_m
    if shape.kind != "cylinder" or depth is None or depth >= shape.size_m[0]:
        return contact.resolution_hint_m
    radius = float(shape.size_m[0])
    sections = sections_for(radius, depth)
    # A hair over 2 pi r / n, so that rounding cannot tip Drake's ceil to n + 1.
    return min(contact.resolution_hint_m, 2.0 * math.pi * radius / sections * (1.0 + 1e-9))


def _check_inputs(geometry: CollisionGeometry, props: PhysicalProperties) -> None:
    if not geometry.shapes:
        raise ValueError(f"collision geometry {geometry.name!r} has no shapes")
    if not (np.isfinite(props.mass_kg) and props.mass_kg > 0):
        raise ValueError(f"mass must be positive and finite, got {props.mass_kg}")
    inertia = props.inertia
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ValueError("inertia must be a finite 3x3 matrix")
    if not np.allclose(inertia, inertia.T, rtol=1e-9, atol=1e-15):
        raise ValueError("inertia must be symmetric")
    if not np.all(np.isfinite(props.com_m)):
        raise ValueError("centre of mass must be finite")


def _urdf_proximity(parent: ET.Element, hydro: str, contact: ContactProperties, hint_m: float) -> None:
    prox = ET.SubElement(parent, _d("proximity_properties"))
    if hydro == "compliant":
        ET.SubElement(prox, _d("compliant_hydroelastic"))
        ET.SubElement(prox, _d("hydroelastic_modulus"), value=num(contact.hydroelastic_modulus_pa))
        ET.SubElement(prox, _d("mesh_resolution_hint"), value=num(hint_m))
    elif hydro == "rigid":
        ET.SubElement(prox, _d("rigid_hydroelastic"))
        ET.SubElement(prox, _d("mesh_resolution_hint"), value=num(hint_m))
    ET.SubElement(prox, _d("point_contact_stiffness"), value=num(contact.point_contact_stiffness_n_per_m))
    ET.SubElement(prox, _d("hunt_crossley_dissipation"), value=num(contact.hunt_crossley_dissipation_s_per_m))
    ET.SubElement(prox, _d("mu_dynamic"), value=num(contact.mu_dynamic))
    ET.SubElement(prox, _d("mu_static"), value=num(contact.mu_static))


def _urdf_geometry(parent: ET.Element, shape: CollisionShape) -> None:
    geom = ET.SubElement(parent, "geometry")
    s = shape.size_m
    if standard_urdf_geometry(geom, shape):
        return
    if shape.kind == "ellipsoid":
        ET.SubElement(geom, _d("ellipsoid"), a=num(s[0]), b=num(s[1]), c=num(s[2]))
    elif shape.kind == "capsule":
        ET.SubElement(geom, _d("capsule"), radius=num(s[0]), length=num(s[1]))
    else:  # convex / mesh
        mesh = ET.SubElement(geom, "mesh", filename=str(shape.mesh_file))
        if shape.kind == "convex":
            ET.SubElement(mesh, _d("declare_convex"))


def build_urdf(
    geometry: CollisionGeometry,
    props: PhysicalProperties,
    contact: ContactProperties,
    visual_mesh_relpath: str = VISUAL_MESH_RELPATH,
    model_name: str = "object",
    link_name: str = LINK_NAME,
) -> ET.Element:
    """The ``<robot>`` element of the URDF (see the module docstring for the content)."""
    _check_inputs(geometry, props)
    robot, link = urdf_link(props, visual_mesh_relpath, model_name, link_name)

    for k, shape in enumerate(geometry.shapes):
        col = ET.SubElement(link, "collision", name=f"collision_{k:04d}")
        urdf_origin(col, shape.position_m, quaternion_to_rpy(shape.quaternion_wxyz))
        _urdf_geometry(col, shape)
        _urdf_proximity(col, _hydroelastic_type(shape, contact), contact, resolution_hint_m(shape, contact))
    return robot


def _xml_text(root: ET.Element) -> str:
    """Indented XML document text of ``root``."""
    ET.indent(root, space=" ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_model_urdf_string(
    geometry: CollisionGeometry,
    props: PhysicalProperties,
    contact: ContactProperties,
    visual_mesh_relpath: str = VISUAL_MESH_RELPATH,
    model_name: str = "object",
    link_name: str = LINK_NAME,
) -> str:
    """The URDF text (UTF-8 XML with the ``drake`` namespace declared on ``<robot>``)."""
    return _xml_text(build_urdf(geometry, props, contact, visual_mesh_relpath, model_name, link_name))


def _text(parent: ET.Element, tag: str, text: str) -> ET.Element:
    el = ET.SubElement(parent, tag)
    el.text = text
    return el


def _sdf_proximity(parent: ET.Element, hydro: str, contact: ContactProperties, hint_m: float) -> None:
    prox = ET.SubElement(parent, _d("proximity_properties"))
    if hydro == "compliant":
        ET.SubElement(prox, _d("compliant_hydroelastic"))
        _text(prox, _d("hydroelastic_modulus"), num(contact.hydroelastic_modulus_pa))
        _text(prox, _d("mesh_resolution_hint"), num(hint_m))
    elif hydro == "rigid":
        ET.SubElement(prox, _d("rigid_hydroelastic"))
        _text(prox, _d("mesh_resolution_hint"), num(hint_m))
    _text(prox, _d("point_contact_stiffness"), num(contact.point_contact_stiffness_n_per_m))
    _text(prox, _d("hunt_crossley_dissipation"), num(contact.hunt_crossley_dissipation_s_per_m))
    _text(prox, _d("mu_dynamic"), num(contact.mu_dynamic))
    _text(prox, _d("mu_static"), num(contact.mu_static))


def _sdf_geometry(parent: ET.Element, shape: CollisionShape) -> None:
    geom = ET.SubElement(parent, "geometry")
    s = shape.size_m
    if shape.kind == "box":
        _text(ET.SubElement(geom, "box"), "size", nums(s))
    elif shape.kind == "sphere":
        _text(ET.SubElement(geom, "sphere"), "radius", num(s[0]))
    elif shape.kind in ("cylinder", "capsule"):
        el = ET.SubElement(geom, shape.kind)
        _text(el, "radius", num(s[0]))
        _text(el, "length", num(s[1]))
    elif shape.kind == "ellipsoid":
        _text(ET.SubElement(geom, "ellipsoid"), "radii", nums(s))
    else:
        mesh = ET.SubElement(geom, "mesh")
        _text(mesh, "uri", str(shape.mesh_file))
        if shape.kind == "convex":
            ET.SubElement(mesh, _d("declare_convex"))


def build_sdf(
    geometry: CollisionGeometry,
    props: PhysicalProperties,
    contact: ContactProperties,
    visual_mesh_relpath: str = VISUAL_MESH_RELPATH,
    model_name: str = "object",
    link_name: str = LINK_NAME,
) -> ET.Element:
    """The ``<sdf>`` element (SDFormat 1.9 with Drake extensions), same content as the URDF."""
    _check_inputs(geometry, props)
    sdf = ET.Element("sdf", version=SDF_VERSION)
    model = ET.SubElement(sdf, "model", name=model_name)
    link = ET.SubElement(model, "link", name=link_name)

    inertial = ET.SubElement(link, "inertial")
    _text(inertial, "pose", nums(tuple(props.com_m) + (0.0, 0.0, 0.0)))
    _text(inertial, "mass", num(props.mass_kg))
    inertia = ET.SubElement(inertial, "inertia")
    i = props.inertia
    for tag, (r, c) in zip(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        _text(inertia, tag, num(i[r, c]))

    if visual_mesh_relpath:
        visual = ET.SubElement(link, "visual", name="visual")
        mesh = ET.SubElement(ET.SubElement(visual, "geometry"), "mesh")
        _text(mesh, "uri", visual_mesh_relpath)

    for k, shape in enumerate(geometry.shapes):
        col = ET.SubElement(link, "collision", name=f"collision_{k:04d}")
        _text(col, "pose", nums(tuple(shape.position_m) + quaternion_to_rpy(shape.quaternion_wxyz)))
        _sdf_geometry(col, shape)
        _sdf_proximity(col, _hydroelastic_type(shape, contact), contact, resolution_hint_m(shape, contact))
    return sdf


def write_model_sdf_string(
    geometry: CollisionGeometry,
    props: PhysicalProperties,
    contact: ContactProperties,
    visual_mesh_relpath: str = VISUAL_MESH_RELPATH,
    model_name: str = "object",
    link_name: str = LINK_NAME,
) -> str:
    """The SDFormat text (``xmlns:drake`` declared on ``<sdf>``)."""
    return _xml_text(build_sdf(geometry, props, contact, visual_mesh_relpath, model_name, link_name))


def write_representation(
    rep_dir: Path,
    geometry: CollisionGeometry,
    props: PhysicalProperties,
    contact: ContactProperties,
    visual_mesh_relpath: str = VISUAL_MESH_RELPATH,
    formats: tuple[str, ...] = ("urdf",),
    model_name: str = "object",
    link_name: str = LINK_NAME,
    mujoco: MujocoConfig = MujocoConfig(),
) -> None:
    """Write ``rep_dir/model.urdf`` for Drake (and ``rep_dir/model_point.urdf``, the same for Drake's point
    contact, when ``contact.point_model`` says so) and ``rep_dir/model_portable.urdf`` for every other URDF
    consumer (always; :mod:`real2sim.asset.export.portable_urdf`), ``rep_dir/model.sdf`` (if "sdf" in
    formats), ``rep_dir/model.xml`` and ``scene.xml`` (with ``mujoco``'s settings) for MuJoCo (if "mjcf"
    in formats; see :mod:`real2sim.asset.export.mjcf`) and ``rep_dir/model.usda`` (if "usd"; :mod:`real2sim.asset.export.usd`).

    ``geometry`` is in the asset frame (metres); mesh files of convex/mesh shapes are
    paths relative to ``rep_dir`` and must already exist there (the decomposition
    writes them). ``visual_mesh_relpath`` is relative to ``rep_dir``; an empty string
    writes no visual. The body is one link named ``link_name`` in a model named
    ``model_name``. Raises ValueError for unknown formats, missing mesh files or
    non-physical properties.
    """
    rep_dir = Path(rep_dir)
    unknown = set(formats) - set(ASSET_FORMATS)
    if unknown:
        raise ValueError(f"unknown asset format(s) {sorted(unknown)}; use {', '.join(ASSET_FORMATS)}")
    for shape in geometry.shapes:
        if shape.mesh_file is not None and not (rep_dir / shape.mesh_file).is_file():
            raise ValueError(f"collision mesh {shape.mesh_file!r} not found in {rep_dir}")
    rep_dir.mkdir(parents=True, exist_ok=True)
    if contact.point_stiffness_per_piece:
        from real2sim.asset.export.point_contact import representation_contact

        contact = representation_contact(contact, geometry, rep_dir)
    args = (geometry, props, contact, visual_mesh_relpath, model_name, link_name)
    (rep_dir / "model.urdf").write_text(write_model_urdf_string(*args))
    point = contact.point_model
    if point is not None:
        (rep_dir / POINT_URDF_NAME).write_text(write_model_urdf_string(geometry, props, point, visual_mesh_relpath,
                                                                        model_name, link_name))
    else:  # rewritten without a point-contact model: none may stay behind from an earlier material
        (rep_dir / POINT_URDF_NAME).unlink(missing_ok=True)
    write_portable_urdf(rep_dir, *args)
    if "sdf" in formats:
        (rep_dir / "model.sdf").write_text(write_model_sdf_string(*args))
    if "mjcf" in formats:
        from real2sim.asset.export.mjcf import MJCF_NAME, write_model_mjcf_string, write_scene_xml

        (rep_dir / MJCF_NAME).write_text(write_model_mjcf_string(
            geometry, props, contact, rep_dir, visual_mesh_relpath, model_name))
        write_scene_xml(rep_dir, geometry, mujoco)
    if "usd" in formats:
        from real2sim.asset.export.usd import write_model_usda

        write_model_usda(rep_dir, geometry, props, contact, visual_mesh_relpath, model_name)
