"""The object's height above the table in a COLMAP capture's table frame, for ``--object-height-m``
(step 3 of :mod:`real2sim.capture.phone.normalise`, whose docstring says why): the masks' visual hull,
or the top of the sparse points on the object where the hull stands over them as a cap. Model
units throughout (the scale is what the height is for)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from real2sim.capture.phone import robot_frame as rf
from real2sim.capture.phone.normalise_config import NormaliseConfig
from real2sim.formats.dataset import CV_FROM_GL, Dataset


@dataclass(frozen=True)
class HullMeasure:
    """The masks' visual hull in the rigid table frame (model units): its ``top`` above the table, its
    footprint ``centre_xy`` (2,), and per horizontal slice of its grid the slice's height ``slice_z``
    (Z,) and the hull's area in it ``slice_area`` (Z,)."""

    top: float
    centre_xy: np.ndarray
    slice_z: np.ndarray
    slice_area: np.ndarray
    voxel: float


def measure_object(ds: Dataset, masks: np.ndarray, table: rf.Similarity, config: NormaliseConfig) -> HullMeasure:
    """The masks' visual hull in the rigid table frame ``table`` (model units)."""
    from real2sim.multiview.hull import visual_hull_mesh
    from real2sim.multiview.views import PosedViews

    k = ds.intrinsics
    c2w_cv = rf.transform_poses(table, ds.poses_c2w_gl()) @ CV_FROM_GL
    # The hull reads masks and poses only: a zero-strided stand-in for the colour images costs no memory.
    rgb = np.broadcast_to(np.zeros((1, 1, 1, 3), np.float32), (len(ds.frames), k.height, k.width, 3))
    views = PosedViews(rgb, masks.astype(np.float32), c2w_cv, k, tuple(f.file_path for f in ds.frames))
    mesh, grid, scores = visual_hull_mesh(views, longest_side_voxels=config.hull_voxels,
                                          outlier_fraction=config.hull_outlier_fraction, table_z_m=0.0)
    lo, hi = mesh.bounds
    slice_z = grid.origin_m[2] + np.arange(grid.shape[2]) * grid.voxel_m
    slice_area = (scores >= 0.5).sum(axis=(0, 1)) * grid.voxel_m ** 2
    return HullMeasure(float(hi[2]), 0.5 * (lo[:2] + hi[:2]), slice_z, slice_area.astype(float), float(grid.voxel_m))


def object_top(hull: HullMeasure, point_heights: np.ndarray | None, config: NormaliseConfig,
               dense_top: float | None = None) -> tuple[float, dict]:
    """The object's top above the table (model units) and a record of how it was chosen: the hull's
    top, or that of the sparse points on the object (``point_heights``, model units above the table)
    where the hull stands over them as a cap (module docstring, step 3). ``dense_top``: the top of the
    dense points on the object (:mod:`real2sim.multiview.dense`) in their place, the same rule."""
    if dense_top is not None:
        points_top, label = float(dense_top), "dense points"
        record = {"hull_top_units": hull.top, "dense_top_units": points_top}
    else:
        heights = np.sort(point_heights[point_heights > 0])[::-1]
        record = {"hull_top_units": hull.top, "object_points": len(heights)}
        if len(heights) < config.min_object_points:
            return hull.top, {**record, "from": f"the visual hull (fewer than {config.min_object_points} sparse "
                                                "points on the object)"}
        points_top, label = float(np.median(heights[:config.top_points])), "sparse points"
    record["points_top_units"] = points_top
    gap = (hull.top - points_top) / hull.top
    record["hull_above_points"] = gap
    if gap <= config.top_gap:
        return hull.top, {**record, "from": f"the visual hull (the {label} reach its top)"}
    above = hull.slice_z >= points_top
    section = float(np.interp(points_top, hull.slice_z, hull.slice_area))
    share = section / float(hull.slice_area.max()) if hull.slice_area.max() > 0 else 0.0
    record["top_section_share"] = share
    if share < config.narrow_top:
        return hull.top, {**record, "from": f"the visual hull (at the top of the {label} the object is "
                                            f"{100 * share:.0f} % of its widest section: a narrowing top, a neck "
                                            "or nozzle too thin for the points, not a cap over a wide top)"}
    prism = section * (hull.top - points_top)
    fill = float(hull.slice_area[above].sum() * hull.voxel / prism) if prism > 0 else 1.0
    record["cap_fill"] = fill
    if fill < config.cap_fill:
        which = ("their 99th percentile" if dense_top is not None
                 else f"the median of the {config.top_points} highest")
        return points_top, {**record, "from": f"the top of the {label} on the object ({which}): the visual hull "
                                              f"rises {100 * gap:.1f} % above them as a cap, an outer bound over a "
                                              "top seen only from above"}
    warnings.warn(f"the object's height is read from the masks' visual hull, which stands {100 * gap:.1f} % above "
                  f"the highest {label} on the object and full width: a top with no features, or a hull "
                  "that no view bounds there; if the asset comes out small, lay the printed board under the "
                  "object (`real2sim board`) or give --scale", stacklevel=2)
    return hull.top, {**record, "from": f"the visual hull (it stands full width above the {label}: a top "
                                        "with no features; warned)"}
