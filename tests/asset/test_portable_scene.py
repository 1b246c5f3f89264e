"""The files for other simulators from the command line, and MuJoCo's scene.xml (issue 34, parts 3, 4).

`real2sim asset --format usd --format mjcf` writes model.usda, model.xml + scene.xml and (always)
model_portable.urdf in every representation folder; scene.xml opens in MuJoCo with the object
standing on a floor and stays there."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is a dependency (pip install mujoco)")

from real2sim.asset.export.mjcf import SCENE_NAME  # noqa: E402
from real2sim.asset.export.round_pieces import lowest_point_z_m  # noqa: E402
from real2sim.asset.export.writers import write_representation  # noqa: E402
from real2sim.formats.collision import CollisionGeometry, CollisionShape  # noqa: E402
from real2sim.formats.contact import ContactProperties  # noqa: E402
from real2sim.formats.physical import PhysicalProperties  # noqa: E402

PROPS = PhysicalProperties(0.35, (0.0, 0.0, 0.0), ((3.9e-4, 0, 0), (0, 3.9e-4, 0), (0, 0, 2.0e-4)))


def test_asset_command_writes_the_files_for_every_simulator(tmp_path, capsys):
    import trimesh

    from real2sim.cli import main

    mesh = tmp_path / "can.obj"
    trimesh.creation.cylinder(radius=0.034, height=0.1, sections=24).export(mesh)
    out = tmp_path / "can_asset"
    code = main(["asset", str(mesh), "--mass-kg", "0.35", "--out", str(out),
                 "--collision", "mesh", "--format", "usd", "--format", "mjcf"])
    assert code == 0, capsys.readouterr().err
    rep = out / "mesh"
    for name in ("model.urdf", "model_portable.urdf", "model.xml", SCENE_NAME, "model.usda"):
        assert (rep / name).is_file(), name
    assert "drake" not in (rep / "model_portable.urdf").read_text()
    from pxr import Usd, UsdPhysics

    stage = Usd.Stage.Open(str(rep / "model.usda"))
    assert UsdPhysics.MassAPI(stage.GetDefaultPrim()).GetMassAttr().Get() == pytest.approx(0.35)


def test_an_unknown_format_is_refused_in_one_line(tmp_path, capsys):
    from real2sim.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["asset", str(tmp_path / "x.obj"), "--mass-kg", "1", "--out", str(tmp_path / "o"), "--format", "fbx"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'fbx'" in capsys.readouterr().err


STANDING = CollisionGeometry("mixed", "test", (
    CollisionShape("cylinder", (0.034, 0.08), (0.0, 0.0, -0.01)),
    CollisionShape("ellipsoid", (0.03, 0.03, 0.012), (0.0, 0.0, 0.03)),
    CollisionShape("box", (0.02, 0.02, 0.02), (0.0, 0.0, 0.035), (math.cos(math.pi / 8), 0.0, 0.0, math.sin(math.pi / 8))),
))


@pytest.fixture()
def standing_rep(tmp_path) -> Path:
    """A can of a cylinder, an ellipsoid cap and a rotated box, written with --format mjcf."""
    write_representation(tmp_path, STANDING, PROPS, ContactProperties(), visual_mesh_relpath="", formats=("mjcf",))
    return tmp_path


def test_scene_includes_the_model_and_puts_a_floor_under_it(standing_rep):
    root = ET.parse(standing_rep / SCENE_NAME).getroot()
    assert [e.get("file") for e in root.iter("include")] == ["model.xml"]
    floor = [g for g in root.iter("geom") if g.get("name") == "floor"][0]
    assert floor.get("type") == "plane"
    lowest = lowest_point_z_m(STANDING, standing_rep)
    assert float(floor.get("pos").split()[2]) == pytest.approx(lowest, abs=1e-12)
    assert lowest == pytest.approx(-0.05, abs=1e-12)  # the cylinder's bottom


def test_scene_opens_in_mujoco_with_the_object_standing_on_the_floor(standing_rep):
    model = mujoco.MjModel.from_xml_path(str(standing_rep / SCENE_NAME))
    data = mujoco.MjData(model)
    body = model.body("object").id
    start = data.qpos[:3].copy()
    while data.time < 0.5:
        mujoco.mj_step(model, data)
    up = data.xmat[body].reshape(3, 3)[:, 2]
    assert data.ncon >= 3  # on the floor, not above it
    assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) < 0.5
    assert abs(data.qpos[2] - start[2]) < 1e-3 and np.linalg.norm(data.qpos[:2] - start[:2]) < 1e-3
