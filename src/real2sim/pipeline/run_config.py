"""What `real2sim run` is given besides the dataset and ASSETDIR (:class:`RunConfig`), what it returns
(:class:`RunResult`), and the settings a phone capture changes (:func:`phone_mask_config`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from real2sim.capture.masks.stage import AUTO, PARALLAX
from real2sim.capture.phone.normalise import NormaliseConfig

if TYPE_CHECKING:
    from real2sim.asset.build import AssetConfig
    from real2sim.capture.masks.methods import MaskConfig
    from real2sim.capture.poses.refinement import RefineConfig
    from real2sim.evaluate.sweep import EvaluationConfig
    from real2sim.pipeline.phone import PhoneConfig
    from real2sim.capture.masks.parallax_config import ParallaxConfig
    from real2sim.reconstruct.stage import ReconstructConfig


@dataclass(frozen=True)
class RunConfig:
    """Everything `run` needs besides the dataset and ASSETDIR: the settings of each stage it chains."""

    asset: "AssetConfig"
    """The asset stage's settings (mass, SPECs, ...); `run` forces ``flat_bottom`` on, at the support it
    finds; its ``pca_up`` (default off) keeps the table's normal as the asset's +z."""
    reconstruct: "ReconstructConfig | None" = None
    """The reconstruct stage's settings; None: its defaults."""
    mask_method: str | None = None
    """None: the dataset's own masks (every frame must have one; photos and videos: ``auto``); else the method
    the masks stage makes them with (:func:`real2sim.capture.masks.stage.make_masks`) on a copy; ``parallax``
    (and ``auto``) masks of a robot capture are made after refine_poses, on the refined poses. ``auto`` (the default for photos and
    videos): parallax masks, or masks from geometry where the data shows parallax masks cannot be the object's."""
    mask: "MaskConfig | ParallaxConfig | None" = None
    """The mask method's settings (a ParallaxConfig for parallax masks); None: the method's defaults, and for
    a phone capture :func:`phone_mask_config`'s."""
    refine: "RefineConfig | None" = None
    """Pose refinement's settings; None: no refinement (the API does what it is given; the command line
    refines by default where :func:`real2sim.pipeline.run_folder.poses_to_refine`)."""
    evaluation: "EvaluationConfig | None" = None
    """The evaluation sweep's settings; None: no evaluation."""
    device: str = "cpu"
    """The torch device the reconstruct stage runs on ("cpu", "cuda")."""
    seed: int = 0
    """Seeds the stages' random choices (parallax masks, robot_frame, reconstruct)."""
    object_height_m: float | None = None
    """A COLMAP dataset's object height above the table, m; > 0. A COLMAP dataset (poses in an arbitrary
    frame and scale) needs exactly one of this and ``scale``, which the robot_frame stage then normalises;
    a transforms.json dataset (metric, table at z = 0) neither."""
    scale: float | None = None
    """A COLMAP dataset's metres per model unit; > 0 (see ``object_height_m``)."""
    marker_mm: float | None = None
    """A COLMAP dataset's printed square markers' side, mm; > 0: scale and table plane from them, instead of
    ``object_height_m`` (see there)."""
    marker_dictionary: str | None = None
    """The markers' OpenCV aruco dictionary; None: the common ones tried (with ``marker_mm`` only)."""
    phone: "PhoneConfig | None" = None
    """A phone capture's settings (video frames, the board's square, structure from motion); None: defaults."""

    def robot_frame(self) -> NormaliseConfig | None:
        """The robot_frame stage's settings; None when none of object_height_m, scale and marker_mm is given."""
        if self.object_height_m is None and self.scale is None and self.marker_mm is None:
            return None
        return NormaliseConfig(object_height_m=self.object_height_m, scale=self.scale, marker_mm=self.marker_mm,
                               marker_dictionary=self.marker_dictionary)


@dataclass
class RunResult:
    asset_dir: Path
    statuses: dict[str, str]  # stage -> "ran" | "skipped"
    manifest_path: Path
    truth: dict | None = None
    urdf_paths: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # run's own notices (a stale evaluation), said once
    #: what degraded: every warning the stages raised, ``{"stage", "message"}``, those of the stages
    #: skipped as unchanged included (from run.json); the command repeats them in its summary
    stage_warnings: list[dict] = field(default_factory=list)
    #: the stage the run stopped before when its ``pause`` asked (None: it ran to the end)
    paused_before: str | None = None


def phone_mask_config(config: RunConfig, kind: str) -> RunConfig:
    """``config`` for a phone capture of ``kind`` ("photos" or "video") masked by parallax (or ``auto``, which tries
    parallax first), unless ``config.mask``
    is a ParallaxConfig already: the object's second opinion on the table plate
    (``ParallaxConfig.plate_object_threshold``), and for photos step 6's stricter outlier share
    (``plate_outlier_fraction``). A clip's frames come a few degrees apart along one path and repeat the
    plate's chance matches on a printed object, which the hull then carves into a hollow; with the opinion
    photos can let fewer views carve (a mug's handle hole), a clip cannot
    (why: docs/design-notes/pipeline.md#phone-masks)."""
    from real2sim.capture.masks.parallax_config import (PHONE_PHOTOS_PLATE_OUTLIER_FRACTION, PHONE_PLATE_OBJECT_THRESHOLD,
                                                      ParallaxConfig)

    if config.mask_method not in (PARALLAX, AUTO) or isinstance(config.mask, ParallaxConfig):
        return config
    outliers = PHONE_PHOTOS_PLATE_OUTLIER_FRACTION if kind == "photos" else None
    return replace(config, mask=ParallaxConfig(plate_object_threshold=PHONE_PLATE_OBJECT_THRESHOLD,
                                               plate_outlier_fraction=outliers))
