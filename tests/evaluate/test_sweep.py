"""The evaluation sweep end to end on a tiny box asset with real Drake simulations.

Scenes are shortened (a 0.3 s push) so the whole file stays fast; the pusher starts
close enough to touch the box within that time.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from real2sim.asset.export.writers import write_representation
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.plumbing.errors import UserInputError
from real2sim.evaluate.discovery import discover_representations, place_reference_mesh
from real2sim.evaluate.scoring import score
from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.formats.results import CHECK_COLUMN, RUN_COLUMNS, read_runs_csv
from real2sim.formats.trajectory import load_trajectory, save_trajectory
from real2sim.formats.physical import PhysicalProperties, write_physical_properties
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import run_duration_s
from tests.progress_check import Recorder

BOX_EXTENTS_M = np.array([0.04, 0.05, 0.08])
SHORT_SCENE = SceneConfig(settle_s=0.05, push_duration_s=0.25, pusher_start_distance_m=0.11,
                          pusher_speed_m_per_s=0.3, hold_s=0.05, tilt_time_s=0.3, total_duration_s=0.4)


def _rotation_about(axis, angle_rad: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle_rad, axis)


def make_box_asset(root: Path, reps=("boxes_1", "boxes_1_x1p2", "mesh"), broken: bool = False,
                   transform: np.ndarray | None = None) -> Path:
    """A 0.3 kg box asset: visual mesh, physical properties, and the named representations.

    boxes_1: one box of the right size; boxes_1_x1p2: the box scaled by 1.2 (a wrong asset);
    mesh: the visual mesh itself (rigid hydroelastic), i.e. the reference; broken: a corrupt URDF.
    ``transform`` is written as canonical_transform.json (T_asset_from_input).
    """
    root.mkdir(parents=True)
    mass = 0.3
    e = BOX_EXTENTS_M
    box = trimesh.creation.box(extents=e)
    (root / "visual").mkdir()
    box.export(root / "visual" / "model.obj", include_normals=True)
    inertia = mass / 12 * np.diag([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2, e[0] ** 2 + e[1] ** 2])
    props = PhysicalProperties(mass, (0.0, 0.0, 0.0), tuple(map(tuple, inertia)))
    write_physical_properties(props, root / "physical_properties.json")
    t = np.eye(4) if transform is None else transform
    (root / "canonical_transform.json").write_text(json.dumps({"T_asset_from_input": t.tolist()}))
    contact = ContactProperties()
    for name in reps:
        rep = root / name
        if name == "mesh":
            rep.mkdir()
            box.export(rep / "mesh.obj", include_normals=True)
            shapes = (CollisionShape("mesh", (), mesh_file="mesh.obj"),)
        else:
            scale = 1.2 if name.endswith("x1p2") else 1.0
            shapes = (CollisionShape("box", tuple(float(v) for v in e * scale)),)
        write_representation(rep, CollisionGeometry(name, name, shapes), props, contact)
    if broken:
        (root / "broken").mkdir()
        (root / "broken" / "model.urdf").write_text("<robot name='x'><link name='a'><collision><geometry>")
    return root


@pytest.fixture(scope="module")
def asset(tmp_path_factory) -> Path:
    return make_box_asset(tmp_path_factory.mktemp("assets") / "box", broken=True)


@pytest.fixture(scope="module")
def sweep_progress() -> Recorder:
    return Recorder()


@pytest.fixture(scope="module")
def sweep(asset, tmp_path_factory, sweep_progress):
    out = tmp_path_factory.mktemp("results") / "res"
    config = EvaluationConfig(tasks=("push",), runs=1, jobs=1, scene=SHORT_SCENE)
    result = evaluate([asset], out, config, progress=sweep_progress)
    return out, config, result


def test_sweep_reports_progress(sweep, sweep_progress):
    events = sweep_progress.check()
    counted = [e for e in events if e[2] > 0]
    assert counted[-1][1] == counted[-1][2]  # every reference and candidate simulation counted
    assert any("simulations to run" in message for message, _, total in events if total == 0)


def _by_key(rows):
    return {(r["representation"], r["contact_model"], r["task"], r["run"]): r for r in rows}


# ------------------------------------------------------------------------------------------
# Inputs


def test_discovery_and_bad_assets(tmp_path, asset):
    reps = discover_representations([asset])
    assert [r.name for r in reps] == ["boxes_1", "boxes_1_x1p2", "broken", "mesh"]
    assert all(r.object == "box" and r.urdf_path.name == "model.urdf" for r in reps)
    with pytest.raises(UserInputError, match="not found"):
        discover_representations([tmp_path / "nope"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserInputError, match="physical_properties.json"):
        discover_representations([tmp_path / "empty"])
    (tmp_path / "empty" / "physical_properties.json").write_text("{}")
    with pytest.raises(UserInputError, match="no representation"):
        discover_representations([tmp_path / "empty"])


def test_config_validation():
    with pytest.raises(UserInputError):
        EvaluationConfig(tasks=("jump",))
    with pytest.raises(UserInputError):
        EvaluationConfig(contact_models=("soft",))
    with pytest.raises(UserInputError):
        EvaluationConfig(runs=0)
    with pytest.raises(UserInputError):
        EvaluationConfig(executor="slurm")


def test_place_reference_mesh_applies_canonical_transform(tmp_path):
    t = _rotation_about([0, 1, 1], 0.7)
    t[:3, 3] = [0.1, -0.2, 0.05]
    asset = make_box_asset(tmp_path / "a", reps=("boxes_1",), transform=t)
    # The user's reference is in the input frame: the asset's box moved back by T^-1.
    ref = trimesh.creation.box(extents=BOX_EXTENTS_M)
    ref.apply_transform(np.linalg.inv(t))
    ref.export(tmp_path / "ref_input_frame.obj")
    out = place_reference_mesh(tmp_path / "ref_input_frame.obj", asset, tmp_path / "placed.obj")
    placed = trimesh.load(out, process=False)
    assert np.allclose(np.sort(placed.vertices, axis=0), np.sort(trimesh.creation.box(extents=BOX_EXTENTS_M).vertices, axis=0),
                       atol=1e-6)
    assert placed.vertex_normals.shape == placed.vertices.shape


# ------------------------------------------------------------------------------------------
# Scoring on hand-made trajectories


def _traj(pos, quat, contacts, dt=0.001, sim_time_s=0.5):
    from real2sim.formats.trajectory import Trajectory

    n = len(pos)
    return Trajectory(
        times_s=np.arange(n) * dt, object_position_m=np.asarray(pos, float), object_quaternion_wxyz=np.asarray(quat, float),
        object_spatial_velocity=np.zeros((n, 6)), actuated_positions=np.zeros((n, 2)), actuated_velocities=np.zeros((n, 2)),
        contact_points_object_m=contacts, sim_time_s=sim_time_s, sim_duration_s=(n - 1) * dt, instrumented_time_s=1.0,
        reset_steps=np.array([], dtype=int), task="push", contact_model="point", representation="x", run=0,
    )


def test_score_and_trajectory_cache_round_trip(tmp_path):
    n = 11
    pos = np.column_stack([np.linspace(0, 0.01, n), np.zeros(n), np.full(n, 0.03)])
    quat = np.tile([1.0, 0, 0, 0], (n, 1))
    contacts = [np.zeros((0, 3))] + [np.array([[0.0, 0.0, -0.02 - 0.001 * i]]) for i in range(1, n)]
    ref = _traj(pos, quat, contacts)
    cand = _traj(pos + [0.0, 0.002, 0.0], quat, contacts, sim_time_s=0.25)
    s = score(ref, cand)
    assert s["ate_m"] == pytest.approx(0.002) and s["ocae_m"] == pytest.approx(0.002)
    assert s["cpd_m_per_s"] == pytest.approx(1.0)  # 1 mm per 1 ms step
    assert s["real_time_factor"] == pytest.approx(0.01 / 0.25)
    # A candidate sampled every 2 ms (with q -> -q sign flips) is interpolated onto the reference's steps.
    half = _traj(pos[::2] + [0.0, 0.002, 0.0], quat[::2] * np.where(np.arange(6) % 2, -1.0, 1.0)[:, None],
                 contacts[::2], dt=0.002)
    s2 = score(ref, half)
    assert s2["ate_m"] == pytest.approx(0.002) and s2["ocae_m"] == pytest.approx(0.002)
    save_trajectory(ref, tmp_path / "t.npz")
    back = load_trajectory(tmp_path / "t.npz")
    assert back.task == "push" and back.run == 0 and isinstance(back.sim_time_s, float)
    assert np.array_equal(back.object_position_m, ref.object_position_m)
    assert [len(c) for c in back.contact_points_object_m] == [len(c) for c in contacts]
    assert np.allclose(np.concatenate(back.contact_points_object_m), np.concatenate(contacts[1:]))


# ------------------------------------------------------------------------------------------
# The sweep


def test_sweep_writes_rows_summary_plots_report(sweep):
    out, config, result = sweep
    assert result.out_dir == out.resolve()
    assert not out.with_name(f".{out.name}.partial").exists()  # published whole
    with open(out / "runs.csv", newline="") as fh:
        assert tuple(next(csv.reader(fh))) == RUN_COLUMNS + (CHECK_COLUMN,)
    rows = read_runs_csv(out / "runs.csv")
    assert len(rows) == 4 * 2  # 4 representations x 2 contact models x 1 task x 1 run
    assert result.simulated == 8 and result.skipped == 0
    by = _by_key(rows)
    for key, r in by.items():
        if key[0] == "broken":
            assert r["error"] and math.isnan(r["ate_m"])
        else:
            assert not r["error"], r["error"]
            assert r["sim_duration_s"] == pytest.approx(run_duration_s("push", SHORT_SCENE))
            assert r["sim_time_s"] > 0 and r["real_time_factor"] > 0
            assert all(math.isfinite(r[c]) for c in ("ate_m", "ocae_m"))
    summary = {s["representation"]: s for s in result.summary}
    assert summary["broken_point"]["runs_failed"] == 1 and summary["broken_point"]["runs_ok"] == 0
    assert summary["boxes_1_point"]["runs_ok"] == 1
    for name in ("summary.csv", "report.html", "config.json", "pareto_ocae_vs_time.png", "pareto_ate_vs_time.png",
                 "pareto_cpd_vs_ocae.png", "pareto_cpd_vs_time.png"):
        assert (out / name).is_file(), name
    html = (out / "report.html").read_text()
    assert "mesh_hydroelastic" in html and "data:image/png;base64" in html
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["scene"]["push_duration_s"] == SHORT_SCENE.push_duration_s and cfg["seed"] == 0


def test_reference_against_itself_scores_zero(sweep):
    by = _by_key(read_runs_csv(sweep[0] / "runs.csv"))
    r = by[("mesh", "hydroelastic", "push", 0)]
    # The reference mesh as a representation with the reference's contact model is the reference.
    assert r["ate_m"] < 1e-6 and r["ocae_m"] < 1e-6
    # The candidate really touched something, so the zero is not vacuous.
    assert math.isfinite(r["cpd_m_per_s"])


def test_scaled_asset_scores_clearly_worse(sweep):
    by = _by_key(read_runs_csv(sweep[0] / "runs.csv"))
    for cm in ("point", "hydroelastic"):
        right = by[("boxes_1", cm, "push", 0)]
        wrong = by[("boxes_1_x1p2", cm, "push", 0)]
        # Measured margins across seeds 0-2 were 10-70x in ATE and 2-15x in OCAE; point rows simulate the
        # point model (model_point.urdf, 20 s/m), whose damping narrows the ATE margin (seed 0: 4.8x).
        assert wrong["ate_m"] > (3 if cm == "point" else 5) * right["ate_m"], (cm, right, wrong)
        assert wrong["ocae_m"] > 2 * right["ocae_m"], (cm, right, wrong)


def test_resume_skips_done_rows_and_retries_failures(sweep):
    out, config, first = sweep
    cache = sorted((out / "reference_cache").glob("*.npz"))
    assert len(cache) == 1
    mtime = cache[0].stat().st_mtime_ns
    before = _by_key(read_runs_csv(out / "runs.csv"))
    # Resume with the same settings: only the two failed rows are simulated again.
    recorded = json.loads((out / "config.json").read_text())["assets"]["box"]
    assert not Path(recorded).is_absolute()  # config.json does not tell where the user's files live
    asset_dir = out / recorded
    result = evaluate([asset_dir], out, config)
    assert result.skipped == 6 and result.simulated == 2
    assert cache[0].stat().st_mtime_ns == mtime  # the reference came from the cache
    after = _by_key(result.runs)
    for key, r in before.items():
        if not r["error"]:
            assert after[key] == r  # kept exactly, timings included
    # Settings that change what a row means must match.
    with pytest.raises(UserInputError, match="seed"):
        evaluate([asset_dir], out, dataclasses.replace(config, seed=1))
    with pytest.raises(UserInputError, match="scene"):
        evaluate([asset_dir], out, dataclasses.replace(config, scene=dataclasses.replace(SHORT_SCENE, floor_mu=0.3)))


def test_output_that_is_not_a_results_folder_is_refused(asset, tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "something.txt").write_text("mine")
    with pytest.raises(UserInputError, match="real2sim did not make"):
        evaluate([asset], tmp_path / "out", EvaluationConfig(tasks=("push",), runs=1, jobs=1, scene=SHORT_SCENE))
    assert (tmp_path / "out" / "something.txt").read_text() == "mine"


def test_ray_executor_gives_the_same_rows(asset, sweep, tmp_path):
    ray = pytest.importorskip("ray")
    out = tmp_path / "ray_res"
    config = EvaluationConfig(tasks=("push",), contact_models=("point",), runs=1, jobs=1, executor="ray",
                              scene=SHORT_SCENE)
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        result = evaluate([asset], out, config)
    finally:
        ray.shutdown()
    local = _by_key(read_runs_csv(sweep[0] / "runs.csv"))
    rows = _by_key(result.runs)
    assert len(rows) == 4
    for key, r in rows.items():
        ref = local[key]
        assert bool(r["error"]) == bool(ref["error"])
        for col in ("ate_m", "ocae_m", "cpd_m_per_s", "sim_duration_s"):
            assert r[col] == ref[col] or (math.isnan(r[col]) and math.isnan(ref[col])), (key, col)


# ------------------------------------------------------------------------------------------
# Command line


def _cli(*args: str) -> tuple[int, str]:
    """Run the real command line in this process: (exit status, stderr)."""
    import contextlib
    import io

    from real2sim.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:  # a bad option value is refused by the parser itself
            code = exc.code
    return code, err.getvalue()


def test_module_entry_point_help():
    proc = subprocess.run([sys.executable, "-m", "real2sim", "evaluate", "--help"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0
    for flag in ("--reference", "--tasks", "--contact", "--runs", "--jobs", "--executor", "--ray-address", "--seed",
                 "--simulation-error", "--recommend", "--overwrite", "--duration-scale"):
        assert flag in proc.stdout


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--tasks", "jump"], "unknown task"),
        (["--contact", "soft"], "unknown contact model"),
        (["--runs", "0"], "--runs"),
        (["--reference", "REF_TXT"], "not a mesh"),
        (["--reference", "MISSING"], "not found"),
        (["NOURDF"], "no representation"),
    ],
)
def test_cli_bad_input_exits_2_with_one_line(asset, tmp_path, extra, needle):
    (tmp_path / "ref.txt").write_text("not a mesh")
    (tmp_path / "nourdf").mkdir()
    (tmp_path / "nourdf" / "physical_properties.json").write_text("{}")
    subst = {"REF_TXT": str(tmp_path / "ref.txt"), "MISSING": str(tmp_path / "missing.obj"),
             "NOURDF": str(tmp_path / "nourdf")}
    extra = [subst.get(a, a) for a in extra]
    assets = [str(asset)] if "NOURDF" not in extra and str(tmp_path / "nourdf") not in extra else []
    code, err = _cli("evaluate", *assets, *extra, "--out", str(tmp_path / "res"))
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], lines
    assert not (tmp_path / "res").exists()


def test_cli_evaluate_with_reference_and_simulation_error_then_report(tmp_path):
    t = _rotation_about([1, 0, 0], 0.4)
    t[:3, 3] = [0.0, 0.03, -0.01]
    asset = make_box_asset(tmp_path / "boxy", reps=("mesh",), transform=t)
    ref = trimesh.creation.box(extents=BOX_EXTENTS_M)
    ref.apply_transform(np.linalg.inv(t))
    ref.export(tmp_path / "scan.obj")
    out = tmp_path / "res"
    code, err = _cli("evaluate", str(asset), "--reference", str(tmp_path / "scan.obj"), "--out", str(out),
                     "--tasks", "push", "--contact", "hydroelastic", "--runs", "1", "--jobs", "1",
                     "--duration-scale", "0.1", "--simulation-error", "--recommend", "accuracy")
    assert code == 0, err
    rows = read_runs_csv(out / "runs.csv")
    assert len(rows) == 1 and not rows[0]["error"]
    # The placed reference is the asset's own box up to float rounding of the .obj text.
    assert rows[0]["ate_m"] < 1e-4
    assert (out / "reference_meshes" / "boxy.obj").is_file()
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["simulation_error"] and cfg["scene"]["reset_interval_s"] is None
    assert cfg["protocol"].startswith("simulation error")
    assert cfg["scene"]["push_duration_s"] == pytest.approx(SceneConfig().push_duration_s * 0.1)
    (out / "report.html").unlink()
    code, err = _cli("report", str(out))
    assert code == 0, err
    assert (out / "report.html").is_file()
    code, err = _cli("report", str(tmp_path / "nothing"))
    assert code == 2 and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_process_pool_and_serial_give_identical_rows_on_both_tasks(tmp_path):
    asset = make_box_asset(tmp_path / "box", reps=("boxes_1", "mesh"))
    rows = {}
    for jobs in (1, 2):
        config = EvaluationConfig(tasks=("push", "ramp"), runs=2, jobs=jobs, scene=SHORT_SCENE)
        rows[jobs] = _by_key(evaluate([asset], tmp_path / f"res{jobs}", config).runs)
    assert len(rows[1]) == 2 * 2 * 2 * 2
    for key, r in rows[1].items():
        assert not r["error"], r["error"]
        for col in ("ate_m", "ocae_m", "cpd_m_per_s", "sim_duration_s"):
            assert rows[2][key][col] == r[col] or (math.isnan(r[col]) and math.isnan(rows[2][key][col])), (key, col)
        if key[:2] == ("mesh", "hydroelastic"):
            assert r["ate_m"] < 1e-6 and r["ocae_m"] < 1e-6


def test_pool_survives_a_worker_dying_in_native_code():
    """os._exit kills its worker outright, as a crash in Drake's C++ would; stdlib functions
    keep the spawned workers from importing this test module."""
    import os as _os

    from real2sim.evaluate.executors import PoolExecutor, Retry

    executor = PoolExecutor(2)
    jobs = [(math.sqrt, 4.0), (_os._exit, 13), (math.sqrt, 9.0), (math.sqrt, 16.0)]
    pending = {executor.submit(fn, arg): i for i, (fn, arg) in enumerate(jobs)}
    results = {}
    try:
        while pending:
            for h in executor.wait(set(pending)):
                i = pending.pop(h)
                out = executor.result(h)
                if isinstance(out, Retry):
                    pending[executor.submit(out.fn, out.arg, out.attempt)] = i
                else:
                    results[i] = out
    finally:
        executor.shutdown()
    assert results[0] == 2.0 and results[2] == 3.0 and results[3] == 4.0
    assert "died" in results[1]["error"]


@pytest.mark.slow
def test_bundled_can_full_scenes_right_primitive_beats_wrong_one(tmp_path):
    """Default scenes (1.5 s push, 2 s ramp) on the bundled soup can: an exact cylinder
    tracks the reference far better than the can's bounding box, for both contact models."""
    from real2sim.asset.canonical import canonicalize
    from real2sim.geometry.objects import make_object

    root = tmp_path / "can"
    (root / "visual").mkdir(parents=True)
    mesh = make_object("can")
    solid, t = canonicalize(trimesh.Trimesh(mesh.vertices, mesh.faces))
    solid.export(root / "visual" / "model.obj", include_normals=True)
    (root / "canonical_transform.json").write_text(json.dumps({"T_asset_from_input": t.tolist()}))
    body = solid.copy()
    body.density = 0.35 / solid.volume
    props = PhysicalProperties(0.35, tuple(map(float, body.center_mass)), tuple(map(tuple, body.moment_inertia)))
    write_physical_properties(props, root / "physical_properties.json")
    centre = tuple(float(v) for v in solid.bounds.mean(axis=0))
    radius, height = float(solid.extents[:2].max() / 2), float(solid.extents[2])
    reps = {"cylinders_1": (CollisionShape("cylinder", (radius, height), centre),),
            "boxes_1": (CollisionShape("box", tuple(float(v) for v in solid.extents), centre),)}
    for name, shapes in reps.items():
        write_representation(root / name, CollisionGeometry(name, name, shapes), props, ContactProperties())
    result = evaluate([root], tmp_path / "res", EvaluationConfig(runs=1, jobs=2))
    summary = {r["representation"]: r for r in result.summary}
    assert result.failed == 0
    for cm in ("point", "hydroelastic"):
        assert summary[f"cylinders_1_{cm}"]["ocae_m"] < 0.5 * summary[f"boxes_1_{cm}"]["ocae_m"]
        assert summary[f"cylinders_1_{cm}"]["ate_m"] < 0.5 * summary[f"boxes_1_{cm}"]["ate_m"]


