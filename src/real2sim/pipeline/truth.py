"""``ASSETDIR/truth.json``: every stage of a run judged against the true object of a simulated capture.

Frames, checked here and recorded in the file:

* ``DATASET/ground_truth/mesh.obj`` is in its own mesh frame; ``object_pose.json``'s
  ``world_from_mesh`` places it in the dataset's world frame (table top z = 0),
  the frame of the cameras and of the reconstruction (``reconstruct`` compares
  against the same placed mesh). We record the placed mesh's lowest z: ~0 when
  the object stands on the table.
* The asset was built from ``.run/reconstruct/mesh.obj`` (world frame), so
  ``canonical_transform.json``'s ``T_asset_from_input`` takes the world frame to
  the asset frame. The true mesh is moved by ``T @ world_from_mesh`` and its mass
  properties are computed there with the asset stage's own function
  (:func:`real2sim.asset.inertia.estimate_physical_properties`, same mass, same
  seed), so both sets of properties are in the asset frame about their own CoM.
* A COLMAP capture (``run``'s ``robot_frame`` stage): ``dataset`` here is the stage's
  copy, whose ``ground_truth/`` the stage re-expressed in the normalised frame by the
  known similarity (``ground_truth/model_from_world.json`` of the source; the rigid part
  of the map, so the true object keeps its true size): the comparison aligns by that
  similarity, not by ICP, and every error of the normalisation (scale, table tilt and
  height) stays in the errors below. The stage's own errors against the truth are
  recorded under ``robot_frame``.
* Inertia error: relative error of the sorted principal moments (eigenvalues),
  and the relative Frobenius error of the whole tensor in the asset axes (this
  one also catches axes that are swapped or turned).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from real2sim.formats.dataset import load_mask, pose_errors, read_dataset, read_ground_truth
from real2sim.formats.physical import PhysicalProperties, read_physical_properties


def has_ground_truth(dataset: Path) -> bool:
    return (Path(dataset) / "ground_truth" / "mesh.obj").is_file()


def pose_error_summary(dataset: Path, ground_truth_root: Path) -> dict | None:
    """Mean / max rotation (deg) and camera-centre (mm) error of ``dataset``'s poses against the true ones."""
    gt = read_ground_truth(ground_truth_root)
    if gt is None:
        return None
    ds = read_dataset(dataset, check_files=False)
    truth = {f.file_path: f.transform_matrix for f in gt.frames}
    names = [f.file_path for f in ds.frames if f.file_path in truth]
    if not names:
        return None
    est = np.stack([f.transform_matrix for f in ds.frames if f.file_path in truth])
    rot, trans = pose_errors(est, np.stack([truth[n] for n in names]))
    return {"frames": len(names), "rot_mean_deg": float(rot.mean()), "rot_max_deg": float(rot.max()),
            "trans_mean_mm": float(trans.mean()), "trans_max_mm": float(trans.max())}


def mask_iou(dataset: Path) -> dict | None:
    """Mean / min IoU of the dataset's masks against ``ground_truth/masks/`` (rendered labels)."""
    root = Path(dataset)
    ds = read_dataset(root, check_files=False)
    ious = []
    for frame in ds.frames:
        true_path = root / "ground_truth" / "masks" / Path(frame.mask_path or "").name
        if not frame.mask_path or not true_path.is_file():
            continue
        est, true = load_mask(root / frame.mask_path), load_mask(true_path)
        union = np.logical_or(est, true).sum()
        ious.append(1.0 if union == 0 else float(np.logical_and(est, true).sum() / union))
    if not ious:
        return None
    return {"frames": len(ious), "mean": float(np.mean(ious)), "min": float(np.min(ious))}


def true_mesh_in_asset_frame(dataset: Path, asset_dir: Path):
    """(true mesh in the asset frame, its lowest z in the world frame before the move)."""
    from real2sim.reconstruct.truth import load_truth

    world = load_truth(dataset)  # ground_truth/mesh.obj placed by object_pose.json: world frame
    transform = np.asarray(json.loads((Path(asset_dir) / "canonical_transform.json").read_text())
                           ["T_asset_from_input"], dtype=float)
    lowest_z = float(world.bounds[0, 2])
    world.apply_transform(transform)
    return world, lowest_z


