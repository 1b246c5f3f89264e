"""`real2sim batch` (issue 31): objects in parallel on a local process pool, isolation, resume, masses, the
catalogue, and bad input refused before anything is written.

Tiny captures (8 views at 64x48) through a visual hull on a 48-voxel grid and `spheres:4` fitted for 30
iterations: one object takes tens of seconds on two loaded cores. The Ray, three-object and
kill-and-resume tests are in test_batch_ray.py and test_batch_resume.py.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli_helpers import run_cli

FAST = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64", "--max-image-px", "64",
        "--iterations", "30", "--no-refine-poses", "--collision", "spheres:4"]


def capture(out: Path, name: str = "can") -> Path:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture as capture_views
    from real2sim.geometry.objects import make_textured_object

    capture_views(make_textured_object(name), out, CaptureConfig(views=8, width=64, height=48))
    return out


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("batch_ds")
    return {name: capture(root / f"{name}_ds", name) for name in ("can", "mug")}


def catalogue_rows(out: Path) -> dict[str, dict]:
    import csv

    with open(out / "catalogue.csv", newline="") as f:
        return {row["name"]: row for row in csv.DictReader(f)}


def run_json(asset_dir: Path) -> dict:
    return json.loads((asset_dir / ".run" / "run.json").read_text())


def test_one_object_done_one_without_mass_failed_and_a_rerun_skips_the_done(capsys, datasets, tmp_path):
    can, mug = datasets["can"], datasets["mug"]
    (can / "mass.json").write_text(json.dumps({"mass_kg": 0.35}))  # the mug has none: failed, not guessed
    out = tmp_path / "catalogue"
    try:
        _done_and_failed_then_skipped(capsys, can, mug, out)
    finally:
        (can / "mass.json").unlink()


def _done_and_failed_then_skipped(capsys, can: Path, mug: Path, out: Path) -> None:
    code, stdout, _err = run_cli(capsys, "batch", can, mug, "--mass-from", "mass.json", "--out", out, *FAST)
    assert code == 1, stdout  # an object failed; the other one is done all the same
    assert "can_ds: done (ran reconstruct, asset, truth)" in stdout
    assert "mug_ds: FAILED: no mass: the dataset has no mass.json" in stdout
    rows = catalogue_rows(out)
    assert list(rows) == ["can_ds", "mug_ds"]
    can_row = rows["can_ds"]
    assert can_row["status"] == "done" and float(can_row["mass_kg"]) == 0.35
    assert can_row["accuracy_representation"] == can_row["speed_representation"] == "spheres_4"
    assert can_row["basis"] == "fit" and 0 < float(can_row["accuracy_iou"]) <= 1
    sizes = [float(can_row[f"size_{a}_m"]) for a in "xyz"]
    assert 0.05 < sizes[0] < 0.1 and 0.08 < sizes[2] < 0.13  # the can: r 0.034 m, h 0.10 m
    assert float(can_row["truth_chamfer_mm"]) > 0 and can_row["report"] == "can_ds/truth.json"
    assert rows["mug_ds"]["status"] == "failed" and "no mass" in rows["mug_ds"]["reason"]
    assert not (out / "mug_ds").exists()
    page = (out / "index.html").read_text()
    assert "data:image/jpeg;base64," in page and "no mass" in page and 'href="can_ds/truth.json"' in page
    assert "http://" not in page and "https://" not in page  # self-contained
    assert (out / "can_ds" / "spheres_4" / "model.urdf").is_file()
    timings = (out / "timings.csv").read_text().splitlines()
    assert timings[0] == "name,stage,wall_s" and any(t.startswith("can_ds,reconstruct,") for t in timings)
    before = run_json(out / "can_ds")
    csv_before = (out / "catalogue.csv").read_bytes()

    # The same command again: the can is not run again (no worker, no stage), the mug fails again.
    code, stdout, _err = run_cli(capsys, "batch", can, mug, "--mass-from", "mass.json", "--out", out, *FAST)
    assert code == 1, stdout
    assert "can_ds: finished before, skipped" in stdout
    assert run_json(out / "can_ds") == before  # nothing redone, nothing rewritten
    assert (out / "catalogue.csv").read_bytes() == csv_before


def _one_line_exit_2(capsys, *argv) -> str:
    code, stdout, err = run_cli(capsys, *argv)
    assert code == 2, (stdout, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_an_object_split_into_tasks_pauses_before_each_tasks_stages_and_ends_as_one_run(datasets, tmp_path):
    """The tasks a batch makes of an object that asks for a GPU (on Ray with GPUs: test_batch_ray.py),
    run here one after the other in this process: each stops before the next one's first stage, the
    next skips what the one before recorded, and the last finishes the run."""
    from dataclasses import replace

    from real2sim.cli import build_parser
    from real2sim.cli.batch import plan
    from real2sim.pipeline.batch import PHASES, run_object

    out = tmp_path / "cat"
    args = build_parser().parse_args(["batch", str(datasets["can"]), "--mass-kg", "0.35", "--out", str(out), *FAST])
    (job,), out, _ = plan(args)
    (out / ".batch").mkdir(parents=True)
    outcomes = [run_object(replace(job, phase=phase, gpu=phase == "gpu")) for phase in PHASES]
    assert [(o["status"], o["ran"]) for o in outcomes] == [("paused", []), ("paused", ["reconstruct", "asset"]),
                                                           ("done", ["truth"])]
    assert set(run_json(job.asset_dir)["stages"]) == {"reconstruct", "asset", "truth"}
    assert run_object(job)["ran"] == []  # one task of the whole run now: everything is current
    log = job.log.read_text().splitlines()
    assert [line for line in log if line.startswith("paused before")] == ["paused before reconstruct",
                                                                          "paused before truth"]
    assert "gpu stages, with a CPU" in log  # asked for a GPU, and no Ray here to give one


def test_bad_input_is_one_line_exit_2_and_nothing_written(capsys, datasets, tmp_path):
    can = datasets["can"]
    out = tmp_path / "cat"
    not_ds = tmp_path / "photos_of_nothing"
    not_ds.mkdir()
    (not_ds / "notes.txt").write_text("not a dataset")
    assert "photos_of_nothing" in _one_line_exit_2(capsys, "batch", can, not_ds, "--mass-kg", "1", "--out", out, *FAST)
    twin = tmp_path / "elsewhere" / "can_ds"
    shutil.copytree(can, twin)
    assert "both named 'can_ds'" in _one_line_exit_2(capsys, "batch", can, twin, "--mass-kg", "1", "--out", out)
    for text, expected in (("name,mass_kg\ncan_ds,\n", "can_ds has no mass"),
                           ("name,mass_kg\ncan_ds,-0.2\n", "must be a number > 0"),
                           ("name,mass_kg\ncan_ds,0\n", "must be a number > 0"),
                           ("name\ncan_ds\n", "needs the columns name,mass_kg")):
        masses = tmp_path / "masses.csv"
        masses.write_text(text)
        assert expected in _one_line_exit_2(capsys, "batch", can, "--masses", masses, "--out", out, *FAST)
    assert "--ray-address is for --executor ray" in _one_line_exit_2(
        capsys, "batch", can, "--mass-kg", "1", "--out", out, "--ray-address", "127.0.0.1:1")
    # nothing listens on port 1 of the loopback: refused at once, well within the 30 s bound
    line = _one_line_exit_2(capsys, "batch", can, "--mass-kg", "1", "--out", out, "--executor", "ray",
                            "--ray-address", "127.0.0.1:1", *FAST)
    assert "could not reach the Ray cluster at 127.0.0.1:1" in line
    asset = tmp_path / "an_asset"
    asset.mkdir()
    (asset / ".real2sim").write_text(json.dumps({"made_by": "real2sim run"}))
    assert "not a batch's" in _one_line_exit_2(capsys, "batch", can, "--mass-kg", "1", "--out", asset, *FAST)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["an_asset", "elsewhere", "masses.csv", "photos_of_nothing"]


def test_a_second_batch_on_the_same_catalogue_is_refused(capsys, datasets, tmp_path):
    out = tmp_path / "cat"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom real2sim.plumbing.outputs import output_lock\n"
         f"with output_lock({str(out)!r}):\n    print('held', flush=True)\n    time.sleep(120)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        line = _one_line_exit_2(capsys, "batch", datasets["can"], "--mass-kg", "1", "--out", out, *FAST)
        assert "another real2sim process is writing" in line
    finally:
        holder.kill()
        holder.wait()
    assert not out.exists()


def evaluated_asset(asset: Path) -> Path:
    """An asset folder with what the catalogue reads of an evaluated asset, summary.csv in its own layout."""
    from real2sim.formats.results import SUMMARY_COLUMNS, write_csv_atomic

    (asset / "visual").mkdir(parents=True)
    (asset / "visual" / "model.obj").write_text("v 0 0 0\nv 0.07 0.068 0.1\nv 0.01 0.02 0.03\n")
    (asset / "physical_properties.json").write_text(json.dumps({"mass_kg": 0.35}))
    fits = {"spheres_64": 0.95, "cylinders_1": 0.97, "boxes_4": 0.8}
    for name, iou in fits.items():
        (asset / name).mkdir()
        (asset / name / "fit_report.json").write_text(json.dumps({"iou": iou, "num_primitives": 4}))
    (asset / "results").mkdir()
    (asset / "results" / "report.html").write_text("<html></html>")
    summary = [  # accuracy: cylinders (OCAE within x1.1 of the best, faster); speed: boxes
        {"representation": "spheres_64_point", "collision": "spheres_64", "contact_model": "point",
         "ocae_m": 0.0100, "ate_m": 0.001, "sim_time_s": 2.0, "cpd_m_per_s": 0.1},
        {"representation": "cylinders_1_point", "collision": "cylinders_1", "contact_model": "point",
         "ocae_m": 0.0105, "ate_m": 0.001, "sim_time_s": 0.5, "cpd_m_per_s": 0.1},
        {"representation": "boxes_4_point", "collision": "boxes_4", "contact_model": "point",
         "ocae_m": 0.0301234567, "ate_m": 0.003, "sim_time_s": 0.2, "cpd_m_per_s": 0.1},
        {"representation": "boxes_4_hydroelastic", "collision": "boxes_4", "contact_model": "hydroelastic",
         "ocae_m": "", "ate_m": "", "sim_time_s": "", "cpd_m_per_s": ""},
    ]
    write_csv_atomic(asset / "results" / "summary.csv", summary, SUMMARY_COLUMNS)
    return asset


def test_the_catalogue_row_of_an_evaluated_asset_takes_the_reports_recommendations(tmp_path):
    """The evaluation's summary.csv decides the recommendations; a representation whose runs all failed
    (empty OCAE) is passed over, and numbers keep 6 digits."""
    from real2sim.pipeline.catalogue import object_row

    asset = evaluated_asset(tmp_path / "can_ds")
    row = object_row("can_ds", asset, {"status": "done", "reason": ""})
    assert row["basis"] == "evaluation" and row["report"] == "can_ds/results/report.html"
    assert (row["accuracy_representation"], row["accuracy_ocae_m"], row["accuracy_sim_time_s"]) == (
        "cylinders_1_point", "0.0105", "0.5")
    assert (row["speed_representation"], row["speed_ocae_m"], row["speed_iou"]) == ("boxes_4_point", "0.0301235", "0.8")
    assert row["accuracy_iou"] == "0.97" and row["mass_kg"] == "0.35"
    assert (row["size_x_m"], row["size_y_m"], row["size_z_m"]) == ("0.07", "0.068", "0.1")
    assert row["representations"] == "boxes_4;cylinders_1;spheres_64"


def test_the_catalogue_page_opens_offline_in_a_browser(datasets, tmp_path):
    """index.html in headless chromium: both pictures load (one of a failed object), and no request
    leaves the machine."""
    from tests.report.test_browser import CHROMIUM, _open, _remote

    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (make test installs Debian's chromium where apt-get runs as root)")
    from real2sim.pipeline.batch import ObjectJob
    from real2sim.pipeline.catalogue import write_catalogue

    out = tmp_path / "cat"
    evaluated_asset(out / "can_ds")
    jobs = [ObjectJob("can_ds", datasets["can"], out / "can_ds"), ObjectJob("mug_ds", datasets["mug"], out / "mug_ds")]
    write_catalogue(out, jobs, {"can_ds": {"status": "done", "reason": ""},
                                "mug_ds": {"status": "failed", "reason": "no mass: <b>none</b>"}})
    page = (out / "index.html").read_text()
    assert "no mass: &lt;b&gt;none&lt;/b&gt;" in page  # escaped
    found, urls = _open(out / "index.html", tmp_path)
    assert found["images"] == 2 and found["broken"] == []
    assert {"catalogue.csv", "timings.csv", "can_ds/results/report.html"} <= set(found["links"])
    assert _remote(urls) == []


@pytest.mark.slow
def test_an_evaluated_batch_recommends_from_the_simulations(capsys, datasets, tmp_path):
    """`--evaluate` reaches every object's run; its row takes OCAE and simulation time from results/ (a
    minute or two; the row's reading of summary.csv is checked quickly above)."""
    out = tmp_path / "cat"
    code, stdout, err = run_cli(capsys, "batch", datasets["can"], "--mass-kg", "0.35", "--out", out, *FAST,
                                "--evaluate", "--tasks", "push", "--contact", "point", "--runs", "1", "--jobs", "2",
                                "--duration-scale", "0.2")
    assert code == 0, (stdout, err)
    row = catalogue_rows(out)["can_ds"]
    assert row["basis"] == "evaluation" and row["report"] == "can_ds/results/report.html"
    assert row["accuracy_representation"].startswith(("spheres_4", "mesh"))
    assert float(row["accuracy_ocae_m"]) >= 0 and float(row["accuracy_sim_time_s"]) > 0


