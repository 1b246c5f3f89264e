"""The keys real2sim adds to nerfstudio's ``transforms.json`` (:mod:`real2sim.formats.dataset`), and what
they say about a dataset: whether its poses are in an SfM model's frame, whether its images show a table
plane, the support height a rig states, and which frames ``refine-poses`` refined.

Each helper reads a :class:`~real2sim.formats.dataset.Dataset`'s ``extra`` (its top-level keys beyond
nerfstudio's) and ``root``; :mod:`real2sim.formats.dataset` re-exports them all.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from real2sim.plumbing.errors import UserInputError

if TYPE_CHECKING:
    from real2sim.formats.dataset import Dataset


#: transforms.json keys that say its poses are in an SfM model's frame (arbitrary scale, no table at
#: z = 0): ``source``/``model_frame`` from :func:`read_dataset` of a COLMAP model and the masks
#: stage's copy of one; ``applied_transform``/``ply_file_path`` from nerfstudio's ``ns-process-data``.
MODEL_FRAME_KEYS = ("source", "model_frame", "applied_transform", "ply_file_path")


#: Top-level transforms.json key: ``false`` when the images show no table plane (``capture --no-table``:
#: the object on a thin stand, its lowest point at z = 0). Absent: the table top is the plane z = 0.
TABLE_PLANE_KEY = "table_plane"


def has_table_plane(ds: "Dataset") -> bool:
    """False when ``ds`` says its images show no table plane (:data:`TABLE_PLANE_KEY`)."""
    return ds.extra.get(TABLE_PLANE_KEY) is not False


#: Top-level transforms.json key of a dataset without a table plane: the height (world z, metres) of the
#: plane the object stands on, when the rig knows it (a stand's or a turntable's top; ``capture --no-table``
#: writes 0, the stand's top). The object is then taken to lie above it: `reconstruct` cuts there and `run`
#: closes the asset's bottom there. Absent: the object's own lowest seen points (:mod:`pipeline.support`).
SUPPORT_Z_KEY = "support_z_m"


def stated_support_z_m(ds: "Dataset") -> float | None:
    """The support height a dataset without a table plane states (:data:`SUPPORT_Z_KEY`), else None.
    UserInputError when the key holds something other than a finite number, or sits beside a table plane
    (whose top is the support already)."""
    if SUPPORT_Z_KEY not in ds.extra:
        return None
    value = ds.extra[SUPPORT_Z_KEY]
    label = f"{ds.root / 'transforms.json'}: {SUPPORT_Z_KEY}"
    if has_table_plane(ds):
        raise UserInputError(f"{label} is for a dataset without a table (\"{TABLE_PLANE_KEY}\": false); "
                             "with a table its top is the support")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserInputError(f"{label} must be a number (metres, world z), got {value!r}")
    return float(value)


#: Per-frame transforms.json key written by ``refine-poses``: whether COLMAP refined that frame's pose
#: (a frame it could not register keeps the robot's pose, with the robot's noise).
POSE_REFINED_KEY = "real2sim_pose_refined"


def is_model_frame(ds: "Dataset") -> bool:
    """True when ``ds``'s poses are in an SfM model's frame and scale (a COLMAP model, or a
    nerfstudio-processed capture), not metres in a frame with the table top at z = 0."""
    return ds.extra.get("source") == "colmap" or any(k in ds.extra for k in MODEL_FRAME_KEYS[1:])


def describe_model_frame(ds: "Dataset") -> str:
    """What kind of model-frame dataset ``ds`` is, for messages."""
    if ds.extra.get("source") == "colmap" or "model_frame" in ds.extra:
        return "a COLMAP model"
    return "a nerfstudio-processed capture (transforms.json with applied_transform: COLMAP's frame and scale)"