def physical_errors(est: PhysicalProperties, true: PhysicalProperties) -> dict:
    est_j, true_j = est.inertia, true.inertia
    ev_est, ev_true = np.linalg.eigvalsh(est_j), np.linalg.eigvalsh(true_j)
    rel = np.abs(ev_est - ev_true) / ev_true
    com_err = 1000.0 * float(np.linalg.norm(np.subtract(est.com_m, true.com_m)))
    return {
        "mass_kg": est.mass_kg,
        "com_error_mm": com_err,
        "com_m": list(est.com_m),
        "true_com_m": list(true.com_m),
        "inertia_eigenvalues_kg_m2": ev_est.tolist(),
        "true_inertia_eigenvalues_kg_m2": ev_true.tolist(),
        "inertia_eigenvalue_rel_error": rel.tolist(),
        "inertia_eigenvalue_max_rel_error": float(rel.max()),
        "inertia_tensor_rel_frobenius_error": float(np.linalg.norm(est_j - true_j) / np.linalg.norm(true_j)),
    }


def _uniform_beside(asset_dir: Path, true_props: PhysicalProperties) -> dict | None:
    """When the asset was given measured properties (``--properties``), the errors uniform density
    would have had, for the side-by-side comparison; None otherwise."""
    record = json.loads((asset_dir / "physical_properties.json").read_text()).get("uniform_density")
    if not record:
        return None
    uniform = PhysicalProperties(mass_kg=float(record["mass_kg"]), com_m=tuple(record["com_m"]),
                                 inertia_kg_m2=tuple(map(tuple, record["inertia_kg_m2"])))
    return physical_errors(uniform, true_props)


def build_truth(dataset: Path, used_dataset: Path, asset_dir: Path, reconstruct_report: dict, *,
                refinement: dict | None, seed: int, robot_frame: dict | None = None,
                true_properties: PhysicalProperties | None = None) -> dict:
    """The truth.json record (see the module docstring). ``used_dataset``: the refined copy, or ``dataset``;
    ``refinement``: the refine stage's RefineResult as JSON, None when the run did not refine;
    ``robot_frame``: the robot_frame stage's result (a COLMAP capture), None otherwise;
    ``true_properties``: the true mesh's mass properties when already computed for this asset (the
    truth evaluation's reference), else computed here the same way."""
    from real2sim.asset.inertia import estimate_physical_properties

    asset_dir = Path(asset_dir)
    est = read_physical_properties(asset_dir / "physical_properties.json")
    true_mesh, lowest_z = true_mesh_in_asset_frame(dataset, asset_dir)
    true_props = true_properties or estimate_physical_properties(true_mesh, est.mass_kg, seed=seed)
    before = pose_error_summary(dataset, dataset)
    refined = bool(refinement and refinement.get("refined"))
    poses = {"before_refinement": before,
             "after_refinement": pose_error_summary(used_dataset, dataset) if refined else None,
             "refinement_asked": refinement is not None, "refined": refined,
             "refinement_outcome": None if refinement is None else refinement.get("reason")}
    record = {
        "dataset": os.path.relpath(Path(dataset).resolve(), asset_dir.resolve()),
        "camera_poses": poses,
        "masks_iou": mask_iou(used_dataset),
        "reconstruction": reconstruct_report.get("truth"),
        "physical_properties": physical_errors(est, true_props),
        "physical_properties_uniform_density": _uniform_beside(asset_dir, true_props),
        "frames": {
            "true_mesh": "ground_truth/mesh.obj moved by object_pose.json world_from_mesh (dataset world frame), "
                         "then by canonical_transform.json T_asset_from_input (asset frame)",
            "true_mesh_lowest_z_world_m": lowest_z,
            "properties": "both about their own centre of mass, asset axes; same mass, same inertia function "
                          "(real2sim.asset.inertia.estimate_physical_properties) and seed",
        },
    }
    if robot_frame is not None:
        record["robot_frame"] = robot_frame
        record["frames"]["true_mesh"] = ("ground_truth/mesh.obj placed by the robot_frame stage's copy of "
                                         "object_pose.json (the source's, moved by the rigid part of the known "
                                         "robot_from_world), then by canonical_transform.json T_asset_from_input")
    return record
