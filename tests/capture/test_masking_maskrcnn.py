"""Mask R-CNN masks with torchvision: our NMS against a brute-force reference, the instance
selection of maskrcnn_mask on fixed detections, and real inference end to end (random
weights saved to a file) through compute_masks and the CLI."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys

import numpy as np
import pytest

# Not pytest.importorskip("torchvision"): on a CPU-only torch the plain import raises
# RuntimeError (its compiled ops are missing), which is what torchvision_compat handles.
if importlib.util.find_spec("torchvision") is None:
    pytest.skip("torchvision is not installed (pip install -e '.[maskrcnn]')", allow_module_level=True)

import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
from real2sim.formats.dataset import load_mask, read_dataset
from real2sim.capture.masks.methods import MaskConfig, compute_masks, maskrcnn_mask
from real2sim.capture.masks.torchvision_compat import ensure_torchvision, greedy_nms, import_maskrcnn_builder

# Small internal resize and few instances: random weights detect up to 100 "objects".
SMALL = dict(maskrcnn_min_size_px=96, maskrcnn_max_size_px=128, maskrcnn_max_instances=3)


def reference_nms(boxes: list[list[float]], scores: list[float], threshold: float) -> list[int]:
    """Greedy NMS in plain Python floats: torchvision's documented semantics, written out."""
    order = sorted(range(len(scores)), key=lambda i: -scores[i])  # stable: ties keep index order
    area = [(b[2] - b[0]) * (b[3] - b[1]) for b in boxes]
    suppressed = [False] * len(boxes)
    keep = []
    for a, i in enumerate(order):
        if suppressed[i]:
            continue
        keep.append(i)
        for j in order[a + 1:]:
            w = max(0.0, min(boxes[i][2], boxes[j][2]) - max(boxes[i][0], boxes[j][0]))
            h = max(0.0, min(boxes[i][3], boxes[j][3]) - max(boxes[i][1], boxes[j][1]))
            inter = w * h
            union = area[i] + area[j] - inter
            if union != 0 and inter / union > threshold:
                suppressed[j] = True
    return keep


coord = st.integers(0, 12).map(float)  # a coarse grid: many identical, touching and zero-area boxes


@st.composite
def box_sets(draw):
    n = draw(st.integers(0, 40))
    boxes = []
    for _ in range(n):
        x1, y1 = draw(coord), draw(coord)
        boxes.append([x1, y1, x1 + draw(st.integers(0, 6)), y1 + draw(st.integers(0, 6))])
    scores = draw(st.lists(st.integers(0, 5).map(lambda s: s / 5), min_size=n, max_size=n))  # many ties
    return boxes, scores


@settings(max_examples=150, deadline=None)
@given(box_sets(), st.sampled_from([0.0, 0.1, 0.3, 0.5, 0.7, 1.0]))
def test_greedy_nms_matches_reference(data, threshold):
    boxes, scores = data
    b = torch.tensor(boxes, dtype=torch.float64).reshape(-1, 4)
    s = torch.tensor(scores, dtype=torch.float64)
    got = greedy_nms(b, s, threshold)
    assert got.dtype == torch.long
    assert got.tolist() == reference_nms(boxes, scores, threshold)
    # Through torchvision's public function (the op we registered, or torchvision's own kernel).
    tv = ensure_torchvision()
    assert tv.ops.nms(b, s, threshold).tolist() == reference_nms(boxes, scores, threshold)


def test_greedy_nms_random_float_boxes_and_blocks(monkeypatch):
    g = torch.Generator().manual_seed(3)
    xy = torch.rand(300, 2, generator=g) * 50
    b = torch.cat([xy, xy + torch.rand(300, 2, generator=g) * 15], 1).double()
    s = torch.rand(300, generator=g).double()
    want = reference_nms(b.tolist(), s.tolist(), 0.4)
    assert greedy_nms(b, s, 0.4).tolist() == want
    assert 0 < len(want) < 300
    # Tiny IoU blocks (a few rows at a time) give the same answer.
    import real2sim.capture.masks.torchvision_compat as compat

    monkeypatch.setattr(compat, "_MAX_BLOCK_ELEMENTS", 700)
    assert greedy_nms(b, s, 0.4).tolist() == want
    # float32 boxes, as the detector passes them.
    assert greedy_nms(b.float(), s.float(), 0.4).tolist() == reference_nms(b.float().tolist(), s.float().tolist(), 0.4)
    with pytest.raises(RuntimeError, match="boxes"):
        greedy_nms(b[:, :3], s, 0.5)


