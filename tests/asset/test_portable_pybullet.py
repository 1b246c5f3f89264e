"""model_portable.urdf in a second URDF consumer, PyBullet (issue 34, parts 1 and 2).

Every representation kind, written by the asset writer for a can (made by hand here, so that
the default suite pays for no primitive fit): the portable URDF holds only standard URDF,
loads in PyBullet with the asset's mass, centre of mass and inertia, and dropped 1 mm onto a
plane rests upright, within 1 degree and 1 mm of where Drake puts model.urdf (Drake's point
contact, which like PyBullet's treats the shapes as rigid). The bundled
objects' fitted representations run the same checks in the slow test at the end.

PyBullet facts these tests rely on (measured on pybullet 3.2.7, docs/formats.md):
* ``loadURDF`` ignores the URDF's inertia unless ``flags=URDF_USE_INERTIA_FROM_FILE``;
* the base pose it reports is the inertial frame (CoM, principal axes), not the link frame;
* each convex mesh piece collides inflated by a 1 mm margin, so mesh-based bodies rest 1 mm high;
  so does a URDF cylinder, a polygon then, unless ``URDF_USE_IMPLICIT_CYLINDER``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

pybullet = pytest.importorskip("pybullet", reason="pybullet is a test dependency (pip install pybullet)")

from real2sim.asset.export.portable_urdf import PORTABLE_ELEMENTS, PORTABLE_URDF_NAME  # noqa: E402
from real2sim.asset.export.round_pieces import lowest_point_z_m  # noqa: E402
from real2sim.asset.export.writers import LINK_NAME, write_representation  # noqa: E402
from real2sim.collision.decomposition import CoacdConfig, VhacdConfig, decompose  # noqa: E402
from real2sim.collision.superquadric import superquadric_hull  # noqa: E402
from real2sim.formats.collision import CollisionGeometry, CollisionShape, read_collision_json, write_collision_json  # noqa: E402
from real2sim.formats.contact import ContactProperties  # noqa: E402
from real2sim.formats.physical import PhysicalProperties, read_physical_properties  # noqa: E402

DROP_M = 1e-3
#: PyBullet's URDF importer gives every convex mesh piece a 1 mm collision margin (a constant in its
#: importer, not settable from Python): the piece collides as if 1 mm larger all round.
PYBULLET_MESH_MARGIN_M = 1e-3
#: How to load an asset's portable URDF in PyBullet (docs/formats.md): the URDF's inertia, not one
#: computed from the collision shapes' bounding box; cylinders as cylinders, not as 1 mm-inflated polygons.
PYBULLET_FLAGS = pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_USE_IMPLICIT_CYLINDER
RADIUS_M, HEIGHT_M, MASS_KG = 0.034, 0.10, 0.35
FAST_COACD = CoacdConfig(mcts_nodes=10, mcts_iterations=40, mcts_max_depth=2, resolution=1000)
SMALL_VHACD = VhacdConfig(max_convex_hulls=4, resolution=20_000)
_Q_Y90 = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)  # shape z -> asset x
_Q_Z45 = (math.cos(math.pi / 8), 0.0, 0.0, math.sin(math.pi / 8))


def _layers(count: int) -> list[float]:
    """Centre heights (m) of ``count`` equal layers filling the can's height."""
    return [(-0.5 + (k + 0.5) / count) * HEIGHT_M for k in range(count)]


