import numpy as np
import pytest
import trimesh

from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.mesh_io import load_mesh


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb", ".off"])
def test_loads_every_format(tmp_path, suffix, can_mesh):
    path = tmp_path / f"can{suffix}"
    can_mesh.export(path)
    mesh = load_mesh(path)
    assert mesh.volume == pytest.approx(can_mesh.volume, rel=1e-4)


def test_missing_file(tmp_path):
    with pytest.raises(UserInputError, match="not found"):
        load_mesh(tmp_path / "nope.obj")


def test_not_a_mesh(tmp_path):
    path = tmp_path / "notes.obj"
    path.write_bytes(b"\x00\x01 this is not a mesh \xff" * 10)
    with pytest.raises(UserInputError):
        load_mesh(path)
    txt = tmp_path / "notes.txt"
    txt.write_text("hello")
    with pytest.raises(UserInputError, match="not a mesh file"):
        load_mesh(txt)


def test_empty_and_degenerate(tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(UserInputError):
        load_mesh(empty)
    flat = trimesh.Trimesh(vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), faces=[[0, 1, 2], [1, 3, 2]])
    path = tmp_path / "flat.ply"
    flat.export(path)
    with pytest.raises(UserInputError, match="degenerate"):
        load_mesh(path)
