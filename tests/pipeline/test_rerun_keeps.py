"""A rerun of `real2sim run` replaces only what it made (issue 33, items 1, 3, 8 and 11).

One tiny capture of the can (8 views at 64x48, no ground truth), a visual hull on a 48-voxel grid and
`spheres:4` fitted for 50 iterations: the first run takes tens of seconds on two loaded cores, and each
test reruns a copy of it. Reruns that change the mass reuse the fitted spheres, so they fit nothing.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.cli_helpers import run_cli

FAST = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64", "--iterations", "50",
        "--no-refine-poses"]
EVALUATE = ["--evaluate", "--tasks", "push", "--contact", "point", "--runs", "1", "--jobs", "1",
            "--duration-scale", "0.2"]


def _capture(out: Path, ground_truth: bool) -> Path:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    capture(make_textured_object("can"), out, CaptureConfig(views=8, width=64, height=48))
    if not ground_truth:
        shutil.rmtree(out / "ground_truth")
    return out


@pytest.fixture(scope="module")
def tiny_ds(tmp_path_factory) -> Path:
    return _capture(tmp_path_factory.mktemp("rerun") / "can_ds", ground_truth=False)


def _run(capsys, ds: Path, out: Path, *extra) -> tuple[int, str, str]:
    return run_cli(capsys, "run", ds, "--mass-kg", extra[0] if extra else "0.35", "--out", out, *FAST, *extra[1:])


@pytest.fixture(scope="module")
def first_run(tiny_ds, tmp_path_factory) -> Path:
    from real2sim.cli import main

    out = tmp_path_factory.mktemp("rerun_first") / "A"
    assert main(["run", str(tiny_ds), "--mass-kg", "0.35", "--out", str(out), *FAST, "--collision", "spheres:4"]) == 0
    return out


@pytest.fixture()
def asset_copy(first_run, tmp_path) -> Path:
    out = tmp_path / "A"
    shutil.copytree(first_run, out, symlinks=True)
    return out


def manifest(asset_dir: Path) -> dict:
    return json.loads((asset_dir / ".run" / "run.json").read_text())


def test_rerun_with_other_settings_keeps_the_users_files(tiny_ds, asset_copy, capsys):
    """Item 1: the user's notes and folder in ASSETDIR survive a rerun that rebuilds the asset."""
    (asset_copy / "MY_NOTES.txt").write_text("notes")
    (asset_copy / "my_stuff").mkdir()
    (asset_copy / "my_stuff" / "plan.txt").write_text("mine")
    code, out, err = _run(capsys, tiny_ds, asset_copy, "0.36", "--collision", "spheres:4")
    assert code == 0, err
    assert "stages run: asset" in out
    assert json.loads((asset_copy / "physical_properties.json").read_text())["mass_kg"] == pytest.approx(0.36)
    # another representation: the run's own spheres_4/ goes, the user's entries stay
    code, out, err = _run(capsys, tiny_ds, asset_copy, "0.36", "--collision", "mesh")
    assert code == 0, err
    assert (asset_copy / "mesh" / "model.urdf").is_file() and not (asset_copy / "spheres_4").exists()
    assert (asset_copy / "MY_NOTES.txt").read_text() == "notes"
    assert (asset_copy / "my_stuff" / "plan.txt").read_text() == "mine"
    assert "MY_NOTES.txt" not in manifest(asset_copy)["owned"]


def test_rerun_of_a_folder_from_before_ownership_was_recorded_keeps_the_users_files(tiny_ds, asset_copy, capsys):
    """Item 1: a run.json without ``owned`` (written by an older real2sim) whose asset stage failed
    since: the entries its asset_config.json names are the run's, the rest the user's."""
    record = manifest(asset_copy)
    del record["owned"], record["stages"]["asset"]
    (asset_copy / ".run" / "run.json").write_text(json.dumps(record))
    (asset_copy / "MY_NOTES.txt").write_text("notes")
    code, out, err = _run(capsys, tiny_ds, asset_copy, "0.35", "--collision", "mesh")
    assert code == 0, err
    assert (asset_copy / "MY_NOTES.txt").read_text() == "notes"
    assert not (asset_copy / "spheres_4").exists() and (asset_copy / "mesh" / "model.urdf").is_file()


