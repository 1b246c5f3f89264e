"""``model.usda``: one representation as a USD rigid body, for Isaac Sim / Isaac Lab (PhysX).

Written with ``usd-core`` (``pxr``) and nothing of Omniverse; read back by the tests with
usd-core's own physics parser (``UsdPhysics.LoadUsdPhysicsFromRange``). Content:

* stage metadata: metres (``metersPerUnit = 1``), kilograms (``kilogramsPerUnit = 1``), z up;
  the default prim ``/object`` is the body, its frame the asset frame;
* ``/object``: ``UsdPhysics.RigidBodyAPI`` and ``MassAPI`` with the asset's mass, centre of
  mass, and inertia as principal moments (``diagonalInertia``) and the rotation from the
  principal axes to the body axes (``principalAxes``, a quaternion): USD has no full tensor;
* ``/object/collisions/collision_NNNN``, one per shape of ``collision.json``, posed by
  ``translate`` + ``orient`` xform ops, each with ``CollisionAPI`` and the physics material:
  box -> ``Cube`` of size 1 scaled by its edge lengths; sphere -> ``Sphere``; cylinder ->
  ``Cylinder`` (axis Z, height = length); capsule -> ``Capsule`` (axis Z, height = the
  cylindrical part's length, as collision.json); ellipsoid -> a convex ``Mesh`` of the
  ellipsoid's volume (:mod:`real2sim.asset.export.round_pieces`; PhysX has no ellipsoid and does not
  scale a sphere non-uniformly); convex pieces and the ``mesh`` representation -> ``Mesh``
  (points inline, shape frame) with ``MeshCollisionAPI`` approximation ``convexHull``. A
  dynamic PhysX body collides a triangle mesh only through an approximation: the non-convex
  ``mesh`` representation becomes its convex hull, as in PyBullet and MuJoCo. Collision prims
  have purpose ``guide`` (hidden in renders);
* ``/object/visual``: the textured visual mesh, no CollisionAPI, bound to a
  ``UsdPreviewSurface`` material whose diffuse colour reads the visual texture
  (``../visual/*.png``, a path relative to the file) through the ``st`` primvar;
* ``/object/physics_material``: ``UsdPhysics.MaterialAPI`` with the asset's static and dynamic
  friction (restitution 0), bound to every collider with purpose ``physics``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.asset.export.round_pieces import ellipsoid_polytope
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.formats.physical import PhysicalProperties
from real2sim.formats.rotations import matrix_to_quaternion

USD_NAME = "model.usda"
BODY_PATH = "/object"


def principal_axes(inertia_kg_m2) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Principal moments (3,) and the rotation (w, x, y, z) whose columns are the principal axes
    in the body frame: ``inertia = R diag(moments) R^T``."""
    moments, axes = np.linalg.eigh(np.asarray(inertia_kg_m2, dtype=float))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, matrix_to_quaternion(axes)


def _require_pxr():
    try:
        from pxr import Usd  # noqa: F401
    except ImportError as exc:  # pragma: no cover - usd-core is a dependency
        from real2sim.plumbing.errors import UserInputError

        raise UserInputError("--format usd needs usd-core (pip install usd-core)") from exc


def _set_pose(prim, shape: CollisionShape, scale=None) -> None:
    from pxr import Gf, UsdGeom

    xform = UsdGeom.Xformable(prim)
    xform.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, shape.position_m)))
    w, x, y, z = (float(v) for v in shape.quaternion_wxyz)
    xform.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(w, Gf.Vec3d(x, y, z)))
    if scale is not None:
        xform.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, scale)))


def _mesh_prim(stage, path: str, mesh: trimesh.Trimesh):
    from pxr import UsdGeom, Vt

    usd_mesh = UsdGeom.Mesh.Define(stage, path)
    vertices = np.asarray(mesh.vertices, dtype=float)
    usd_mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices.astype(np.float32)))
    faces = np.asarray(mesh.faces, dtype=np.int32)
    usd_mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    usd_mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    usd_mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack((vertices.min(0), vertices.max(0))).astype(np.float32)))
    usd_mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return usd_mesh


def _collider(stage, path: str, shape: CollisionShape, rep_dir: Path):
    """The collision prim of one shape (module docstring), posed, without API schemas."""
    from pxr import UsdGeom, UsdPhysics

    s = shape.size_m
    if shape.kind == "box":
        prim = UsdGeom.Cube.Define(stage, path)
        prim.CreateSizeAttr(1.0)
        _set_pose(prim, shape, scale=s)
    elif shape.kind == "sphere":
        prim = UsdGeom.Sphere.Define(stage, path)
        prim.CreateRadiusAttr(float(s[0]))
        _set_pose(prim, shape)
    elif shape.kind in ("cylinder", "capsule"):
        prim = (UsdGeom.Cylinder if shape.kind == "cylinder" else UsdGeom.Capsule).Define(stage, path)
        prim.CreateRadiusAttr(float(s[0]))
        prim.CreateHeightAttr(float(s[1]))
        prim.CreateAxisAttr(UsdGeom.Tokens.z)
        _set_pose(prim, shape)
    else:
        if shape.kind == "ellipsoid":
            mesh = ellipsoid_polytope(s)
        else:
            mesh = trimesh.load(rep_dir / shape.mesh_file, process=False, force="mesh")
        prim = _mesh_prim(stage, path, mesh)
        _set_pose(prim, shape)
        UsdPhysics.MeshCollisionAPI.Apply(prim.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)
    UsdGeom.Imageable(prim).CreatePurposeAttr(UsdGeom.Tokens.guide)
    return prim