def test_compat_is_idempotent_and_keeps_other_ops_checked():
    tv = ensure_torchvision()
    assert ensure_torchvision() is tv and sys.modules["torchvision"] is tv
    assert import_maskrcnn_builder() is import_maskrcnn_builder()
    boxes = torch.tensor([[0.0, 0, 10, 10], [1, 1, 10, 10], [20, 20, 30, 30]])
    scores = torch.tensor([0.9, 0.8, 0.7])
    assert tv.ops.nms(boxes, scores, 0.5).tolist() == [0, 2]
    assert tv.ops.batched_nms(boxes, scores, torch.tensor([0, 1, 0]), 0.5).tolist() == [0, 1, 2]
    if not tv.extension._has_ops():
        # Our shim lets only nms through; another compiled op still fails with torchvision's message.
        with pytest.raises(RuntimeError, match="Couldn't load custom C\\+\\+ ops"):
            tv.ops.deform_conv2d(torch.zeros(1, 1, 4, 4), torch.zeros(1, 18, 2, 2), torch.zeros(1, 1, 3, 3))


@pytest.mark.parametrize("aligned", [False, True])
@pytest.mark.parametrize("sampling_ratio", [1, 2, 3])
def test_roi_align_by_grid_sample_equals_torchvisions_own(aligned, sampling_ratio):
    """Boxes inside, across and outside the feature maps' edges, two images, two scales: the same values
    as torchvision's pure-PyTorch roi_align (uncompiled), to float rounding."""
    from real2sim.capture.masks.torchvision_compat import roi_align_by_grid_sample

    ensure_torchvision()
    torchvisions = sys.modules["torchvision.ops.roi_align"]._roi_align
    torchvisions = getattr(torchvisions, "__wrapped__", torchvisions)  # without torch.compile's wrapper
    gen = torch.Generator().manual_seed(sampling_ratio)
    features = torch.randn(2, 5, 13, 17, generator=gen)
    corner = torch.rand(40, 2, generator=gen) * torch.tensor([40.0, 30.0]) - 8.0
    rois = torch.cat([torch.randint(0, 2, (40, 1), generator=gen).float(), corner,
                      corner + torch.rand(40, 2, generator=gen) * 30.0], dim=1)
    for scale in (0.25, 0.5):
        expected = torchvisions(features, rois, scale, 7, 5, sampling_ratio, aligned)
        got = roi_align_by_grid_sample(features, rois, scale, 7, 5, sampling_ratio, aligned, adaptive=None)
        assert got.shape == (40, 5, 7, 5)
        torch.testing.assert_close(got, expected, rtol=0, atol=2e-5)
    # adaptive sampling (sampling_ratio 0) is torchvision's own function
    assert roi_align_by_grid_sample(features, rois, 0.5, 7, 5, 0, aligned, adaptive=torchvisions).shape == (40, 5, 7, 5)


def test_without_compiled_ops_roi_align_runs_by_grid_sample():
    tv = ensure_torchvision()
    installed = sys.modules["torchvision.ops.roi_align"]._roi_align
    assert getattr(installed, "_real2sim_grid_sample", False) == (not tv.extension._has_ops())

