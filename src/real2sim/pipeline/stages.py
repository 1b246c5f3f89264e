"""The work of each `run` stage: the stage function called on the run's folders.

Each takes the run's folders and settings and the stage's :class:`~real2sim.plumbing.progress.ProgressFn`
(:class:`real2sim.pipeline.run.RunProgress` names the stage in front of its messages), and
returns what run.json records of it. :mod:`real2sim.pipeline.run` decides which stages run.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Callable

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME, publish_dir
from real2sim.plumbing.progress import ProgressFn
from real2sim.pipeline import manifest as mf
from real2sim.capture.phone.normalise import NormaliseConfig
from real2sim.plumbing import digests

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


def run_masks(dataset: Path, run_dir: Path, method: str, mask_cfg, progress: ProgressFn, table_z_m: float = 0.0,
              seed: int = 0) -> dict:
    """The masks stage: ``method``'s masks made on a copy of ``dataset`` in ``run_dir/masked``."""
    from real2sim.capture.masks.stage import MASK_CHOICE, make_masks

    def edit(copy: Path) -> dict:
        if not (copy / "transforms.json").exists():  # a COLMAP model: masks need a transforms.json to point from
            from real2sim.capture.phone.normalise import write_model_transforms

            write_model_transforms(copy)
        # the copy is run's own: a masks_<method>/ copied from the dataset is replaced there, not in the dataset
        result = make_masks(copy, method, mask_cfg, table_z_m=table_z_m, seed=seed, progress=progress,
                            may_replace="any")
        record = {"method": result.method, "num_frames": result.num_frames,
                  "mean_object_fraction": result.mean_object_fraction, "mean_iou": result.mean_iou,
                  "min_iou": result.min_iou}
        if (copy / MASK_CHOICE).is_file():  # auto: which method, and why
            record["choice"] = json.loads((copy / MASK_CHOICE).read_text())
        return {"result": record}

    return _edited_copy(dataset, run_dir / "masked", edit)


def run_refine(dataset: Path, run_dir: Path, refine_cfg, progress: ProgressFn) -> dict:
    """refine_poses on a copy. When COLMAP keeps all the given poses, refine_poses warns itself; when it
    keeps some, this stage says so: those frames keep the robot's noise."""
    from real2sim.capture.poses.refinement import refine_poses

    def edit(copy: Path) -> dict:
        result = refine_poses(copy, refine_cfg, progress)
        kept = result.num_frames - result.num_refined_frames
        if result.refined and kept:
            warnings.warn(f"pose refinement kept the given poses of {kept} of {result.num_frames} frames (too few "
                          "triangulated observations, or a refined pose too far from the given one); the "
                          "reconstruction aligns them to the others", RuntimeWarning, stacklevel=2)
        return {"result": result.to_json()}

    return _edited_copy(dataset, run_dir / "dataset", edit)


#: Why poses are not refined without pycolmap, for the warning and truth.json.
PYCOLMAP_MISSING = "pycolmap is not installed (`make install` installs it; or pip install pycolmap)"


def refine_unavailable(run_dir: Path) -> dict:
    """The refine_poses stage without pycolmap: no copy, the given poses go on, with a warning."""
    shutil.rmtree(run_dir / "dataset", ignore_errors=True)  # an earlier run's refined copy: not this run's poses
    warnings.warn(f"pose refinement skipped: {PYCOLMAP_MISSING}; the given poses are used as they are",
                  RuntimeWarning, stacklevel=2)
    return {"outputs": [], "result": {"refined": False, "reason": f"skipped: {PYCOLMAP_MISSING}"}}


def run_robot_frame(dataset: Path, run_dir: Path, cfg: NormaliseConfig, seed: int, progress: ProgressFn) -> dict:
    """The robot_frame stage: ``dataset`` (a COLMAP model) normalised into ``run_dir/robot_frame``."""
    from real2sim.capture.phone.normalise import normalise

    record = normalise(dataset, run_dir / "robot_frame", cfg, seed=seed, progress=progress)
    keep = ("scale_from", "hull_height_m", "sparse_points", "table_fit_rms_mm", "errors_vs_ground_truth")
    return {"result": {"scale": record["robot_from_model"]["scale"], **{k: record[k] for k in keep if k in record}}}


