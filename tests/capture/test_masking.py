"""Object masks: background difference (IoU vs rendered masks), provided masks, Mask R-CNN error paths."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from tests.progress_check import Recorder
from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
from real2sim.formats.dataset import load_mask, read_dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.capture.masks.methods import MaskConfig, clean_mask, compute_masks, iou


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    from real2sim.geometry.objects import make_textured_object

    root = tmp_path_factory.mktemp("mask")
    out = {}
    for name in ("bottle", "can", "mug"):
        out[name] = root / name
        progress = Recorder()
        capture(make_textured_object(name), out[name],
                CaptureConfig(views=5, width=320, height=240, with_background=True, seed=1), progress=progress)
        assert progress.check()[-1] == ("rendering", 10, 10)  # the views, then the empty scene's
    return out


@pytest.mark.parametrize("name", ["bottle", "can", "mug"])
def test_background_masks_match_rendered(captures, name, tmp_path):
    import shutil

    root = tmp_path / name
    shutil.copytree(captures[name], root)
    before = json.loads((root / "transforms.json").read_text())
    progress = Recorder()
    result = compute_masks(root, "background", progress=progress)
    assert progress.check()[-1] == ("masks (background)", 5, 5)
    assert result.mean_iou >= 0.95, result
    assert result.min_iou >= 0.90, result
    ds = read_dataset(root)
    assert all(f.mask_path == f"masks_background/{f.file_path.split('/')[-1]}" for f in ds.frames)
    # Our own IoU check, independent of compute_masks' bookkeeping.
    ious = [iou(load_mask(root / f.mask_path), load_mask(root / "masks" / f.file_path.split("/")[-1]))
            for f in ds.frames]
    assert np.mean(ious) >= 0.95
    # Only mask_path changed in transforms.json.
    after = json.loads((root / "transforms.json").read_text())
    assert [f["transform_matrix"] for f in after["frames"]] == [f["transform_matrix"] for f in before["frames"]]
    # Running again replaces the folder whole.
    compute_masks(root, "background")
    assert not [p for p in root.iterdir() if p.name.startswith(".") and p.name != ".real2sim"]


def test_clean_mask_keeps_large_background_holes_and_fills_small_ones():
    m = np.zeros((100, 100), bool)
    m[20:80, 20:80] = True
    m[30:50, 30:50] = False      # large hole matching the background: a handle's opening
    m[60:63, 60:63] = False      # tiny hole: unmatched object pixels
    diff = np.where(m, 50, 0).astype(float)
    out = clean_mask(m, MaskConfig(), diff=diff)
    assert not out[35:45, 35:45].any()
    assert out[60:63, 60:63].all()
    # A large hole whose pixels still differ from the background is object (similar colour): filled.
    diff[30:50, 30:50] = 10.0
    assert clean_mask(m, MaskConfig(), diff=diff)[35:45, 35:45].all()
    # Speckle away from the object is removed.
    m2 = m.copy()
    m2[5, 5] = True
    assert not clean_mask(m2, MaskConfig(), diff=diff)[5, 5]


def test_provided(tmp_path, captures):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(captures["bottle"], root)
    r = compute_masks(root, "provided")
    assert r.mask_dir == "masks" and r.mean_iou == pytest.approx(1.0) and 0.005 < r.mean_object_fraction < 0.5
    # Frames without mask_path pick up masks/<stem>.png.
    data = json.loads((root / "transforms.json").read_text())
    for fr in data["frames"]:
        fr.pop("mask_path", None)
    (root / "transforms.json").write_text(json.dumps(data))
    compute_masks(root, "provided")
    assert all(f.mask_path == f"masks/{f.file_path.split('/')[-1]}" for f in read_dataset(root).frames)
    # A wrong-size mask, then a missing one.
    good = (root / "masks/frame_00001.png").read_bytes()
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(root / "masks/frame_00001.png")
    with pytest.raises(UserInputError, match="10x10"):
        compute_masks(root, "provided")
    (root / "masks/frame_00001.png").write_bytes(good)
    data = json.loads((root / "transforms.json").read_text())
    data["frames"][2].pop("mask_path")
    (root / "transforms.json").write_text(json.dumps(data))
    (root / "masks/frame_00002.png").unlink()
    with pytest.raises(UserInputError, match="no mask for images/frame_00002.png"):
        compute_masks(root, "provided")


def test_background_missing_leaves_dataset_untouched(tmp_path, captures):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(captures["can"], root)
    (root / "background/frame_00003.png").unlink()
    before = (root / "transforms.json").read_bytes()
    with pytest.raises(UserInputError, match="--with-background"):
        compute_masks(root, "background")
    assert (root / "transforms.json").read_bytes() == before
    assert sorted(p.name for p in root.iterdir()) == sorted(p.name for p in captures["can"].iterdir())


def test_maskrcnn_error_paths(tmp_path, captures):
    root = captures["bottle"]
    with pytest.raises(UserInputError, match="--mask-weights"):
        compute_masks(root, "maskrcnn", MaskConfig(mask_weights=None))
    with pytest.raises(UserInputError, match="not found"):
        compute_masks(root, "maskrcnn", MaskConfig(mask_weights=tmp_path / "missing.pth"))
    weights = tmp_path / "w.pth"
    weights.write_bytes(b"not weights")
    # Not `import torchvision`: on a CPU-only torch that raises RuntimeError until
    # real2sim.capture.masks.torchvision_compat has defined the ops it needs.
    import importlib.util

    if importlib.util.find_spec("torchvision") is None:
        with pytest.raises(UserInputError, match="torchvision"):
            compute_masks(root, "maskrcnn", MaskConfig(mask_weights=weights))
    else:
        with pytest.raises(UserInputError, match="is not a Mask R-CNN weights file"):
            compute_masks(root, "maskrcnn", MaskConfig(mask_weights=weights))
    assert not (root / "masks_maskrcnn").exists()


def test_unknown_method_and_bad_dataset(tmp_path):
    with pytest.raises(UserInputError, match="unknown mask method"):
        compute_masks(tmp_path, "grabcut")
    with pytest.raises(UserInputError, match="neither transforms.json"):
        compute_masks(tmp_path, "provided")


def test_cli_mask(captures, capsys, tmp_path):
    from real2sim.cli import main

    assert main(["mask", str(captures["mug"]), "--method", "provided"]) == 0
    assert "IoU vs ground truth" in capsys.readouterr().out
    assert main(["mask", str(captures["mug"]), "--method", "maskrcnn", "--mask-weights", str(tmp_path / "x.pth")]) == 2
    assert "not found" in capsys.readouterr().err
