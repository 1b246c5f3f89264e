"""Whether a `refine-poses` result is plausible: how far COLMAP may move the given poses (their stated
accuracy and COLMAP's own reprojection error), the verdict (ok, warn, refuse), and, with ground truth,
whether the refined poses are worse than the given ones (:mod:`real2sim.capture.poses.refinement`
runs COLMAP and applies the verdict).

Distances in millimetres, angles in degrees, medians over the refined frames.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
import numpy as np

from real2sim.capture.poses.refine_config import RefineResult
from real2sim.formats.dataset import Dataset, pose_errors


def _allowance(ds: Dataset, noise_mm: float, noise_deg: float, reproj_px: float | None
               ) -> tuple[float, float, float, float]:
    """How far (median mm, degrees) refinement may plausibly move the frames, in two parts: 3 x the given
    poses' stated accuracy (``noise_mm`` / ``noise_deg``, RMS), and what COLMAP's own reprojection error
    (``reproj_px``) leaves uncertain, a pixel at the cameras' distance from the scene. Returns
    (stated mm, stated deg, COLMAP mm, COLMAP deg)."""
    k = ds.intrinsics
    c2w = ds.poses_c2w_gl()
    centres, axes = c2w[:, :3, 3], -c2w[:, :3, 2]
    # the scene's distance: to the point nearest every optical axis (least squares)
    off_axis = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    scene = np.linalg.lstsq(off_axis.sum(axis=0), (off_axis @ centres[:, :, None]).sum(axis=0)[:, 0], rcond=None)[0]
    distance_m = float(np.median(np.linalg.norm(centres - scene, axis=1)))
    px_rad = float(reproj_px or 1.0) / max(k.fl_x, k.fl_y)
    return 3.0 * noise_mm, 3.0 * noise_deg, 1e3 * px_rad * distance_m, float(np.degrees(px_rad))


def _bounds(ds: Dataset, noise_mm: float, noise_deg: float, reproj_px: float | None
            ) -> tuple[float, float, float, float]:
    """(allowed mm, allowed deg, refusal limit mm, refusal limit deg): 3 x the stated accuracy plus once
    (allowed) or ``IMPLAUSIBLE_FACTOR`` times (limit) COLMAP's uncertainty (:func:`_allowance`)."""
    stated_mm, stated_deg, colmap_mm, colmap_deg = _allowance(ds, noise_mm, noise_deg, reproj_px)
    return (stated_mm + colmap_mm, stated_deg + colmap_deg,
            stated_mm + IMPLAUSIBLE_FACTOR * colmap_mm, stated_deg + IMPLAUSIBLE_FACTOR * colmap_deg)


def refusal_limit(ds: Dataset, noise_mm: float, noise_deg: float, reproj_px: float | None) -> tuple[float, float]:
    """(mm, degrees): a median move beyond this is refused (:func:`judge_change`)."""
    return _bounds(ds, noise_mm, noise_deg, reproj_px)[2:]


def judge_change(ds: Dataset, moved_mm: float, moved_deg: float, noise_mm: float, noise_deg: float,
                 reproj_px: float | None) -> tuple[str, float, float]:
    """("ok" | "warn" | "refuse", allowed mm, allowed degrees) for a refinement that moved the frames by
    ``moved_mm`` / ``moved_deg`` (median). Allowed: 3 x the stated accuracy plus COLMAP's uncertainty
    (:func:`_allowance`); within it, ok. Refused beyond 3 x the stated accuracy plus ``IMPLAUSIBLE_FACTOR``
    x COLMAP's uncertainty (:func:`refusal_limit`): under the stated noise the median frame moves about
    its RMS, and three times it for the median of many frames is not noise but a model that bent. In
    between (only where that uncertainty is a large part: poses stated nearly exact) a warning."""
    allowed_mm, allowed_deg, limit_mm, limit_deg = _bounds(ds, noise_mm, noise_deg, reproj_px)
    if moved_mm > limit_mm or moved_deg > limit_deg:
        return "refuse", allowed_mm, allowed_deg
    if moved_mm > allowed_mm or moved_deg > allowed_deg:
        return "warn", allowed_mm, allowed_deg
    return "ok", allowed_mm, allowed_deg


def warn_beyond_given_accuracy(moved_mm: float, moved_deg: float, noise_mm: float, noise_deg: float,
                                reproj_px: float | None, allowed_mm: float, allowed_deg: float) -> None:
    """Warn when COLMAP moved the refined frames by more than :func:`judge_change` allows (but not so far
    that it refuses): given poses that are already right (a noise-free capture) are then made worse, not
    better."""
    warnings.warn(f"refine-poses moved the refined frames by {moved_mm:.2f} mm / {moved_deg:.3f} deg (median), "
                  f"more than the given poses' stated accuracy ({noise_mm:g} mm / {noise_deg:g} deg) and COLMAP's "
                  f"{reproj_px or 0:.2f} px reprojection error allow ({allowed_mm:.2f} mm / {allowed_deg:.3f} deg): "
                  "the refined poses may be worse than the given ones; keep transforms_unrefined.json if the "
                  "given poses are accurate", RuntimeWarning, stacklevel=4)


def with_errors(result: RefineResult, gt: Dataset | None, names: list[str], before: np.ndarray,
                 after: np.ndarray) -> RefineResult:
    if gt is None:
        return result
    gt_by_name = {f.file_path: f.transform_matrix for f in gt.frames}
    if not all(nm in gt_by_name for nm in names):
        return result
    ref = np.stack([gt_by_name[nm] for nm in names])
    rb, tb = pose_errors(before, ref)
    ra, ta = pose_errors(after, ref)
    return replace(result, rot_error_before_deg=float(rb.mean()), trans_error_before_mm=float(tb.mean()),
                   rot_error_after_deg=float(ra.mean()), trans_error_after_mm=float(ta.mean()))


#: How many times COLMAP's own uncertainty (a pixel of reprojection error at the scene's distance) a
#: refinement may move the frames beyond 3 x the given poses' stated accuracy before it is refused
#: (:func:`judge_change`). (why: docs/design-notes/capture.md#refine-refusal)
IMPLAUSIBLE_FACTOR = 2.0
#: Worsening against ground truth below which a refinement is not called worse (COLMAP's jitter).
WORSE_TOLERANCE_MM = 0.1
WORSE_TOLERANCE_DEG = 0.02


def warn_if_worse_than_given(result: RefineResult) -> None:
    """With ground truth: warn when the refined poses are further from it than the given ones were."""
    if not result.refined or result.trans_error_after_mm is None:
        return
    if (result.trans_error_after_mm > result.trans_error_before_mm + WORSE_TOLERANCE_MM
            or result.rot_error_after_deg > result.rot_error_before_deg + WORSE_TOLERANCE_DEG):
        warnings.warn(f"refine-poses made the poses worse against ground_truth/: position "
                      f"{result.trans_error_before_mm:.2f} -> {result.trans_error_after_mm:.2f} mm, rotation "
                      f"{result.rot_error_before_deg:.3f} -> {result.rot_error_after_deg:.3f} deg (mean over frames)",
                      RuntimeWarning, stacklevel=3)
