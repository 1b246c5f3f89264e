"""`real2sim demo --quick`: the whole system end to end on the bundled bottle.

Simulated capture -> reconstruction -> asset -> truth.json -> Drake evaluation -> plots, report.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import pytest

from real2sim.cli import demo, main
from real2sim.cli.demo import QUICK, DemoPlan

# Measured: the quick demo's hull reconstruction is 0.53 mm Chamfer, IoU 0.964 from the true
# bottle (60 noise-free views at 160x120 px); the bounds leave room for platform differences.
MAX_CHAMFER_MM = 1.0
MIN_IOU = 0.92

# The default suite's demo: --quick's capture and reconstruction (so the same bounds hold), and every
# later stage of it on less work: smaller fits of the same primitive families, a fifth of the tasks'
# simulated time (the quick demo itself is about 3 minutes on 2 idle cores; make test-slow runs it).
SMALL = replace(QUICK, specs=("cylinders:2", "spheres:4", "coacd"), fit_iterations=60, duration_scale=0.2)


def test_small_demo_from_capture_to_report(tmp_path, capsys, monkeypatch):
    """`demo --quick` end to end with the SMALL plan in place of QUICK: every stage and output, checked as
    below; the simulations in this process (--jobs 1: the suite's workers already share the cores; the
    process pool is tested in tests/evaluate)."""
    monkeypatch.setattr(demo, "QUICK", SMALL)
    asset = _check_demo(tmp_path, capsys, SMALL, jobs=1)
    # the SMALL plan's own settings reached the fits and the simulations
    fits = [json.loads((asset / name / "fit_report.json").read_text()) for name in ("cylinders_2", "spheres_4")]
    assert all(0 < fit["iterations"] <= SMALL.fit_iterations for fit in fits), fits
    with open(asset / "results" / "runs.csv") as f:
        assert all(float(row["sim_duration_s"]) < 0.5 for row in csv.DictReader(f))  # 1.5 and 2 s unscaled


@pytest.mark.slow
def test_quick_demo_from_capture_to_report(tmp_path, capsys):
    _check_demo(tmp_path, capsys, QUICK, jobs=2)


def _check_demo(tmp_path, capsys, plan: DemoPlan, jobs: int):
    """Run `demo --quick` (its plan: ``plan``) into ``tmp_path``, check every output; the asset folder."""
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--out", str(out), "--jobs", str(jobs)]) == 0
    stdout = capsys.readouterr().out
    assert "report.html" in stdout and "noise-free capture" in stdout and "Chamfer" in stdout
    assert (out / "capture" / "transforms.json").is_file() and (out / "capture" / "ground_truth" / "mesh.obj").is_file()
    asset = out / "bottle_asset"
    assert (asset / ".run" / "run.json").is_file()
    urdfs = sorted(asset.glob("*/model.urdf"))
    names = sorted(p.parent.name for p in urdfs)
    # The demo's SPECs, and the reconstruction itself ("mesh"), whose dynamics are judged against the truth.
    assert names == sorted([s.replace(":", "_").replace("+", "_") for s in plan.specs] + ["mesh"])
    assert all((urdf.parent / "model.xml").is_file() for urdf in urdfs)  # MuJoCo too
    for urdf in urdfs:  # each loads in Drake as it is
        plant = MultibodyPlant(0.0)
        assert Parser(plant).AddModels(str(urdf))
        plant.Finalize()
        assert plant.num_bodies() >= 2

    truth = json.loads((asset / "truth.json").read_text())
    assert truth["reconstruction"]["chamfer_mm"] < MAX_CHAMFER_MM
    assert truth["reconstruction"]["iou"] > MIN_IOU
    assert truth["physical_properties"]["com_error_mm"] < 2.0
    assert truth["camera_poses"]["before_refinement"]["trans_max_mm"] < 1e-3  # noise-free capture

    results = asset / "results"
    with open(results / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    # The reconstruction (`mesh`) is the paper protocol's reference itself: only the truth sweep simulates it.
    assert {r["representation"] for r in rows} == {f"{n}_{c}" for n in names if n != "mesh"
                                                   for c in plan.contact_models}
    for r in rows:
        assert int(r["runs_failed"]) == 0
        assert 0 <= float(r["ate_m"]) < 0.5 and float(r["sim_time_s"]) > 0
    assert len(list(results.glob("pareto_*.png"))) == 4
    html = (results / "report.html").read_text()
    assert "coacd" in html and "<table" in html
    assert "Against the truth" in html and html.count("class='pic'") == len(names) + 1
    dynamics = truth["dynamics"]
    assert {r["contact_model"] for r in dynamics["reconstruction_vs_truth"]} == set(plan.contact_models)
    assert all(r["ocae_vs_truth_m"] is not None for r in dynamics["representations"])
    assert (asset / "results_truth" / "summary.csv").is_file()
    assert not list(tmp_path.glob(".demo.tmp-*"))  # the temporary folder was renamed into place
    return asset


def test_demo_refuses_an_existing_output_folder(tmp_path, capsys):
    out = tmp_path / "demo"
    out.mkdir()
    assert main(["demo", "--quick", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