def run_reconstruct(dataset: Path, out: Path, cfg, device: str, seed: int, progress: ProgressFn) -> dict:
    """The reconstruct stage: the mesh and report of ``dataset`` written into ``out``."""
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
    no bottom to close at the table. ``asset``'s own message speaks of ``--support-height-m``, which
    ``run`` sets itself."""
    from real2sim.asset.checks import SUPPORT_BELOW_TOLERANCE, support_below_mesh
    from real2sim.plumbing.errors import UserInputError
    from real2sim.geometry.mesh_io import load_mesh

    z_m = load_mesh(mesh).vertices[:, 2]
    bottom_m, top_m = float(z_m.min()), float(z_m.max())
    if support_below_mesh(bottom_m, top_m, table_z_m):
        gap_m, height_m = bottom_m - table_z_m, top_m - bottom_m
        raise UserInputError(
            f"the reconstruction's lowest point is {1000 * gap_m:.1f} mm above the table (z = {table_z_m:g} m), "
            f"more than {100 * SUPPORT_BELOW_TOLERANCE:g} % of its {1000 * height_m:.0f} mm height, so its bottom "
            "cannot be closed at the table: check that the masks reach the table in the low views, or give the "
            "table's height with --table-z-m")


#: What the asset stage writes into ASSETDIR besides one folder per SPEC (real2sim.asset.build).
ASSET_FILES = ("asset_config.json", "physical_properties.json", "canonical_transform.json", "visual", "README.md",
               "preview.png")


def refuse_foreign(asset_dir: Path, manifest: mf.Manifest, names) -> None:
    """UserInputError (one line) before ``names`` in ASSETDIR are replaced or removed: an entry there
    that `run` did not write (a folder or file of the user's under a name the stage writes), or a
    folder of the run's holding files the run did not write. Nothing of the user's is ever deleted."""
    owned = manifest.owned()
    theirs = sorted(n for n in names if n not in owned and os.path.lexists(asset_dir / n))
    if theirs:
        raise UserInputError(f"{asset_dir / theirs[0]} was not written by run, and run writes that name; "
                             "move it out of the folder and run again")
    extra = manifest.foreign_files(n for n in names if n in owned)
    if extra:
        more = f" (and {len(extra) - 1} more files)" if len(extra) > 1 else ""
        folder = extra[0].split("/")[0]
        raise UserInputError(f"{asset_dir / extra[0]}{more} was not written by run, and this rerun replaces "
                             f"{folder}/: move your files out of it and run again (files beside run's folders are kept)")


def _infer_legacy_asset(asset_dir: Path, manifest: mf.Manifest) -> None:
    """A run.json from before ownership was recorded, whose asset stage was forgotten (it failed):
    the entries the asset's own asset_config.json names are the run's (their files unknown)."""
    import json

    from real2sim.formats.spec import parse_spec

    try:
        specs = json.loads((asset_dir / "asset_config.json").read_text())["collision"]
        names = list(ASSET_FILES) + [parse_spec(text).name for text in specs]
    except (OSError, ValueError, KeyError, TypeError, UserInputError):
        return
    manifest.claim("asset", {name: None for name in names if (asset_dir / name).exists()})


def run_asset(mesh: Path, asset_dir: Path, cfg, manifest: mf.Manifest, progress: ProgressFn) -> dict:
    """build_asset into ``.run/asset`` (whole or not at all), then swap its entries into ASSETDIR.

    Only what the previous asset stage wrote (the manifest's ``owned`` record) is replaced or
    removed; the user's own files and folders in ASSETDIR are left alone. A representation whose
    geometry settings are unchanged is reused instead of refitted (``build_asset(reuse_from=)``)."""
    from real2sim.asset.build import build_asset

    check_reaches_table(mesh, cfg.support_height_m)
    if manifest.legacy and not manifest.owned("asset"):
        _infer_legacy_asset(asset_dir, manifest)
    previous = set(manifest.owned("asset"))
    planned = set(ASSET_FILES) | {spec.name for spec in cfg.specs}
    refuse_foreign(asset_dir, manifest, sorted(planned | previous))
    built = asset_dir / mf.RUN_DIRNAME / "asset"
    reuse = asset_dir if "asset_config.json" in previous else None
    build_asset(mesh, built, cfg, overwrite=True, progress=progress, reuse_from=reuse)
    (built / MARKER_NAME).unlink(missing_ok=True)  # ASSETDIR has its own
    outputs = sorted(entry.name for entry in built.iterdir())
    refuse_foreign(asset_dir, manifest, outputs)  # a name the plan did not foresee
    for name in (RESULTS_DIRNAME, TRUTH_RESULTS_DIRNAME):  # the evaluation's resume folders: for the old asset
        shutil.rmtree(asset_dir / f".{name}.partial", ignore_errors=True)
    # Swap: the old entries aside (a hidden '.old-' name, cleared by the next run if this one is
    # killed), the new ones in. Ownership is recorded first, as the union of both, so that a kill
    # halfway leaves every entry of the run's known as the run's.
    aside = Path(tempfile.mkdtemp(prefix=".asset.old-", dir=asset_dir / mf.RUN_DIRNAME))
    manifest.claim("asset", {n: digests.all_files(built / n) if (built / n).is_dir() else None for n in outputs})
    for name in sorted(previous | set(outputs)):
        if (asset_dir / name).exists() or (asset_dir / name).is_symlink():
            os.replace(asset_dir / name, aside / name)
        if name in outputs:
            os.replace(built / name, asset_dir / name)
    manifest.disown(previous - set(outputs))
    manifest.own("asset", outputs)
    shutil.rmtree(aside, ignore_errors=True)
    built.rmdir()
    return {"outputs": outputs}


def run_evaluate_truth(dataset: Path, asset_dir: Path, cfg, seed: int, manifest: mf.Manifest,
                       progress: ProgressFn) -> dict:
    """The sweep again, against the true mesh with the true mass properties (see truth_dynamics)."""
    from real2sim.evaluate.sweep import evaluate
    from real2sim.pipeline.truth_dynamics import write_true_reference

    refuse_foreign(asset_dir, manifest, [TRUTH_RESULTS_DIRNAME])
    mesh, properties = write_true_reference(dataset, asset_dir, asset_dir / mf.RUN_DIRNAME / "truth", seed)
    shutil.rmtree(asset_dir / f".{TRUTH_RESULTS_DIRNAME}.partial", ignore_errors=True)
    result = evaluate([asset_dir], asset_dir / TRUTH_RESULTS_DIRNAME, cfg, reference_mesh=mesh,
                      reference_properties=properties, progress=progress, overwrite=True)
    return {"summary": {"simulated": result.simulated, "failed": result.failed}}


def run_evaluate(asset_dir: Path, cfg, manifest: mf.Manifest, progress: ProgressFn, skip: tuple[str, ...] = ()) -> dict:
    """The evaluate stage: the sweep of the asset in ``asset_dir`` into its results folder."""
    from real2sim.evaluate.sweep import evaluate

    refuse_foreign(asset_dir, manifest, [RESULTS_DIRNAME])
    result = evaluate([asset_dir], asset_dir / RESULTS_DIRNAME, cfg, progress=progress, overwrite=True,
                      animations=True, skip_representations=skip)
    return {"summary": {"simulated": result.simulated, "failed": result.failed}}


#: The evaluation stages and their folders in ASSETDIR.
EVALUATIONS = (("evaluate", RESULTS_DIRNAME), ("evaluate_truth", TRUTH_RESULTS_DIRNAME))
#: The note put into an evaluation's folder once the asset it simulated has changed.
STALE_NAME = "STALE.txt"


def check_evaluations(asset_dir: Path, manifest: mf.Manifest, inputs_now: dict[str, dict]) -> tuple[dict, list]:
    """Which earlier evaluations still hold: ``({stage: True | False}, warnings)`` for each evaluation
    stage run.json records. One holds while the asset (and ground truth) it simulated are the ones
    ``inputs_now`` gives and its folder is there. One that no longer holds is kept, never deleted:
    marked ``"stale"`` in run.json, with a :data:`STALE_NAME` note in its folder and one warning."""
    valid, warnings = {}, []
    for stage, folder in EVALUATIONS:
        entry = manifest.entry(stage)
        if entry is None:
            continue
        valid[stage] = entry.get("inputs") == inputs_now.get(stage) and (asset_dir / folder).is_dir()
        if valid[stage]:  # the asset it simulated is back (a setting changed, then changed back)
            if entry.pop("stale", None):
                manifest.save()
                (asset_dir / folder / STALE_NAME).unlink(missing_ok=True)
            continue
        if entry.get("stale"):
            continue
        entry["stale"] = True
        manifest.save()
        if (asset_dir / folder).is_dir():
            (asset_dir / folder / STALE_NAME).write_text(
                f"The results in this folder were simulated for an earlier asset of {asset_dir.name}/, which has "
                "changed since (run.json marks the stage stale). They are kept, not deleted: run the same "
                "`real2sim run` command with --evaluate to simulate the current asset.\n")
            manifest.add_owned_files(folder, [STALE_NAME])
            warnings.append(f"{folder}/ holds the evaluation of an earlier asset: kept, marked stale "
                            f"({folder}/{STALE_NAME}); add --evaluate to simulate the current one")
    return valid, warnings


def rewrite_reports(asset_dir: Path, manifest: mf.Manifest, folders) -> None:
    """report.html (and summary, plots) of the evaluation ``folders`` of ASSETDIR written again, now that
    truth.json or run.json's warnings hold more; the new files are recorded as the run's."""
    from real2sim.report.html import write_report

    for name in folders:
        folder = Path(asset_dir) / name
        if (folder / "runs.csv").is_file():
            before = set(digests.all_files(folder))
            write_report(folder)
            manifest.add_owned_files(name, set(digests.all_files(folder)) - before)


def run_truth(dataset: Path, used: Path, asset_dir: Path, recon_dir: Path, manifest: mf.Manifest, seed: int,
              dynamics: bool, *, refined: bool, robot_frame: bool, raised: list[dict] = ()) -> None:
    """truth.json; ``dynamics``: with the evaluations' comparison (run now, or kept and still valid);
    ``refined`` / ``robot_frame``: whether those stages are part of this run; ``raised``: the warnings the
    stages before raised (``{"stage", "message"}``), repeated in truth.json."""
    import json

    from real2sim.pipeline.truth import build_truth

    report = json.loads((recon_dir / "report.json").read_text())
    refine_entry = manifest.entry("refine_poses") if refined else None
    refinement = refine_entry.get("result", {}) if refine_entry else None
    frame_entry = manifest.entry("robot_frame") if robot_frame else None
    true_properties = None
    if dynamics:
        # the truth evaluation, redone whenever the asset changes, wrote the same mass properties
        from real2sim.formats.physical import read_physical_properties
        from real2sim.pipeline.truth_dynamics import TRUE_PROPERTIES_NAME

        written = asset_dir / mf.RUN_DIRNAME / "truth" / TRUE_PROPERTIES_NAME
        true_properties = read_physical_properties(written) if written.is_file() else None
    record = build_truth(dataset, used, asset_dir, report, refinement=refinement, seed=seed,
                         robot_frame=frame_entry.get("result") if frame_entry else None,
                         true_properties=true_properties)
    record["warnings"] = list(raised)  # what degraded on the way: judge the errors above with it
    results, results_truth = asset_dir / RESULTS_DIRNAME, asset_dir / TRUTH_RESULTS_DIRNAME
    if dynamics and (results_truth / "summary.csv").is_file():
        from real2sim.pipeline.truth_dynamics import dynamics_record

        record["dynamics"] = dynamics_record(results, results_truth)
    mf.write_json_atomic(asset_dir / "truth.json", record)
    if dynamics:  # their reports show the truth now
        rewrite_reports(asset_dir, manifest, (RESULTS_DIRNAME, TRUTH_RESULTS_DIRNAME))