def test_fresh_process_plain_import_then_compat():
    """In a new interpreter: whatever the plain import does, the compat layer gives a working nms."""
    import subprocess

    code = (
        "import torch\n"
        "try:\n    import torchvision\n    print('plain ok')\nexcept RuntimeError:\n    print('plain failed')\n"
        "from real2sim.capture.masks.torchvision_compat import ensure_torchvision, compiled_ops_loaded\n"
        "tv = ensure_torchvision()\n"
        "print(compiled_ops_loaded())\n"
        "b = torch.tensor([[0., 0, 10, 10], [0, 0, 10, 9], [5, 5, 20, 20]])\n"
        "print(tv.ops.nms(b, torch.tensor([0.5, 0.9, 0.7]), 0.5).tolist())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    plain, loaded, kept = out.stdout.split("\n")[:3]
    assert kept == "[1, 2]"
    # The plain import fails exactly when torchvision's own ops do not load.
    assert (plain == "plain failed") == (loaded == "False")


def test_missing_torchvision_is_a_user_error(monkeypatch):
    from real2sim.plumbing.errors import UserInputError

    monkeypatch.setitem(sys.modules, "torchvision", None)  # makes `import torchvision` raise ImportError
    with pytest.raises(UserInputError, match=r"pip install -e '\.\[maskrcnn\]'"):
        import_maskrcnn_builder()


class FixedDetections:
    """Stands in for the detector: called like it (a list of CHW images), returns fixed detections."""

    def __init__(self, boxes, scores, masks):
        self.out = {"boxes": torch.tensor(boxes, dtype=torch.float32),
                    "scores": torch.tensor(scores, dtype=torch.float32),
                    "labels": torch.ones(len(scores), dtype=torch.long),
                    "masks": torch.as_tensor(np.asarray(masks, np.float32))[:, None]}
        self.calls = []

    def __call__(self, images):
        self.calls.append([tuple(x.shape) for x in images])
        return [self.out]


def _prob_mask(h, w, box, p):
    m = np.zeros((h, w), np.float32)
    m[box[1]:box[3], box[0]:box[2]] = p
    return m


def test_maskrcnn_mask_selection():
    h, w = 60, 80
    image = np.zeros((h, w, 3), np.uint8)
    corner, centre, other = (0, 0, 20, 20), (30, 20, 50, 40), (60, 40, 80, 60)
    masks = [_prob_mask(h, w, corner, 0.9), _prob_mask(h, w, centre, 0.9), _prob_mask(h, w, other, 0.9)]
    # Clear winner by score.
    model = FixedDetections([corner, centre, other], [0.95, 0.80, 0.60], masks)
    m = maskrcnn_mask(model, image, MaskConfig())
    assert model.calls == [[(3, h, w)]]
    assert m.shape == (h, w) and m.dtype == bool
    assert m[0:20, 0:20].all() and m.sum() == 400
    # Scores within 0.05: the instance nearer the image centre wins.
    model = FixedDetections([corner, centre, other], [0.95, 0.92, 0.60], masks)
    m = maskrcnn_mask(model, image, MaskConfig())
    assert m[20:40, 30:50].all() and m.sum() == 400
    # Probability threshold 0.5 is strict: 0.5 is background, 0.51 object.
    half = _prob_mask(h, w, centre, 0.5)
    half[20:30, 30:50] = 0.51
    m = maskrcnn_mask(FixedDetections([centre], [0.9], [half]), image, MaskConfig())
    assert m[20:30, 30:50].all() and m.sum() == 200
    # No instance above the score threshold: empty mask.
    m = maskrcnn_mask(FixedDetections([centre], [0.4], [masks[1]]), image, MaskConfig())
    assert m.shape == (h, w) and not m.any()
    # A score exactly at the threshold does not count either (strictly greater).
    assert not maskrcnn_mask(FixedDetections([centre], [0.5], [masks[1]]), image, MaskConfig()).any()


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory):
    builder = import_maskrcnn_builder()
    torch.manual_seed(0)
    model = builder(weights=None, weights_backbone=None, num_classes=2)
    path = tmp_path_factory.mktemp("weights") / "maskrcnn_random.pth"
    torch.save(model.state_dict(), path)
    return path


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory):
    from real2sim.geometry.objects import make_textured_object

    root = tmp_path_factory.mktemp("mrcnn") / "can"
    capture(make_textured_object("can"), root, CaptureConfig(views=2, width=80, height=60, seed=2))
    return root


def _check_written(root, n_frames, w, h):
    ds = read_dataset(root)
    assert len(ds.frames) == n_frames
    # the folder's marker (the masks mask wrote) aside, it holds one mask per frame
    assert sorted(p.name for p in (root / "masks_maskrcnn").iterdir() if p.name != ".real2sim") == sorted(
        f.file_path.split("/")[-1] for f in ds.frames)
    for f in ds.frames:
        assert f.mask_path == f"masks_maskrcnn/{f.file_path.split('/')[-1]}"
        with Image.open(root / f.mask_path) as im:
            assert im.size == (w, h) and im.mode == "L"
        assert load_mask(root / f.mask_path).shape == (h, w)
    assert not [p for p in root.iterdir() if p.name.startswith(".") and p.name != ".real2sim"]


