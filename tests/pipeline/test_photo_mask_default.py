"""Photos given to the Python front door without a mask method are masked ``auto``, as on the command line."""

from __future__ import annotations

import numpy as np
from PIL import Image

from real2sim.asset.config import AssetConfig
from real2sim.formats.spec import parse_spec
from real2sim.pipeline.run import RunConfig, run_pipeline


def test_photos_without_a_mask_method_are_not_refused(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        Image.fromarray(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)).save(photos / f"IMG_{k:04d}.jpg")
    asked = []
    config = RunConfig(asset=AssetConfig(mass_kg=0.3, specs=(parse_spec("cylinders:2"),)), object_height_m=0.1)
    result = run_pipeline(photos, tmp_path / "asset", config, pause=lambda stage: asked.append(stage) or True)
    assert result.paused_before == asked[0]  # checked, planned, and stopped before its first stage's work
