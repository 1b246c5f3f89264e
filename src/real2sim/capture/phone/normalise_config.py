"""How the ``robot_frame`` stage (:mod:`real2sim.capture.phone.normalise`) finds the robot frame of a COLMAP
capture; below the stage and its object-height step (:mod:`real2sim.capture.phone.object_height`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from real2sim.plumbing.errors import UserInputError


@dataclass(frozen=True)
class NormaliseConfig:
    """How to find the robot frame: the metric scale (exactly one of ``object_height_m``, ``scale`` and
    ``marker_mm``), the
    table plane and the object's height. Distances are fractions of the median camera distance from the
    look-at point, so they do not depend on the model's unknown scale."""

    object_height_m: float | None = None
    """The object's height above the table, metres (> 0); the scale is this over the measured height."""
    scale: float | None = None
    """Metres per model unit (> 0), instead of ``object_height_m``."""
    marker_mm: float | None = None
    """Side of the printed square markers on the table, mm (> 0), instead of ``object_height_m``: the scale is
    this over their mean triangulated side, and the table plane the plane of their corners
    (:mod:`real2sim.capture.phone.markers`)."""
    marker_dictionary: str | None = None
    """The markers' OpenCV aruco dictionary (e.g. DICT_4X4_50, DICT_APRILTAG_36h11); None: the common ones
    are tried and the one with the most detections is used."""
    near_radius: float = 1.0
    """Sparse points within this many median camera distances of the cameras' look-at point are the table
    and the object around it (step 1; > 0)."""
    inlier_threshold: float = 0.01
    """RANSAC's inlier distance from the table plane, as a fraction of the median camera distance."""
    ransac_iterations: int = 1000
    """RANSAC hypotheses (3-point samples) for the table plane."""
    min_table_points: int = 30
    """Fewest inliers the table plane needs."""
    max_plane_disagreement_deg: float = 2.0
    """A WARNING when the sparse points' table plane and the dense points' differ by more than this, degrees
    (> 0): on the bundled objects' captures they agree within a degree."""
    object_vote_fraction: float = 0.8
    """A sparse point is the object's when it lies inside the masks in at least this share (0-1) of the views
    that see it; those are left out of the table's fit."""
    hull_voxels: int = 128
    """Voxels along the longest side of the masks' visual hull (step 3)."""
    hull_outlier_fraction: float = 0.03
    """Share (0-1) of the views that see a voxel whose masks may leave it out without carving it."""
    top_points: int = 7
    """The top of the sparse points on the object is the median of this many highest of them (step 3)."""
    min_object_points: int = 20
    """Fewest sparse points on the object for their top to be considered at all."""
    top_gap: float = 0.03
    """The points' top replaces the hull's only when the hull rises more than this fraction of its height
    above it (and fills under ``cap_fill``)."""
    cap_fill: float = 0.7
    """... and the hull's volume above the points' top is under this share of a prism on its cross-section
    there (a cone's: 1/3). (why: docs/design-notes/capture.md#normalise-object-top)"""
    narrow_top: float = 0.25
    """... and the hull's cross-section at the points' top is at least this share (0-1) of its widest: a cap's
    base is a top face as wide as the object there, while a top narrowing below it (a bottle's nozzle, a
    neck, a knob) is the object itself, too thin for the points to reach (bottle 0.02, can 1.0, mug 0.79;
    docs/design-notes/capture.md#normalise-object-top)."""

    def validate(self) -> None:
        given = [v for v in (self.object_height_m, self.scale, self.marker_mm) if v is not None]
        if len(given) != 1:
            raise UserInputError("a COLMAP model has no metric scale: give exactly one of --object-height-m H "
                                 "(the object's height above the table, m), --scale S (metres per model unit) or "
                                 "--marker-mm S (the side of printed square markers on the table, mm)")
        if not (np.isfinite(given[0]) and given[0] > 0):
            raise UserInputError(f"--object-height-m / --scale / --marker-mm must be a finite number > 0 (got {given[0]})")
        if self.marker_dictionary is not None and self.marker_mm is None:
            raise UserInputError("--marker-dictionary is for --marker-mm (the markers' side)")
