"""The work of each `run` stage: the stage function called on the run's folders.

Each takes the run's folders and settings and the stage's :class:`~real2sim.formats.progress.ProgressFn`
(:class:`real2sim.pipeline.run.RunProgress` names the stage in front of its messages), and
returns what run.json records of it. :mod:`real2sim.pipeline.run` decides which stages run.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable

from real2sim.formats.outputs import MARKER_NAME, publish_dir
from real2sim.formats.progress import ProgressFn
from real2sim.pipeline import manifest as mf
from real2sim.pipeline.normalise import NormaliseConfig

RESULTS_DIRNAME = "results"
TRUTH_RESULTS_DIRNAME = "results_truth"
# Entries of ASSETDIR that the asset stage does not own.
RESERVED = (mf.RUN_DIRNAME, "truth.json", RESULTS_DIRNAME, TRUTH_RESULTS_DIRNAME)


def _edited_copy(dataset: Path, target: Path, edit: Callable[[Path], dict]) -> dict:
    """Copy ``dataset`` beside ``target``, let ``edit`` change the copy, then rename it to ``target``."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        shutil.copytree(dataset, tmp, dirs_exist_ok=True, ignore=shutil.ignore_patterns("refine_report.json"))
        extra = edit(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, target)
    return extra


def _masks(dataset: Path, run_dir: Path, method: str, mask_cfg, progress: ProgressFn, table_z_m: float = 0.0,
           seed: int = 0) -> dict:
    from real2sim.pipeline.masks import make_masks

    def edit(copy: Path) -> dict:
        if not (copy / "transforms.json").exists():  # a COLMAP model: masks need a transforms.json to point from
            from real2sim.pipeline.normalise import write_model_transforms

            write_model_transforms(copy)
        result = make_masks(copy, method, mask_cfg, table_z_m=table_z_m, seed=seed, progress=progress)
        return {"result": {"num_frames": result.num_frames, "mean_object_fraction": result.mean_object_fraction,
                           "mean_iou": result.mean_iou, "min_iou": result.min_iou}}

    return _edited_copy(dataset, run_dir / "masked", edit)


def _refine(dataset: Path, run_dir: Path, refine_cfg, progress: ProgressFn) -> dict:
    from real2sim.capture.pose_refinement import refine_poses

    def edit(copy: Path) -> dict:
        result = refine_poses(copy, refine_cfg, progress)
        return {"result": result.to_json()}

    return _edited_copy(dataset, run_dir / "dataset", edit)


def _robot_frame(dataset: Path, run_dir: Path, cfg: NormaliseConfig, seed: int, progress: ProgressFn) -> dict:
    from real2sim.pipeline.normalise import normalise

    record = normalise(dataset, run_dir / "robot_frame", cfg, seed=seed, progress=progress)
    keep = ("scale_from", "hull_height_m", "sparse_points", "table_fit_rms_mm", "errors_vs_ground_truth")
    return {"result": {"scale": record["robot_from_model"]["scale"], **{k: record[k] for k in keep if k in record}}}


def _reconstruct(dataset: Path, out: Path, cfg, device: str, seed: int, progress: ProgressFn) -> dict:
    from real2sim.reconstruct.stage import reconstruct, write_reconstruction

    result = reconstruct(dataset, cfg, device=device, seed=seed, progress=progress)
    write_reconstruction(result, out, overwrite=True)
    report = result.report
    return {"summary": {"faces": report["mesh"]["faces"], "stage_seconds": report["total_seconds"],
                        "truth": report.get("truth")}}


def check_reaches_table(mesh: Path, table_z_m: float) -> None:
    """UserInputError (one line) when the reconstruction ``mesh`` (world frame, metres) stops short
    of the table by more than the asset's flat-bottom tolerance: its lowest part was not
    reconstructed (masks that miss it near the table, a table height that is wrong), and there is
    no bottom to close at the table. ``asset``'s own message speaks of ``--support-height``, which
    ``run`` sets itself."""
    from real2sim.asset.build import SUPPORT_BELOW_TOLERANCE, support_below_mesh
    from real2sim.formats.errors import UserInputError
    from real2sim.formats.mesh_io import load_mesh

    z_m = load_mesh(mesh).vertices[:, 2]
    bottom_m, top_m = float(z_m.min()), float(z_m.max())
    if support_below_mesh(bottom_m, top_m, table_z_m):
        gap_m, height_m = bottom_m - table_z_m, top_m - bottom_m
        raise UserInputError(
            f"the reconstruction's lowest point is {1000 * gap_m:.1f} mm above the table (z = {table_z_m:g} m), "
            f"more than {100 * SUPPORT_BELOW_TOLERANCE:g} % of its {1000 * height_m:.0f} mm height, so its bottom "
            "cannot be closed at the table: check that the masks reach the table in the low views, or give the "
            "table's height with --table-z")


def _asset(mesh: Path, asset_dir: Path, cfg, manifest: mf.Manifest, progress: ProgressFn) -> dict:
    """build_asset into ``.run/asset`` (whole or not at all), then move its entries into ASSETDIR."""
    from real2sim.asset.build import build_asset

    check_reaches_table(mesh, cfg.support_height_m)
    built = asset_dir / mf.RUN_DIRNAME / "asset"
    build_asset(mesh, built, cfg, overwrite=True, progress=progress)
    # Downstream outputs of the previous asset are stale now.
    for stage, path in (("truth", asset_dir / "truth.json"), ("evaluate", asset_dir / RESULTS_DIRNAME),
                        ("evaluate_truth", asset_dir / TRUTH_RESULTS_DIRNAME)):
        manifest.forget(stage)
        shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)
    for name in (RESULTS_DIRNAME, TRUTH_RESULTS_DIRNAME):
        shutil.rmtree(asset_dir / f".{name}.partial", ignore_errors=True)
    for entry in asset_dir.iterdir():
        if entry.name not in RESERVED and not entry.name.startswith("."):
            shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
    (built / MARKER_NAME).unlink(missing_ok=True)  # ASSETDIR has its own
    outputs = sorted(entry.name for entry in built.iterdir())
    for name in outputs:
        os.replace(built / name, asset_dir / name)
    built.rmdir()
    return {"outputs": outputs}


def _evaluate_truth(dataset: Path, asset_dir: Path, cfg, seed: int, progress: ProgressFn) -> dict:
    """The sweep again, against the true mesh with the true mass properties (see truth_dynamics)."""
    from real2sim.evaluate.sweep import evaluate
    from real2sim.pipeline.truth_dynamics import write_true_reference

    mesh, properties = write_true_reference(dataset, asset_dir, asset_dir / mf.RUN_DIRNAME / "truth", seed)
    shutil.rmtree(asset_dir / f".{TRUTH_RESULTS_DIRNAME}.partial", ignore_errors=True)
    result = evaluate([asset_dir], asset_dir / TRUTH_RESULTS_DIRNAME, cfg, reference_mesh=mesh,
                      reference_properties=properties, progress=progress, overwrite=True)
    return {"summary": {"simulated": result.simulated, "failed": result.failed}}


def _evaluate(asset_dir: Path, cfg, progress: ProgressFn, skip: tuple[str, ...] = ()) -> dict:
    from real2sim.evaluate.sweep import evaluate

    result = evaluate([asset_dir], asset_dir / RESULTS_DIRNAME, cfg, progress=progress, overwrite=True,
                      animations=True, skip_representations=skip)
    return {"summary": {"simulated": result.simulated, "failed": result.failed}}
