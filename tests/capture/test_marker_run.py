"""`run --marker-mm` end to end on small hard handheld captures (slow: structure from motion, parallax masks,
the robot frame): metres and the table from printed markers, and one line, exit 2, when the photos show none."""

from __future__ import annotations

import json

import pytest

from real2sim.cli import main
from tests.cli_helpers import run_cli

CAPTURE = ["--handheld", "--views", "12", "--width-px", "960", "--height-px", "540", "--room", "--close-fraction", "0.5",
           "--table-texture-px", "4096"]


@pytest.mark.slow
def test_run_marker_mm_gives_metres_and_the_table(tmp_path, capsys):
    photos = tmp_path / "photos"
    assert main(["capture", "can", *CAPTURE, "--markers", "6", "--marker-mm", "50", "--out", str(photos)]) == 0
    code, out, err = run_cli(capsys, "run", photos, "--marker-mm", "50", "--mass-kg", "0.35", "--backend", "hull",
                             "--collision", "cylinders:2", "--out", tmp_path / "asset")
    assert code == 0, err
    record = json.loads((tmp_path / "asset/.run/robot_frame/robot_frame.json").read_text())
    assert record["scale_from"] == "marker_mm" and len(record["markers"]["markers_used"]) >= 1
    errors = record["errors_vs_ground_truth"]
    assert abs(errors["scale_rel_error"]) < 0.01 and errors["table_tilt_deg"] < 1.0, errors


@pytest.mark.slow
def test_run_marker_mm_without_markers_is_one_line(tmp_path, capsys):
    photos = tmp_path / "photos"
    assert main(["capture", "can", *CAPTURE, "--out", str(photos)]) == 0
    code, out, err = run_cli(capsys, "run", photos, "--marker-mm", "40", "--mass-kg", "0.35", "--backend", "hull",
                             "--out", tmp_path / "asset")
    lines = [line for line in err.strip().splitlines() if not line.startswith("WARNING")]
    assert code == 2 and len(lines) == 1, err
    assert "square markers" in lines[0] and "registered views" in lines[0] and "at least 3" in lines[0]
