"""`real2sim mask --method geometry`: masks from dense geometry alone, as `run --mask geometry` makes them."""

from __future__ import annotations

import json
import re

from tests.cli_helpers import run_cli


def test_mask_from_geometry_on_a_small_exact_capture(tmp_path, capsys):
    data = tmp_path / "mug"
    code, _, err = run_cli(capsys, "capture", "mug", "--out", data, "--views", "16", "--width-px", "240",
                           "--height-px", "180", "--pose-noise-mm", "0", "--pose-noise-deg", "0")
    assert code == 0, err
    code, out, err = run_cli(capsys, "mask", data, "--method", "geometry")
    assert code == 0, err
    assert (data / "dense_geometry.json").is_file() and len(list((data / "masks_geometry").glob("*.png"))) == 16
    mean_iou = float(re.search(r"IoU vs ground truth mean ([0-9.]+)", out).group(1))
    assert mean_iou > 0.85, out
    frames = json.loads((data / "transforms.json").read_text())["frames"]
    assert all(f["mask_path"].startswith("masks_geometry/") for f in frames)