def can_representations(mesh: trimesh.Trimesh, root: Path) -> dict[str, CollisionGeometry]:
    """One hand-made representation of the can per shape kind, each able to stand upright."""
    r, h, third = RADIUS_M, HEIGHT_M, HEIGHT_M / 3
    side = r * math.sqrt(2.0)  # square inscribed in the circle
    half = r / 2
    quarter_xy = [(sx * half, sy * half) for sx in (-1, 1) for sy in (-1, 1)]
    shapes = {
        "cylinders_1": [CollisionShape("cylinder", (r, h))],
        "boxes_2": [CollisionShape("box", (side, side, h / 2), (0.0, 0.0, z)) for z in _layers(2)],
        "rotated_boxes_2": [CollisionShape("box", (side, side, h / 2), (0.0, 0.0, z), q)
                            for z, q in zip(_layers(2), (_Q_Z45, (1.0, 0.0, 0.0, 0.0)))],
        "spheres_12": [CollisionShape("sphere", (third / 2,), (x, y, z)) for z in _layers(3) for x, y in quarter_xy],
        "ellipsoids_3": [CollisionShape("ellipsoid", (r, r, third / 2), (0.0, 0.0, z)) for z in _layers(3)],
        # capsules lying along x, two side by side per layer: the body stands on two lines
        "capsules_6": [CollisionShape("capsule", (third / 2, r), (0.0, y, z), _Q_Y90)
                       for z in _layers(3) for y in (-half, half)],
        "boxes_1_cylinders_1": [CollisionShape("box", (side, side, h / 2), (0.0, 0.0, _layers(2)[0])),
                                CollisionShape("cylinder", (r, h / 2), (0.0, 0.0, _layers(2)[1]))],
    }
    reps = {name: CollisionGeometry(name, name, tuple(s)) for name, s in shapes.items()}
    sq_dir = root / "superquadrics_1"
    (sq_dir / "pieces").mkdir(parents=True)
    superquadric_hull((r, r, h / 2), (0.2, 1.0)).export(sq_dir / "pieces" / "superquadric_000.obj", include_normals=False)
    reps["superquadrics_1"] = CollisionGeometry("superquadrics_1", "superquadrics:1", (
        CollisionShape("convex", (), mesh_file="pieces/superquadric_000.obj"),))
    reps["coacd"] = decompose(mesh, "coacd", root / "coacd", coacd_config=FAST_COACD)
    reps["vhacd"] = decompose(mesh, "vhacd", root / "vhacd", vhacd_config=SMALL_VHACD)
    reps["mesh"] = decompose(mesh, "mesh", root / "mesh")
    return reps


@pytest.fixture(scope="module")
def can_asset(tmp_path_factory) -> Path:
    """An asset folder of the can: visual/, physical_properties.json, one folder per kind."""
    from real2sim.formats.physical import write_physical_properties

    root = tmp_path_factory.mktemp("can_asset")
    mesh = trimesh.creation.cylinder(radius=RADIUS_M, height=HEIGHT_M, sections=48)
    (root / "visual").mkdir()
    mesh.export(root / "visual" / "model.obj", include_normals=True)
    i_xx = MASS_KG * (3 * RADIUS_M**2 + HEIGHT_M**2) / 12
    i_zz = MASS_KG * RADIUS_M**2 / 2
    props = PhysicalProperties(MASS_KG, (0.0, 0.0, 0.0), ((i_xx, 0, 0), (0, i_xx, 0), (0, 0, i_zz)), method="closed form")
    write_physical_properties(props, root / "physical_properties.json")
    for name, geometry in can_representations(mesh, root).items():
        (root / name).mkdir(exist_ok=True)
        write_collision_json(geometry, root / name / "collision.json")
        write_representation(root / name, geometry, props, ContactProperties(), formats=("urdf",))
    return root


def representations(asset: Path) -> list[Path]:
    return sorted(p.parent for p in asset.glob("*/collision.json"))


def check_plain_urdf(path: Path) -> None:
    """A URDF of standard elements only (plus PyBullet's <contact>), no Drake extension, every mesh
    file present and relative."""
    text = path.read_text()
    assert "drake" not in text, path
    root = ET.fromstring(text)
    parents = {child: parent for parent in root.iter() for child in parent}
    for element in root.iter():
        assert element.tag in PORTABLE_ELEMENTS, (path, element.tag)
        parent = parents.get(element)
        assert (parent.tag if parent is not None else None) in PORTABLE_ELEMENTS[element.tag], (path, element.tag)
        if element.tag == "mesh":
            name = element.get("filename")
            assert not Path(name).is_absolute() and (path.parent / name).is_file(), (path, name)


