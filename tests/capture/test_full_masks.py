"""Issue 33 #9: all-white masks (every pixel object) are no silhouettes. `mask --method provided` and the
reconstruction's view loading refuse them (exit 2, one line) when every mask is full, and warn with the
count and the measured coverage when only some are."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
from PIL import Image

from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.objects import make_object
from tests.cli_helpers import run_cli


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("full") / "ds"
    capture(make_object("can"), root, CaptureConfig(views=8, width=32, height=24, seed=1))
    return root


def _whiten(root, count: int) -> list[str]:
    """Make the first ``count`` rendered masks all white; their names."""
    frames = json.loads((root / "transforms.json").read_text())["frames"]
    names = []
    for frame in frames[:count]:
        path = root / frame["mask_path"]
        Image.fromarray(np.full(np.asarray(Image.open(path)).shape[:2], 255, np.uint8)).save(path)
        names.append(frame["file_path"])
    return names


def test_every_mask_full_is_refused(tiny, tmp_path, capsys):
    from real2sim.multiview.views import load_views

    root = tmp_path / "ds"
    shutil.copytree(tiny, root)
    _whiten(root, 8)
    before = (root / "transforms.json").read_bytes()
    code, _, err = run_cli(capsys, "mask", root, "--method", "provided")
    errors = [line for line in err.splitlines() if "error:" in line]
    assert code == 2 and len(errors) == 1 and "Traceback" not in err, err
    assert "every mask covers over 95 % of the image (least 100.0 %)" in err
    assert (root / "transforms.json").read_bytes() == before
    with pytest.raises(UserInputError, match="every mask covers over 95 %"):
        load_views(root)
    load_views(root, need_masks=False)  # parallax masks do not read them


def test_some_masks_full_warn(tiny, tmp_path, capsys):
    from real2sim.multiview.views import load_views

    root = tmp_path / "ds"
    shutil.copytree(tiny, root)
    names = _whiten(root, 2)
    code, out, err = run_cli(capsys, "mask", root, "--method", "provided")
    assert code == 0, err
    warning = [line for line in err.splitlines() if line.startswith("WARNING:")]
    assert len(warning) == 1 and f"2 of 8 masks cover over 95 % of the image (first: {names[0]}, 100.0 %)" in warning[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        views = load_views(root)
    assert views.count == 8
    assert [str(w.message) for w in caught if "2 of 8 masks" in str(w.message)], [str(w.message) for w in caught]


def test_silhouettes_pass_quietly(tiny, capsys, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(tiny, root)
    code, _, err = run_cli(capsys, "mask", root, "--method", "provided")
    assert code == 0 and "WARNING" not in err, err


def test_computed_masks_all_full_publish_nothing(tiny, tmp_path):
    """A method whose every mask is full (here a stand-in for a background difference against the wrong
    empty scene) is refused before masks_<method>/ or transforms.json change."""
    from real2sim.capture.masks.methods import publish_masks
    from real2sim.formats.dataset import read_dataset

    root = tmp_path / "ds"
    shutil.copytree(tiny, root)
    before = (root / "transforms.json").read_bytes()
    ds = read_dataset(root)
    with pytest.raises(UserInputError, match="the background masks of .*: every mask covers over 95 %"):
        publish_masks(root, ds, "background", lambda i, f: np.ones((24, 32), bool))
    assert (root / "transforms.json").read_bytes() == before
    assert not [p.name for p in root.iterdir() if "masks_background" in p.name]