def test_compute_masks_maskrcnn_end_to_end(weights_file, small_dataset, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(small_dataset, root)
    before = json.loads((root / "transforms.json").read_text())
    result = compute_masks(root, "maskrcnn", MaskConfig(mask_weights=weights_file, **SMALL))
    assert result.method == "maskrcnn" and result.num_frames == 2 and result.mask_dir == "masks_maskrcnn"
    assert 0.0 <= result.mean_object_fraction <= 1.0
    assert result.mean_iou is not None  # simulated captures carry ground-truth masks
    _check_written(root, 2, 80, 60)
    after = json.loads((root / "transforms.json").read_text())
    assert [f["transform_matrix"] for f in after["frames"]] == [f["transform_matrix"] for f in before["frames"]]
    # The file holds what the model gives for that image (inference is deterministic on CPU).
    from real2sim.formats.dataset import load_image_rgb
    from real2sim.capture.masks.methods import load_maskrcnn

    cfg = MaskConfig(mask_weights=weights_file, **SMALL)
    model = load_maskrcnn(weights_file, "cpu", cfg.maskrcnn_min_size_px, cfg.maskrcnn_max_size_px,
                          cfg.score_threshold, cfg.maskrcnn_max_instances)
    frame = read_dataset(root).frames[0]
    direct = maskrcnn_mask(model, load_image_rgb(root / frame.file_path), cfg)
    np.testing.assert_array_equal(load_mask(root / frame.mask_path), direct)


def test_load_maskrcnn_applies_resize_and_checkpoint_layout(weights_file, tmp_path):
    from real2sim.plumbing.errors import UserInputError
    from real2sim.capture.masks.methods import load_maskrcnn

    model = load_maskrcnn(weights_file, "cpu", min_size_px=96, max_size_px=128, score_threshold=0.5, max_instances=7)
    assert not model.training
    assert model.transform.min_size == (96,) and model.transform.max_size == 128
    assert model.roi_heads.score_thresh == 0.5 and model.roi_heads.detections_per_img == 7
    assert model.roi_heads.box_predictor.cls_score.out_features == 2
    # A checkpoint dict with a "model" entry loads too.
    ckpt = tmp_path / "ckpt.pth"
    torch.save({"model": torch.load(weights_file, weights_only=True), "epoch": 3}, ckpt)
    assert load_maskrcnn(ckpt, "cpu", 96, 128).roi_heads.box_predictor.cls_score.out_features == 2
    with pytest.raises(UserInputError, match="min size"):
        load_maskrcnn(weights_file, "cpu", min_size_px=200, max_size_px=100)
    wrong = tmp_path / "wrong.pth"
    torch.save({"x": torch.zeros(1)}, wrong)
    with pytest.raises(UserInputError, match="not a torchvision Mask R-CNN state dict"):
        load_maskrcnn(wrong)


def test_cli_mask_maskrcnn(weights_file, small_dataset, tmp_path, capsys):
    from real2sim.cli import main

    root = tmp_path / "ds"
    shutil.copytree(small_dataset, root)
    # One small image, resized small: the default 800 px takes ~30 s on 2 cores.
    data = json.loads((root / "transforms.json").read_text())
    data["frames"] = data["frames"][:1]
    (root / "transforms.json").write_text(json.dumps(data))
    assert main(["mask", str(root), "--method", "maskrcnn", "--mask-weights", str(weights_file),
                 "--maskrcnn-min-size-px", "96", "--maskrcnn-max-size-px", "128"]) == 0
    assert "masks: 1 frames in masks_maskrcnn/" in capsys.readouterr().out
    _check_written(root, 1, 80, 60)


def test_cli_mask_maskrcnn_rejects_a_bad_size(small_dataset, weights_file):
    from real2sim.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["mask", str(small_dataset), "--method", "maskrcnn", "--mask-weights", str(weights_file),
              "--maskrcnn-min-size-px", "0"])
    assert exc.value.code == 2
