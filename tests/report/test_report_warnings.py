"""report.html repeats what degraded while `real2sim run` made the assets (their .run/run.json), near the top;
an asset without a readable run record simply has nothing to repeat."""

from __future__ import annotations

import json
from pathlib import Path

from real2sim.formats.results import RUN_COLUMNS, write_csv_atomic
from real2sim.report.html import write_report
from real2sim.report.sections import asset_warnings


def _results(root: Path, assets: dict[str, Path]) -> Path:
    results = root / "results"
    results.mkdir()
    rows = [dict(object=name, representation="boxes_4", contact_model="point", task="push", run=0, ate_m=0.001,
                 ocae_m=0.01, cpd_m_per_s=0.002, sim_time_s=0.1, sim_duration_s=1.0, real_time_factor=10.0, error="")
            for name in assets]
    write_csv_atomic(results / "runs.csv", rows, RUN_COLUMNS)
    (results / "config.json").write_text(json.dumps({"assets": {n: str(p) for n, p in assets.items()}}))
    return results


def _asset(root: Path, name: str, run_json: str | None) -> Path:
    folder = root / name
    (folder / ".run").mkdir(parents=True)
    if run_json is not None:
        (folder / ".run" / "run.json").write_text(run_json)
    return folder


def test_report_lists_each_assets_warnings_and_nothing_for_assets_without_any(tmp_path):
    stages = {"refine_poses": {"key": "k", "warnings": ["pose refinement kept the given poses: <0 points>"]},
              "reconstruct": {"key": "k"}, "asset": {"key": "k", "warnings": ["a fallback & another"]}}
    warned = _asset(tmp_path, "can", json.dumps({"version": 1, "stages": stages}))
    quiet = _asset(tmp_path, "bottle", json.dumps({"version": 1, "stages": {"asset": {"key": "k"}}}))
    garbage = _asset(tmp_path, "mug", "{not json")
    assert asset_warnings(warned) == [
        {"stage": "refine_poses", "message": "pose refinement kept the given poses: <0 points>"},
        {"stage": "asset", "message": "a fallback & another"}]
    assert asset_warnings(quiet) == asset_warnings(garbage) == asset_warnings(tmp_path / "none") == []
    assert asset_warnings(_asset(tmp_path, "odd", json.dumps({"stages": {"asset": {"warnings": "text"}}}))) == []

    page = write_report(_results(tmp_path, {"can": warned, "bottle": quiet, "mug": garbage})).read_text()
    assert page.index("Warnings") < page.index("Summary (layout")  # read before the numbers
    assert "stage refine_poses: pose refinement kept the given poses: &lt;0 points&gt;" in page
    assert "stage asset: a fallback &amp; another" in page and page.count(", stage ") == 2

    (tmp_path / "alone").mkdir()
    page = write_report(_results(tmp_path / "alone", {"bottle": quiet, "mug": garbage})).read_text()
    assert "Warnings" not in page
