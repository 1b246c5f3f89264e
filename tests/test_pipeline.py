"""`real2sim run` (real2sim.pipeline): one real, small capture of the can, chained through the stages.

The capture has 60 views at 120x90 px: with fewer, the visual hull of the can does not
close (see tests/reconstruct/conftest.py). Reconstruction is the visual hull on a 64-voxel
grid with 4000 faces; the collision representation is `mesh` (no fitting) or `boxes:4`
with 20 iterations, so the suite stays in the default run. The ground-truth comparison of
the reconstruct stage costs ~20 s on 2 loaded cores, so only the first run keeps
ground_truth/; the other tests use a copy without it.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from real2sim.cli import main

# the hull, small; poses as given (refinement is the default where a dataset has poses to refine)
HULL = ["--backend", "hull", "--voxels", "64", "--max-faces", "4000", "--texture-px", "256"]
FAST = [*HULL, "--no-refine-poses"]


def _capture(out: Path) -> Path:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    capture(make_textured_object("can"), out,
            CaptureConfig(views=60, width=120, height=90, pose_noise_mm=0, pose_noise_deg=0))
    return out


@pytest.fixture(scope="module")
def can_ds(tmp_path_factory) -> Path:
    return _capture(tmp_path_factory.mktemp("pipeline") / "can_ds")


@pytest.fixture(scope="module")
def can_ds_no_truth(can_ds, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("pipeline_nogt") / "can_ds"
    shutil.copytree(can_ds, out, ignore=shutil.ignore_patterns("ground_truth"))
    return out


def run_cli(capsys, *args) -> tuple[int, str, str]:
    try:
        code = main(["run", *map(str, args)])
    except SystemExit as exc:  # argparse's own checks (the mass's type) exit from the parser
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def manifest(asset_dir: Path) -> dict:
    return json.loads((asset_dir / ".run" / "run.json").read_text())


@pytest.fixture(scope="module")
def first_run(can_ds, tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("pipeline_run") / "can_asset"
    code = main(["run", str(can_ds), "--mass-kg", "0.35", "--out", str(out), "--collision", "mesh", *FAST])
    assert code == 0
    return out, json.dumps(manifest(out), sort_keys=True)


def test_run_writes_a_drake_loadable_asset_manifest_and_truth(first_run, can_ds):
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    out, _ = first_run
    for name in ("asset_config.json", "physical_properties.json", "canonical_transform.json", "visual/model.obj",
                 "mesh/model.urdf", "mesh/collision.json", ".run/reconstruct/mesh.obj", ".run/reconstruct/report.json"):
        assert (out / name).is_file(), name
    plant = MultibodyPlant(0.0)
    models = Parser(plant).AddModels(str(out / "mesh" / "model.urdf"))
    plant.Finalize()
    assert len(models) == 1 and plant.num_bodies() >= 2
    body = [plant.get_body(i) for i in plant.GetBodyIndices(models[0])][0]
    assert body.default_mass() == pytest.approx(0.35)

    record = manifest(out)
    assert not Path(record["dataset"]).is_absolute()  # written files hold no absolute paths
    assert (out / record["dataset"]).resolve() == can_ds.resolve()
    assert list(record["stages"]) == ["reconstruct", "asset", "truth"]
    for stage in record["stages"].values():
        assert stage["wall_seconds"] > 0 and stage["peak_memory_mb"] > 50
        assert stage["outputs"] and len(stage["key"]) == 64
    dataset_digest = record["stages"]["reconstruct"]["inputs"]["dataset"]
    assert dataset_digest["files"] >= 121 and len(dataset_digest["sha256"]) == 64  # transforms + 60 images + 60 masks
    assert record["stages"]["reconstruct"]["settings"]["config"]["backend"] == "hull"
    assert record["stages"]["asset"]["settings"]["flat_bottom"] is True
    assert "mesh" in record["stages"]["asset"]["outputs"]

    truth = json.loads((out / "truth.json").read_text())
    rec, phys = truth["reconstruction"], truth["physical_properties"]
    assert rec["chamfer_mm"] < 2.0 and rec["iou"] > 0.9 and rec["fscore_1mm"] > 0.8
    assert truth["camera_poses"]["before_refinement"]["rot_max_deg"] < 1e-3  # a noise-free capture
    assert truth["camera_poses"]["after_refinement"] is None
    assert truth["masks_iou"]["mean"] == pytest.approx(1.0)
    assert abs(truth["frames"]["true_mesh_lowest_z_world_m"]) < 1e-6  # the can stands on the table
    assert 0 <= phys["com_error_mm"] < 3.0
    assert phys["inertia_eigenvalue_max_rel_error"] < 0.1
    assert phys["inertia_tensor_rel_frobenius_error"] < 0.1  # same axes: the frames agree
    assert math.isclose(phys["mass_kg"], 0.35)


def test_second_identical_run_skips_every_stage(first_run, can_ds, capsys):
    out, before = first_run
    code, stdout, _ = run_cli(capsys, can_ds, "--mass-kg", "0.35", "--out", out, "--collision", "mesh", *FAST)
    assert code == 0 and "none, all unchanged" in stdout
    assert json.dumps(manifest(out), sort_keys=True) == before  # nothing recorded again


def test_changing_collision_refits_without_reconstructing(first_run, can_ds, tmp_path):
    from real2sim.cli import build_parser
    from real2sim.cli.run import config_from_args
    from real2sim.pipeline.run import run_pipeline

    out = tmp_path / "can_asset"
    shutil.copytree(first_run[0], out)
    mesh_before = (out / ".run" / "reconstruct" / "mesh.obj").read_bytes()
    recon_before = manifest(out)["stages"]["reconstruct"]
    args = build_parser().parse_args(["run", str(can_ds), "--mass-kg", "0.35", "--out", str(out), *FAST,
                                      "--collision", "boxes:4", "--iterations", "20"])
    from tests.progress_check import Recorder

    progress = Recorder()
    result = run_pipeline(can_ds, out, config_from_args(args), progress=progress)
    assert result.statuses == {"reconstruct": "skipped", "asset": "ran", "truth": "ran"}
    events = progress.check()  # the fit's counted iterations, inside the asset stage
    assert ("[1/3] reconstruct: unchanged, skipped", 0, 0) in events and ("[2/3] asset: done", 0, 0) in events
    assert any(m.startswith("[2/3] asset - collision boxes:4: fit") and t > 0 for m, _, t in events)
    assert manifest(out)["stages"]["reconstruct"] == recon_before
    assert (out / ".run" / "reconstruct" / "mesh.obj").read_bytes() == mesh_before
    assert (out / "boxes_4" / "model.urdf").is_file() and not (out / "mesh").exists()
    assert manifest(out)["stages"]["asset"]["settings"]["specs"][0]["text"] == "boxes:4"


def _config(**asset_kw):
    from real2sim.asset.build import AssetConfig
    from real2sim.formats.spec import parse_spec
    from real2sim.pipeline.run import RunConfig
    from real2sim.reconstruct.stage import ReconstructConfig

    specs = tuple(parse_spec(s) for s in asset_kw.pop("specs", ("mesh",)))
    return RunConfig(asset=AssetConfig(mass_kg=0.35, specs=specs, **asset_kw),
                     reconstruct=ReconstructConfig(backend="hull", hull_voxels=64, max_faces=4000, texture_px=256))


def test_interrupted_run_resumes_without_redoing_finished_stages(can_ds_no_truth, tmp_path, monkeypatch):
    import real2sim.asset.build as asset_build
    from real2sim.pipeline.run import run_pipeline

    real_build = asset_build.build_asset
    calls = []

    def interrupted_once(*args, **kwargs):  # fault injection: Ctrl-C inside the asset stage, once
        calls.append(1)
        if len(calls) == 1:
            real_build(*args, **kwargs)  # even after the asset is built, before it is recorded
            raise KeyboardInterrupt
        return real_build(*args, **kwargs)

    monkeypatch.setattr(asset_build, "build_asset", interrupted_once)
    out = tmp_path / "can_asset"
    with pytest.raises(KeyboardInterrupt):
        run_pipeline(can_ds_no_truth, out, _config())
    record = manifest(out)
    assert list(record["stages"]) == ["reconstruct"]
    assert not (out / "mesh").exists() and not (out / "physical_properties.json").exists()
    (out / ".run" / ".asset.tmp-killed").mkdir()  # what a killed process leaves behind

    result = run_pipeline(can_ds_no_truth, out, _config())
    assert result.statuses == {"reconstruct": "skipped", "asset": "ran"}
    assert manifest(out)["stages"]["reconstruct"] == record["stages"]["reconstruct"]
    assert (out / "mesh" / "model.urdf").is_file() and not (out / ".run" / ".asset.tmp-killed").exists()
    assert len(calls) == 2


def test_failed_stage_is_named_and_finished_stages_kept(can_ds_no_truth, tmp_path, monkeypatch, capsys):
    import real2sim.asset.build as asset_build

    def broken(*args, **kwargs):
        raise RuntimeError("fitting exploded")

    monkeypatch.setattr(asset_build, "build_asset", broken)
    out = tmp_path / "can_asset"
    code, _, err = run_cli(capsys, can_ds_no_truth, "--mass-kg", "0.35", "--out", out, "--collision", "mesh", *FAST)
    assert code == 1
    assert "stage asset failed" in err and "fitting exploded" in err
    assert list(manifest(out)["stages"]) == ["reconstruct"]
    monkeypatch.undo()
    code, stdout, _ = run_cli(capsys, can_ds_no_truth, "--mass-kg", "0.35", "--out", out, "--collision", "mesh", *FAST)
    assert code == 0 and "stages run: asset" in stdout


def test_bad_input_exits_2_with_one_line_and_writes_nothing(can_ds_no_truth, tmp_path, capsys):
    no_masks = tmp_path / "no_masks"
    shutil.copytree(can_ds_no_truth, no_masks)
    data = json.loads((no_masks / "transforms.json").read_text())
    for frame in data["frames"]:
        frame.pop("mask_path", None)
    (no_masks / "transforms.json").write_text(json.dumps(data))
    other = tmp_path / "other_folder"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    ds = can_ds_no_truth
    cases = {
        "missing dataset": [tmp_path / "nope", "--mass-kg", "0.3"],
        "not a dataset": [other, "--mass-kg", "0.3"],
        "zero mass": [ds, "--mass-kg", "0"],
        "negative mass": [ds, "--mass-kg", "-1"],
        "nan mass": [ds, "--mass-kg", "nan"],
        "inf mass": [ds, "--mass-kg", "inf"],
        "unknown spec": [ds, "--mass-kg", "0.3", "--collision", "pyramids:3"],
        "no masks": [no_masks, "--mass-kg", "0.3"],
        "cuda without a GPU": [ds, "--mass-kg", "0.3", "--device", "cuda"],
    }
    import torch

    if torch.cuda.is_available():
        del cases["cuda without a GPU"]
    for label, args in cases.items():
        out = tmp_path / f"out_{label.replace(' ', '_')}"
        code, _, err = run_cli(capsys, *args, "--out", out, *FAST)
        assert code == 2, label
        assert len(err.strip().splitlines()) == 1, (label, err)
        assert not out.exists(), label
    code, _, err = run_cli(capsys, no_masks, "--mass-kg", "0.3", "--out", tmp_path / "x", *FAST)
    assert "real2sim mask" in err
    code, _, err = run_cli(capsys, ds, "--mass-kg", "0.3", "--out", ds / "asset_inside", *FAST)
    assert code == 2 and not (ds / "asset_inside").exists()
    code, _, err = run_cli(capsys, ds, "--mass-kg", "0.3", "--out", other, *FAST)
    assert code == 2 and "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in other.iterdir()) == ["keep.txt"]


def test_refine_poses_works_on_a_copy_and_leaves_the_dataset_alone(can_ds_no_truth, tmp_path, capsys):
    before = {p.relative_to(can_ds_no_truth): p.read_bytes() for p in can_ds_no_truth.rglob("*") if p.is_file()}
    out = tmp_path / "can_asset"
    # --no-silhouette-poses: when COLMAP refines too few of these small frames, aligning all 60 by their
    # silhouettes takes minutes; the copy is what this test is about
    code, stdout, _ = run_cli(capsys, can_ds_no_truth, "--mass-kg", "0.35", "--out", out, "--collision", "mesh",
                              "--refine-poses", "--no-silhouette-poses", *HULL)
    assert code == 0 and "stages run: refine_poses, reconstruct, asset" in stdout
    after = {p.relative_to(can_ds_no_truth): p.read_bytes() for p in can_ds_no_truth.rglob("*") if p.is_file()}
    assert after == before  # not one byte of the user's dataset written
    copy = out / ".run" / "dataset"
    assert (copy / "transforms.json").is_file() and (copy / "refine_report.json").is_file()
    record = manifest(out)["stages"]
    assert record["refine_poses"]["result"]["num_frames"] == 60
    # frames COLMAP could not refine keep the robot's poses: said, and kept in run.json for the summary
    result, said = record["refine_poses"]["result"], record["refine_poses"].get("warnings", [])
    kept = result["num_frames"] - result["num_refined_frames"]
    if not result["refined"]:
        assert [w for w in said if w.startswith("pose refinement kept the given poses:")], said
    elif kept:
        assert f"pose refinement kept the given poses of {kept} of 60 frames" in " ".join(said), said
    else:
        assert said == []
    assert record["reconstruct"]["inputs"]["dataset"]["files"] >= 121


def test_evaluate_after_the_asset_runs_only_the_evaluation(first_run, can_ds, tmp_path, capsys):
    from real2sim.formats.results import read_summary_csv

    out = tmp_path / "can_asset"
    shutil.copytree(first_run[0], out)
    code, stdout, _ = run_cli(capsys, can_ds, "--mass-kg", "0.35", "--out", out, "--collision", "mesh", *FAST,
                              "--evaluate", "--tasks", "push", "--contact", "point", "--runs", "1", "--jobs", "1",
                              "--duration-scale", "0.2")
    assert code == 0 and "stages run: evaluate, evaluate_truth, truth" in stdout
    rows = read_summary_csv(out / "results" / "summary.csv")
    assert [r["representation"] for r in rows] == ["mesh_point"]
    assert manifest(out)["stages"]["evaluate"]["outputs"] == ["results"]
    assert "jobs" not in manifest(out)["stages"]["evaluate"]["settings"]

    # The same sweep against the true can (true mesh, true mass properties): the reconstruction's
    # own error against the truth, beside its error against itself (the paper's protocol).
    assert manifest(out)["stages"]["evaluate_truth"]["outputs"] == ["results_truth"]
    truth_config = json.loads((out / "results_truth" / "config.json").read_text())
    assert truth_config["reference"]["file"] == "true_mesh_world.obj"
    assert truth_config["reference_properties"]["file"] == "true_physical_properties.json"
    # truth.json judges the asset's mass properties against the very ones the true reference simulated
    from real2sim.formats.physical import read_physical_properties

    reference = read_physical_properties(out / ".run" / "truth" / "true_physical_properties.json")
    judged = json.loads((out / "truth.json").read_text())["physical_properties"]
    assert judged["true_com_m"] == pytest.approx(list(reference.com_m), abs=1e-12)
    assert judged["true_inertia_eigenvalues_kg_m2"] == pytest.approx(np.linalg.eigvalsh(reference.inertia).tolist(),
                                                                     rel=1e-9)
    dynamics = json.loads((out / "truth.json").read_text())["dynamics"]
    (mesh_row,) = dynamics["reconstruction_vs_truth"]
    assert mesh_row["contact_model"] == "point"
    assert 0 < mesh_row["ocae_vs_truth_m"] < 0.5 and mesh_row["ocae_vs_reconstruction_m"] >= 0
    # The true can differs from its reconstruction: the true reference moves differently.
    assert mesh_row["ocae_vs_truth_m"] != pytest.approx(mesh_row["ocae_vs_reconstruction_m"], rel=1e-6)
    report = (out / "results" / "report.html").read_text()
    assert "Against the truth" in report and "OCAE [m] vs truth" in report
    assert report.count("class='pic'") == 2  # the visual mesh and the one representation
    assert "http://" not in report.replace("http://www.w3.org", "")  # self-contained


def test_assetdir_of_another_dataset_is_refused(can_ds_no_truth, tmp_path, capsys):
    out = tmp_path / "can_asset"
    (out / ".run").mkdir(parents=True)
    foreign = {"version": 1, "dataset": str(tmp_path / "another_dataset"), "stages": {}}
    (out / ".run" / "run.json").write_text(json.dumps(foreign))
    (out / ".real2sim").write_text("{}")  # made by real2sim
    code, _, err = run_cli(capsys, can_ds_no_truth, "--mass-kg", "0.35", "--out", out, *FAST)
    assert code == 2 and "another dataset" in err and len(err.strip().splitlines()) == 1
    assert json.loads((out / ".run" / "run.json").read_text()) == foreign
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [".real2sim", ".run", ".run/run.json"]


def test_tiny_field_run(can_ds_no_truth, tmp_path):
    """The radiance-field backend through run: a tiny field (16 s on 2 idle cores, about a minute when
    the cores are shared)."""
    from dataclasses import replace

    from real2sim.pipeline.run import run_pipeline
    from real2sim.reconstruct.field.train import FieldConfig

    config = _config()
    field = FieldConfig(coarse_voxels=24, fine_voxels=48, coarse_steps=40, fine_steps=80, rays_per_step=1024)
    config = replace(config, reconstruct=replace(config.reconstruct, backend="field", field=field))
    result = run_pipeline(can_ds_no_truth, tmp_path / "can_asset", config)
    assert result.statuses == {"reconstruct": "ran", "asset": "ran"}
    report = json.loads((tmp_path / "can_asset" / ".run" / "reconstruct" / "report.json").read_text())
    assert report["backend"] == "field" and report["field_grid"][2] == 48  # voxels along the can's height
    assert (tmp_path / "can_asset" / "mesh" / "model.urdf").is_file()


def test_missing_masks_are_made_with_mask_method_on_a_copy(can_ds_no_truth, tmp_path, capsys):
    no_masks = tmp_path / "no_masks"
    shutil.copytree(can_ds_no_truth, no_masks)
    data = json.loads((no_masks / "transforms.json").read_text())
    for frame in data["frames"]:
        frame.pop("mask_path", None)
    (no_masks / "transforms.json").write_text(json.dumps(data))
    before = (no_masks / "transforms.json").read_bytes()
    out = tmp_path / "can_asset"
    code, stdout, _ = run_cli(capsys, no_masks, "--mass-kg", "0.35", "--out", out, "--collision", "mesh", "--mask",
                              "provided", *FAST)
    assert code == 0 and "stages run: masks, reconstruct, asset" in stdout
    assert (no_masks / "transforms.json").read_bytes() == before
    masked = json.loads((out / ".run" / "masked" / "transforms.json").read_text())
    assert all(frame.get("mask_path") for frame in masked["frames"])
    assert manifest(out)["stages"]["masks"]["settings"]["method"] == "provided"


def test_surface_level_reaches_the_reconstruct_stage(can_ds_no_truth, tmp_path):
    """`run --surface-level` sets the reconstruct stage's setting (part of its recorded settings, so a
    change redoes the reconstruction); silhouettes by default."""
    from real2sim.cli import build_parser
    from real2sim.cli.run import config_from_args

    base = ["run", str(can_ds_no_truth), "--mass-kg", "0.35", "--out", str(tmp_path / "out")]
    default = config_from_args(build_parser().parse_args(base))
    chosen = config_from_args(build_parser().parse_args([*base, "--surface-level", "half-light"]))
    assert default.reconstruct.surface_level == "silhouettes"
    assert chosen.reconstruct.surface_level == "half-light"


def test_hollow_prior_reaches_the_reconstruct_stage(can_ds_no_truth, tmp_path):
    """`run --no-hollow-prior` turns photo carving's second pass off (on by default), and nothing else."""
    from real2sim.cli import build_parser
    from real2sim.cli.run import config_from_args

    base = ["run", str(can_ds_no_truth), "--mass-kg", "0.35", "--out", str(tmp_path / "out")]
    default = config_from_args(build_parser().parse_args(base))
    chosen = config_from_args(build_parser().parse_args([*base, "--no-hollow-prior"]))
    assert default.reconstruct.field.carving.hollow_prior and default.reconstruct.field.photo_carving
    assert not chosen.reconstruct.field.carving.hollow_prior and chosen.reconstruct.field.photo_carving
    assert chosen.reconstruct.field.carving.min_wall_voxels == default.reconstruct.field.carving.min_wall_voxels


def test_a_reconstruction_short_of_the_table_is_named_before_the_asset_is_built(tmp_path):
    """A reconstruction whose lowest point is above the table by more than the asset's flat-bottom
    tolerance (5 % of its height) gets run's own message, not asset's ``--support-height-m`` one."""
    import trimesh

    from real2sim.plumbing.errors import UserInputError
    from real2sim.pipeline.stages import check_reaches_table

    box = trimesh.creation.box((0.05, 0.05, 0.04))
    box.apply_translation([0.0, 0.0, 0.02 + 0.005])  # 40 mm tall, 5 mm above z = 0
    path = tmp_path / "mesh.obj"
    box.export(path)
    with pytest.raises(UserInputError, match=r"5\.0 mm above the table \(z = 0 m\).*--table-z-m"):
        check_reaches_table(path, 0.0)
    check_reaches_table(path, 0.0035)  # 1.5 mm short: within 2 mm, the flat bottom closes it
    check_reaches_table(path, 0.01)  # the table cuts the mesh