def test_a_worker_holds_every_numeric_library_to_its_share_of_the_cpus():
    """Two workers on two cores each start a thread per CPU in torch, numpy's BLAS and OpenMP unless held to
    one: four busy threads on two cores (bench_batch: 52-54 s against 44-45 s for the six captures). numpy's
    BLAS loads with real2sim's first import, before the worker's job: its limit must reach a loaded library.
    In a fresh interpreter, as a spawned worker starts, so that this process keeps its own thread pools."""
    script = (
        "import real2sim.pipeline.batch as b, numpy, threadpoolctl, json\n"
        "b.limit_threads(1)\n"
        "import torch, scipy.linalg\n"
        "pools = threadpoolctl.threadpool_info()\n"
        "print(json.dumps({'torch': torch.get_num_threads(), 'pools': [(p['internal_api'], p['num_threads']) "
        "for p in pools]}))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                          env={**__import__("os").environ, "OMP_NUM_THREADS": "", "OPENBLAS_NUM_THREADS": ""})
    found = json.loads(done.stdout.strip().splitlines()[-1])
    assert found["torch"] == 1
    apis = {api for api, _ in found["pools"]}
    assert any("blas" in api for api in apis), found  # numpy's BLAS was found and held
    assert all(n == 1 for _, n in found["pools"]), found