def test_no_urdf_for_other_simulators_has_drake_geometry(can_asset):
    for rep in representations(can_asset):
        check_plain_urdf(rep / PORTABLE_URDF_NAME)
        collisions = ET.parse(rep / PORTABLE_URDF_NAME).getroot().iter("collision")
        assert len(list(collisions)) == len(read_collision_json(rep / "collision.json").shapes)
    # model.urdf keeps Drake's native shapes: the two files differ exactly where URDF has no shape
    assert "drake:ellipsoid" in (can_asset / "ellipsoids_3" / "model.urdf").read_text()
    assert "drake:capsule" in (can_asset / "capsules_6" / "model.urdf").read_text()


def test_round_pieces_have_the_shapes_volume_and_pose(can_asset):
    for name, kind in (("ellipsoids_3", "ellipsoid"), ("capsules_6", "capsule")):
        rep = can_asset / name
        shapes = read_collision_json(rep / "collision.json").shapes
        for k, shape in enumerate(shapes):
            piece = trimesh.load(rep / "portable" / f"{kind}_{k:03d}.obj", process=False)
            s = shape.size_m
            exact = (4 / 3 * math.pi * s[0] * s[1] * s[2] if kind == "ellipsoid"
                     else math.pi * s[0] ** 2 * s[1] + 4 / 3 * math.pi * s[0] ** 3)
            assert piece.is_watertight and piece.volume == pytest.approx(exact, rel=1e-5)  # OBJ text: 8 decimals
            # in the shape frame: centred, its axis along z
            np.testing.assert_allclose(piece.bounds.mean(axis=0), 0.0, atol=1e-9)
            axis_half = s[2] if kind == "ellipsoid" else s[0] + s[1] / 2
            assert piece.bounds[1, 2] == pytest.approx(axis_half, rel=0.02)
            # no pole vertex: each end is a flat facet across the axis, on which an upright piece stands
            for sign in (-1.0, 1.0):
                cap = piece.area_faces[piece.face_normals[:, 2] * sign > 1.0 - 1e-9].sum()
                assert cap > 1e-3 * piece.area, (name, k, sign)  # a pole vertex gives 0


def _connect():
    client = pybullet.connect(pybullet.DIRECT)
    pybullet.setGravity(0.0, 0.0, -9.81, physicsClientId=client)
    return client


def load_in_pybullet(urdf: Path, client: int, z_m: float = 0.0) -> int:
    return pybullet.loadURDF(str(urdf), [0.0, 0.0, z_m], flags=PYBULLET_FLAGS,
                             physicsClientId=client)


def test_every_representation_loads_in_pybullet_with_the_assets_mass_and_inertia(can_asset):
    check_mass_properties_in_pybullet(can_asset)


def check_mass_properties_in_pybullet(asset: Path) -> None:
    props = read_physical_properties(asset / "physical_properties.json")
    for rep in representations(asset):
        client = _connect()
        try:
            body = load_in_pybullet(rep / PORTABLE_URDF_NAME, client)
            info = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)
            shapes = pybullet.getCollisionShapeData(body, -1, physicsClientId=client)
        finally:
            pybullet.disconnect(client)
        assert len(shapes) == len(read_collision_json(rep / "collision.json").shapes), rep.name
        assert info[0] == pytest.approx(props.mass_kg, rel=1e-12), rep.name
        # PyBullet keeps principal moments and the inertial frame's rotation to them
        axes = np.array(pybullet.getMatrixFromQuaternion(info[4])).reshape(3, 3)
        np.testing.assert_allclose(axes @ np.diag(info[2]) @ axes.T, props.inertia, rtol=1e-6, atol=1e-9 * np.abs(props.inertia).max())
        np.testing.assert_allclose(info[3], props.com_m, atol=1e-9)


