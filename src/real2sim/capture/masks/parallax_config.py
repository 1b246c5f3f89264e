"""The parallax masks' settings (:mod:`real2sim.capture.masks.parallax`).

The measurements behind the defaults are in docs/design-notes/capture.md (the parallax sections).
"""

from __future__ import annotations

from dataclasses import dataclass

from real2sim.plumbing.errors import UserInputError

#: ``ParallaxConfig.plate_object_threshold`` of a phone capture: `run` of photos or a clip turns the object's second
#: opinion on at this level, and for photos the plate round's stricter outlier share
#: (``PHONE_PHOTOS_PLATE_OUTLIER_FRACTION``). (why: docs/design-notes/capture.md#parallax-plate-object)
PHONE_PLATE_OBJECT_THRESHOLD = 0.08
PHONE_PHOTOS_PLATE_OUTLIER_FRACTION = 0.04


@dataclass(frozen=True)
class ParallaxConfig:
    """Settings of the parallax masks: the neighbours each view is judged against, the table test, the
    standing hull and the table plate. The steps named (1-7) are those of
    :mod:`real2sim.capture.masks.parallax`'s docstring."""

    neighbours: int = 8
    """Views warped onto each view (>= 2)."""
    min_angle_deg: float = 8.0
    """Neighbours are chosen among the views whose direction from the cameras' common point differs by at
    least this many degrees (0 to ``max_angle_deg``)..."""
    max_angle_deg: float = 35.0
    """... and at most this many (up to 90): more angle, more parallax, and more of the table hidden
    differently."""
    threshold: float = 14.0
    """Largest channel difference (0-255) of a table pixel from the colour range of a neighbour's warped
    image around it."""
    agreement: float = 0.6
    """Share (0-1) of the voting neighbours that must agree for a pixel to be table."""
    min_texture: float = 4.0
    """Local standard deviation (0-255, the largest over the colour channels, ``texture_px`` radius) below
    which a pixel is undecided: a plain patch, which takes the verdict of the textured pixels around it."""
    texture_px: int = 2
    """Radius (px) of the window of the texture and aperture tests."""
    outlier_fraction: float = 0.05
    """Share (0-1) of the views seeing a voxel that may call it table without carving it (step 3).
    (why: docs/design-notes/capture.md#parallax-outlier-fraction)"""
    base_outlier_fraction: float = 0.1
    """The same for the object's foot, up to the height ``base_parallax_px`` gives (``outlier_fraction`` to
    below 1). (why: docs/design-notes/capture.md#parallax-outlier-fraction)"""
    base_parallax_px: float = 8.0
    """The foot is what lies below the height at which a point moves this many pixels against the table
    between a view and its neighbours (:func:`~real2sim.capture.masks.parallax.low_parallax_height_m`; >= 0)."""
    hull_voxels: int = 160
    """Voxels along the hull grid's longest side (fewer where a voxel would span under half a pixel)."""
    max_image_px: int = 640
    """Images are reduced to this longer side (px) first; the masks come back at full size."""
    bottom_band: float = 0.08
    """Columns whose lowest voxel lies within this fraction of the hull's height above the table are filled
    down to it (step 4)."""
    table_z_m: float = 0.0
    """Height of the table plane, z in the views' units (metres in the robot frame)."""
    match_reach_px: float = 1.0
    """How far (px, 0-1) around a warped pixel its colour range reaches (step 2).
    (why: docs/design-notes/capture.md#parallax-reach)"""
    base_reach_px: float = 0.5
    """The same for the object's base (step 4), at most ``match_reach_px``.
    (why: docs/design-notes/capture.md#parallax-reach)"""
    min_parallax_share: float = 0.25
    """A neighbour votes on a pixel only where at least this share (0-1) of the local gradient energy lies
    along its parallax (0.25: the parallax within 60 degrees of the gradient); 0: off.
    (why: docs/design-notes/capture.md#parallax-aperture)"""
    min_table_speck_share: float = 0.0005
    """Parts of a view's table verdict smaller than this share of the image (0 to below 1; 154 px at 640x480)
    are dropped (step 2); 0 keeps them. (why: docs/design-notes/capture.md#parallax-specks)"""
    plate_threshold: float = 0.06
    """Step 6: a mask pixel is explained by the table plate when the mean difference over its window is below
    this (largest channel, RGB in [0, 1]); 0 leaves step 6 out.
    (why: docs/design-notes/capture.md#parallax-plate)"""
    plate_window_px: int = 2
    """Step 6: radius (px) of the window (:func:`real2sim.capture.masks.table_plate.explained_by_plate`)."""
    plate_min_texture: float = 0.02
    """Step 6: the plate's grey standard deviation over the window must exceed this (RGB in [0, 1]).
    (why: docs/design-notes/capture.md#parallax-plate)"""
    plate_pixel_threshold: float = 0.04
    """Step 6 with sliding windows: any window holding the pixel may pass, and the pixel's own difference must
    be below this (RGB in [0, 1]); 0: the centred window only.
    (why: docs/design-notes/capture.md#parallax-plate-sliding)"""
    plate_min_island_share: float = 0.0
    """Step 6's explained pixels that form an island of their own (holding none of steps 2-5's table) smaller
    than this share of the image are dropped; 0: off. (why: docs/design-notes/capture.md#parallax-plate-islands)"""
    plate_object_threshold: float = 0.0
    """An explained pixel stays object when the round's solid explains its image as well: the median difference
    (largest channel, RGB in [0, 1]) to what the neighbours see where its ray meets the solid, averaged over
    the window, is below this; 0: off; `run` of phone photos or a video sets
    :data:`PHONE_PLATE_OBJECT_THRESHOLD`. (why: docs/design-notes/capture.md#parallax-plate-object)"""
    plate_outlier_fraction: float | None = None
    """Share (0 to below 1) of the views that may call a voxel table in step 6's hull; None:
    ``outlier_fraction``; `run` of phone photos sets :data:`PHONE_PHOTOS_PLATE_OUTLIER_FRACTION`.
    (why: docs/design-notes/capture.md#parallax-plate-outliers)"""

    def validate(self) -> None:
        if self.neighbours < 2:
            raise UserInputError("parallax masks need at least 2 neighbouring views per view")
        if not 0 <= self.min_angle_deg < self.max_angle_deg <= 90:
            raise UserInputError("parallax masks: need 0 <= min_angle_deg < max_angle_deg <= 90")
        if not 0 <= self.base_reach_px <= self.match_reach_px <= 1:
            raise UserInputError("parallax masks: need 0 <= base_reach_px <= match_reach_px <= 1 (pixels)")
        if not 0 <= self.outlier_fraction <= self.base_outlier_fraction < 1 or self.base_parallax_px < 0:
            raise UserInputError("parallax masks: need 0 <= outlier_fraction <= base_outlier_fraction < 1 and "
                                 "base_parallax_px >= 0")
        if min(self.plate_threshold, self.plate_window_px, self.plate_min_texture, self.plate_pixel_threshold,
               self.plate_object_threshold) < 0:
            raise UserInputError("parallax masks: need plate_threshold, plate_window_px, plate_min_texture, "
                                 "plate_pixel_threshold and plate_object_threshold >= 0")
        if self.plate_outlier_fraction is not None and not 0 <= self.plate_outlier_fraction < 1:
            raise UserInputError("parallax masks: need 0 <= plate_outlier_fraction < 1 (a share of the views)")
        if not 0 <= self.min_parallax_share <= 1 or not 0 <= self.min_table_speck_share < 1 \
                or not 0 <= self.plate_min_island_share < 1:
            raise UserInputError("parallax masks: need 0 <= min_parallax_share <= 1, 0 <= min_table_speck_share < 1 "
                                 "and 0 <= plate_min_island_share < 1 (shares)")
