"""Refine a dataset's robot-reported camera poses with COLMAP, keeping the robot frame.

As in the paper (IV-A): COLMAP is seeded with the poses from the wrist-camera
calibration, refines them, and the refined model is aligned back to the robot
frame with a similarity transform (Umeyama on camera centres, the role of
COLMAP's model aligner). Steps:

1. SIFT features on every image (the whole image by default: the textured table
   gives far more, and better spread, features than the object alone).
2. Matching of the pairs chosen from the known poses: each view with its
   ``k_neighbors`` nearest views by camera centre and viewing direction
   (not exhaustive: O(N k) pairs), with geometric verification.
3. Triangulation with the given poses fixed, using tolerances wide enough for
   the pose noise; then bundle adjustment (poses + points, robust loss,
   intrinsics fixed); then filtering of bad observations, re-triangulation with
   normal tolerances and a second bundle adjustment.
4. Similarity alignment of the refined model onto the given poses: Umeyama on
   the camera centres (robust: one round of outlier rejection), then the rotation
   re-estimated from centres and orientations together, weighted by the robot's
   pose noise (``align="centres"`` keeps the centres-only fit).

Frames that COLMAP could not constrain (too few observations) or whose
refined pose moved implausibly far keep their given pose. When too few frames
are refined, all poses are kept and the result says why; so they are when the
refined frames moved, as a whole, further than the given poses' stated accuracy
makes plausible (:mod:`real2sim.capture.poses.refine_quality`).
"""

from __future__ import annotations

import shutil
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from real2sim.capture.poses.colmap import ColmapFailure, colmap_logging, refine_steps, run_colmap
from real2sim.capture.poses.refine_config import RefineConfig, RefineResult
from real2sim.capture.poses.refine_quality import (IMPLAUSIBLE_FACTOR, judge_change, refusal_limit,
                                                   warn_beyond_given_accuracy, warn_if_worse_than_given, with_errors)
from real2sim.formats.dataset import (
    CV_FROM_GL,
    POSE_REFINED_KEY,
    Dataset,
    check_dataset_outputs,
    pose_errors,
    read_dataset,
    read_ground_truth,
    write_json_atomic,
    write_transforms,
)
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import check_replaceable
from real2sim.plumbing.progress import ProgressFn


# ----------------------------------------------------------------------------- geometry helpers


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising sum ||s R src_i + t - dst_i||^2 for (N, 3) point sets."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rot = u @ sign @ vt
    var_s = (xs ** 2).sum() / len(src)
    scale = float(np.trace(np.diag(d) @ sign) / var_s)
    trans = mu_d - scale * rot @ mu_s
    return scale, rot, trans


