"""Masks' edges moved to the images' colour edges (issue #28 part 4): real recipes' masks carry a halo
of blur and shadow or stop short of the rim; within a few pixels of the edge the colours decide.

Judged against the exact masks of a rendered capture (``ground_truth/masks``) and the true can.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, binary_erosion

from tests.reconstruct.conftest import copy_dataset


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a >= 0.5, b >= 0.5
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def can_views(can_capture):
    from real2sim.multiview.views import load_views

    return load_views(can_capture)


@pytest.mark.parametrize("change", ["halo", "short"])
def test_a_rough_mask_comes_back_to_the_object(can_views, change):
    """Masks grown by 2 px (a threshold's halo) or shrunk by 2 px (a network that misses the rim) on a
    160x120 capture: refined, they agree with the exact masks much better than before."""
    from real2sim.geometry.silhouettes import colour_refined_mask, edge_band_px

    disk = np.ones((5, 5), bool)
    band = edge_band_px(can_views.intrinsics.width, can_views.intrinsics.height)
    before, after = [], []
    for i in range(0, can_views.count, 6):
        exact = can_views.mask[i] >= 0.5
        rough = binary_dilation(exact, disk) if change == "halo" else binary_erosion(exact, disk)
        refined = colour_refined_mask(can_views.rgb[i], rough.astype(np.float32), band)
        before.append(_iou(rough, exact))
        after.append(_iou(refined, exact))
    assert np.mean(after) >= 0.95 and np.mean(after) >= np.mean(before) + 0.04, (before, after)


def test_exact_masks_are_kept_as_given(can_views):
    """A rendered capture's masks differ from the colours only at a few mixed pixels (a rim seen
    edge-on): the stage keeps them, and says so."""
    from real2sim.multiview.views import MIN_EDGE_SHIFT_PX, refined_mask_edges

    kept, report = refined_mask_edges(can_views)
    assert not report["applied"] and report["median_edge_shift_px"] < MIN_EDGE_SHIFT_PX, report
    assert kept.mask is can_views.mask


def test_a_mask_with_nothing_outside_the_band_is_left_alone():
    from real2sim.geometry.silhouettes import colour_refined_mask

    rgb = np.random.default_rng(0).random((40, 50, 3)).astype(np.float32)
    full = np.ones((40, 50), np.float32)
    assert np.array_equal(colour_refined_mask(rgb, full, 3), full)
    empty = np.zeros((40, 50), np.float32)
    assert np.array_equal(colour_refined_mask(rgb, empty, 3), empty)


def test_the_hull_of_haloed_masks_is_nearer_the_can_with_colour_edges(can_capture, tiny_config, tmp_path):
    """Every mask of the capture grown by 2 px, then the hull backend: with the masks as given the
    can comes out fat; with their edges moved to the colours it is nearer the truth, and report.json
    says what was moved."""
    from PIL import Image

    from real2sim.formats.dataset import read_dataset
    from real2sim.reconstruct.stage import reconstruct

    haloed = copy_dataset(can_capture, tmp_path / "can", ground_truth=True)
    for frame in read_dataset(haloed).frames:
        path = haloed / frame.mask_path
        grown = binary_dilation(np.asarray(Image.open(path).convert("L")) >= 128, np.ones((5, 5), bool))
        Image.fromarray((grown * 255).astype(np.uint8)).save(path)
    config = replace(tiny_config, backend="hull")
    as_given = reconstruct(haloed, replace(config, mask_edges="as-given")).report
    colour = reconstruct(haloed, config).report
    assert as_given["mask_edges"] == {"method": "as-given"}
    assert colour["mask_edges"]["applied"] and colour["mask_edges"]["median_edge_shift_px"] > 1.0, colour["mask_edges"]
    assert colour["truth"]["chamfer_mm"] < 0.8 * as_given["truth"]["chamfer_mm"], (colour["truth"], as_given["truth"])