def pybullet_rest(urdf: Path, start_z_m: float, duration_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Link-frame position (3,) and rotation (3x3) after dropping onto a plane at z = 0 (240 Hz)."""
    client = _connect()
    try:
        plane = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=client)
        pybullet.createMultiBody(0, plane, physicsClientId=client)
        body = load_in_pybullet(urdf, client, start_z_m)
        for _ in range(int(round(duration_s * 240))):
            pybullet.stepSimulation(physicsClientId=client)
        com_pos, com_orn = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
        info = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)
        # the base pose is the inertial frame's: undo its offset to get the link (asset) frame
        pos, orn = pybullet.multiplyTransforms(com_pos, com_orn, *pybullet.invertTransform(info[3], info[4]))
    finally:
        pybullet.disconnect(client)
    return np.array(pos), np.array(pybullet.getMatrixFromQuaternion(orn)).reshape(3, 3)


def drake_rest(urdf: Path, start_z_m: float, duration_s: float = 1.0,
               contact_model: str = "point") -> tuple[np.ndarray, np.ndarray]:
    """Link-frame position and rotation after the same drop in Drake (SAP, 1 ms). Point contact on a
    half-space by default: like PyBullet's, it treats the shapes as rigid. Hydroelastic contact on a
    compliant box (tests/asset/test_drake_rest.py says why) presses into corners and polar vertices
    and can rest a bottom of several boxes or a superquadric's facet fan up to 1.3 degrees straighter
    than any rigid-contact simulator does (docs/formats.md)."""
    from pydrake.geometry import AddCompliantHydroelasticProperties, Box, HalfSpace, ProximityProperties
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlant, CoulombFriction, MultibodyPlantConfig
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(MultibodyPlantConfig(time_step=1e-3, discrete_contact_approximation="sap",
                                                      contact_model=contact_model), builder)
    Parser(plant).AddModels(str(urdf))
    floor = ProximityProperties()
    floor.AddProperty("material", "coulomb_friction", CoulombFriction(0.5, 0.5))
    if contact_model == "point":
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform(), HalfSpace(), "floor", floor)
    else:
        AddCompliantHydroelasticProperties(resolution_hint=1.0, hydroelastic_modulus=1e7, properties=floor)
        plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform([0, 0, -0.1]), Box(2.0, 2.0, 0.2), "floor",
                                        floor)
    plant.Finalize()
    simulator = Simulator(builder.Build())
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    body = plant.GetBodyByName(LINK_NAME)
    plant.SetFreeBodyPose(context, body, RigidTransform([0.0, 0.0, start_z_m]))
    simulator.AdvanceTo(duration_s)
    pose = plant.EvalBodyPoseInWorld(context, body)
    return pose.translation(), pose.rotation().matrix()


def tilt_deg(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(rotation[2, 2], -1.0, 1.0))))


def mesh_margin_m(geometry: CollisionGeometry) -> float:
    """How high PyBullet's margin lifts the body: 1 mm when every shape is a mesh piece in the
    portable URDF, none when none is (its boxes, spheres and cylinders keep the margin inside)."""
    meshes = [s.kind in ("convex", "mesh", "ellipsoid", "capsule") for s in geometry.shapes]
    return PYBULLET_MESH_MARGIN_M if all(meshes) else 0.0


def compare_rest(rep: Path, contact_model: str = "point") -> dict[str, float]:
    """Drop both files 1 mm onto a floor at z = 0; return how the rest poses compare."""
    geometry = read_collision_json(rep / "collision.json")
    start_z = DROP_M - lowest_point_z_m(geometry, rep)
    pb_pos, pb_rot = pybullet_rest(rep / PORTABLE_URDF_NAME, start_z)
    dk_pos, dk_rot = drake_rest(rep / "model.urdf", start_z, contact_model=contact_model)
    return {
        "pybullet_tilt_deg": tilt_deg(pb_rot), "drake_tilt_deg": tilt_deg(dk_rot),
        # between the two up (z) axes: how differently it stands, whatever it turned about the vertical
        "angle_apart_deg": float(np.degrees(np.arccos(np.clip(pb_rot[:, 2] @ dk_rot[:, 2], -1, 1)))),
        "xy_apart_m": float(np.linalg.norm(pb_pos[:2] - dk_pos[:2])),
        "z_apart_m": float(pb_pos[2] - mesh_margin_m(geometry) - dk_pos[2]),
    }


CAN_REPRESENTATIONS = ("boxes_1_cylinders_1", "boxes_2", "capsules_6", "coacd", "cylinders_1", "ellipsoids_3",
                       "mesh", "rotated_boxes_2", "spheres_12", "superquadrics_1", "vhacd")


def test_the_can_has_every_representation_kind(can_asset):
    assert tuple(p.name for p in representations(can_asset)) == CAN_REPRESENTATIONS


@pytest.mark.parametrize("name", CAN_REPRESENTATIONS)
def test_dropped_1mm_it_rests_upright_where_drake_puts_it(can_asset, name):
    result = compare_rest(can_asset / name)
    assert result["pybullet_tilt_deg"] < 1.0, result
    assert result["angle_apart_deg"] < 1.0, result
    assert result["xy_apart_m"] < 1e-3, result
    assert abs(result["z_apart_m"]) < 1e-3, result


BUNDLED_SPECS = ("cylinders:4", "boxes:8", "rotated_boxes:4", "spheres:16", "ellipsoids:4", "capsules:4",
                 "superquadrics:2", "boxes:4+cylinders:2", "coacd", "vhacd", "mesh")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bottle", "can", "mug"])
def test_every_fitted_representation_of_every_bundled_object(tmp_path_factory, name):
    """Fitted representations (small budgets): every one loads with the asset's mass properties,
    and every one that Drake brings to rest upright (under 1 degree) rests upright within 1 degree
    and 1 mm of it in PyBullet. Printed, not compared: fits that Drake itself rests tilted (a
    150-iteration fit's bottom is rarely flat: 1.4-6.5 degrees on the bottle, where the two
    simulators agree on the tilt within 0.7 degree but a tilted body's origin lands 1-4 mm apart)
    and round-bottomed fits that fall over in Drake too, whose pose after a fall is chaotic
    (docs/formats.md)."""
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.collision.fit import FitConfig
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import OBJECTS, export_object

    mesh = export_object(name, tmp_path_factory.mktemp(name) / f"{name}.obj")
    config = AssetConfig(mass_kg=OBJECTS[name].mass_kg, specs=tuple(parse_spec(s) for s in BUNDLED_SPECS),
                         flat_bottom=True, pca_up=name != "mug", coacd_config=FAST_COACD,
                         fit_config=FitConfig(max_iterations=150, min_iterations=50))
    asset = build_asset(mesh, tmp_path_factory.mktemp(f"{name}_asset") / "asset", config).asset_dir
    check_mass_properties_in_pybullet(asset)
    compared, disagree = [], {}
    for rep in representations(asset):
        check_plain_urdf(rep / PORTABLE_URDF_NAME)
        result = compare_rest(rep)
        print(rep.name, {k: round(v, 5) for k, v in result.items()})
        if result["drake_tilt_deg"] >= 1.0:
            continue
        compared.append(rep.name)
        if not (result["pybullet_tilt_deg"] < 1.0 and result["angle_apart_deg"] < 1.0 and result["xy_apart_m"] < 1e-3
                and abs(result["z_apart_m"]) < 1e-3):
            disagree[rep.name] = result
    assert not disagree, disagree
    assert len(compared) >= 2, compared  # boxes_8 and vhacd stand upright in Drake on the bottle and the can