def test_rerun_never_replaces_a_folder_holding_the_users_files(tiny_ds, asset_copy, capsys):
    """Item 1: a file of the user's inside a representation folder, or a folder of the user's under a
    name the run writes, stops the rerun with one line before anything is replaced."""
    (asset_copy / "spheres_4" / "my_notes.txt").write_text("mine")
    before = (asset_copy / "spheres_4" / "model.urdf").read_bytes()
    code, _, err = _run(capsys, tiny_ds, asset_copy, "0.36", "--collision", "spheres:4")
    errors = [line for line in err.splitlines() if "error:" in line]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err
    assert "spheres_4/my_notes.txt" in errors[0]
    assert (asset_copy / "spheres_4" / "my_notes.txt").read_text() == "mine"
    assert (asset_copy / "spheres_4" / "model.urdf").read_bytes() == before
    (asset_copy / "spheres_4" / "my_notes.txt").unlink()
    (asset_copy / "mesh").mkdir()
    (asset_copy / "mesh" / "thesis.tex").write_text("mine")
    code, _, err = _run(capsys, tiny_ds, asset_copy, "0.35", "--collision", "mesh")
    assert code == 2 and "was not written by run" in err
    assert (asset_copy / "mesh" / "thesis.tex").read_text() == "mine"
    assert (asset_copy / "spheres_4" / "model.urdf").read_bytes() == before


def test_adding_a_collision_fits_only_the_new_one(tiny_ds, asset_copy, capsys):
    """Item 11: spheres_4 was fitted by the first run; adding `mesh` reuses it instead of refitting."""
    collision_before = (asset_copy / "spheres_4" / "collision.json").read_bytes()
    code, out, err = _run(capsys, tiny_ds, asset_copy, "0.35", "--collision", "spheres:4", "--collision", "mesh")
    assert code == 0, err
    assert "collision spheres:4: unchanged, reused" in err
    assert "collision spheres:4: fitting" not in err and "spheres:4: fit:" not in err
    assert "collision mesh: fitting" in err
    assert (asset_copy / "spheres_4" / "collision.json").read_bytes() == collision_before
    assert "reused" in json.loads((asset_copy / "spheres_4" / "fit_report.json").read_text())
    assert (asset_copy / "mesh" / "model.urdf").is_file()
    # a setting that shapes the geometry (the seed) refits
    code, _, err = _run(capsys, tiny_ds, asset_copy, "0.35", "--collision", "spheres:4", "--seed", "1")
    assert code == 0 and "collision spheres:4: fitting" in err and "reused" not in err


def test_reused_representation_loads_in_drake_with_the_new_mass(tiny_ds, asset_copy, capsys):
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    assert _run(capsys, tiny_ds, asset_copy, "0.4", "--collision", "spheres:4")[0] == 0
    plant = MultibodyPlant(0.0)
    models = Parser(plant).AddModels(str(asset_copy / "spheres_4" / "model.urdf"))
    plant.Finalize()
    body = [plant.get_body(i) for i in plant.GetBodyIndices(models[0])][0]
    assert body.default_mass() == pytest.approx(0.4)


@pytest.fixture(scope="module")
def evaluated_run(first_run, tiny_ds, tmp_path_factory) -> Path:
    from real2sim.cli import main

    out = tmp_path_factory.mktemp("rerun_evaluated") / "A"
    shutil.copytree(first_run, out, symlinks=True)
    assert main(["run", str(tiny_ds), "--mass-kg", "0.35", "--out", str(out), *FAST, "--collision", "spheres:4",
                 *EVALUATE]) == 0
    return out