def _visual(stage, rep_dir: Path, visual_mesh_relpath: str) -> None:
    """The textured, non-colliding visual mesh and its UsdPreviewSurface material."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    from real2sim.asset.export.mjcf import visual_texture

    loaded = trimesh.load(rep_dir / visual_mesh_relpath, process=False, force="mesh")
    mesh = _mesh_prim(stage, f"{BODY_PATH}/visual", loaded)
    normals = np.asarray(loaded.vertex_normals, dtype=np.float32)
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    material = UsdShade.Material.Define(stage, f"{BODY_PATH}/looks/visual")
    surface = UsdShade.Shader.Define(stage, f"{BODY_PATH}/looks/visual/surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    texture = visual_texture(rep_dir, visual_mesh_relpath)
    uv = getattr(loaded.visual, "uv", None)
    if texture is not None and uv is not None and len(uv) == len(loaded.vertices):
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(uv, dtype=np.float32)))
        reader = UsdShade.Shader.Define(stage, f"{BODY_PATH}/looks/visual/st_reader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        image = UsdShade.Shader.Define(stage, f"{BODY_PATH}/looks/visual/diffuse_texture")
        image.CreateIdAttr("UsdUVTexture")
        image.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
        image.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        image.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(image.ConnectableAPI(), "rgb")
    else:
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.7, 0.7, 0.7))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def build_stage(rep_dir: Path, geometry: CollisionGeometry, props: PhysicalProperties, contact: ContactProperties,
                visual_mesh_relpath: str = "../visual/model.obj", model_name: str = "object"):
    """The in-memory ``Usd.Stage`` of ``model.usda`` (module docstring); ``rep_dir`` is where the file
    goes (mesh files and the visual are read relative to it)."""
    _require_pxr()
    from pxr import Gf, Usd, UsdGeom, UsdPhysics, UsdShade

    rep_dir = Path(rep_dir)
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().documentation = f"real2sim asset {model_name}: metres, kilograms, z up"
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    body = UsdGeom.Xform.Define(stage, BODY_PATH).GetPrim()
    stage.SetDefaultPrim(body)
    UsdPhysics.RigidBodyAPI.Apply(body)
    mass = UsdPhysics.MassAPI.Apply(body)
    mass.CreateMassAttr(float(props.mass_kg))
    mass.CreateCenterOfMassAttr(Gf.Vec3f(*map(float, props.com_m)))
    moments, (w, x, y, z) = principal_axes(props.inertia)
    mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*map(float, moments)))
    mass.CreatePrincipalAxesAttr(Gf.Quatf(w, Gf.Vec3f(x, y, z)))

    material = UsdShade.Material.Define(stage, f"{BODY_PATH}/physics_material")
    physics_material = UsdPhysics.MaterialAPI.Apply(material.GetPrim())
    physics_material.CreateStaticFrictionAttr(float(contact.mu_static))
    physics_material.CreateDynamicFrictionAttr(float(contact.mu_dynamic))
    physics_material.CreateRestitutionAttr(0.0)

    UsdGeom.Scope.Define(stage, f"{BODY_PATH}/collisions")
    UsdGeom.Scope.Define(stage, f"{BODY_PATH}/looks")
    for k, shape in enumerate(geometry.shapes):
        prim = _collider(stage, f"{BODY_PATH}/collisions/collision_{k:04d}", shape, rep_dir).GetPrim()
        UsdPhysics.CollisionAPI.Apply(prim)
        UsdShade.MaterialBindingAPI.Apply(prim).Bind(material, UsdShade.Tokens.weakerThanDescendants,
                                                     "physics")
    if visual_mesh_relpath:
        _visual(stage, rep_dir, visual_mesh_relpath)
    return stage


def write_model_usda(rep_dir: Path, geometry: CollisionGeometry, props: PhysicalProperties,
                     contact: ContactProperties, visual_mesh_relpath: str = "../visual/model.obj",
                     model_name: str = "object") -> Path:
    """Write ``rep_dir/model.usda`` (:func:`build_stage`); returns its path."""
    path = Path(rep_dir) / USD_NAME
    stage = build_stage(rep_dir, geometry, props, contact, visual_mesh_relpath, model_name)
    stage.GetRootLayer().Export(str(path))  # the stage must outlive this call: it owns the layer
    return path
