"""The settings of photo-consistent carving (:mod:`real2sim.reconstruct.carving.photo`), apart from the
carving so that the verdict on each voxel (:mod:`real2sim.reconstruct.carving.verdict`) reads them too.

Colours are RGB in [0, 1]; lengths are in voxels of the carving grid, or in voxel footprints (the
pixels one voxel spans in a typical view, :func:`real2sim.multiview.voxel_grid.voxel_footprint_px`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CarvingConfig:
    """How photo-consistent carving tests the visual hull's surface voxels against the views' colours,
    and how far its two passes (the carving and the hollow prior) may go."""

    voxels: int = 80
    """Voxels along the longest side of the carving grid, at least (a finer field grid is carved as it
    is); > 0. On coarser voxels a true surface's voxel centres lie so far inside it that its views
    disagree (why: docs/design-notes/reconstruct.md#carving-grid)."""
    max_spread: float = 0.15
    """A surface voxel disagrees when its views' colour spread (RGB distance from their per-channel
    median, at ``spread_quantile``) exceeds this; in (0, sqrt 3]."""
    spread_quantile: float = 0.75
    """The quantile of the views' colour distances taken as a voxel's spread; in [0, 1]."""
    max_hue_spread: float = 0.15
    """A carve starts only where the views' hue spread (colour over brightness) exceeds this too, so
    that brightness alone (a shiny or curved surface) opens nothing; > 0."""
    hue_quantile: float = 0.75
    """The quantile of the views' hue distances taken as a voxel's hue spread; in [0, 1]."""
    hue_floor: float = 0.3
    """Added to a colour's R + G + B before the hue divides by it: it damps the hues of dark pixels,
    whose ratios are noise; >= 0, in RGB-sum units (0 to 3)."""
    min_views: int = 4
    """Views that must see a voxel for its verdict to count, and for the counts of views that reach it
    through the carved space or from outside; >= 1."""
    neighbour_fraction: float = 0.5
    """A disagreeing voxel is carved only when at least this share of the surface voxels in its 3x3x3
    neighbourhood disagree too (an isolated one is a texture edge); in [0, 1]."""
    blur_voxels: float = 0.5
    """The images are blurred with a Gaussian of this many voxel footprints (sigma) before their
    colours are compared; >= 0, 0 leaves them sharp."""
    max_rounds: int = 150
    """Rounds of each pass, at most (a round removes the surface voxels found inconsistent and tests
    the ones it exposes); >= 0."""
    visibility_tolerance_voxels: float = 1.0
    """A view sees a voxel when nothing of the solid lies on its ray nearer than the voxel less this
    many voxels; >= 0."""
    visibility: str = "auto"
    """How a line of sight is tested against the solid: "mesh" (Embree on its marching-cubes surface,
    rebuilt each round), "voxels" (the ray walked through the solid's trilinear interpolation with
    torch, :func:`real2sim.reconstruct.carving.voxel_rays.segments_blocked`), or "auto": the mesh on a
    CPU, the voxels on a GPU (why: docs/design-notes/reconstruct.md#carving-visibility)."""
    min_component_fraction: float = 0.1
    """Carved parts (26-connected) smaller than this share of the hull's volume are put back: shading
    makes small inconsistent patches, a concavity that matters is large; in [0, 1]."""
    hollow_prior: bool = True
    """Run the second pass, the hollow prior: once a concavity is open, the space behind it that the
    images cannot place a surface in is removed too (the module docstring of
    :mod:`real2sim.reconstruct.carving.photo`)."""
    featureless_contrast: float = 0.03
    """The hollow prior: image contrast (RGB standard deviation over ``contrast_window_voxels``
    footprints) below which a view cannot place a surface; >= 0."""
    contrast_window_voxels: float = 2.0
    """The hollow prior: the width, in voxel footprints, of the square window the image contrast is
    measured over; > 0 (at least 3 px are used)."""
    min_spread_to_contrast: float = 1.25
    """The hollow prior: a voxel's views cannot place it where they disagree at least this many times
    as much as their images vary around it; > 0 (why: docs/design-notes/reconstruct.md#spread-to-contrast)."""
    depth_test_voxels: float = 2.0
    """The hollow prior's depth test: how many voxels deeper, along the views' mean line of sight, a
    surface is tried; >= 0, 0: no depth test (why: docs/design-notes/reconstruct.md#depth-test)."""
    depth_test_margin: float = 0.02
    """The depth test: the views cannot place a voxel when they would agree within this much (RGB
    distance) as well about the deeper surface; >= 0."""
    min_wall_voxels: float = 2.0
    """The hollow prior keeps every voxel within this many voxels of the visual hull's outside or of
    the table: the wall the silhouettes vouch for; >= 0."""
    exposure_correction: bool = True
    """Take each view's exposure and white balance out of its images before the colours are compared,
    where that makes the views agree clearly better (:mod:`real2sim.reconstruct.carving.view_exposure`)."""
    restore_band_voxels: int = 1
    """The masks' re-check puts back, round by round, only the carved voxels within this many voxels
    of the carved solid on each emptied ray (:func:`real2sim.reconstruct.carving.mask_recheck.put_back_for_masks`);
    >= 1 (why: docs/design-notes/reconstruct.md#mask-recheck)."""
    max_restore_rounds: int = 20
    """Rounds of that band-wise put-back, at most; a ray still empty after them gets back every carved
    voxel on it; >= 0."""
    void_gap_voxels: int = 2
    """The re-check then fills the carved space its skin closes off: openings at most twice this many
    voxels wide do not count as a way out; >= 0 (why: docs/design-notes/reconstruct.md#mask-recheck)."""
