"""The identify verbs as a user types them: properties into the asset frame, and bad logs refused."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import trimesh

from real2sim.formats.joint_log import JointLog, write_joint_log
from real2sim.geometry.objects import make_object
from real2sim.identify.arm import default_arm_urdf
from tests.cli_helpers import run_cli


def _one_line(code, err):
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and "Traceback" not in err, err


def test_identified_properties_go_into_the_asset_frame(tmp_path, capsys):
    """A can lying tilted and off the origin in its mesh file: the asset's canonical pose moves it, and the
    given centre of mass and inertia move with it."""
    mesh = make_object("can")
    tilt = trimesh.transformations.rotation_matrix(0.7, [1.0, 0.5, 0.0])
    tilt[:3, 3] = [0.3, -0.2, 0.1]
    mesh.apply_transform(tilt)
    mesh_path = tmp_path / "can_tilted.stl"
    mesh.export(mesh_path)
    com_mesh = np.asarray(mesh.center_mass) + tilt[:3, :3] @ [0.01, 0.0, 0.0]
    inertia_mesh = tilt[:3, :3] @ np.diag([4e-4, 5e-4, 2e-4]) @ tilt[:3, :3].T
    props = {"mass_kg": 0.45, "com_m": com_mesh.tolist(), "inertia_kg_m2": inertia_mesh.tolist(),
             "method": "identified from joint torques (test)", "frame": "mesh"}
    props_path = tmp_path / "props.json"
    props_path.write_text(json.dumps(props))
    code, _, err = run_cli(capsys, "asset", mesh_path, "--properties", props_path, "--out", tmp_path / "asset",
                           "--collision", "mesh")
    assert code == 0, err
    written = json.loads((tmp_path / "asset" / "physical_properties.json").read_text())
    transform = np.asarray(json.loads((tmp_path / "asset" / "canonical_transform.json").read_text())["T_asset_from_input"])
    assert not np.allclose(transform[:3, :3], np.eye(3), atol=0.1)  # the canonical pose did turn it
    assert written["mass_kg"] == pytest.approx(0.45)
    np.testing.assert_allclose(written["com_m"], transform[:3, :3] @ com_mesh + transform[:3, 3], atol=1e-9)
    np.testing.assert_allclose(written["inertia_kg_m2"], transform[:3, :3] @ inertia_mesh @ transform[:3, :3].T,
                               atol=1e-12)
    assert "identified" in written["method"] and str(props_path) in written["source"]
    uniform = written["uniform_density"]  # side by side with what uniform density would have said
    assert uniform["mass_kg"] == pytest.approx(0.45) and not np.allclose(uniform["com_m"], written["com_m"], atol=1e-3)
    assert json.loads((tmp_path / "asset" / "asset_config.json").read_text())["properties"]["frame"] == "mesh"
    # truth.json and the report put uniform density's errors beside the given properties' errors
    from real2sim.formats.physical import read_physical_properties
    from real2sim.pipeline.truth import _uniform_beside
    from real2sim.report.sections import _truth_table

    true_props = read_physical_properties(tmp_path / "asset" / "physical_properties.json")  # the given are true here
    beside = _uniform_beside(tmp_path / "asset", true_props)
    assert beside["com_error_mm"] > 5.0  # uniform density puts the CoM 10 mm from where it was given
    page = _truth_table({"physical_properties": {"com_error_mm": 0.0, "inertia_eigenvalue_max_rel_error": 0.0},
                         "physical_properties_uniform_density": beside})
    assert "uniform density instead" in page
    # a different --mass-kg beside the properties is a contradiction
    code, _, err = run_cli(capsys, "asset", mesh_path, "--properties", props_path, "--mass-kg", "0.3", "--out",
                           tmp_path / "asset2", "--collision", "mesh")
    _one_line(code, err)
    assert not (tmp_path / "asset2").exists()


@pytest.fixture(scope="module")
def good_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("log") / "log"
    folder.mkdir()
    t = np.arange(0, 12.0, 1e-3)
    q = 0.3 * np.sin(np.outer(t, np.arange(1, 8)) * 0.7)
    log = JointLog(t, q, np.gradient(q, 1e-3, axis=0), np.ones_like(q), None, np.eye(4))
    write_joint_log(folder, log, default_arm_urdf().read_text())
    return folder


def _broken(good_log, tmp_path, name, edit):
    folder = tmp_path / name
    shutil.copytree(good_log, folder)
    edit(folder)
    return folder


def _rewrite_csv(change):
    def edit(folder):
        lines = (folder / "joints.csv").read_text().splitlines()
        (folder / "joints.csv").write_text("\n".join(change(lines)) + "\n")
    return edit


BAD_LOGS = {
    "missing column": _rewrite_csv(lambda ls: [",".join(ls[0].split(",")[:-1])] + [",".join(r.split(",")[:-1]) for r in ls[1:]]),
    "mismatched lengths": _rewrite_csv(lambda ls: ls[:100] + [",".join(ls[100].split(",")[:-3])] + ls[101:]),
    "NaN": _rewrite_csv(lambda ls: ls[:50] + [ls[50].replace(ls[50].split(",")[3], "nan", 1)] + ls[51:]),
    "too short": _rewrite_csv(lambda ls: ls[:300]),
    "grasp not rigid": lambda f: (f / "grasp.json").write_text(json.dumps(
        {"flange_frame": "flange", "flange_from_object": (2 * np.eye(4)).tolist()})),
    "robot does not load": lambda f: (f / "robot.urdf").write_text("<robot name='x'><link name='a'/><joint/></robot>"),
    "no flange frame": lambda f: (f / "grasp.json").write_text(json.dumps(
        {"flange_frame": "tool0", "flange_from_object": np.eye(4).tolist()})),
    "not excited": _rewrite_csv(lambda ls: [ls[0]] + [",".join(r.split(",")[:1] + ["0"] * 14 + r.split(",")[15:])
                                                      for r in ls[1:]]),
}


@pytest.mark.parametrize("case", sorted(BAD_LOGS))
def test_bad_logs_are_one_line_and_exit_2(good_log, tmp_path, capsys, case):
    folder = _broken(good_log, tmp_path, case.replace(" ", "_"), BAD_LOGS[case])
    code, _, err = run_cli(capsys, "identify", folder, "--out", tmp_path / "props.json")
    _one_line(code, err)
    assert not (tmp_path / "props.json").exists()


def test_bad_excite_inputs_are_one_line_and_exit_2(tmp_path, capsys):
    cases = [
        ["can", "--mass-kg", "0.3", "--extra-mass-kg", "0.1", "--extra-mass-at-m", "1", "0", "0", "--out", tmp_path / "a"],
        ["can", "--mass-kg", "0.3", "--extra-mass-kg", "0.1", "--out", tmp_path / "b"],
        ["can", "--mass-kg", "0", "--out", tmp_path / "c"],
        ["no_such.obj", "--mass-kg", "0.3", "--out", tmp_path / "d"],
        ["can", "--mass-kg", "0.3", "--extra-mass-at-m", "0", "0", "0.03", "--out", tmp_path / "e"],
        ["can", "--mass-kg", "0.3", "--duration-s", "2", "--out", tmp_path / "f"],
    ]
    for argv in cases:
        code, _, err = run_cli(capsys, "excite", *argv)
        _one_line(code, err)
    assert not any((tmp_path / n).exists() for n in "abcdef")


@pytest.mark.slow
def test_excite_then_identify_from_the_command_line_meets_the_mass_and_com_targets(tmp_path, capsys, monkeypatch):
    """The verbs as typed, with the default 6-minute trajectory and noise: mass within 2 %, CoM within 2 mm."""
    monkeypatch.setenv("REAL2SIM_CACHE", str(tmp_path / "cache"))
    code, out, err = run_cli(capsys, "excite", "bottle", "--mass-kg", "0.4", "--extra-mass-kg", "0.2", "--extra-mass-at-m",
                             "0.01", "0.01", "0.05", "--out", tmp_path / "log")
    assert code == 0, err
    code, out, err = run_cli(capsys, "identify", tmp_path / "log", "--out", tmp_path / "props.json")
    assert code == 0, err
    assert "against LOG/truth.json" in out
    from real2sim.identify.stage import errors_against_truth

    props = json.loads((tmp_path / "props.json").read_text())
    err = errors_against_truth(props, json.loads((tmp_path / "log" / "truth.json").read_text()))
    assert err["mass_rel"] < 0.02 and err["com_m"] < 2e-3
