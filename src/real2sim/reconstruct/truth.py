"""How far a reconstruction is from the true object, when the dataset knows it (simulated captures).

``DATASET/ground_truth/mesh.obj`` placed by ``ground_truth/object_pose.json``
(``world_from_mesh``) is the truth, in the dataset's world frame, metres.

* Chamfer (mm): as :func:`real2sim.geometry.fidelity.chamfer_distance_mm`, the mean of the two
  directions' mean point-to-surface distances.
* F-score at ``tau`` (default 1 mm): precision = share of points on the
  reconstruction within ``tau`` of the true surface, recall = the converse,
  F = 2PR / (P + R) (Knapitsch et al. 2017).
* IoU: points drawn uniformly in the union of the two bounding boxes, inside
  tests by winding number (robust to the open bottom of a TSDF mesh).
* ``concave_recovered``: of the points inside the true mesh's convex hull but
  outside the true mesh (a mug's cavity and the hole of its handle), the share
  the reconstruction also leaves empty; 1 = every concavity is present.
* ``chamfer_concave_mm`` / ``chamfer_hull_mm``: the Chamfer distance split by where
  the samples lie. *Concave*: true surface points more than ``tau`` inside the true
  convex hull's surface (a cavity's wall and floor, a handle's inner side), and
  reconstructed points more than ``tau`` off the true surface but within that hull
  (a lid across a cavity, a wall made too thick); *hull*: the rest, the part a
  silhouette can judge. Each is the mean of its two directions' mean distances; None
  when a part has no samples (a convex object has no concave part).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError


def load_truth(dataset_root: Path | str) -> trimesh.Trimesh | None:
    """The true mesh in the dataset's world frame (metres), or None when the dataset has no ground truth."""
    from real2sim.geometry.mesh_io import load_mesh

    gt = Path(dataset_root) / "ground_truth"
    if not (gt / "mesh.obj").is_file():
        return None
    mesh = load_mesh(gt / "mesh.obj")
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # geometry only; texture seams merged
    pose_file = gt / "object_pose.json"
    if pose_file.is_file():
        try:
            world_from_mesh = np.asarray(json.loads(pose_file.read_text())["world_from_mesh"], dtype=float)
        except (ValueError, KeyError, TypeError) as exc:
            raise UserInputError(f"{pose_file}: no readable world_from_mesh ({exc})") from None
        mesh.apply_transform(world_from_mesh)
    return mesh


def compare_to_truth(mesh: trimesh.Trimesh, truth: trimesh.Trimesh, *, tau_m: float = 0.001,
                     surface_samples: int = 30_000, volume_samples: int = 400_000, seed: int = 0) -> dict:
    """Chamfer (mm), F-score at ``tau_m``, IoU and concavity recovery of ``mesh`` against ``truth``."""
    from real2sim.geometry.fidelity import surface_distance_m
    from real2sim.geometry.inside import compact_triangles, inside_mask

    rng = np.random.default_rng(seed)
    rec_pts, _ = trimesh.sample.sample_surface(mesh, surface_samples, seed=int(rng.integers(2**31)))
    gt_pts, _ = trimesh.sample.sample_surface(truth, surface_samples, seed=int(rng.integers(2**31)))
    rec_to_gt = surface_distance_m(rec_pts, truth)
    gt_to_rec = surface_distance_m(gt_pts, mesh)
    precision = float(np.mean(rec_to_gt <= tau_m))
    recall = float(np.mean(gt_to_rec <= tau_m))
    fscore = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)

    lo = np.minimum(mesh.bounds[0], truth.bounds[0])
    hi = np.maximum(mesh.bounds[1], truth.bounds[1])
    pts = lo + rng.random((volume_samples, 3)) * (hi - lo)
    # long sliver triangles (a can's fan caps, any convex hull) make winding numbers slow
    in_rec, in_gt = inside_mask(mesh, pts), inside_mask(compact_triangles(truth), pts)
    union = np.count_nonzero(in_rec | in_gt)
    hull = compact_triangles(truth.convex_hull)
    concave = ~in_gt  # only these can be in the hull's concave part: the hull is asked about them alone
    concave[concave] = inside_mask(hull, pts[concave])
    # the true surface deeper than tau inside its hull is where silhouettes cannot judge it; a
    # reconstructed point off the true surface within the hull (a lid across a cavity) is in that space
    gt_deep = surface_distance_m(gt_pts, hull) > tau_m
    rec_deep = (rec_to_gt > tau_m) & (inside_mask(hull, rec_pts) | (surface_distance_m(rec_pts, hull) <= tau_m))
    return {
        "chamfer_mm": _chamfer_mm(rec_to_gt, gt_to_rec),
        "chamfer_rec_to_true_mm": float(1000.0 * rec_to_gt.mean()),
        "chamfer_true_to_rec_mm": float(1000.0 * gt_to_rec.mean()),
        f"fscore_{tau_m * 1000:g}mm": float(fscore),
        "precision": precision,
        "recall": recall,
        "iou": float(np.count_nonzero(in_rec & in_gt) / union) if union else 0.0,
        "concave_recovered": float(np.mean(~in_rec[concave])) if concave.any() else None,
        "concave_volume_fraction": float(concave.sum() / max(in_gt.sum(), 1)),
        "chamfer_concave_mm": _chamfer_mm(rec_to_gt[rec_deep], gt_to_rec[gt_deep]),
        "chamfer_hull_mm": _chamfer_mm(rec_to_gt[~rec_deep], gt_to_rec[~gt_deep]),
    }


def _chamfer_mm(rec_to_gt_m: np.ndarray, gt_to_rec_m: np.ndarray) -> float | None:
    """The mean of the two directions' mean distances (metres in, mm out); None when one has no samples."""
    if len(rec_to_gt_m) == 0 or len(gt_to_rec_m) == 0:
        return None
    return float(500.0 * (rec_to_gt_m.mean() + gt_to_rec_m.mean()))


def psnr(prediction: np.ndarray, target: np.ndarray, region: np.ndarray) -> float:
    """PSNR (dB) of RGB images in [0, 1] over the pixels where ``region`` (bool, same leading shape) holds."""
    err = ((prediction - target) ** 2)[region]
    mse = float(err.mean()) if err.size else 0.0
    return float("inf") if mse == 0 else float(-10.0 * np.log10(mse))
