"""`real2sim run`: posed, masked images -> reconstruction -> simulation asset (-> evaluation), resumable."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.asset import add_asset_arguments
from real2sim.cli.evaluate import add_simulator_argument, simulators_from_args
from real2sim.cli.options import COLMAP_SEED_MAX, existing_file, integer, jobs, nonnegative, positive
from real2sim.cli.reconstruct import (IMAGE_PX, STEPS, TABLE_Z_HELP, TABLE_Z_M, TEXTURE_PX, VOXELS,
                                      add_field_arguments, reconstruct_config)

#: Evaluation: runs per task, scale of the tasks' durations.
RUNS = integer(1, 1000)
DURATION_SCALE = positive(100.0)

# run always closes the bottom at the support (the table plane, or the object's lowest seen points
# without one: real2sim.pipeline.support), so these `asset` flags are hidden (and ignored).
_FORCED_ASSET_FLAGS = ("flat_bottom", "support_height_m")


#: run's evaluation options (dest by flag): refused without --evaluate rather than silently unused.
EVALUATION_FLAGS = {"--tasks": "tasks", "--contact": "contact", "--runs": "runs", "--jobs": "jobs",
                    "--duration-scale": "duration_scale", "--simulator": "simulator"}
EVALUATION_DEFAULTS = {"tasks": "push,ramp", "contact": "point,hydroelastic", "runs": 10, "jobs": None, "duration_scale": 1.0,
                       "simulator": None}


def register(sub) -> None:
    p = sub.add_parser(
        "run",
        help="images to asset in one command: [refine poses] -> reconstruct -> asset [-> evaluate], resumable",
        description="Chain the stages over one dataset (transforms.json, images/, masks/, table top at z = 0): "
        "pose refinement of given poses (on a copy in ASSETDIR/.run/dataset; the dataset is never modified; "
        "--no-refine-poses skips it), "
        "reconstruction (ASSETDIR/.run/reconstruct: mesh.obj, report.json), the asset (flat bottom at the table "
        "plane, or for a dataset without one (transforms.json table_plane: false) at the support height it states "
        "(support_z_m) or else at the lowest part of the reconstruction the cameras see; canonical pose, inertia, one folder per SPEC with model.urdf), ASSETDIR/truth.json when the "
        "dataset has ground_truth/ (pose, mask, reconstruction and mass-property errors), and with --evaluate the Drake evaluation into ASSETDIR/results. "
        "ASSETDIR/.run/run.json records each stage's input hashes, settings, outputs, wall seconds and peak "
        "memory, and the warnings each stage raised (repeated at the end of every run, and in truth.json); "
        "running again skips the unchanged stages and redoes those downstream of a change "
        "(a new --collision fits only that one), and resumes an interrupted run. A rerun replaces only what run "
        "wrote: your own files in ASSETDIR are kept, and an evaluation of an earlier asset is kept, marked stale.",
        epilog="example: real2sim capture can.obj --out can_ds && "
        "real2sim run can_ds --mass-kg 0.35 --out can_asset --collision cylinders:10 --backend hull",
    )
    p.add_argument("dataset", type=Path, metavar="DATASET|PHOTOS_DIR|VIDEO",
                   help="dataset folder (transforms.json, images/, masks/), or a folder of phone photos, or a video "
                   "(.mp4, .mov, ...): poses by structure from motion, metres and the table from the printed board "
                   "(`real2sim board`) or --object-height-m")
    p.add_argument("--frames", type=integer(8, 2000), default=None, metavar="N",
                   help="a video: frames kept, the sharpest of each equal stretch of the clip (default 80)")
    p.add_argument("--board-square-mm", type=positive(1000.0), default=None, metavar="MM",
                   help="photos or a video: the printed board's square side as measured, mm, when the print was scaled")
    p.add_argument("--board", type=Path, default=None, metavar="PDF|PNG",
                   help="photos or a video: the board file `real2sim board` wrote, when it was not the default "
                   "one (other squares or sizes; its layout is read from the file)")
    p.add_argument("--object-height-m", type=positive(10.0), default=None, metavar="H", help="a COLMAP dataset "
                   "(images/ + sparse/0, no transforms.json) or an ns-process-data folder (transforms.json with "
                   "applied_transform, sparse_pc.ply): the object's height above the table, metres; sets the "
                   "scale (the table plane is found in the sparse points)")
    p.add_argument("--scale", type=positive(1e6), default=None, metavar="M_PER_UNIT",
                   help="COLMAP or ns-process-data dataset: metres per model unit, instead of --object-height-m")
    p.add_argument("--marker-mm", type=positive(1000.0), default=None, metavar="MM",
                   help="photos, a video, a COLMAP or ns-process-data dataset: the side of printed square markers "
                   "(ArUco, AprilTag) lying flat on the table, mm, seen in at least 3 photos; sets the scale and the "
                   "table plane, instead of --object-height-m")
    p.add_argument("--marker-dictionary", default=None, metavar="NAME",
                   help="with --marker-mm: the markers' OpenCV aruco dictionary (e.g. DICT_4X4_50, "
                   "DICT_APRILTAG_36h11; default: the common ones are tried)")
    p.add_argument("--out", type=Path, required=True, metavar="ASSETDIR",
                   help="asset folder: new, a previous run of the same dataset (resumed), or --overwrite")
    p.add_argument("--overwrite", action="store_true",
                   help="discard ASSETDIR first: its cached stages, results and any files of yours in it")
    refine = p.add_mutually_exclusive_group()
    refine.add_argument("--refine-poses", dest="refine_poses", action="store_const", const=True, default=None,
                        help="refine the camera poses with COLMAP first (the default for a transforms.json of given "
                        "poses not refined yet; a COLMAP dataset's poses are COLMAP's own); when COLMAP keeps the "
                        "given poses, or pycolmap is missing, the run goes on with them and says so (WARNING)")
    refine.add_argument("--no-refine-poses", dest="refine_poses", action="store_const", const=False,
                        help="use the dataset's poses as they are")
    p.add_argument("--mask", choices=["provided", "maskrcnn", "background", "parallax", "geometry", "auto"], default=None,
                   metavar="METHOD",
                   help="make the masks first (on a copy in ASSETDIR/.run/masked): provided (masks/<image stem>.png), "
                   "maskrcnn (needs --mask-weights), background (background/<image name>), parallax (from the "
                   "images and poses alone: what stands above a textured table; after --refine-poses), geometry "
                   "(the object standing on the table in dense depth from the photos, drawn into each; close-ups "
                   "that cut it keep what they see), auto (parallax, or geometry where the parallax masks cannot "
                   "be the object's: no table plane in the sparse points, masks at the border in most views or "
                   "covering nearly all of an image; the run says which, and why); default: photos and videos "
                   "auto, a dataset the masks the frames name, all frames must have one")
    p.add_argument("--mask-weights", type=existing_file, default=None, metavar="PATH",
                   help="local Mask R-CNN weights file for --mask maskrcnn")
    p.add_argument("--background-threshold", type=nonnegative(255.0), default=12.0,
                   help="--mask background: difference threshold, 0-255 (default 12)")
    g = p.add_argument_group("reconstruction")
    g.add_argument("--backend", choices=["field", "hull"], default="field",
                   help="radiance field (default) or visual hull (fast)")
    g.add_argument("--steps", type=STEPS, default=None, help="field: fine-grid training steps (a GPU takes half as many of twice the rays)")
    g.add_argument("--voxels", type=VOXELS, default=None,
                   help="voxels along the object's longest side (field: fine grid; hull: carving grid, default 192)")
    g.add_argument("--texture-px", type=TEXTURE_PX, default=1024, help="texture image size, px (default 1024)")
    g.add_argument("--max-image-px", type=IMAGE_PX, default=640,
                   help="reconstruct from images reduced to this many px on their longer side (default 640)")
    g.add_argument("--table-z-m", type=TABLE_Z_M, default=0.0, metavar="M",
                   help=TABLE_Z_HELP + "; the flat bottom is closed there")
    add_field_arguments(g)
    g.add_argument("--max-faces", type=integer(100, 5_000_000), default=None, help="simplify the mesh to this many faces "
                   "(default 40000)")
    add_asset_arguments(p, seed_max=COLMAP_SEED_MAX)  # the seed reaches COLMAP with --refine-poses
    for action in p._actions:  # argparse has no public way to hide an inherited flag
        if action.dest in _FORCED_ASSET_FLAGS:
            action.help = argparse.SUPPRESS
    e = p.add_argument_group("evaluation (with --evaluate; results in ASSETDIR/results)")
    e.add_argument("--evaluate", action="store_true", help="run the Drake evaluation of every representation")
    e.add_argument("--tasks", default=EVALUATION_DEFAULTS["tasks"], metavar="LIST", help="comma-separated tasks (default push,ramp)")
    e.add_argument("--contact", default=EVALUATION_DEFAULTS["contact"], metavar="LIST",
                   help="comma-separated contact models (default point,hydroelastic)")
    add_simulator_argument(e)
    e.add_argument("--runs", type=RUNS, default=EVALUATION_DEFAULTS["runs"], metavar="N", help="runs per task (default 10)")
    e.add_argument("--jobs", type=jobs, default=None, metavar="N", help="simulations in parallel (default CPU count)")
    e.add_argument("--duration-scale", type=DURATION_SCALE, default=EVALUATION_DEFAULTS["duration_scale"], metavar="K",
                   help="multiply the tasks' durations by K (default 1)")
    options.finish(p)
    options.declare_paths(p, reads=("dataset", "board", "mask_weights", "properties"), writes=("out",),
                          cache=("sdf_cache",))
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace):
    """RunConfig from parsed flags; UserInputError for bad values (before anything is written)."""
    from dataclasses import replace

    from real2sim.cli.asset import config_from_args as asset_config
    from real2sim.plumbing.errors import UserInputError
    from real2sim.pipeline.run import RunConfig, check_dataset, poses_to_refine
    from real2sim.reconstruct.stage import resolve_device

    if args.seed < 0 or args.seed >= 2**63:
        raise UserInputError(f"--seed must be in 0..2^63-1 (got {args.seed})")
    scale_given = args.object_height_m is not None or args.scale is not None or args.marker_mm is not None
    if scale_given or args.marker_dictionary is not None:
        from real2sim.capture.phone.normalise import NormaliseConfig

        NormaliseConfig(object_height_m=args.object_height_m, scale=args.scale, marker_mm=args.marker_mm,
                        marker_dictionary=args.marker_dictionary).validate()
        if args.marker_dictionary is not None:
            from real2sim.capture.phone.markers import aruco_dictionary

            aruco_dictionary(args.marker_dictionary)
    phone = phone_config(args)
    if phone is None:  # every image and mask, and the frame options against the dataset's kind, before any display
        check_dataset(args.dataset, masks_needed=args.mask is None, scale_given=scale_given)
    elif args.mask is None:
        args.mask = "auto"  # parallax where the board's or the table's texture lets it, else geometry
    if scale_given and args.table_z_m != 0.0:
        raise UserInputError("--table-z-m is for a dataset in metres; a COLMAP capture's table is found in its "
                             "sparse points and put at z = 0")
    args.flat_bottom, args.support_height_m = True, 0.0
    asset = asset_config(args)
    resolve_device(args.device)
    # --voxels is the field's grid for the field, the carving grid for the hull
    field_voxels = args.voxels if args.backend == "field" else None
    recon = reconstruct_config(args, field_voxels)
    if args.voxels is not None and args.backend != "field":
        recon = replace(recon, hull_voxels=args.voxels)
    if args.max_faces is not None:
        recon = replace(recon, max_faces=args.max_faces)
    recon.validate()
    if args.mask_weights is not None and args.mask != "maskrcnn":
        raise UserInputError("--mask-weights is for --mask maskrcnn")
    if not args.evaluate:
        for flag, dest in EVALUATION_FLAGS.items():
            if getattr(args, dest) != EVALUATION_DEFAULTS[dest]:
                raise UserInputError(f"{flag} is for --evaluate (the evaluation of the asset); add --evaluate "
                                     f"or drop {flag}")
    if args.evaluate and "mujoco" in simulators_from_args(args) and "mjcf" not in (args.formats or ()):
        raise UserInputError("--simulator mujoco evaluates each representation's model.xml: add --format mjcf")
    mask = None
    if args.mask is not None:
        from real2sim.capture.masks.methods import MaskConfig

        if args.mask == "maskrcnn" and (args.mask_weights is None or not args.mask_weights.is_file()):
            raise UserInputError("--mask maskrcnn needs --mask-weights PATH, a local weights file")
        if not 0 <= args.background_threshold <= 255:
            raise UserInputError(f"--background-threshold must be in 0..255 (got {args.background_threshold})")
        mask = MaskConfig(background_threshold=args.background_threshold, mask_weights=args.mask_weights, device=args.device)
    refine = None
    if phone is not None and args.refine_poses:
        raise UserInputError("--refine-poses is for given poses; photos and videos get theirs from structure from motion")
    if phone is None and (args.refine_poses or (args.refine_poses is None and not scale_given
                                                and poses_to_refine(args.dataset))):
        from real2sim.capture.poses.refinement import RefineConfig

        refine = RefineConfig(seed=args.seed)
    evaluation = None
    if args.evaluate:
        from real2sim.cli.evaluate import config_from_args as evaluation_config

        args.executor, args.ray_address, args.simulation_error = "local", None, False
        evaluation = evaluation_config(args)
    return RunConfig(asset=asset, reconstruct=recon, mask_method=args.mask, mask=mask, refine=refine,
                     evaluation=evaluation, device=args.device, seed=args.seed,
                     object_height_m=args.object_height_m, scale=args.scale, marker_mm=args.marker_mm,
                     marker_dictionary=args.marker_dictionary, phone=phone)


def phone_config(args: argparse.Namespace):
    """PhoneConfig when DATASET is a folder of photos or a video (UserInputError for one with no images),
    else None (and then --frames, --board-square-mm and --board are refused)."""
    from real2sim.plumbing.errors import UserInputError
    from real2sim.pipeline.phone import PhoneConfig, phone_input
    from real2sim.capture.phone.sfm import SfmConfig
    from real2sim.capture.phone.video import DEFAULT_FRAMES

    phone = phone_input(args.dataset)
    if phone is None:
        for flag, value in (("--frames", args.frames), ("--board-square-mm", args.board_square_mm),
                            ("--board", args.board)):
            if value is not None:
                raise UserInputError(f"{flag} is for photos or a video, and {args.dataset} is a dataset")
        return None
    if args.frames is not None and phone.kind != "video":
        raise UserInputError(f"--frames is for a video, and {args.dataset} is a folder of photos")
    board = None
    if args.board is not None:
        from real2sim.capture.phone.board import read_board_spec

        board = read_board_spec(args.board)
    return PhoneConfig(frames=args.frames or DEFAULT_FRAMES, board_square_mm=args.board_square_mm, board=board,
                       sfm=SfmConfig(seed=args.seed))


def run(args: argparse.Namespace) -> int:
    from real2sim.cli.progress import progress_display
    from real2sim.pipeline.run import StageFailed, kept_note, run_pipeline

    config = config_from_args(args)
    try:
        with progress_display() as progress:  # one display for the whole run (pipeline.run.RunProgress)
            result = run_pipeline(args.dataset, args.out, config, overwrite=args.overwrite, progress=progress)
    except StageFailed as exc:
        print(f"real2sim run: error: {exc}; {kept_note(args.out)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"real2sim run: interrupted; {kept_note(args.out)}", file=sys.stderr)
        return 130
    for warning in result.warnings:
        print(f"WARNING: {warning}", file=sys.stderr)
    ran = [s for s, status in result.statuses.items() if status == "ran"]
    print(f"asset: {result.asset_dir} (stages run: {', '.join(ran) or 'none, all unchanged'})")
    for urdf in result.urdf_paths:
        print(f"  {urdf.parent.name:28s} {urdf}")
    if result.truth:
        phys, rec = result.truth["physical_properties"], result.truth.get("reconstruction") or {}
        print(f"vs truth: Chamfer {rec.get('chamfer_mm', float('nan')):.2f} mm, IoU {rec.get('iou', float('nan')):.3f}; "
              f"CoM {phys['com_error_mm']:.2f} mm, inertia eigenvalues {100 * phys['inertia_eigenvalue_max_rel_error']:.1f} %"
              f" ({result.asset_dir / 'truth.json'})")
    for line in judged_lines(result):
        print(line)
    for line in stage_warning_lines(result.stage_warnings):
        print(line)
    return 0


def judged_lines(result) -> list[str]:
    """What a run of photos without truth lets a user judge: the photos structure from motion placed and left
    out, its reprojection error, and the outline picture (``.run/outline.png``) to check by eye."""
    import json

    lines = []
    sfm = (json.loads(result.manifest_path.read_text()).get("stages", {}).get("sfm") or {}).get("result")
    if sfm:
        lines.append(f"photos: {sfm['registered']} placed, {sfm['left_out']} left out (why: .run/sfm/sfm.json), "
                     f"reprojection {sfm['mean_reprojection_px']:.2f} px")
    outline = result.asset_dir / ".run" / "outline.png"
    if outline.is_file():
        lines.append(f"check by eye: {outline} (the reconstruction's outline over four photos)")
    return lines


def stage_warning_lines(stage_warnings: list[dict]) -> list[str]:
    """What degraded, again at the end of the summary (each was printed when it happened, or by the
    run that made a stage this one skipped): one ``WARNING: ...`` line each, naming the stage."""
    return [f"WARNING: {w['message']} (stage {w['stage']})" for w in stage_warnings]