def robust_umeyama(src: np.ndarray, dst: np.ndarray, reject_factor: float = 3.0
                   ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Umeyama, then refit without points whose residual exceeds ``reject_factor`` x the median."""
    s, r, t = umeyama(src, dst)
    res = np.linalg.norm(s * src @ r.T + t - dst, axis=1)
    keep = res <= reject_factor * max(np.median(res), 1e-12)
    if 3 <= keep.sum() < len(src):
        s, r, t = umeyama(src[keep], dst[keep])
    return s, r, t, keep


def align_poses(est_c2w: np.ndarray, given_c2w: np.ndarray, noise_mm: float, noise_deg: float
                ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) taking refined camera poses onto the given (robot) ones, and the inlier mask.

    Start from a robust Umeyama fit of the camera centres (the paper's model aligner), then
    re-estimate the rotation from centres *and* orientations, each weighted by the inverse
    variance of the robot's pose noise: E|dc|^2 = noise_mm^2 for centres, and
    E||R_noise - I||_F^2 = 2 theta^2 for orientations (theta = noise_deg in radians).
    The orientations carry as much information about the frame's rotation as the
    centres do, so using both roughly halves the variance of the aligned rotation.
    """
    src, dst = est_c2w[:, :3, 3], given_c2w[:, :3, 3]
    s, r, t, keep = robust_umeyama(src, dst)
    w_t = 1.0 / max((1e-3 * noise_mm) ** 2, 1e-12)
    w_r = 1.0 / max(2.0 * np.radians(noise_deg) ** 2, 1e-12)
    x = src[keep] - src[keep].mean(0)
    y = dst[keep] - dst[keep].mean(0)
    m = w_t * s * (y.T @ x) + w_r * np.einsum("nij,nkj->ik", given_c2w[keep, :3, :3], est_c2w[keep, :3, :3])
    u, _, vt = np.linalg.svd(m)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ fix @ vt
    s = float(np.einsum("ij,ij->", y, x @ r.T) / (x ** 2).sum())
    t = dst[keep].mean(0) - s * r @ src[keep].mean(0)
    return s, r, t, keep


def select_pairs(c2w_gl: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Unordered index pairs: each view with its k nearest by centre distance and viewing direction.

    Distance = |c_i - c_j| / (mean camera-to-centroid distance) + (1 - cos angle between
    viewing directions); views looking more than 90 degrees apart are never paired.
    """
    n = len(c2w_gl)
    if n < 2:
        return []
    centres = c2w_gl[:, :3, 3]
    dirs = -c2w_gl[:, :3, 2]
    scale = np.linalg.norm(centres - centres.mean(0), axis=1).mean() + 1e-9
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=2) / scale
    cos = np.clip(dirs @ dirs.T, -1.0, 1.0)
    score = dist + (1.0 - cos)
    score[cos < 0.0] = np.inf
    np.fill_diagonal(score, np.inf)
    kk = min(k, n - 1)
    nearest = np.argsort(score, axis=1)[:, :kk]
    pairs = set()
    for i in range(n):
        for j in nearest[i]:
            if np.isfinite(score[i, j]):
                pairs.add((min(i, int(j)), max(i, int(j))))
    return sorted(pairs)


def _c2w_gl_from_cfw(cfw: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :] = cfw
    return np.linalg.inv(m) @ CV_FROM_GL



def refine_dataset_poses(ds: Dataset, cfg: RefineConfig = RefineConfig(), progress: ProgressFn | None = None
                         ) -> tuple[np.ndarray, RefineResult]:
    """Refined (N, 4, 4) camera-to-world poses (OpenGL axes, the dataset's frame) and a report.

    Never raises for a COLMAP failure: it returns the given poses with ``refined=False``
    and the reason (also issued as a warning).
    """
    if cfg.align not in ("centres", "poses"):
        raise UserInputError(f"align must be 'centres' or 'poses' (got {cfg.align!r})")
    if cfg.feature_region not in ("all", "object"):
        raise UserInputError(f"feature_region must be 'all' or 'object' (got {cfg.feature_region!r})")
    t_start = time.perf_counter()
    given = ds.poses_c2w_gl()
    n = len(given)

    def fallback(reason: str, **kw) -> tuple[np.ndarray, RefineResult]:
        warnings.warn(f"pose refinement kept the given poses: {reason} (reconstruct aligns every view to the "
                      "others by its silhouette instead)", RuntimeWarning, stacklevel=3)
        base = dict(refined=False, reason=reason, num_frames=n, num_refined_frames=0, num_pairs=0,
                    num_points3d=0, mean_reproj_error_px=None, sim3_scale=None)
        base.update(kw)
        base["seconds"] = time.perf_counter() - t_start
        return given.copy(), RefineResult(**base)

    if cfg.feature_region == "object":
        # asked for explicitly: without masks there is nothing to honour it with, so say so before any work
        unmasked = [f.file_path for f in ds.frames if f.mask_path is None]
        if unmasked:
            raise UserInputError(f"--features object needs a mask for every frame, but {len(unmasked)} of {n} "
                                 f"have none (first: {unmasked[0]}); run `real2sim mask` first, or use --features all")
    if n < 3:
        return fallback(f"only {n} frames (need at least 3)")
    try:
        import pycolmap  # noqa: F401  (checked here for the message; the stages import it themselves)
    except ImportError:
        raise UserInputError("refine-poses needs pycolmap (pip install pycolmap)") from None

    work = Path(tempfile.mkdtemp(prefix="real2sim-colmap-"))
    try:
        with colmap_logging(quiet=cfg.quiet):
            try:
                pairs = select_pairs(given, cfg.k_neighbors)
                refined_cfw, counts, num_pairs, num_pts, reproj, timings = run_colmap(ds, cfg, work, pairs, progress)
            except ColmapFailure as exc:
                return fallback(str(exc))
            except UserInputError:
                raise
            except Exception as exc:  # COLMAP raises plain RuntimeErrors/ValueErrors on degenerate input
                return fallback(f"COLMAP failed: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    finally:
        shutil.rmtree(work, ignore_errors=True)

    names = [f.file_path for f in ds.frames]
    ok = np.array([names[i] in refined_cfw and counts.get(names[i], 0) >= cfg.min_observations
                   for i in range(n)])
    info = dict(num_pairs=num_pairs, num_points3d=num_pts, mean_reproj_error_px=reproj, timings_s=timings)
    if ok.sum() < max(3, cfg.min_refined_fraction * n):
        return fallback(f"only {int(ok.sum())} of {n} frames have >= {cfg.min_observations} triangulated "
                        "observations", **info)
    est = np.stack([_c2w_gl_from_cfw(refined_cfw[names[i]]) if ok[i] else given[i] for i in range(n)])

    # Align COLMAP's frame back to the robot frame using the refined frames only.
    noise = {**{"pose_noise_mm": 5.0, "pose_noise_deg": 1.0}, **ds.extra.get("real2sim", {})}
    noise_mm = cfg.prior_noise_mm if cfg.prior_noise_mm is not None else float(noise["pose_noise_mm"])
    noise_deg = cfg.prior_noise_deg if cfg.prior_noise_deg is not None else float(noise["pose_noise_deg"])
    if cfg.align == "centres":
        s, r, t, _ = robust_umeyama(est[ok, :3, 3], given[ok, :3, 3])
    else:
        s, r, t, _ = align_poses(est[ok], given[ok], noise_mm, noise_deg)
    aligned = given.copy()
    idx = np.nonzero(ok)[0]
    aligned[idx, :3, :3] = r @ est[idx, :3, :3]
    aligned[idx, :3, 3] = s * est[idx, :3, 3] @ r.T + t
    # A frame that moved implausibly far is a COLMAP mistake for that frame: keep its given pose.
    rot_change, trans_change = pose_errors(aligned, given)
    bad = ok & ((rot_change > cfg.max_change_deg) | (trans_change > cfg.max_change_mm))
    aligned[bad] = given[bad]
    ok &= ~bad
    if ok.sum() < max(3, cfg.min_refined_fraction * n):
        return fallback(f"only {int(ok.sum())} of {n} refined frames stayed within {cfg.max_change_deg} deg / "
                        f"{cfg.max_change_mm} mm of the given poses", **info)
    moved_deg, moved_mm = float(np.median(rot_change[ok])), float(np.median(trans_change[ok]))
    verdict, allowed_mm, allowed_deg = judge_change(ds, moved_mm, moved_deg, noise_mm, noise_deg, reproj)
    if verdict == "refuse":
        limit_mm, limit_deg = refusal_limit(ds, noise_mm, noise_deg, reproj)
        return fallback(f"COLMAP moved the refined frames by {moved_mm:.1f} mm / {moved_deg:.2f} deg (median), more "
                        f"than the given poses' stated accuracy ({noise_mm:g} mm / {noise_deg:g} deg RMS) makes "
                        f"plausible (3 x that, plus {IMPLAUSIBLE_FACTOR:g} x what COLMAP's {reproj or 0:.2f} px "
                        f"reprojection error leaves uncertain: {limit_mm:.1f} mm / {limit_deg:.2f} deg): its model "
                        "does not agree with the given poses (a long lens or few features leave it free to bend); "
                        "if the given poses are less accurate than stated, say so (refine-poses "
                        "--pose-noise-mm/--pose-noise-deg, or transforms.json's real2sim.pose_noise_mm/pose_noise_deg)",
                        **info, median_correction_mm=moved_mm, median_correction_deg=moved_deg)
    if verdict == "warn":
        warn_beyond_given_accuracy(moved_mm, moved_deg, noise_mm, noise_deg, reproj, allowed_mm, allowed_deg)
    return aligned, RefineResult(refined=True, reason="ok", num_frames=n, num_refined_frames=int(ok.sum()),
                                 sim3_scale=float(s), seconds=time.perf_counter() - t_start,
                                 frame_refined=tuple(bool(x) for x in ok), median_correction_mm=moved_mm,
                                 median_correction_deg=moved_deg, **info)


def refine_poses(dataset_dir: Path | str, cfg: RefineConfig = RefineConfig(),
                 progress: ProgressFn | None = None) -> RefineResult:
    """Refine ``dataset_dir/transforms.json`` in place; the original is kept as transforms_unrefined.json.

    When a transforms_unrefined.json already exists (a second run), it is kept:
    it still holds the robot's original poses. Errors vs ``ground_truth/`` are
    filled in when it exists. Each frame records whether its pose was refined
    (``POSE_REFINED_KEY``; one COLMAP did not register keeps the robot's pose). Writes ``refine_report.json``. Files are written
    to temporary names and renamed, so an interrupted run leaves the dataset as it was.
    """
    root = Path(dataset_dir)
    ds = read_dataset(root)
    if ds.extra.get("source") == "colmap":
        raise UserInputError(f"{root} has no transforms.json (its poses come from COLMAP already)")
    check_dataset_outputs(root, files=("transforms.json", "transforms_unrefined.json", "refine_report.json"),
                          what="refine-poses output")
    # the end of the work replaces transforms.json: find out now, not after COLMAP, that it cannot be
    check_replaceable(root / "transforms.json", what="refine-poses output")
    poses, result = refine_dataset_poses(ds, cfg, progress)
    names = [f.file_path for f in ds.frames]
    result = with_errors(result, read_ground_truth(root), names, ds.poses_c2w_gl(), poses)
    warn_if_worse_than_given(result)
    if progress:
        progress("writing", refine_steps(cfg) - 1, refine_steps(cfg))
    unrefined = root / "transforms_unrefined.json"
    if not unrefined.exists():
        write_json_atomic(unrefined, __import__("json").loads((root / "transforms.json").read_text()))
    extra = dict(ds.extra)
    extra["real2sim_refinement"] = {k: v for k, v in result.to_json().items() if k != "timings_s"}
    # a frame COLMAP could not refine keeps its given pose; say so, for the reconstruction (which
    # aligns such frames by their silhouettes: to the refined ones, or, when none is, to each other)
    marks = result.frame_refined if result.refined else (False,) * len(ds.frames)
    new = replace(ds, frames=tuple(replace(f, transform_matrix=poses[i] if result.refined else f.transform_matrix,
                                           extra={**f.extra, POSE_REFINED_KEY: bool(marks[i])})
                                   for i, f in enumerate(ds.frames)), extra=extra)
    write_transforms(root / "transforms.json", new)
    write_json_atomic(root / "refine_report.json", result.to_json())
    if progress:
        progress("written", refine_steps(cfg), refine_steps(cfg))
    return result


__all__ = ["RefineConfig", "RefineResult", "align_poses", "colmap_logging", "refine_dataset_poses", "refine_poses",
           "robust_umeyama", "select_pairs", "umeyama"]
