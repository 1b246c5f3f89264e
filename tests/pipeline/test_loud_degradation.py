"""Degradation is loud (issue 28 part 6): a run whose pose refinement keeps the given poses says so
when it happens, at the end of its summary, in truth.json and in report.html, and again on a resume.

The capture is 8 views at 64x48 px, where COLMAP cannot triangulate: the run refines by default
(a transforms.json of robot poses), the refinement falls back to the given poses with a warning,
and the run goes on. A dataset whose pose refinement has nothing to refine, --no-refine-poses, and
a machine without pycolmap are checked on the settings alone or with the same tiny capture.
"""

from __future__ import annotations

import html
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.cli_helpers import run_cli

HULL = ["--backend", "hull", "--voxels", "48", "--max-faces", "2000", "--texture-px", "64", "--collision", "mesh",
        "--mass-kg", "0.35"]
KEPT = "pose refinement kept the given poses"


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory) -> Path:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    out = tmp_path_factory.mktemp("loud") / "can"
    capture(make_textured_object("can"), out, CaptureConfig(views=8, width=64, height=48))
    return out


def _warning_lines(text: str, words: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("WARNING: ") and words in line]


def test_failed_refinement_is_reported_while_running_at_the_end_in_truth_json_and_on_resume(
        tiny_capture, tmp_path, capsys):
    out = tmp_path / "asset"
    code, stdout, err = run_cli(capsys, "run", tiny_capture, "--out", out, *HULL)  # refines by default
    assert code == 0, err
    said = _warning_lines(err, KEPT)
    assert len(said) == 1 and ".py" not in said[0], err  # once, plain, when it happened
    summary = stdout.splitlines()
    assert summary[0].startswith("asset: ") and "refine_poses" in summary[0]
    repeated = _warning_lines(stdout, KEPT)
    assert len(repeated) == 1 and "(stage refine_poses)" in repeated[0]
    assert summary.index(repeated[0]) > summary.index(next(s for s in summary if s.strip().endswith("model.urdf")))
    message = said[0][len("WARNING: "):]
    assert repeated[0] == f"WARNING: {message} (stage refine_poses)"

    record = json.loads((out / ".run" / "run.json").read_text())["stages"]
    assert record["refine_poses"]["warnings"] == [message]
    truth = json.loads((out / "truth.json").read_text())
    # 8 views are too few for the reconstruction to align to each other: it says so too
    assert truth["warnings"][0] == {"stage": "refine_poses", "message": message}
    assert [w["stage"] for w in truth["warnings"][1:]] == ["reconstruct"]
    assert truth["warnings"][1]["message"].startswith("poses not aligned: 8 views: too few")
    assert truth["camera_poses"]["refinement_asked"] and not truth["camera_poses"]["refined"]

    # The same command again: every stage unchanged and skipped, nothing happens, and the summary still says it.
    code, stdout, err = run_cli(capsys, "run", tiny_capture, "--out", out, *HULL)
    assert code == 0 and "none, all unchanged" in stdout, err
    assert _warning_lines(err, KEPT) == []
    assert _warning_lines(stdout, KEPT) == repeated

    # The evaluation report of this asset shows it too (runs.csv made by hand: a sweep takes minutes).
    report = _report_of(out, tmp_path / "results")
    assert "Warnings" in report and html.escape(message) in report and "refine_poses" in report


def _report_of(asset: Path, results: Path) -> str:
    from real2sim.formats.results import RUN_COLUMNS, write_csv_atomic
    from real2sim.report.html import write_report

    results.mkdir()
    rows = [dict(object=asset.name, representation="mesh", contact_model="point", task="push", run=run, ate_m=0.001,
                 ocae_m=0.01, cpd_m_per_s=0.002, sim_time_s=0.1, sim_duration_s=1.0, real_time_factor=10.0, error="")
            for run in range(2)]
    write_csv_atomic(results / "runs.csv", rows, RUN_COLUMNS)
    (results / "config.json").write_text(json.dumps({"assets": {asset.name: f"../{asset.name}"}}))
    return write_report(results).read_text()


