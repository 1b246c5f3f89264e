"""Bring-your-own reconstruction: a mesh in nerfstudio's normalised frame (p_ns = s (R p + t)) is
put back in the dataset's world frame, by the function and by `real2sim reconstruct --from-mesh`;
malformed dataparser_transforms.json files are refused with one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from real2sim.plumbing.errors import UserInputError
from real2sim.reconstruct.external import import_nerfstudio_mesh, read_dataparser_transforms, world_from_nerfstudio
from tests.cli_helpers import run_cli as _run

LIFT_M = 0.005  # the test meshes float 5 mm above the table, clear of the clean-up at z = 0


def _nerfstudio_frame(seed: int) -> tuple[np.ndarray, float]:
    """A random 3x4 [R | t] and scale, as nerfstudio's dataparser writes them (scale ~ 1 / scene size)."""
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    transform = np.hstack([rotation, rng.normal(0.0, 0.4, (3, 1))])
    return transform, float(rng.uniform(0.5, 4.0))


def _to_nerfstudio(points: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    return scale * (points @ transform[:, :3].T + transform[:, 3])


def _write_transforms(path: Path, transform: np.ndarray, scale: float) -> Path:
    path.write_text(json.dumps({"transform": transform.tolist(), "scale": scale}))
    return path


def _max_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance from a point of either set to the nearest point of the other."""
    return max(cKDTree(b).query(a)[0].max(), cKDTree(a).query(b)[0].max())


@pytest.fixture(scope="module")
def world_can(truth) -> trimesh.Trimesh:
    mesh = truth.copy()
    mesh.apply_translation([0.0, 0.0, LIFT_M])
    return mesh


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_import_undoes_the_normalisation(world_can, tmp_path, suffix, seed):
    transform, scale = _nerfstudio_frame(seed)
    ns_mesh = trimesh.Trimesh(_to_nerfstudio(world_can.vertices, transform, scale), world_can.faces, process=False)
    assert _max_distance(ns_mesh.vertices, world_can.vertices) > 0.05  # really somewhere else
    ns_mesh.export(tmp_path / f"mesh{suffix}")
    back = import_nerfstudio_mesh(tmp_path / f"mesh{suffix}",
                                  _write_transforms(tmp_path / "dataparser_transforms.json", transform, scale))
    assert len(back.faces) == len(world_can.faces) and len(back.vertices) == len(world_can.vertices)
    # PLY stores float32, OBJ 8 decimals: measured at most 2e-8 m back in the world frame
    np.testing.assert_allclose(back.vertices, world_can.vertices, atol=1e-6)
    assert back.is_watertight


def test_world_from_nerfstudio_is_the_inverse():
    transform, scale = _nerfstudio_frame(5)
    points = np.random.default_rng(5).normal(0.0, 0.2, (50, 3))
    forward = np.vstack([transform, [0.0, 0.0, 0.0, 1.0]])
    back = world_from_nerfstudio(forward, scale)
    ns = _to_nerfstudio(points, transform, scale)
    np.testing.assert_allclose(ns @ back[:3, :3].T + back[:3, 3], points, atol=1e-12)


def test_import_keeps_the_texture(tmp_path):
    """A textured nerfstudio export (OBJ + MTL + PNG) comes back textured, its UVs untouched."""
    from real2sim.geometry.mesh_io import export_textured_mesh
    from real2sim.geometry.objects import make_textured_object

    can = make_textured_object("can")
    can.apply_translation([0.0, 0.0, LIFT_M - can.bounds[0, 2]])
    transform, scale = _nerfstudio_frame(7)
    ns_can = can.copy()
    ns_can.vertices = _to_nerfstudio(can.vertices, transform, scale)
    export_textured_mesh(ns_can, tmp_path / "export" / "mesh.obj")
    back = import_nerfstudio_mesh(tmp_path / "export" / "mesh.obj",
                                  _write_transforms(tmp_path / "dp.json", transform, scale))
    assert isinstance(back.visual, trimesh.visual.TextureVisuals) and back.visual.material.image is not None
    assert back.visual.uv.shape == (len(back.vertices), 2)
    assert _max_distance(back.vertices, can.vertices) < 1e-6


def test_import_drops_what_is_below_the_table_and_floaters(world_can, tmp_path):
    """Faces wholly under z = 0 (the table the reconstruction caught) and small detached parts go."""
    transform, scale = _nerfstudio_frame(3)
    table = trimesh.creation.box(extents=[0.3, 0.3, 0.01])
    table.apply_translation([0.0, 0.0, -0.006])  # top face at -1 mm: wholly below the table plane
    floater = trimesh.creation.icosphere(subdivisions=1, radius=0.003)
    floater.apply_translation([0.1, 0.1, 0.05])
    scene = trimesh.util.concatenate([world_can, table, floater])
    scene.vertices = _to_nerfstudio(scene.vertices, transform, scale)
    scene.export(tmp_path / "mesh.ply")
    back = import_nerfstudio_mesh(tmp_path / "mesh.ply", _write_transforms(tmp_path / "dp.json", transform, scale))
    assert len(back.faces) == len(world_can.faces)
    assert _max_distance(back.vertices, world_can.vertices) < 1e-6


def test_import_keeps_a_bottom_that_lies_on_the_table(truth, tmp_path):
    assert abs(truth.bounds[0, 2]) < 1e-12  # the true can stands on z = 0
    lost = []
    for seed in range(10):
        transform, scale = _nerfstudio_frame(seed)
        trimesh.Trimesh(_to_nerfstudio(truth.vertices, transform, scale), truth.faces,
                        process=False).export(tmp_path / "mesh.ply")
        back = import_nerfstudio_mesh(tmp_path / "mesh.ply", _write_transforms(tmp_path / "dp.json", transform, scale))
        lost.append(len(truth.faces) - len(back.faces))
    assert lost == [0] * 10


def _bad_transforms():
    good, _ = _nerfstudio_frame(0)
    singular = good.copy()
    singular[:, :3] = 0.0
    nan = good.copy()
    nan[1, 1] = float("nan")
    return {
        "not json": "{transform: nope",
        "top level list": "[1, 2, 3]",
        "no scale": json.dumps({"transform": good.tolist()}),
        "no transform": json.dumps({"scale": 2.0}),
        "scale not a number": json.dumps({"transform": good.tolist(), "scale": "big"}),
        "zero scale": json.dumps({"transform": good.tolist(), "scale": 0.0}),
        "negative scale": json.dumps({"transform": good.tolist(), "scale": -1.5}),
        "2x2 transform": json.dumps({"transform": [[1, 0], [0, 1]], "scale": 1.0}),
        "ragged transform": json.dumps({"transform": [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0]], "scale": 1.0}),
        "singular transform": json.dumps({"transform": singular.tolist(), "scale": 1.0}),
        "non-finite transform": json.dumps({"transform": nan.tolist(), "scale": 1.0}),
    }


@pytest.mark.parametrize("case", list(_bad_transforms()))
def test_bad_dataparser_transforms_are_refused(case, tmp_path):
    path = tmp_path / "dataparser_transforms.json"
    path.write_text(_bad_transforms()[case])
    with pytest.raises(UserInputError) as info:
        read_dataparser_transforms(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_missing_dataparser_transforms(tmp_path):
    with pytest.raises(UserInputError, match="not found"):
        read_dataparser_transforms(tmp_path / "nope.json")


def test_mesh_wholly_below_the_table_is_refused(world_can, tmp_path):
    transform, scale = _nerfstudio_frame(4)
    upside_down = world_can.copy()
    upside_down.vertices[:, 2] *= -1.0  # what a wrong up axis in the transforms gives
    trimesh.Trimesh(_to_nerfstudio(upside_down.vertices, transform, scale), upside_down.faces[:, ::-1],
                    process=False).export(tmp_path / "mesh.ply")
    with pytest.raises(UserInputError, match="below the table"):
        import_nerfstudio_mesh(tmp_path / "mesh.ply", _write_transforms(tmp_path / "dp.json", transform, scale))




def test_cli_from_mesh(can_without_truth, world_can, tmp_path, capsys):
    transform, scale = _nerfstudio_frame(11)
    trimesh.Trimesh(_to_nerfstudio(world_can.vertices, transform, scale), world_can.faces,
                    process=False).export(tmp_path / "ns_mesh.ply")
    dp = _write_transforms(tmp_path / "dataparser_transforms.json", transform, scale)
    out = tmp_path / "imported"
    code, stdout, stderr = _run(capsys, "reconstruct", can_without_truth, "--out", out,
                                "--from-mesh", tmp_path / "ns_mesh.ply", "--dataparser-transforms", dp)
    assert code == 0, stderr
    lines = stdout.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"mesh: {out.resolve() / 'mesh.obj'}")
    assert f"{len(world_can.faces)} faces" in lines[0]
    written = trimesh.load(out / "mesh.obj", force="mesh", process=False)
    assert _max_distance(written.vertices, world_can.vertices) < 1e-6  # measured 3e-9 m
    report = json.loads((out / "report.json").read_text())
    assert report["backend"] == "nerfstudio-import" and report["source_mesh"] == "ns_mesh.ply"
    assert report["mesh"]["watertight"] is True and "truth" not in report


@pytest.mark.parametrize("case", ["mesh without transforms", "transforms without mesh", "bad transforms"])
def test_cli_from_mesh_bad_input(case, can_without_truth, world_can, tmp_path, capsys):
    world_can.export(tmp_path / "mesh.ply")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"transform": np.eye(4)[:3].tolist()}))
    args = {"mesh without transforms": ["--from-mesh", tmp_path / "mesh.ply"],
            "transforms without mesh": ["--dataparser-transforms", bad],
            "bad transforms": ["--from-mesh", tmp_path / "mesh.ply", "--dataparser-transforms", bad]}[case]
    out = tmp_path / "out"
    code, _, stderr = _run(capsys, "reconstruct", can_without_truth, "--out", out, *args)
    assert code == 2
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