def test_reference_uses_the_assets_own_contact_properties(tmp_path):
    # An asset built with non-default friction: its own mesh representation must still be the
    # reference (the reference takes the asset's contact material from asset_config.json).
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec

    mesh_path = tmp_path / "box.obj"
    trimesh.creation.box(extents=BOX_EXTENTS_M).export(mesh_path, include_normals=True)
    contact = ContactProperties(mu_static=0.9, mu_dynamic=0.9)
    asset_dir = tmp_path / "box"
    build_asset(mesh_path, asset_dir, AssetConfig(mass_kg=0.3, specs=(parse_spec("mesh"),), contact=contact))
    recorded = json.loads((asset_dir / "asset_config.json").read_text())
    assert recorded["contact"]["mu_static"] == 0.9 and recorded["collision"] == ["mesh"]

    config = EvaluationConfig(tasks=("push",), contact_models=("hydroelastic",), runs=1, jobs=1, scene=SHORT_SCENE)
    result = evaluate([asset_dir], tmp_path / "res", config)
    (row,) = [r for r in result.runs if r["representation"] == "mesh"]
    assert not row["error"]
    assert row["ate_m"] < 1e-6 and row["ocae_m"] < 1e-6
    saved = json.loads((tmp_path / "res" / "config.json").read_text())
    assert saved["reference_contact"]["box"]["mu_dynamic"] == 0.9
