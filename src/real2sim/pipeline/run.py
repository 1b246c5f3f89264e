"""`real2sim run`: a posed, masked dataset -> a simulation asset folder, stage by stage, resumable.

A phone capture (a folder of photos, or a video: :func:`real2sim.pipeline.phone.phone_input`) first
goes through ``sfm`` and, without object_height_m/scale, ``board_frame`` (:mod:`real2sim.pipeline.phone`),
which make the dataset the stages below read.

Stages, in order (each one the existing stage function, called as it is; ``masks``
(with ``mask_method``) first makes the masks on a copy in ``ASSETDIR/.run/masked/``):

0. ``robot_frame`` (a COLMAP dataset: images + ``sparse/0``, no transforms.json):
   :func:`real2sim.capture.phone.normalise.normalise` moves it into the robot frame (table
   plane z = 0, z up, metres from ``object_height_m`` or ``scale``) -> ``ASSETDIR/.run/robot_frame/``;
1. ``refine_poses`` (``RunConfig.refine``; the command's default where :func:`poses_to_refine`):
   :func:`real2sim.capture.refine_poses` on a copy of the dataset in ``ASSETDIR/.run/dataset/``
   (the user's dataset is never written); without pycolmap, skipped with a warning;
2. ``reconstruct``: :func:`real2sim.reconstruct.stage.reconstruct` +
   ``write_reconstruction`` -> ``ASSETDIR/.run/reconstruct/`` (mesh.obj, report.json);
3. ``asset``: :func:`real2sim.asset.build_asset` on that mesh (flat bottom at the support:
   the table plane z = 0 of the dataset's world frame, or, for a dataset without a table
   plane, the object's own lowest seen points, :mod:`real2sim.pipeline.support`) -> the usual ASSETDIR layout;
4. ``truth`` (when the dataset has ``ground_truth/``; a COLMAP dataset also needs
   ``ground_truth/model_from_world.json``, see :mod:`real2sim.capture.phone.normalise`): ``ASSETDIR/truth.json``;
5. ``evaluate`` (optional): :func:`real2sim.evaluate.sweep.evaluate` -> ``ASSETDIR/results/``.

A capture whose frame the run found (robot_frame, board_frame) also gets ``ASSETDIR/.run/outline.png``: the
reconstruction's outline over four of its photos (:func:`real2sim.pipeline.phone.write_outline`), the check by
eye where there is no truth.

Caching, resuming and the manifest: :mod:`real2sim.pipeline.manifest`. Every Python warning a
stage raises (a fallback, pose refinement that kept the given poses) is shown when it happens,
recorded in the stage's run.json entry, and returned in :attr:`RunResult.stage_warnings` (those of
stages skipped as unchanged too), which the command repeats in its summary and truth.json lists.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Callable

from real2sim.formats.dataset import has_table_plane, read_dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import check_output_dir, make_output_dir, output_lock
from real2sim.plumbing.progress import ProgressFn
from real2sim.pipeline import manifest as mf
from real2sim.capture.masks.stage import AUTO, GEOMETRY, PARALLAX
from real2sim.capture.phone.normalise import MODEL_FROM_WORLD
from real2sim.pipeline.stages import (RESERVED, RESULTS_DIRNAME, TRUTH_RESULTS_DIRNAME,  # noqa: F401 (public here)
                                      EVALUATIONS, check_evaluations, refine_unavailable, rewrite_reports, run_asset,
                                      run_evaluate, run_evaluate_truth, run_masks, run_reconstruct, run_refine,
                                      run_robot_frame, run_truth)
from real2sim.pipeline.run_folder import (check_dataset, dataset_files, discard, kept_note,  # noqa: F401
                                          poses_to_refine, prepare_asset_dir, remove_stale_temporaries)
from real2sim.pipeline.phone import OUTLINE_PNG, PHONE_DIRNAME, write_outline
from real2sim.pipeline.run_config import RunConfig, RunResult, phone_mask_config  # noqa: F401 (public here)
from real2sim.pipeline.runner import Paused, RunProgress, Runner, StageFailed
from real2sim.pipeline.support import support_height_m
from real2sim.pipeline.truth import has_ground_truth
from real2sim.plumbing import digests

# Evaluation settings that change how fast, not what: not part of the evaluate stage's key.
_EVAL_SCHEDULING = ("jobs", "executor", "ray_address", "ray_timeout_s", "sim_timeout_s")


def run_pipeline(dataset: Path | str, asset_dir: Path | str, config: RunConfig, *, overwrite: bool = False,
                 progress: ProgressFn | None = None, pause: Callable[[str], bool] | None = None) -> RunResult:
    """Run (or resume) every stage for ``dataset`` into ``asset_dir``; see the module docstring.

    Bad input (unreadable dataset, frames without masks, an ASSETDIR that is neither
    new, nor ``overwrite``, nor a run of this dataset) raises UserInputError before
    anything is written. A failing stage raises StageFailed (or UserInputError naming
    the stage); stages finished before it stay recorded for the next call. ``progress``
    receives every stage's start and end and, prefixed by the stage, its work (:class:`RunProgress`).
    ``pause``: asked with each stage's name before it; True stops the run there, the stages before it
    recorded (``RunResult.paused_before``): the next call resumes from it.
    """
    from real2sim.reconstruct.stage import ReconstructConfig

    from real2sim.pipeline.phone import phone_input

    run_progress = RunProgress(progress)
    robot_frame = config.robot_frame()
    phone = phone_input(dataset)
    if phone is None:
        dataset = check_dataset(Path(dataset), masks_needed=config.mask_method is None, scale_given=bool(robot_frame))
    else:
        dataset = phone.path
        if config.mask_method is None:  # photos have no masks: the command line's default, for the API too
            config = replace(config, mask_method=AUTO)
    if robot_frame is not None:
        robot_frame.validate()
    recon_cfg = config.reconstruct or ReconstructConfig()
    if recon_cfg.mask_edges == "auto" and config.mask_method in (PARALLAX, GEOMETRY, AUTO):
        # parallax masks come from the images already (warps and colour agreement over a textured table, where
        # colour models of object and table overlap): their edges stay (why: docs/design-notes/pipeline.md#mask-edges);
        # masks from geometry are snapped to the colour edges already
        recon_cfg = replace(recon_cfg, mask_edges="as-given")
    recon_cfg.validate()
    if (robot_frame is not None or phone is not None) and recon_cfg.table_z_m != 0.0:
        raise UserInputError("a table height is for a dataset in metres; a COLMAP capture's table is found in its "
                             "sparse points and put at z = 0")
    if phone is None and recon_cfg.table_z_m != 0.0 and not has_table_plane(read_dataset(dataset, check_files=False)):
        raise UserInputError(f"{dataset} has no table plane (transforms.json table_plane: false), so a table height "
                             "does not apply: the support is found from the object's own lowest points")
    asset_cfg = replace(config.asset, flat_bottom=True, support_height_m=recon_cfg.table_z_m)
    # A run resumes in place, so an existing ASSETDIR passes the "exists" rule; every other rule of
    # the output helper (inputs, working folder, foreign folders) holds even for a resume.
    read = [dataset, *([config.asset.given_properties_source] if config.asset.given_properties_source else []),
            *([config.mask.mask_weights] if getattr(config.mask, "mask_weights", None) else []),
            *([config.phone.board.source] if config.phone is not None and config.phone.board is not None
              and config.phone.board.source else [])]
    asset_dir = check_output_dir(asset_dir, overwrite=True, inputs=read, what="ASSETDIR")
    with output_lock(asset_dir):
        manifest, created = prepare_asset_dir(asset_dir, dataset, overwrite)
        if overwrite and asset_dir.exists():
            discard(asset_dir)
            created = True
        make_output_dir(asset_dir, made_by="real2sim run")
        remove_stale_temporaries(asset_dir)
        manifest.save()
        return _run_locked(manifest, created, dataset, asset_dir, config, recon_cfg, asset_cfg, run_progress, phone,
                           pause)


def _run_locked(manifest: mf.Manifest, created: bool, dataset: Path, asset_dir: Path, config: RunConfig,
                recon_cfg, asset_cfg, progress: RunProgress, phone=None,
                pause: Callable[[str], bool] | None = None) -> RunResult:
    runner = Runner(manifest, progress, 0, pause)
    try:
        if phone is not None:  # the dataset the stages below read is made first
            from real2sim.pipeline.phone import phone_stages

            truth = "ground_truth/mesh.obj" in phone.files
            config = phone_mask_config(config, phone.kind)
            runner.count = 1 + (config.robot_frame() is None) + _stage_count(config, truth)
            dataset = phone_stages(runner, phone, asset_dir / mf.RUN_DIRNAME, config)
        return _counted_stages(runner, dataset, asset_dir, config, recon_cfg, asset_cfg)
    except Paused as exc:  # asked for: what ran is recorded, the folder stays for the next call
        return RunResult(asset_dir, runner.statuses, manifest.path, stage_warnings=runner.warnings(),
                         paused_before=exc.stage)
    except BaseException as exc:
        if created and not manifest.data["stages"]:
            shutil.rmtree(asset_dir, ignore_errors=True)  # nothing finished: leave nothing behind
        elif isinstance(exc, UserInputError):  # the folder stays, deliberately: say so on the one line
            raise UserInputError(f"{exc}; {kept_note(asset_dir)}") from exc
        raise


def _counted_stages(runner: Runner, dataset: Path, asset_dir: Path, config: RunConfig, recon_cfg, asset_cfg
                    ) -> RunResult:
    manifest = runner.manifest
    robot_frame = config.robot_frame()
    # A COLMAP dataset's ground truth is usable only when it says how the model frame relates to it.
    truth = has_ground_truth(dataset) and (robot_frame is None or (dataset / "ground_truth" / MODEL_FROM_WORLD).is_file())
    evaluation_mesh = truth and not any(s.name == "mesh" for s in asset_cfg.specs) and (
        config.evaluation is not None or _kept_evaluation_mesh(manifest))
    if evaluation_mesh:
        from real2sim.formats.spec import parse_spec

        # The reconstruction itself as a representation: its own dynamics against the truth.
        asset_cfg = replace(asset_cfg, specs=asset_cfg.specs + (parse_spec("mesh"),))
    runner.count = runner.index + _stage_count(config, truth)
    return _run_stages(runner, dataset, asset_dir, config, recon_cfg, asset_cfg, truth, evaluation_mesh)


def _stage_count(config: RunConfig, truth: bool) -> int:
    """The stages from masks on (a phone capture's own come before)."""
    return (2 + bool(config.mask_method) + bool(config.robot_frame()) + bool(config.refine) + truth
            + bool(config.evaluation) + (truth and config.evaluation is not None))


def _kept_evaluation_mesh(manifest: mf.Manifest) -> bool:
    """Whether the asset of an earlier evaluated run has the ``mesh`` representation `run` added for
    the evaluation, and that evaluation is kept: a run without --evaluate keeps the representation,
    so that an unchanged asset stays unchanged and its evaluation valid."""
    entry = manifest.entry("asset")
    if not entry or not manifest.entry("evaluate"):
        return False
    # run.json from before the flag was recorded: a `mesh` the user does not ask for now was run's
    specs = entry.get("settings", {}).get("specs", [])
    return bool(entry.get("evaluation_mesh", any(isinstance(s, dict) and s.get("text") == "mesh" for s in specs)))


def _prepare_dataset(runner: Runner, dataset: Path, run_dir: Path, config: RunConfig, table_z_m: float
                     ) -> tuple[Path, Path, str | None]:
    """The optional stages before the reconstruction (masks, robot_frame, refine_poses): the dataset
    the reconstruction reads, the one whose ground_truth/ is in its frame, and the last stage's key.
    A stage no longer asked for is forgotten, with its folder."""
    manifest, progress = runner.manifest, runner.progress
    used, upstream = dataset, None
    truth_root, robot_frame = dataset, config.robot_frame()
    # Parallax masks test the table through the poses: on a robot capture they wait for refine_poses
    # (which needs no masks). A COLMAP capture's poses are COLMAP's already, and robot_frame needs masks.
    masks_last = config.mask_method in (PARALLAX, AUTO) and robot_frame is None and config.refine is not None

    def masks_stage(source: Path, upstream: str | None) -> str:
        from real2sim.capture.masks.methods import MaskConfig

        mask_cfg = config.mask or MaskConfig()
        settings = {"method": config.mask_method, "config": mask_cfg}
        if config.mask_method in (PARALLAX, AUTO):
            from real2sim.capture.masks.parallax_config import ParallaxConfig

            settings = {"method": config.mask_method, "table_z_m": table_z_m, "seed": config.seed}
            if isinstance(mask_cfg, ParallaxConfig):  # only what differs from the defaults: older runs still match
                default = ParallaxConfig()
                changed = {k: v for k, v in vars(mask_cfg).items() if k != "table_z_m" and getattr(default, k) != v}
                if changed:
                    settings["parallax"] = changed
        return runner.stage("masks", {"dataset": digests.files_digest(source, dataset_files(source))}, settings,
                            upstream, [f"{mf.RUN_DIRNAME}/masked"],
                            lambda: run_masks(source, run_dir, config.mask_method, mask_cfg, progress, table_z_m,
                                              config.seed))

    if config.mask_method is not None and not masks_last:
        upstream = masks_stage(dataset, None)
        used = run_dir / "masked"
    elif config.mask_method is None and manifest.entry("masks"):
        manifest.forget("masks")
        shutil.rmtree(run_dir / "masked", ignore_errors=True)
    if robot_frame is not None:
        source = used
        upstream = runner.stage("robot_frame", {"dataset": digests.files_digest(source, dataset_files(source))},
                                {"config": robot_frame, "seed": config.seed}, upstream,
                                [f"{mf.RUN_DIRNAME}/robot_frame"],
                                lambda: run_robot_frame(source, run_dir, robot_frame, config.seed, progress))
        used = truth_root = run_dir / "robot_frame"  # its ground_truth/ (if any) is re-expressed in the new frame
    elif manifest.entry("robot_frame"):
        manifest.forget("robot_frame")
        shutil.rmtree(run_dir / "robot_frame", ignore_errors=True)
    if config.refine is not None:
        source = used
        inputs = {"dataset": digests.files_digest(source, dataset_files(source))}
        if importlib.util.find_spec("pycolmap") is not None:
            upstream = runner.stage("refine_poses", inputs, config.refine, upstream, [f"{mf.RUN_DIRNAME}/dataset"],
                                    lambda: run_refine(source, run_dir, config.refine, progress))
            used = run_dir / "dataset"
        else:  # `make install` has it; without it the run goes on with the given poses, with a warning
            upstream = runner.stage("refine_poses", inputs, {"config": config.refine, "pycolmap": "missing"},
                                    upstream, None, lambda: refine_unavailable(run_dir))
    elif manifest.entry("refine_poses"):
        manifest.forget("refine_poses")
        shutil.rmtree(run_dir / "dataset", ignore_errors=True)
    if masks_last:
        upstream = masks_stage(used, upstream)
        used = run_dir / "masked"
    return used, truth_root, upstream


def _run_stages(runner: Runner, dataset: Path, asset_dir: Path, config: RunConfig, recon_cfg, asset_cfg,
                with_truth: bool, evaluation_mesh: bool) -> RunResult:
    run_dir = asset_dir / mf.RUN_DIRNAME
    manifest, progress = runner.manifest, runner.progress
    used, truth_root, upstream = _prepare_dataset(runner, dataset, run_dir, config, recon_cfg.table_z_m)

    recon_dir = run_dir / "reconstruct"
    upstream = runner.stage(
        "reconstruct", {"dataset": digests.files_digest(used, dataset_files(used))},
        {"config": recon_cfg, "device": config.device, "seed": config.seed}, upstream,
        [f"{mf.RUN_DIRNAME}/reconstruct/mesh.obj", f"{mf.RUN_DIRNAME}/reconstruct/report.json"],
        lambda: run_reconstruct(used, recon_dir, recon_cfg, config.device, config.seed, progress))

    if config.robot_frame() is not None or dataset == run_dir / PHONE_DIRNAME:  # photos without truth: a check by eye
        write_outline(used, recon_dir / "mesh.obj", run_dir / OUTLINE_PNG)
    mesh_files = [f for f in digests.tree_files(recon_dir) if f != "report.json"]
    support_m, support_from = support_height_m(used, recon_dir / "mesh.obj", recon_cfg.table_z_m)
    asset_cfg = replace(asset_cfg, support_height_m=support_m)
    asset_key = runner.stage("asset", {"mesh": digests.files_digest(recon_dir, mesh_files)}, asset_cfg, upstream, None,
                             lambda: {**run_asset(recon_dir / "mesh.obj", asset_dir, asset_cfg, manifest, progress),
                                      "evaluation_mesh": evaluation_mesh, "support": support_from})
    asset_outputs = manifest.entry("asset")["outputs"]

    gt_files = [f for f in dataset_files(truth_root) if f.startswith("ground_truth/")] if with_truth else []
    files = [f"{top}/{rel}" for top in asset_outputs if (asset_dir / top).is_dir()
             for rel in digests.tree_files(asset_dir / top)]
    files += [top for top in asset_outputs if (asset_dir / top).is_file()]
    asset_digest = digests.files_digest(asset_dir, files)
    inputs_now = {"evaluate": {"asset": asset_digest}}
    if with_truth:
        inputs_now["evaluate_truth"] = {"asset": asset_digest, "ground_truth": digests.files_digest(truth_root, gt_files)}
    # An earlier evaluation is never deleted: kept while its asset is unchanged, else marked stale.
    valid, warnings = check_evaluations(asset_dir, manifest, inputs_now)
    warnings = [] if config.evaluation is not None else warnings  # simulated again just below
    eval_key = None
    if config.evaluation is not None:
        settings = {k: v for k, v in mf.settings_record(config.evaluation).items() if k not in _EVAL_SCHEDULING}
        # The reconstruction added as `mesh` for the truth sweep is, under hydroelastic contact, the
        # paper protocol's reference itself (OCAE 0) and the slowest simulation: not simulated there.
        skip = () if any(s.name == "mesh" for s in config.asset.specs) else ("mesh",)
        eval_key = runner.stage("evaluate", inputs_now["evaluate"], {**settings, "skip": list(skip)}, asset_key,
                                [RESULTS_DIRNAME],
                                lambda: run_evaluate(asset_dir, config.evaluation, manifest, progress, skip))
        if with_truth:
            eval_key = runner.stage(
                "evaluate_truth", inputs_now["evaluate_truth"],
                {**settings, "seed_properties": asset_cfg.seed}, eval_key, [TRUTH_RESULTS_DIRNAME],
                lambda: run_evaluate_truth(truth_root, asset_dir, config.evaluation, asset_cfg.seed, manifest, progress))
        # a report is written inside its stage, before the stage's own warnings are recorded: again with them
        rewrite_reports(asset_dir, manifest, [folder for stage, folder in EVALUATIONS if runner.statuses.get(stage)
                                              == "ran" and (manifest.entry(stage) or {}).get("warnings")])
    else:  # no --evaluate: an evaluation of this very asset still holds, and truth.json keeps its dynamics
        for stage in ("evaluate", "evaluate_truth") if with_truth else ("evaluate",):
            if valid.get(stage):
                eval_key = manifest.entry(stage)["key"]
    dynamics = config.evaluation is not None or (with_truth and valid.get("evaluate_truth", False))

    truth = None
    if with_truth:
        inputs = {"ground_truth": digests.files_digest(truth_root, gt_files),
                  "asset": digests.files_digest(asset_dir, ["physical_properties.json", "canonical_transform.json"]),
                  "reconstruct_report": digests.files_digest(recon_dir, ["report.json"])}
        raised = runner.warnings()  # the stages' so far, repeated in truth.json
        settings = {"seed": asset_cfg.seed, "refined": config.refine is not None, "dynamics": dynamics,
                    **({"warnings": raised} if raised else {})}  # none: the key of runs from before warnings
        runner.stage("truth", inputs, settings, eval_key or asset_key, ["truth.json"],
                     lambda: run_truth(truth_root, used, asset_dir, recon_dir, manifest, asset_cfg.seed, dynamics,
                                       refined=config.refine is not None, robot_frame=config.robot_frame() is not None,
                                       raised=raised))
        truth = json.loads((asset_dir / "truth.json").read_text())
    elif manifest.entry("truth"):  # the dataset lost its ground_truth/: a stale truth.json would mislead
        manifest.forget("truth")
        (asset_dir / "truth.json").unlink(missing_ok=True)

    urdfs = sorted(asset_dir.glob("*/model.urdf"))
    return RunResult(asset_dir, runner.statuses, manifest.path, truth, urdfs, warnings, runner.warnings())