def test_without_pycolmap_refinement_is_skipped_with_a_warning(tiny_capture, tmp_path, capsys, monkeypatch):
    dataset = tmp_path / "can"
    shutil.copytree(tiny_capture, dataset, ignore=shutil.ignore_patterns("ground_truth"))
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # `import pycolmap` fails, as where it is not installed
    out = tmp_path / "asset"
    for _ in range(2):  # the second run skips every stage and still says it
        code, stdout, err = run_cli(capsys, "run", dataset, "--out", out, *HULL)
        assert code == 0, err
        assert len(_warning_lines(stdout, "pose refinement skipped: pycolmap is not installed")) == 1, stdout
    assert not (out / ".run" / "dataset").exists()
    assert "none, all unchanged" in stdout


def test_poses_are_refined_by_default_where_there_are_poses_to_refine(tiny_capture, tmp_path):
    from real2sim.cli import build_parser
    from real2sim.cli.run import config_from_args
    from real2sim.pipeline.run import poses_to_refine

    def refine(dataset: Path, *flags: str):
        args = build_parser().parse_args(["run", str(dataset), "--out", str(tmp_path / "a"), *HULL, *flags])
        return config_from_args(args).refine

    assert refine(tiny_capture) is not None  # robot poses
    assert refine(tiny_capture, "--refine-poses") is not None  # the old flag, still accepted
    assert refine(tiny_capture, "--no-refine-poses") is None
    refined = tmp_path / "refined"  # `capture refine-poses` refined them already: nothing left to refine
    shutil.copytree(tiny_capture, refined, ignore=shutil.ignore_patterns("ground_truth"))
    data = json.loads((refined / "transforms.json").read_text())
    (refined / "transforms.json").write_text(json.dumps({**data, "real2sim_refinement": {"refined": True}}))
    assert refine(refined) is None and refine(refined, "--refine-poses") is not None
    colmap = tmp_path / "colmap_frame"  # poses in COLMAP's own frame (ns-process-data): COLMAP's already
    shutil.copytree(refined, colmap)
    (colmap / "transforms.json").write_text(json.dumps({**data, "applied_transform": np.eye(4)[:3].tolist()}))
    assert not poses_to_refine(colmap) and poses_to_refine(tiny_capture)
    with pytest.raises(SystemExit):  # both: a usage error
        build_parser().parse_args(["run", str(tiny_capture), "--out", "a", "--refine-poses", "--no-refine-poses"])


def test_standalone_reconstruct_repeats_its_warnings_in_the_summary_and_report_json(tiny_capture, tmp_path, capsys):
    """`reconstruct` on its own says what degraded where its result is read: after its summary line and
    in report.json (8 views marked as a failed refine-poses leaves them: too few to align to each other)."""
    from real2sim.formats.dataset import POSE_REFINED_KEY

    dataset = tmp_path / "can"
    shutil.copytree(tiny_capture, dataset, ignore=shutil.ignore_patterns("ground_truth"))
    meta = json.loads((dataset / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame[POSE_REFINED_KEY] = False
    (dataset / "transforms.json").write_text(json.dumps(meta))
    out = tmp_path / "mesh"
    code, stdout, err = run_cli(capsys, "reconstruct", dataset, "--out", out, "--backend", "hull", "--voxels", "48",
                                "--texture-px", "64")
    assert code == 0, err
    said = _warning_lines(err, "poses not aligned: 8 views: too few")
    assert len(said) == 1 and ".py" not in said[0], err
    lines = stdout.splitlines()
    assert lines[0].startswith("mesh: ") and lines[1:] == said
    assert json.loads((out / "report.json").read_text())["warnings"] == [said[0][len("WARNING: "):]]
