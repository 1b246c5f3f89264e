"""The object's height for ``--object-height-m``: the visual hull's top, or the sparse points' where the
hull stands over them as a cap (real2sim.capture.phone.object_height.object_top)."""

import warnings

import numpy as np
import pytest

from real2sim.capture.phone.normalise import NormaliseConfig
from real2sim.capture.phone.object_height import HullMeasure, object_top

VOXEL = 0.005


def _hull(wall_top: float, cap_height: float) -> HullMeasure:
    """A hull of unit cross-section up to ``wall_top``, then a cone ``cap_height`` tall over it (the
    cap the silhouettes leave over a flat top seen only from above)."""
    z = np.arange(0.0, wall_top + cap_height + 3 * VOXEL, VOXEL)
    area = np.where(z <= wall_top, 1.0, np.clip(1.0 - (z - wall_top) / max(cap_height, 1e-9), 0.0, None) ** 2)
    return HullMeasure(top=wall_top + cap_height, centre_xy=np.zeros(2), slice_z=z, slice_area=area, voxel=VOXEL)


def _points_up_to(top: float, count: int = 300, seed: int = 0) -> np.ndarray:
    """Sparse points spread over a wall up to ``top``, a few on its rim, with 0.2 % noise."""
    rng = np.random.default_rng(seed)
    heights = np.r_[rng.uniform(0.0, top, count), np.full(8, top)]
    return heights + rng.normal(0.0, 0.002 * top, len(heights))


def test_a_cap_over_a_flat_top_gives_way_to_the_sparse_points():
    hull = _hull(1.0, 0.08)  # the hull 8 % above the rim
    height, record = object_top(hull, _points_up_to(1.0), NormaliseConfig(object_height_m=0.1))
    assert height == pytest.approx(1.0, abs=0.005), record
    assert record["cap_fill"] < 0.7 and "sparse points" in record["from"]


def test_a_wall_standing_full_width_above_the_points_keeps_the_hull_and_warns():
    hull = _hull(1.08, 0.0)  # a featureless lid: the object goes on 8 % above the last sparse point
    with pytest.warns(UserWarning, match="visual hull"):
        height, record = object_top(hull, _points_up_to(1.0), NormaliseConfig(object_height_m=0.1))
    assert height == hull.top and record["cap_fill"] > 0.9


@pytest.mark.parametrize("points_top", [1.0, 0.985])
def test_points_that_reach_the_hull_s_top_keep_it(points_top):
    hull = _hull(1.0, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        height, record = object_top(hull, _points_up_to(points_top), NormaliseConfig(object_height_m=0.1))
    assert height == hull.top and "reach its top" in record["from"]


def test_too_few_points_on_the_object_keep_the_hull():
    hull = _hull(1.0, 0.08)
    height, record = object_top(hull, _points_up_to(1.0, count=5)[:12], NormaliseConfig(object_height_m=0.1))
    assert height == hull.top and record["object_points"] == 12 and "fewer than" in record["from"]


def test_a_narrowing_top_above_the_points_is_the_object_not_a_cap():
    # a bottle: a body of unit section up to 0.9, then a nozzle whose section falls to 2 % of it by 0.97 and
    # ends at 1.0; the points stop on the nozzle at 0.97 (too thin for them), the cone above fills a third
    z = np.arange(0.0, 1.0 + 3 * VOXEL, VOXEL)
    area = np.interp(z, [0.0, 0.9, 0.97, 1.0, 1.0 + VOXEL], [1.0, 1.0, 0.02, 0.0, 0.0])
    hull = HullMeasure(top=1.0, centre_xy=np.zeros(2), slice_z=z, slice_area=area, voxel=VOXEL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        height, record = object_top(hull, _points_up_to(0.97), NormaliseConfig(object_height_m=0.1))
    assert height == hull.top and record["top_section_share"] < 0.05 and "narrowing top" in record["from"]
    wide = _hull(0.97, 0.03)  # the same gap over a wide flat top is a cap: the points' top
    height, record = object_top(wide, _points_up_to(0.97), NormaliseConfig(object_height_m=0.1))
    assert height == pytest.approx(0.97, abs=0.005) and record["top_section_share"] > 0.9
