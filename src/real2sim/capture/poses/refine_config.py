"""What the pose refinement (:mod:`real2sim.capture.poses.refinement`) is asked to do, and what it reports.

Below both the refinement and its COLMAP and quality-gate helpers, which read the settings and fill the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class RefineConfig:
    """Pose refinement settings: COLMAP's features, matching, triangulation and bundle adjustment, and when
    the refined poses replace the given ones."""

    k_neighbors: int = 30
    """Views each view is matched with: its nearest by camera centre and viewing direction (>= 1).
    (why: docs/design-notes/capture.md#refine-neighbours)"""
    feature_region: str = "all"
    """Where SIFT features are taken: "all" (the whole image) or "object" (only inside the masks)."""
    mask_dilation_px: int = 15
    """Pixels the masks are grown by before they limit the features (``feature_region="object"``; >= 0)."""
    max_num_features: int = 4096
    """Most SIFT features per image (>= 1)."""
    sift_first_octave: int | None = None
    """SIFT's first octave: -1 (the image upsampled once) or 0; None picks -1 for images whose longer side is
    at most 400 px, else 0. (why: docs/design-notes/capture.md#refine-colmap)"""
    max_image_size: int = 1600
    """Longer side (px) an image is reduced to for feature extraction."""
    min_num_inliers: int = 15
    """Inlier matches an image pair needs to pass geometric verification."""
    init_max_reproj_error_px: float | None = None
    """Reprojection tolerance (px) of the first triangulation round, which sees the given (noisy) poses;
    None: 5 % of the image's longer side."""
    final_max_reproj_error_px: float = 4.0
    """Reprojection tolerance (px) of the later triangulation rounds and of the observation filter (twice
    this after the first round)."""
    robust_loss_scale_px: float = 2.0
    """Scale (px) of the bundle adjustment's Cauchy loss."""
    ba_rounds: int = 2
    """Rounds of triangulation (poses fixed) then bundle adjustment (poses and points) (>= 1)."""
    ba_function_tolerance: float = 1e-6
    """Ceres' relative cost tolerance that ends a bundle adjustment (Ceres' default: none).
    (why: docs/design-notes/capture.md#refine-colmap)"""
    ba_max_iterations: int = 50
    """Most Ceres iterations per bundle adjustment."""
    min_observations: int = 60
    """Triangulated observations a frame needs; one with fewer keeps its given pose."""
    max_change_deg: float = 10.0
    """Degrees a refined frame may turn from its given pose; beyond, it keeps the given pose."""
    max_change_mm: float = 100.0
    """Millimetres a refined frame may move from its given pose; beyond, it keeps the given pose."""
    min_refined_fraction: float = 0.5
    """Share of the frames (0-1) that must be refined (and at least 3), else every given pose is kept."""
    align: str = "poses"
    """How the refined model is put back onto the given frame: "centres" (Umeyama on the camera centres, as
    COLMAP's model aligner) or "poses" (centres and orientations, weighted by the given poses' noise)."""
    prior_noise_mm: float | None = None
    """The given poses' RMS position noise (mm, >= 0) for the alignment and the plausibility check; None
    reads ``pose_noise_mm`` from the dataset's ``real2sim`` block, else 5 mm."""
    prior_noise_deg: float | None = None
    """The given poses' RMS rotation noise (degrees, >= 0), as ``prior_noise_mm``; None: the dataset's
    ``pose_noise_deg``, else 1 degree."""
    num_threads: int = -1
    """COLMAP's and Ceres' threads; -1: every core."""
    seed: int = 0
    """COLMAP's random seed (the triangulator)."""
    quiet: bool = True
    """COLMAP's log cut to fatal messages (its errors become the refinement's own outcome)."""


@dataclass(frozen=True)
class RefineResult:
    """What happened. Errors are means over frames vs ground_truth/ (None without it)."""

    refined: bool
    reason: str
    num_frames: int
    num_refined_frames: int
    num_pairs: int
    num_points3d: int
    mean_reproj_error_px: float | None
    sim3_scale: float | None
    rot_error_before_deg: float | None = None
    trans_error_before_mm: float | None = None
    rot_error_after_deg: float | None = None
    trans_error_after_mm: float | None = None
    seconds: float = 0.0
    timings_s: dict = field(default_factory=dict)
    # per frame, in the dataset's order: whether COLMAP's pose replaced the given one (written into
    # transforms.json per frame, not into the report)
    frame_refined: tuple[bool, ...] = ()
    # the median move of the refined frames from their given poses (after the alignment), mm and deg
    median_correction_mm: float | None = None
    median_correction_deg: float | None = None

    def to_json(self) -> dict:
        from dataclasses import asdict

        return {k: v for k, v in asdict(self).items() if k != "frame_refined"}
