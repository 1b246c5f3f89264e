"""Convex-decomposition baselines on a small non-convex solid, loaded back in Drake."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import manifold3d
import numpy as np
import pytest
import trimesh

from real2sim.asset.export.writers import LINK_NAME, write_representation
from real2sim.formats.contact import ContactProperties
from real2sim.collision.decomposition import CoacdConfig, VhacdConfig, decompose
from real2sim.geometry.inside import inside_mask
from real2sim.formats.physical import PhysicalProperties

# small tree search: CoACD stays well under a second on this mesh
FAST_COACD = CoacdConfig(mcts_nodes=10, mcts_iterations=40, mcts_max_depth=2, resolution=1000)
FAST_VHACD = VhacdConfig(max_convex_hulls=4, resolution=20_000)


def _l_shape() -> trimesh.Trimesh:
    """An L-shaped solid (metres, centred near the origin), built as a manifold union."""
    foot = manifold3d.Manifold.cube((0.10, 0.03, 0.03)).translate((-0.015, -0.015, -0.05))
    post = manifold3d.Manifold.cube((0.03, 0.03, 0.10)).translate((-0.015, -0.015, -0.05))
    mesh = (foot + post).to_mesh()
    out = trimesh.Trimesh(mesh.vert_properties[:, :3], mesh.tri_verts)
    out.apply_translation(-out.bounding_box.centroid)
    return out


def _inside_hull(hull: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Points inside a convex hull, from its face planes (outward normals)."""
    offsets = np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
    return np.all(points @ hull.face_normals.T - offsets <= 1e-9, axis=1)


def _iou(mesh: trimesh.Trimesh, pieces: list[trimesh.Trimesh], n: int = 60_000) -> float:
    rng = np.random.default_rng(0)
    lo, hi = mesh.bounds
    pts = rng.uniform(lo - 0.01, hi + 0.01, size=(n, 3))
    target = inside_mask(mesh, pts)
    union = np.zeros(n, dtype=bool)
    for piece in pieces:
        union |= _inside_hull(piece, pts)
    return float((target & union).sum() / (target | union).sum())


def _load_pieces(rep: Path, geometry) -> list[trimesh.Trimesh]:
    return [trimesh.load(rep / s.mesh_file, force="mesh", process=True) for s in geometry.shapes]


def _props(mesh: trimesh.Trimesh) -> PhysicalProperties:
    mass_kg = 0.2
    inertia = mesh.moment_inertia * (mass_kg / mesh.volume)  # uniform density, about the CoM
    return PhysicalProperties(mass_kg, tuple(mesh.center_mass), tuple(tuple(r) for r in inertia))


def _drake_collision_shapes(urdf: Path) -> list:
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 1e-3)
    Parser(plant).AddModels(str(urdf))
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    return [inspector.GetShape(g) for g in plant.GetCollisionGeometriesForBody(plant.GetBodyByName(LINK_NAME))]


@pytest.mark.parametrize(
    "method, kwargs",
    [("coacd", {"coacd_config": FAST_COACD, "seed": 1}), ("vhacd", {"vhacd_config": FAST_VHACD})],
)
def test_convex_decomposition_covers_the_solid_and_loads(tmp_path, method, kwargs):
    from pydrake.geometry import Convex

    mesh = _l_shape()
    assert not mesh.is_convex and mesh.is_watertight
    rep = tmp_path / "asset" / method
    (rep / "pieces").mkdir(parents=True)
    (rep / "pieces" / "piece_099.obj").write_text("v 0 0 0\n")  # stale file from an older run

    geometry = decompose(mesh, method, rep, **kwargs)

    assert geometry.name == method and geometry.spec == method
    assert len(geometry.shapes) >= 2  # an L is not convex: one hull would fill its corner
    assert all(s.kind == "convex" and s.quaternion_wxyz == (1.0, 0.0, 0.0, 0.0) for s in geometry.shapes)
    written = sorted(p.name for p in (rep / "pieces").glob("piece_*.obj"))
    assert written == sorted(Path(s.mesh_file).name for s in geometry.shapes)  # stale piece removed
    pieces = _load_pieces(rep, geometry)
    for piece in pieces:
        assert piece.is_watertight and piece.is_convex and piece.volume > 0
    volume_ratio = sum(p.volume for p in pieces) / mesh.volume
    assert 0.9 < volume_ratio < 1.3  # overlaps may add a little volume
    assert _iou(mesh, pieces) > 0.9

    write_representation(rep, geometry, _props(mesh), ContactProperties(), visual_mesh_relpath="")
    shapes = _drake_collision_shapes(rep / "model.urdf")
    assert len(shapes) == len(geometry.shapes)
    assert all(isinstance(s, Convex) for s in shapes)


