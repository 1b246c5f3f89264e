"""`run --mask parallax` on photos with no masks: a COLMAP model (a phone capture) goes to an asset.

The masks stage runs before robot_frame there (robot_frame needs masks to measure the object) and finds
the table plane itself, by RANSAC on the sparse points; the asset is judged against the true can.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.pipeline.colmap_capture import make_colmap_capture, random_similarity
from tests.pipeline.test_robot_frame import CAN_HEIGHT_M, FAST, HULL


@pytest.fixture(scope="module")
def phone_capture(tmp_path_factory) -> Path:
    """The can at 160x120 moved into a random similarity frame as a COLMAP model, its masks deleted."""
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    root = tmp_path_factory.mktemp("parallax_run")
    capture(make_textured_object("can"), root / "can",
            CaptureConfig(views=60, width=160, height=120, pose_noise_mm=0, pose_noise_deg=0))
    moved = make_colmap_capture(root / "can", root / "moved", random_similarity(np.random.default_rng(11)), seed=11)
    shutil.rmtree(moved / "masks")
    return moved


def test_a_colmap_capture_without_masks_becomes_an_asset_close_to_the_truth(phone_capture, tmp_path):
    from real2sim.cli import main

    out = tmp_path / "asset"
    assert main(["run", str(phone_capture), "--out", str(out), "--object-height-m", str(CAN_HEIGHT_M),
                 "--mask", "parallax", *FAST]) == 0
    stages = list(json.loads((out / ".run" / "run.json").read_text())["stages"])
    assert stages.index("masks") < stages.index("robot_frame") < stages.index("reconstruct")
    truth = json.loads((out / "truth.json").read_text())
    assert truth["masks_iou"]["mean"] >= 0.9, truth["masks_iou"]
    assert truth["reconstruction"]["chamfer_mm"] <= 1.5, truth["reconstruction"]
    assert truth["reconstruction"]["iou"] >= 0.85, truth["reconstruction"]


# about 100 s: the COLMAP capture above keeps parallax masks in the default suite
@pytest.mark.slow
def test_parallax_masks_of_a_robot_capture_wait_for_refined_poses(tmp_path):
    """With --refine-poses the masks are made on the refined dataset, after refine_poses."""
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.cli import main
    from real2sim.geometry.objects import make_textured_object

    ds = tmp_path / "can"
    capture(make_textured_object("can"), ds, CaptureConfig(views=60, width=160, height=120, seed=3))
    shutil.rmtree(ds / "masks")
    transforms = json.loads((ds / "transforms.json").read_text())
    for frame in transforms["frames"]:
        frame.pop("mask_path", None)
    (ds / "transforms.json").write_text(json.dumps(transforms))
    out = tmp_path / "asset"
    assert main(["run", str(ds), "--out", str(out), "--mask", "parallax", "--refine-poses", *HULL]) == 0
    stages = list(json.loads((out / ".run" / "run.json").read_text())["stages"])
    assert stages.index("refine_poses") < stages.index("masks") < stages.index("reconstruct")
    truth = json.loads((out / "truth.json").read_text())
    assert truth["masks_iou"]["mean"] >= 0.85, truth["masks_iou"]