def test_rerun_without_evaluate_keeps_the_evaluation_and_marks_it_stale(tiny_ds, evaluated_run, tmp_path, capsys):
    """Item 3: no --evaluate, same asset: results/ kept as they are; another mass: kept, marked stale."""
    out = tmp_path / "A"
    shutil.copytree(evaluated_run, out, symlinks=True)
    runs_before = (out / "results" / "runs.csv").read_bytes()
    code, stdout, err = _run(capsys, tiny_ds, out, "0.35", "--collision", "spheres:4")
    assert code == 0 and "none, all unchanged" in stdout and "WARNING" not in err
    code, stdout, err = _run(capsys, tiny_ds, out, "0.36", "--collision", "spheres:4")
    assert code == 0, err
    assert (out / "results" / "runs.csv").read_bytes() == runs_before
    assert (out / "results" / "STALE.txt").is_file()
    assert manifest(out)["stages"]["evaluate"]["stale"] is True
    warnings = [line for line in err.splitlines() if line.startswith("WARNING: ")]
    assert len(warnings) == 1 and "results/" in warnings[0] and "--evaluate" in warnings[0]
    # the same command again: still stale, no new note needed
    code, stdout, err = _run(capsys, tiny_ds, out, "0.36", "--collision", "spheres:4")
    assert code == 0 and "none, all unchanged" in stdout
    # --evaluate simulates the current asset and replaces the stale results
    code, stdout, err = _run(capsys, tiny_ds, out, "0.36", "--collision", "spheres:4", *EVALUATE)
    assert code == 0 and "stages run: evaluate" in stdout
    assert not (out / "results" / "STALE.txt").exists() and "stale" not in manifest(out)["stages"]["evaluate"]


def test_a_late_bad_input_keeps_the_cache_and_says_so_on_one_line(tiny_ds, tmp_path, capsys):
    """Item 8: masks that miss the can's lower part make a reconstruction short of the table; the asset
    stage refuses it after the reconstruction finished. The folder stays as a resumable cache, and the
    one error line says so."""
    import numpy as np
    from PIL import Image

    ds = tmp_path / "cut"
    shutil.copytree(tiny_ds, ds)
    for path in (ds / "masks").glob("*.png"):
        mask = np.array(Image.open(path))
        rows = np.nonzero(mask.any(axis=1))[0]
        mask[int(rows.max() - 0.3 * (rows.max() - rows.min())):] = 0
        Image.fromarray(mask).save(path)
    out = tmp_path / "A"
    code, _, err = _run(capsys, ds, out, "0.35", "--collision", "spheres:4")
    errors = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err
    assert "above the table" in errors[0] and f"kept in {out / '.run'}" in errors[0]
    assert list(manifest(out)["stages"]) == ["reconstruct"]


def test_a_failure_before_any_stage_finished_says_nothing_was_kept(tiny_ds, tmp_path, capsys, monkeypatch):
    """Item 8: the message names no `.run` folder when the run removed the folder it had made."""
    import real2sim.reconstruct.stage as stage

    def broken(*args, **kwargs):
        raise RuntimeError("reconstruction exploded")

    monkeypatch.setattr(stage, "reconstruct", broken)
    out = tmp_path / "A"
    code, _, err = _run(capsys, tiny_ds, out, "0.35", "--collision", "spheres:4")
    assert code == 1 and "reconstruction exploded" in err
    assert not out.exists() and ".run" not in err and "nothing was written" in err


@pytest.mark.slow
def test_rerun_without_evaluate_keeps_the_mesh_representation_of_an_evaluated_run(tmp_path, capsys):
    """Item 3 with ground truth: --evaluate adds the reconstruction itself as `mesh`; a rerun without
    --evaluate keeps it, results/, results_truth/ and truth.json's dynamics, and reruns nothing."""
    ds = _capture(tmp_path / "can_gt", ground_truth=True)
    out = tmp_path / "A"
    assert _run(capsys, ds, out, "0.35", "--collision", "spheres:4", *EVALUATE)[0] == 0
    before = {p: (out / p).read_bytes() for p in ("mesh/model.urdf", "results/runs.csv", "results_truth/runs.csv",
                                                  "truth.json")}
    code, stdout, err = _run(capsys, ds, out, "0.35", "--collision", "spheres:4")
    assert code == 0 and "none, all unchanged" in stdout, err
    assert {p: (out / p).read_bytes() for p in before} == before
    assert "dynamics" in json.loads((out / "truth.json").read_text())