def test_coacd_is_deterministic_for_a_seed(tmp_path):
    mesh = _l_shape()
    a = decompose(mesh, "coacd", tmp_path / "a", coacd_config=FAST_COACD, seed=3)
    b = decompose(mesh, "coacd", tmp_path / "b", coacd_config=FAST_COACD, seed=3)
    assert len(a.shapes) == len(b.shapes)
    for sa, sb in zip(a.shapes, b.shapes):
        va = trimesh.load(tmp_path / "a" / sa.mesh_file, force="mesh").vertices
        vb = trimesh.load(tmp_path / "b" / sb.mesh_file, force="mesh").vertices
        np.testing.assert_allclose(np.sort(va, axis=0), np.sort(vb, axis=0))


def test_coacd_decimation_bounds_hull_vertices(tmp_path):
    can = trimesh.creation.cylinder(radius=0.034, height=0.10, sections=96)  # 192 vertices, convex
    for max_vertices in (64, 128):
        config = dataclasses.replace(FAST_COACD, max_ch_vertex=max_vertices)
        geometry = decompose(can, "coacd", tmp_path / str(max_vertices), coacd_config=config)
        pieces = _load_pieces(tmp_path / str(max_vertices), geometry)
        assert all(len(p.vertices) <= max_vertices for p in pieces)
        assert sum(p.volume for p in pieces) == pytest.approx(can.volume, rel=0.05)
    raw = decompose(can, "coacd", tmp_path / "raw", coacd_config=dataclasses.replace(FAST_COACD, decimate=False))
    assert max(len(p.vertices) for p in _load_pieces(tmp_path / "raw", raw)) > 128


def test_mesh_baseline_is_the_mesh_itself(tmp_path):
    from pydrake.geometry import Convex, Mesh

    mesh = _l_shape()
    geometry = decompose(mesh, "mesh", tmp_path / "mesh")
    assert len(geometry.shapes) == 1 and geometry.shapes[0].kind == "mesh"
    assert geometry.shapes[0].mesh_file == "pieces/mesh.obj"
    back = trimesh.load(tmp_path / "mesh" / "pieces" / "mesh.obj", force="mesh")
    assert back.volume == pytest.approx(mesh.volume, rel=1e-6)
    assert not back.is_convex

    write_representation(tmp_path / "mesh", geometry, _props(mesh), ContactProperties(), visual_mesh_relpath="")
    (shape,) = _drake_collision_shapes(tmp_path / "mesh" / "model.urdf")
    assert isinstance(shape, Mesh) and not isinstance(shape, Convex)


def test_mesh_baseline_keeps_its_concavity_only_in_hydroelastic_contact(tmp_path):
    """Rigid hydroelastic keeps the non-convex mesh; Drake's point contact uses its hull."""
    from pydrake.geometry import (
        AddCompliantHydroelasticProperties,
        HydroelasticContactRepresentation,
        ProximityProperties,
        Sphere,
    )
    from pydrake.math import RigidTransform
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
    from pydrake.systems.framework import DiagramBuilder

    mesh = _l_shape()  # the corner x, z in (-0.02, 0.05) is empty; the hull covers x + z < 0.03
    geometry = decompose(mesh, "mesh", tmp_path)
    write_representation(tmp_path, geometry, _props(mesh), ContactProperties(), visual_mesh_relpath="")
    probe_centre = np.zeros(3)  # 15 mm from the L, inside its convex hull
    probe_radius_m = 0.005
    assert not inside_mask(mesh, probe_centre[None])[0]
    assert mesh.nearest.on_surface(probe_centre[None])[1][0] > 2 * probe_radius_m

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 1e-3)
    Parser(plant).AddModels(str(tmp_path / "model.urdf"))
    probe = ProximityProperties()
    AddCompliantHydroelasticProperties(probe_radius_m, 1e7, probe)
    probe.AddProperty("material", "coulomb_friction", CoulombFriction(0.5, 0.5))
    plant.RegisterCollisionGeometry(
        plant.world_body(), RigidTransform(probe_centre), Sphere(probe_radius_m), "probe", probe
    )
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    assert len(query.ComputePointPairPenetration()) == 1  # point contact: the hull
    surfaces, pairs = query.ComputeContactSurfacesWithFallback(HydroelasticContactRepresentation.kPolygon)
    assert not surfaces and not pairs  # hydroelastic (rigid mesh vs compliant probe): the true shape


def test_unknown_method_and_bad_config_raise(tmp_path):
    with pytest.raises(ValueError, match="unknown decomposition method"):
        decompose(_l_shape(), "quickhull", tmp_path)
    with pytest.raises(ValueError):
        CoacdConfig(threshold=0.0)
    with pytest.raises(ValueError):
        VhacdConfig(fill_mode="magic")
