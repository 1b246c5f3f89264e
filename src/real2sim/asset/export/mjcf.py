"""MJCF (MuJoCo) model files for one collision representation.

``model.xml`` beside ``model.urdf`` describes the same rigid body for MuJoCo (and
MJX / MuJoCo Warp), in the same asset frame and units (metres, kg):

* one free body ``object`` (a ``<freejoint/>``) whose frame is the asset frame;
* the inertial block written explicitly from ``physical_properties.json``
  (``<compiler inertiafromgeom="false"/>``): MuJoCo would otherwise infer mass and
  inertia from the collision geoms, and those are approximations of the shape;
* one ``<geom>`` per collision shape. MuJoCo has native spheres, boxes, cylinders,
  capsules and ellipsoids, so fitted primitives map onto it exactly. MuJoCo sizes
  are *half* lengths: box half-extents, cylinder and capsule half-lengths of the
  cylindrical part (Drake and our ``collision.json`` store full lengths).
  Orientation is ``quat`` in (w, x, y, z) order, the order ``collision.json`` uses.
* convex pieces (CoACD, V-HACD, superquadric polytopes) as ``<mesh>`` assets;
* the textured visual mesh as a non-colliding geom (``contype=conaffinity=0``,
  group 1, no mass), with its texture from the visual MTL's ``map_Kd``;
* friction from the asset's contact properties: MuJoCo has one sliding
  coefficient per geom, written from ``mu_dynamic``; torsional and rolling
  friction keep MuJoCo's defaults. Contact softness is not mapped from Drake's
  point-contact stiffness (there is no one-to-one map). ``model.xml`` keeps MuJoCo's
  defaults, so a scene that includes it decides; ``scene.xml`` sets the asset's
  :class:`~real2sim.formats.contact.MujocoConfig`, the settings the evaluation
  measured closest to the Drake reference: its world options (time step, integrator,
  friction cone, ``impratio``) and, as the default of every geom (the object's and the
  floor), ``condim``, ``solref`` and ``solimp``.

MuJoCo collides every mesh geom as its **convex hull**. The ``mesh``
representation (the whole non-convex object) therefore changes shape in MuJoCo:
:func:`mjcf_notes` says so, and the asset stage prints it and records it in
``fit_report.json``.

``scene.xml`` beside it (:func:`write_scene_xml`) is the file to open, as in MuJoCo
Menagerie: it includes ``model.xml`` and adds a floor under the object, a light and a sky.

All file names are relative to the representation folder (``meshdir`` and
``texturedir`` are left unset, so MuJoCo resolves them from the model file).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties, MujocoConfig
from real2sim.formats.physical import PhysicalProperties

MJCF_NAME = "model.xml"
BODY_NAME = "object"
COLLISION_GROUP = 3  # MuJoCo's viewer hides group 3 by default: collision geoms stay out of the picture
VISUAL_GROUP = 1

# MuJoCo's defaults for the torsional and rolling coefficients of <geom friction>.
_TORSIONAL_FRICTION = 0.005
_ROLLING_FRICTION = 0.0001


def _num(x: float) -> str:
    return repr(float(x))


def _nums(values) -> str:
    return " ".join(_num(v) for v in values)


def mjcf_size(shape: CollisionShape) -> tuple[str, tuple[float, ...]]:
    """MuJoCo geom ``type`` and ``size`` (half lengths) of a primitive shape."""
    s = shape.size_m
    if shape.kind == "sphere":
        return "sphere", (s[0],)
    if shape.kind == "box":
        return "box", tuple(0.5 * v for v in s)
    if shape.kind in ("cylinder", "capsule"):
        return shape.kind, (s[0], 0.5 * s[1])
    if shape.kind == "ellipsoid":
        return "ellipsoid", tuple(s)
    raise ValueError(f"{shape.kind} is a mesh shape, not a primitive")


def mjcf_notes(geometry: CollisionGeometry) -> list[str]:
    """What the MJCF cannot say as the URDF does (one sentence each; empty when nothing)."""
    meshes = [s for s in geometry.shapes if s.kind == "mesh"]
    if not meshes:
        return []
    return [f"MuJoCo collides mesh geoms as their convex hulls: the {len(meshes)} non-convex mesh "
            f"shape(s) of {geometry.name!r} are convex in model.xml, so concavities (a mug's cavity, "
            "a handle's hole) are filled; use a primitive or convex-decomposition representation in MuJoCo"]


def visual_texture(rep_dir: Path, visual_mesh_relpath: str) -> str | None:
    """The visual mesh's texture image (relative to ``rep_dir``), from its MTL's ``map_Kd``."""
    obj = rep_dir / visual_mesh_relpath
    mtl = obj.with_suffix(".mtl")
    if not mtl.is_file():
        return None
    for line in mtl.read_text(errors="replace").splitlines():
        key, _, value = line.strip().partition(" ")
        if key == "map_Kd" and value.strip():
            image = Path(visual_mesh_relpath).parent / value.strip()
            return image.as_posix() if (rep_dir / image).is_file() else None
    return None


def build_mjcf(geometry: CollisionGeometry, props: PhysicalProperties, contact: ContactProperties,
               rep_dir: Path, visual_mesh_relpath: str = "../visual/model.obj",
               model_name: str = "object") -> ET.Element:
    """The ``<mujoco>`` element (see the module docstring). ``rep_dir`` is where model.xml goes;
    mesh files are looked up relative to it."""
    rep_dir = Path(rep_dir)
    root = ET.Element("mujoco", model=model_name)
    ET.SubElement(root, "compiler", angle="radian", inertiafromgeom="false", autolimits="true")
    asset = ET.SubElement(root, "asset")
    worldbody = ET.SubElement(root, "worldbody")
    body = ET.SubElement(worldbody, "body", name=BODY_NAME)
    ET.SubElement(body, "freejoint", name=f"{BODY_NAME}_free")
    i = props.inertia
    ET.SubElement(body, "inertial", pos=_nums(props.com_m), mass=_num(props.mass_kg),
                  fullinertia=_nums((i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])))

    if visual_mesh_relpath:
        ET.SubElement(asset, "mesh", name="visual", file=visual_mesh_relpath)
        visual = {"name": "visual", "type": "mesh", "mesh": "visual", "contype": "0", "conaffinity": "0",
                  "group": str(VISUAL_GROUP), "mass": "0"}
        texture = visual_texture(rep_dir, visual_mesh_relpath)
        if texture is not None:
            ET.SubElement(asset, "texture", name="visual", type="2d", file=texture)
            ET.SubElement(asset, "material", name="visual", texture="visual")
            visual["material"] = "visual"
        ET.SubElement(body, "geom", visual)

    friction = _nums((contact.mu_dynamic, _TORSIONAL_FRICTION, _ROLLING_FRICTION))
    for k, shape in enumerate(geometry.shapes):
        attrs = {"name": f"collision_{k:04d}", "pos": _nums(shape.position_m),
                 "quat": _nums(np.asarray(shape.quaternion_wxyz) / np.linalg.norm(shape.quaternion_wxyz)),
                 "group": str(COLLISION_GROUP), "friction": friction, "rgba": "0.9 0.4 0.1 0.5"}
        if shape.kind in ("convex", "mesh"):
            mesh_name = f"collision_{k:04d}"
            ET.SubElement(asset, "mesh", name=mesh_name, file=str(shape.mesh_file))
            attrs.update(type="mesh", mesh=mesh_name)
        else:
            kind, size = mjcf_size(shape)
            attrs.update(type=kind, size=_nums(size))
        ET.SubElement(body, "geom", attrs)
    if not len(asset):
        root.remove(asset)
    return root


def write_model_mjcf_string(geometry: CollisionGeometry, props: PhysicalProperties, contact: ContactProperties,
                            rep_dir: Path, visual_mesh_relpath: str = "../visual/model.obj",
                            model_name: str = "object") -> str:
    """The MJCF text of one representation."""
    root = build_mjcf(geometry, props, contact, rep_dir, visual_mesh_relpath, model_name)
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="unicode") + "\n"


def lowest_collision_z(model, data) -> float:
    """Lowest world z (m) of the ``object`` body's collision geoms in MuJoCo's current state
    (``mj_forward`` first): each geom's support point along -z, the vertices for mesh geoms.
    Used to set a loaded model down on a floor at a known gap."""
    import mujoco

    kinds = mujoco.mjtGeom
    body = model.body(BODY_NAME).id
    low = np.inf
    for g in range(model.ngeom):
        if model.geom_bodyid[g] != body or not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        r, p, s = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g], model.geom_size[g]
        kind = model.geom_type[g]
        if kind == kinds.mjGEOM_SPHERE:
            z = p[2] - s[0]
        elif kind == kinds.mjGEOM_BOX:
            z = p[2] - np.abs(r[2]) @ s
        elif kind == kinds.mjGEOM_CYLINDER:
            z = p[2] - (abs(r[2, 2]) * s[1] + s[0] * np.sqrt(max(0.0, 1.0 - r[2, 2] ** 2)))
        elif kind == kinds.mjGEOM_CAPSULE:
            z = p[2] - (abs(r[2, 2]) * s[1] + s[0])
        elif kind == kinds.mjGEOM_ELLIPSOID:
            z = p[2] - np.sqrt(((r[2] * s) ** 2).sum())
        else:
            mesh_id = model.geom_dataid[g]
            start, count = model.mesh_vertadr[mesh_id], model.mesh_vertnum[mesh_id]
            z = (p + model.mesh_vert[start:start + count] @ r.T)[:, 2].min()
        low = min(low, float(z))
    return low


SCENE_NAME = "scene.xml"


def build_scene_xml(floor_z_m: float, model_file: str = MJCF_NAME, mujoco: MujocoConfig = MujocoConfig()) -> ET.Element:
    """A MuJoCo Menagerie-style ``scene.xml``: ``mujoco``'s world options and, as every geom's default (the
    included object's and the floor's), its contact settings; then ``model_file`` and a floor whose top is
    at ``floor_z_m`` (the object's lowest collision point, so it stands on it when opened), a light, a sky
    and a camera framing. The object keeps the asset frame: centred, not on z = 0."""
    root = ET.Element("mujoco", model="object scene")
    ET.SubElement(root, "option", timestep=_num(mujoco.timestep_s), integrator=mujoco.integrator,
                  cone=mujoco.cone, impratio=_num(mujoco.impratio))
    defaults = ET.SubElement(root, "default")  # before the include: MuJoCo applies it to the included geoms
    ET.SubElement(defaults, "geom", condim=str(mujoco.condim),
                  solref=_nums((mujoco.solref_timeconst_s, mujoco.solref_dampratio)), solimp=_nums(mujoco.solimp))
    ET.SubElement(root, "include", file=model_file)
    ET.SubElement(root, "statistic", center=_nums((0.0, 0.0, 0.0)), extent="0.4")
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "headlight", diffuse="0.6 0.6 0.6", ambient="0.3 0.3 0.3", specular="0 0 0")
    ET.SubElement(visual, "global", azimuth="120", elevation="-20")
    asset = ET.SubElement(root, "asset")
    ET.SubElement(asset, "texture", type="skybox", builtin="gradient", rgb1="0.3 0.5 0.7", rgb2="0 0 0",
                  width="512", height="3072")
    ET.SubElement(asset, "texture", type="2d", name="groundplane", builtin="checker", mark="edge",
                  rgb1="0.2 0.3 0.4", rgb2="0.1 0.2 0.3", markrgb="0.8 0.8 0.8", width="300", height="300")
    ET.SubElement(asset, "material", name="groundplane", texture="groundplane", texuniform="true",
                  texrepeat="5 5", reflectance="0.2")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos=_nums((0.0, 0.0, floor_z_m + 1.5)), dir="0 0 -1", directional="true")
    ET.SubElement(world, "geom", name="floor", size="0 0 0.05", type="plane", material="groundplane",
                  pos=_nums((0.0, 0.0, floor_z_m)))
    return root


def write_scene_xml(rep_dir: Path, geometry: CollisionGeometry, mujoco: MujocoConfig = MujocoConfig()) -> Path:
    """Write ``rep_dir/scene.xml`` beside model.xml (:func:`build_scene_xml`); returns its path."""
    from real2sim.asset.export.round_pieces import lowest_point_z_m

    root = build_scene_xml(lowest_point_z_m(geometry, rep_dir), mujoco=mujoco)
    ET.indent(root, space=" ")
    path = Path(rep_dir) / SCENE_NAME
    path.write_text(ET.tostring(root, encoding="unicode") + "\n")
    return path
