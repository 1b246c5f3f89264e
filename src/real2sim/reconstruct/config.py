"""The reconstruct stage's settings (:func:`real2sim.reconstruct.stage.reconstruct`), and what the stage turns
off in them when every pose came from aligning the silhouettes.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

from real2sim.plumbing.errors import UserInputError
from real2sim.reconstruct.field.train import FieldConfig

BACKENDS = ("field", "hull")
EXTRACTIONS = ("density", "tsdf")
# where the density extraction cuts: the level the masks' edges choose, or ln 2 per voxel
SURFACE_LEVELS = ("silhouettes", "half-light")
MASK_EDGES = ("auto", "colour", "as-given")


@dataclass(frozen=True)
class ReconstructConfig:
    """Settings of the reconstruct stage: which surface it makes from the posed, masked images and how.
    Lengths in metres, world frame; the table top is the plane z = ``table_z_m``."""

    backend: str = "field"
    """What makes the surface: "field" (a voxel radiance field trained on the masked images) or "hull"
    (the visual hull's surface, textured from the images: the baseline); one of ``BACKENDS``."""
    extraction: str = "density"
    """How the field backend gets its mesh: "density" (marching cubes on the field's density) or
    "tsdf" (TSDF fusion of depth rendered from the field, the paper's way); one of ``EXTRACTIONS``."""
    surface_level: str = "silhouettes"
    """Where the density extraction cuts: "silhouettes" (the level whose silhouettes agree best with the
    masks' edges, :func:`real2sim.reconstruct.field.extract.silhouette_surface_level`) or "half-light"
    (ln 2 per voxel: half the light through one voxel); one of ``SURFACE_LEVELS``."""
    mask_edges: str = "auto"
    """"colour": each mask's edge moved to its image's colour edge within a few pixels
    (:func:`real2sim.multiview.views.refined_mask_edges`); "as-given": the masks as they are; "auto":
    as "colour", except that `run` keeps parallax masks as given; one of ``MASK_EDGES``."""
    silhouette_poses: bool = True
    """Align the frames refine-poses could not refine by their silhouettes
    (:mod:`real2sim.reconstruct.poses.silhouette`); False: take their poses as given."""
    field: FieldConfig = field(default_factory=FieldConfig)
    """How the radiance field is trained (the field backend)."""
    hull_voxels: int = 192
    """Voxels along the longest side of the hull backend's grid; 16 to 1024."""
    hull_outlier_fraction: float = 0.03
    """The share of the views that see a point that may put it outside their masks while the visual hull
    keeps it (the object's region, the hull backend, the unrefined views' alignment); in [0, 1)."""
    texture_px: int = 1024
    """The side of the square texture image, pixels; 64 to 8192."""
    max_faces: int = 40_000
    """The mesh is simplified to at most this many faces; > 0."""
    held_out_every: int = 10
    """Every this-many-th view (from the ``held_out_every // 2``-th) is held out: never used to build
    anything, it judges the field's and the mesh's PSNR; >= 2."""
    table_z_m: float = 0.0
    """The height of the table top, metres, where the dataset has a table plane (the object stands on it,
    nothing below it is kept)."""
    min_part_volume_fraction: float = 0.05
    """Mesh parts smaller than this share of the largest part's volume (area, for open parts) are dropped
    as floaters; in [0, 1]."""
    max_image_side_px: int | None = 640
    """Images are reduced to this many pixels on their longer side, the camera with them (None: as
    captured): the field's grid cannot use more detail (:func:`real2sim.multiview.views.load_views`); >= 16."""

    def validate(self) -> None:
        if self.backend not in BACKENDS:
            raise UserInputError(f"unknown backend {self.backend!r} (choose from {', '.join(BACKENDS)})")
        if self.extraction not in EXTRACTIONS:
            raise UserInputError(f"unknown extraction {self.extraction!r} (choose from {', '.join(EXTRACTIONS)})")
        if self.mask_edges not in MASK_EDGES:
            raise UserInputError(f"unknown mask edges {self.mask_edges!r} (choose from {', '.join(MASK_EDGES)})")
        if self.surface_level not in SURFACE_LEVELS:
            raise UserInputError(f"unknown surface level {self.surface_level!r} (choose from {', '.join(SURFACE_LEVELS)})")
        if not 16 <= self.hull_voxels <= 1024 or not 64 <= self.texture_px <= 8192:
            raise UserInputError("hull voxels must be in 16..1024 and texture size in 64..8192 px")
        if self.max_image_side_px is not None and self.max_image_side_px < 16:
            raise UserInputError(f"images must keep at least 16 px on their longer side (got {self.max_image_side_px})")
        self.field.validate()


#: Why photo carving is left out when every pose came from the silhouettes (report.json's ``photo_carving``).
CARVING_OFF_ALIGNED = ("off: every pose came from aligning the silhouettes (1-2 px apart on our captures), too "
                       "coarse to compare colours between views; concavities the silhouettes cannot see stay filled")


def carving_after_alignment(config: ReconstructConfig) -> tuple[ReconstructConfig, str]:
    """``config`` without photo-consistent carving, when it had it, and what was done (for the report).

    Photo carving removes hull voxels where the views disagree about their colour, which needs the
    views registered to a fraction of a pixel; poses aligned by silhouettes alone are 1-2 px apart
    (:mod:`real2sim.reconstruct.poses.silhouette`), and on a textured surface the views then disagree
    everywhere (why: docs/design-notes/reconstruct.md#carving-after-alignment)."""
    if config.backend != "field" or not config.field.photo_carving:
        return config, "off" if config.backend == "field" else "not used by the hull backend"
    warnings.warn("photo carving skipped: the poses were aligned by their silhouettes alone, too coarse to compare "
                  "colours between views; concavities the silhouettes cannot see stay filled", RuntimeWarning,
                  stacklevel=2)
    return replace(config, field=config.field.with_carving(False)), CARVING_OFF_ALIGNED


FIELD_POSES_OFF_ALIGNED = ("off: every pose came from aligning the silhouettes; learnt on top of that they made "
                           "the shape worse on the one capture measured")


def field_poses_after_alignment(config: ReconstructConfig) -> tuple[ReconstructConfig, str]:
    """``config`` without the field's per-view pose corrections, when it had them, and what was done: learnt on
    top of poses aligned by the silhouettes, they made the shape worse on the one capture measured, for a
    reason not known (why: docs/design-notes/reconstruct.md#field-poses-after-alignment). They stay the
    default where refine-poses refined the views."""
    if config.backend != "field" or not config.field.pose_refinement:
        return config, "off" if config.backend == "field" else "not used by the hull backend"
    warnings.warn("field pose corrections skipped: every pose came from aligning the silhouettes, and on top of "
                  "that they made the shape worse where measured", RuntimeWarning, stacklevel=2)
    return replace(config, field=replace(config.field, pose_refinement=False)), FIELD_POSES_OFF_ALIGNED
