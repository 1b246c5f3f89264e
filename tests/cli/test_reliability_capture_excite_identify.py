"""capture, excite and identify refuse what they used to ignore or half-do (issue #69).

capture: flags that did nothing are one-line errors before any work. excite: the meshes real2sim
writes (an OBJ split at UV seams, an STL that shares no vertices) are closed solids, an object of no
graspable size is refused with the --mesh-units hint. identify: a bad LOG/truth.json or an --out that
cannot be replaced is found before the solve, and --out is never written.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from real2sim.cli import main
from real2sim.formats.dataset import read_ground_truth
from real2sim.geometry.objects import make_object
from real2sim.identify.excite import payload_truth
from tests.cli_helpers import run_cli

SMALL_CAPTURE = ("--views", "12", "--width-px", "96", "--height-px", "72")


def assert_refused(code: int, err: str, *says: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert all(s in err for s in says), err


# --- capture ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, says", [
    (["--ring-elevation-deg", "-5"], ("--ring-elevation-deg", "--no-table")),
    (["--jpeg", "--video"], ("--jpeg", "--video")),
    (["--handheld", "--video", "--jpeg"], ("--jpeg", "--video")),
    (["--fps", "24"], ("--fps", "--video")),
    (["--handheld", "--fps", "30"], ("--fps", "--video")),  # the default's value, given: still no video
])
def test_capture_refuses_flags_it_would_ignore(tmp_path, capsys, argv, says):
    out = tmp_path / "DS"
    code, _, err = run_cli(capsys, "capture", "can", *SMALL_CAPTURE, "--out", out, *argv)
    assert_refused(code, err, *says)
    assert not out.exists()


def test_capture_video_without_fps_is_30_fps(tmp_path, capsys):
    out = tmp_path / "DS"
    code, _, err = run_cli(capsys, "capture", "can", "--handheld", "--video", *SMALL_CAPTURE, "--out", out)
    assert code == 0, err
    assert read_ground_truth(out).extra["real2sim"]["video"]["fps"] == 30.0


# --- excite -------------------------------------------------------------------------------------------

def _excite(capsys, mesh_path, out):
    return run_cli(capsys, "excite", mesh_path, "--mass-kg", "0.4", "--duration-s", "8", "--out", out)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with the trajectory cache of this module's excite runs (one design for the can's grasp)."""
    folder = tmp_path_factory.mktemp("reliability")
    with pytest.MonkeyPatch.context() as env:
        env.setenv("REAL2SIM_CACHE", str(folder / "cache"))
        yield folder


@pytest.fixture(scope="module")
def can_log(work):
    """The log of `excite` on the OBJ that `objects export can` writes; identify's tests reuse it."""
    assert main(["objects", "export", "can", str(work / "can.obj")]) == 0  # pytest's capsys is per test
    assert main(["excite", str(work / "can.obj"), "--mass-kg", "0.4", "--duration-s", "8", "--out",
                 str(work / "can_log")]) == 0
    return work / "can_log"


def _assert_truth_of_the_can(log):
    truth = json.loads((log / "truth.json").read_text())
    expected = payload_truth(make_object("can"), 0.4)
    assert truth["mass_kg"] == pytest.approx(0.4)
    np.testing.assert_allclose(truth["com_m"], expected.com_m, atol=1e-6)
    np.testing.assert_allclose(truth["inertia_kg_m2"], expected.inertia_kg_m2, rtol=1e-4, atol=1e-9)


def test_excite_takes_the_exported_can_obj(can_log):
    mesh = trimesh.load(can_log.parent / "can.obj", process=False)
    assert not mesh.is_watertight  # its vertices split at the texture's seams, as excite used to test it
    _assert_truth_of_the_can(can_log)


def test_excite_takes_a_closed_stl(work, tmp_path, capsys):
    stl = tmp_path / "can.stl"
    make_object("can").export(stl)
    assert not trimesh.load(stl, process=False).is_watertight  # an STL shares no vertices
    code, _, err = _excite(capsys, stl, tmp_path / "log")
    assert code == 0, err
    _assert_truth_of_the_can(tmp_path / "log")


@pytest.mark.parametrize("side_m, says", [
    (0.001, "1 mm across"),
    (100.0, "pass --mesh-units mm"),
])
def test_excite_refuses_an_object_of_no_graspable_size(tmp_path, capsys, side_m, says):
    stl = tmp_path / "box.stl"
    trimesh.creation.box(extents=[side_m] * 3).export(stl)
    code, _, err = _excite(capsys, stl, tmp_path / "log")
    assert_refused(code, err, says, "--mesh-units")
    assert not (tmp_path / "log").exists()


def test_excite_still_refuses_an_open_mesh(tmp_path, capsys):
    box = trimesh.creation.box(extents=[0.1, 0.08, 0.06])
    stl = tmp_path / "open.stl"
    trimesh.Trimesh(box.vertices, box.faces[1:], process=False).export(stl)  # one triangle missing
    code, _, err = _excite(capsys, stl, tmp_path / "log")
    assert_refused(code, err, "closed solid")
    assert not (tmp_path / "log").exists()


# --- identify -----------------------------------------------------------------------------------------

def _log_with_truth(can_log, tmp_path, text):
    log = tmp_path / "log"
    shutil.copytree(can_log, log)
    (log / "truth.json").write_text(text)
    return log


@pytest.mark.parametrize("name, truth", [
    ("corrupt", lambda t: '{"mass_kg": 0.4, "com_m": ['),
    ("zero mass", lambda t: json.dumps({**t, "mass_kg": 0.0})),
    ("no finite mass", lambda t: json.dumps({**t, "mass_kg": "NaN"})),
])
def test_identify_refuses_a_bad_truth_before_writing(can_log, tmp_path, capsys, name, truth):
    log = _log_with_truth(can_log, tmp_path, truth(json.loads((can_log / "truth.json").read_text())))
    out = tmp_path / "props.json"
    code, _, err = run_cli(capsys, "identify", log, "--out", out)
    assert_refused(code, err, "truth.json")
    assert not out.exists()


def test_identify_of_the_log_compares_with_its_truth(can_log, tmp_path, capsys):
    code, out, err = run_cli(capsys, "identify", can_log, "--out", tmp_path / "props.json")
    assert code == 0, err
    assert "against LOG/truth.json" in out and json.loads((tmp_path / "props.json").read_text())["mass_kg"] > 0


def test_identify_refuses_an_immutable_out_before_the_solve(can_log, tmp_path, capsys):
    out = tmp_path / "props.json"
    out.write_text("mine")
    if subprocess.run(["chattr", "+i", str(out)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i does not work on this file system (or without the capability)")
    try:
        code, _, err = run_cli(capsys, "identify", can_log, "--out", out, "--overwrite")
    finally:
        subprocess.run(["chattr", "-i", str(out)], check=True)
    assert_refused(code, err, "--out", "cannot be replaced")
    assert out.read_text() == "mine"


def test_identify_refuses_an_out_under_a_file(can_log, tmp_path, capsys):
    (tmp_path / "notes").write_text("mine")
    code, _, err = run_cli(capsys, "identify", can_log, "--out", tmp_path / "notes" / "props.json")
    assert_refused(code, err, "--out", "is a file")
    assert (tmp_path / "notes").read_text() == "mine"
