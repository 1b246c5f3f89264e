"""`real2sim capture`, `refine-poses`, `mask`: posed-image datasets (simulated capture, COLMAP, masks)."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.asset import add_mesh_units_argument
from real2sim.cli.options import COLMAP_SEED_MAX, device, integer, nonnegative, number, seed
from real2sim.cli.reconstruct import TABLE_Z_M

#: Image sides, px (the capture's renderer and COLMAP work within this).
IMAGE_PX = integer(16, 8192)
#: RMS calibration noise of robot camera poses: position, mm, and orientation, degrees.
NOISE_MM = nonnegative(100.0)
NOISE_DEG = nonnegative(30.0)
#: Hard-rig settings (see CaptureConfig): ring elevation, degrees; focal length, px; horizontal field
#: of view, degrees; fractions; exposure, stops; JPEG quality.
RING_ELEVATION_DEG = number(-85.0, 85.0)
FOCAL_PX = number(1.0, 1e5)
FOV_DEG = number(1.0, 170.0)
FRACTION = number(0.0, 1.0)
EXPOSURE_STOPS = nonnegative(3.0)
WHITE_BALANCE = nonnegative(1.0)
JPEG_QUALITY = integer(1, 100)
#: --jpeg without --jpeg-quality.
DEFAULT_JPEG_QUALITY = 90


def register(sub) -> None:
    p = sub.add_parser(
        "capture",
        help="render a posed-image dataset of a mesh on a table, as a robot's wrist camera would see it",
        description="Simulated robot capture (Drake VTK, headless): the object stands on a textured table; a "
        "wrist camera (RealSense D435-like, fx = fy = 615 px at 640x480) looks at it from rings of poses the arm "
        "can reach (its base at one side of the table, so the far side is seen only from above). Writes a "
        "nerfstudio dataset: transforms.json (poses with calibration noise), images/, masks/, and ground_truth/ "
        "(exact poses, depth in mm, the mesh and its pose). The 'hard rigs' flags make captures like real "
        "photographs: a turntable ring, a long lens, views cut by the image border, no table, exposure and white-"
        "balance jitter, JPEG.",
        epilog="example: real2sim capture bottle --out bottle_ds --views 120   (a bundled object name or a mesh file)",
    )
    p.add_argument("mesh", help="object mesh in metres or --mesh-units (standing on z = 0 is not required), or a "
                   "bundled object name (bottle, can, mug)")
    add_mesh_units_argument(p)
    p.add_argument("--out", type=Path, required=True, metavar="DATASET", help="output dataset folder (must not exist)")
    p.add_argument("--overwrite", action="store_true", help="replace DATASET if it exists")
    p.add_argument("--views", type=integer(1, 2000), default=None,
                   help="number of images (default 200; --handheld 60; --video: frames, e.g. 600 = 20 s at 30 fps)")
    p.add_argument("--width-px", type=IMAGE_PX, default=640, help="image width, px (default 640)")
    p.add_argument("--height-px", type=IMAGE_PX, default=480, help="image height, px (default 480)")
    p.add_argument("--pose-noise-mm", type=NOISE_MM, default=5.0, metavar="MM",
                   help="RMS camera-position error of the robot poses, mm (default 5)")
    p.add_argument("--pose-noise-deg", type=NOISE_DEG, default=1.0, metavar="DEG",
                   help="RMS camera-orientation error of the robot poses, degrees (default 1)")
    p.add_argument("--seed", type=seed(), default=0, help="seed of the pose noise (default 0)")
    p.add_argument("--with-background", action="store_true",
                   help="also render the empty table from the same poses into background/ (for mask --method background)")
    _add_hard_rig_arguments(p)
    _add_handheld_arguments(p)
    options.finish(p)
    options.declare_paths(p, reads=("mesh",), writes=("out",))
    p.set_defaults(func=run_capture)

    p = sub.add_parser(
        "refine-poses",
        help="refine a dataset's camera poses with COLMAP, keeping the robot frame",
        description="COLMAP (pycolmap) seeded with the dataset's poses: SIFT features, matching of each view with "
        "its nearest views, triangulation, bundle adjustment, then a similarity alignment back onto the given "
        "camera centres. Rewrites transforms.json (the original is kept as transforms_unrefined.json) and writes "
        "refine_report.json; when COLMAP fails, the poses are kept and a warning says why.",
    )
    p.add_argument("dataset", type=Path, help="dataset folder with transforms.json")
    p.add_argument("--neighbors", type=integer(1, 200), default=30, metavar="K", help="views matched with each view (default 30)")
    p.add_argument("--features", choices=["all", "object"], default="all",
                   help="where to detect features: the whole image (default; the table helps) or the object masks")
    p.add_argument("--max-features", type=integer(64, 32768), default=4096, help="SIFT features per image (default 4096)")
    p.add_argument("--align", choices=["poses", "centres"], default="poses",
                   help="how the refined model is put back onto the robot frame: similarity from camera centres "
                   "and orientations weighted by the pose noise (default), or centres only (COLMAP's model aligner)")
    p.add_argument("--pose-noise-mm", type=NOISE_MM, default=None, metavar="MM",
                   help="RMS position noise of the given poses, mm, weighting --align poses "
                   "(default: from transforms.json's real2sim block, else 5)")
    p.add_argument("--pose-noise-deg", type=NOISE_DEG, default=None, metavar="DEG",
                   help="RMS orientation noise of the given poses, degrees (default: from transforms.json, else 1)")
    p.add_argument("--seed", type=seed(COLMAP_SEED_MAX), default=0, help="COLMAP random seed (default 0)")
    options.finish(p)
    options.declare_paths(p, in_place=("dataset",))
    p.set_defaults(func=run_refine)

    p = sub.add_parser(
        "mask",
        help="make or check object masks of a dataset",
        description="Object masks (255 = object) for the frames of a dataset: 'provided' checks the masks the "
        "frames name (or masks/<image stem>.png); 'maskrcnn' runs torchvision's Mask R-CNN from a local weights "
        "file (pixels with probability > 0.5); 'background' differences each image with background/<image name> "
        "(the empty scene from the same pose); 'parallax' needs neither weights nor an empty scene: it finds "
        "what stands above the table from how it moves against the table between views (a textured table, "
        "poses good to a pixel: refine them first); 'geometry' needs the poses alone: dense multi-view stereo, the "
        "support plane and the object standing on it (written to dense_geometry.json), each mask the object's solid "
        "drawn into the view (photos with clutter, close-ups that cut the object); 'auto' makes parallax masks and "
        "keeps them unless they cannot be the object's, then masks from geometry, with a warning saying why "
        "(mask_choice.json), as `run --mask auto` does. Computed masks go to masks_<method>/ and transforms.json "
        "points to them; IoU against ground_truth/masks is printed when present.",
    )
    p.add_argument("dataset", type=Path, help="dataset folder with transforms.json")
    p.add_argument("--method", choices=["provided", "maskrcnn", "background", "parallax", "geometry", "auto"], required=True)
    p.add_argument("--overwrite", action="store_true",
                   help="replace masks_<method>/ even where you edited masks `mask` wrote earlier; a folder `mask` "
                   "did not make, and files in it that `mask` did not write, are never replaced")
    p.add_argument("--table-z-m", type=TABLE_Z_M, default=0.0, metavar="M",
                   help="--method parallax: height of the table top in the dataset's frame, m (default 0; a COLMAP "
                   "model's table is fitted to its sparse points)")
    p.add_argument("--mask-weights", type=Path, default=None, metavar="PATH",
                   help="Mask R-CNN (torchvision ResNet-50 FPN) weights file, for --method maskrcnn")
    p.add_argument("--background-threshold", type=nonnegative(255.0), default=12.0,
                   help="background difference threshold, 0-255 (default 12)")
    p.add_argument("--device", type=device, default="cpu", help="torch device for Mask R-CNN: cpu, cuda, cuda:N (default cpu)")
    p.add_argument("--maskrcnn-min-size-px", type=integer(32, 4096), default=800, metavar="PX",
                   help="Mask R-CNN resizes the shorter image side to this, px (default 800, as trained; "
                   "smaller is faster on a CPU)")
    p.add_argument("--maskrcnn-max-size-px", type=integer(32, 8192), default=1333, metavar="PX",
                   help="upper bound on the longer side after resizing, px (default 1333)")
    p.add_argument("--maskrcnn-max-instances", type=integer(1, 1000), default=100, metavar="N",
                   help="detections kept per image before choosing the object (default 100)")
    options.finish(p)
    options.declare_paths(p, in_place=("dataset",), reads=("mask_weights",))
    p.set_defaults(func=run_mask)


def _add_hard_rig_arguments(p: argparse.ArgumentParser) -> None:
    """What real capture rigs do (issue #28): each flag alone or together; none given, the capture is as before."""
    g = p.add_argument_group("hard rigs", "captures like real photographs; masks and ground_truth/ stay exact")
    g.add_argument("--ring-elevation-deg", type=RING_ELEVATION_DEG, default=None, metavar="DEG",
                   help="a turntable ring instead of the arm's hemisphere: all views evenly around one horizontal "
                   "ring at this elevation, degrees, seen from the object's middle (0 = level with it, cameras "
                   "below its top; negative = from below, needs --no-table)")
    lens = g.add_mutually_exclusive_group()
    lens.add_argument("--focal-px", type=FOCAL_PX, default=None, metavar="PX",
                      help="focal length, pixels of the written images (fx = fy; default D435-like, 615 px at 640 "
                      "wide; real turntable rigs: > 3000 px at 640x480); the cameras stand back until the object "
                      "fills 75%% of the view, on a tripod (beyond the arm's reach)")
    lens.add_argument("--fov-deg", type=FOV_DEG, default=None, metavar="DEG",
                      help="horizontal field of view, degrees, instead of --focal-px (fx = fy = w / 2 / tan(fov / 2))")
    g.add_argument("--cut-off-fraction", type=FRACTION, default=0.0, metavar="P",
                   help="fraction of the views, 0-1, aimed off the object so that the image border cuts 20-40%% "
                   "of its extent (default 0)")
    g.add_argument("--no-table", action="store_true",
                   help="no table: the object on a thin grey post (not in the masks) against a dark background, its "
                   "lowest point at z = 0; transforms.json says \"table_plane\": false")
    g.add_argument("--exposure-jitter-stops", type=EXPOSURE_STOPS, default=0.0, metavar="STOPS",
                   help="RMS per-view exposure change, stops (factors of 2 in linear light; default 0)")
    g.add_argument("--white-balance-jitter", type=WHITE_BALANCE, default=0.0, metavar="FRACTION",
                   help="RMS per-view change of the red and blue gains against green, as a fraction "
                   "(0.1 = about 10%%; default 0)")
    g.add_argument("--jpeg", action="store_true", help="write images/*.jpg instead of PNG (masks and depth stay PNG)")
    g.add_argument("--jpeg-quality", type=JPEG_QUALITY, default=None, metavar="Q",
                   help="JPEG quality, 1-100, with --jpeg (default 90)")


def _add_handheld_arguments(p: argparse.ArgumentParser) -> None:
    """A person with a phone instead of a robot (issue #29): photos or a video, no poses given."""
    g = p.add_argument_group("handheld phone", "what a person walking around the object with a phone gets: "
                             "JPEG photos named IMG_0001.jpg... (or clip.mp4) directly in DATASET, no poses; the "
                             "exact poses only in DATASET/ground_truth/")
    g.add_argument("--handheld", action="store_true",
                   help="an orbit at varying height and distance, camera rolled a few degrees, some views close enough "
                   "to cut the object, a phone lens (--fov-deg, default 65), motion blur, JPEG (default 60 views)")
    g.add_argument("--with-board", action="store_true",
                   help="with --handheld: the printed board of `real2sim board` (default 7x5, 32 mm) lies flat on the "
                   "table under the object; its frame is the world frame")
    g.add_argument("--video", action="store_true",
                   help="with --handheld: write DATASET/clip.mp4 (H.264) of --views frames at --fps instead of photos")
    g.add_argument("--fps", type=FPS, default=None, help="with --video: frames per second (default 30)")
    g.add_argument("--distortion-k1", type=DISTORTION, default=0.0, metavar="K1",
                   help="with --handheld: the lens's radial distortion, OpenCV's k1 (default 0: phones correct it; "
                   "-0.1 is a visible barrel), stated in ground_truth/")
    g.add_argument("--video-rotation-deg", choices=["0", "90", "180", "270"], default="0",
                   help="with --video: store the frames turned, with rotation metadata that turns them back by this "
                   "much counter-clockwise, as phones do (270: held upright); --width-px x --height-px is the upright picture")
    g.add_argument("--close-fraction", type=FRACTION, default=None, metavar="P",
                   help="with --handheld: share of the photos, 0-1, taken close enough that the image border cuts the "
                   "object: at --close-factor times the distance at which its bounding sphere fills 70%% of the "
                   "view's height, then nearer by 15%% steps until the border cuts it (default 0.12, without the "
                   "steps; 0.7 is how people photograph an object)")
    g.add_argument("--close-factor", type=CLOSE_FACTOR, default=None, metavar="K",
                   help="with --handheld: the close photos' distance factor, 0.2-1 (default 0.55)")
    g.add_argument("--room", action="store_true",
                   help="with --handheld: a room behind the table (walls, floor, shelves with boxes, things on the "
                   "table 0.55-1.05 m away), textured, laid out from the texture seed; default a plain backdrop")
    g.add_argument("--auto-exposure", action="store_true",
                   help="with --handheld: each photo's exposure follows its brightness as a phone's does (centre-"
                   "weighted mean brought to middle grey, within 2 stops), on top of the usual 0.1-stop jitter")
    g.add_argument("--table-texture-px", type=integer(256, 16384), default=2048, metavar="PX",
                   help="with --handheld: side of the table's texture, px (default 2048; above it the table gains "
                   "mm-scale grain, which close-ups at phone resolution need: 4096)")
    g.add_argument("--markers", type=integer(0, 16), default=0, metavar="N",
                   help="with --handheld: N printed square fiducials (0-16) flat on the table around the object; "
                   "their true corners in ground_truth/markers.json (for `run --marker-mm`; default 0)")
    g.add_argument("--marker-mm", type=MARKER_MM, default=None, metavar="MM",
                   help="with --markers: side of each marker's black square, mm (default 40)")
    g.add_argument("--marker-dictionary", default=None, metavar="NAME",
                   help="with --markers: the OpenCV aruco dictionary printed (default DICT_4X4_50; e.g. "
                   "DICT_APRILTAG_36h11)")


#: --fps of a handheld video; --distortion-k1 of its lens.
FPS = number(1.0, 240.0)
#: --video without --fps.
DEFAULT_FPS = 30.0
DISTORTION = number(-0.5, 0.5)
#: --close-factor (distance factor of the close photos); --marker-mm (printed marker side).
CLOSE_FACTOR = number(0.2, 1.0)
MARKER_MM = number(5.0, 300.0)
#: Handheld flags (dest -> the value that means "not given").
_HANDHELD_ONLY = {"close_fraction": None, "close_factor": None, "room": False, "auto_exposure": False, "markers": 0,
                  "marker_mm": None, "marker_dictionary": None, "table_texture_px": 2048}


def _resolve_mesh(text: str):
    """A mesh file path, or the textured bundled object of that name when no such file exists."""
    path = Path(text)
    if not path.exists() and path.suffix == "":
        from real2sim.geometry.objects import OBJECTS, make_textured_object

        if text in OBJECTS:
            return make_textured_object(text)
    return path


def _checked_input(args: argparse.Namespace):
    """The object to capture, after the output folder is checked (never the mesh's own folder): a
    bundled object, or the mesh file loaded in ``--mesh-units`` and of an object's size."""
    from real2sim.plumbing.outputs import check_output_dir

    check_output_dir(args.out, args.overwrite, inputs=[Path(args.mesh)] if Path(args.mesh).exists() else [])
    mesh = _resolve_mesh(args.mesh)
    if isinstance(mesh, Path):
        from real2sim.geometry.mesh_io import check_object_size, load_mesh

        mesh_path, mesh = mesh, load_mesh(mesh, args.mesh_units)
        check_object_size(mesh, str(mesh_path), args.mesh_units)
    return mesh


def run_capture(args: argparse.Namespace) -> int:
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.cli.progress import progress_display
    from real2sim.plumbing.errors import UserInputError

    # Checked in every mode, before any work: each would otherwise be ignored without a word.
    if args.jpeg and args.video:
        raise UserInputError("--jpeg and --video do not go together: a video has no JPEG images (drop --jpeg)")
    if args.fps is not None and not args.video:
        raise UserInputError("--fps needs --video")
    if args.ring_elevation_deg is not None and args.ring_elevation_deg < 0 and not args.no_table:
        raise UserInputError(f"--ring-elevation-deg {args.ring_elevation_deg:g} (from below) needs --no-table: "
                             "with a table, use 0 or more")
    if args.handheld:
        return _run_handheld(args)
    for flag in ("with_board", "video"):
        if getattr(args, flag):
            raise UserInputError(f"--{flag.replace('_', '-')} needs --handheld")
    for flag, unset in _HANDHELD_ONLY.items():
        if getattr(args, flag) != unset:
            raise UserInputError(f"--{flag.replace('_', '-')} needs --handheld")
    if args.video_rotation_deg != "0":
        raise UserInputError("--video-rotation-deg needs --handheld --video")
    if args.distortion_k1 != 0.0:
        raise UserInputError("--distortion-k1 needs --handheld")
    if args.jpeg_quality is not None and not args.jpeg:
        raise UserInputError("--jpeg-quality needs --jpeg")
    args.views = 200 if args.views is None else args.views
    cfg = CaptureConfig(views=args.views, width=args.width_px, height=args.height_px, pose_noise_mm=args.pose_noise_mm,
                        pose_noise_deg=args.pose_noise_deg, seed=args.seed, with_background=args.with_background,
                        ring_elevation_deg=args.ring_elevation_deg, focal_px=args.focal_px, fov_deg=args.fov_deg,
                        cut_off_fraction=args.cut_off_fraction, no_table=args.no_table,
                        exposure_jitter_stops=args.exposure_jitter_stops, white_balance_jitter=args.white_balance_jitter,
                        jpeg_quality=(args.jpeg_quality or DEFAULT_JPEG_QUALITY) if args.jpeg else None)
    cfg.validate()
    mesh = _checked_input(args)
    with progress_display() as progress:
        result = capture(mesh, args.out, cfg, progress=progress, overwrite=args.overwrite)
    print(f"dataset: {result.out_dir} ({result.num_views} views, rendered in {result.render_seconds:.1f} s)")
    return 0


def run_refine(args: argparse.Namespace) -> int:
    import sys
    import warnings

    from real2sim.capture.poses.refinement import RefineConfig, refine_poses
    from real2sim.cli.progress import progress_display
    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import output_lock
    from real2sim.plumbing.progress import prefixed

    if args.neighbors < 1:
        raise UserInputError(f"--neighbors must be at least 1 (got {args.neighbors})")
    if args.max_features < 64:
        raise UserInputError(f"--max-features must be at least 64 (got {args.max_features})")
    cfg = RefineConfig(k_neighbors=args.neighbors, feature_region=args.features, max_num_features=args.max_features,
                       align=args.align, prior_noise_mm=args.pose_noise_mm, prior_noise_deg=args.pose_noise_deg,
                       seed=args.seed)
    # refine-poses edits the dataset in place: one writer at a time.
    with output_lock(args.dataset, inside=True), warnings.catch_warnings(record=True) as caught, \
            progress_display() as progress:
        warnings.simplefilter("always", RuntimeWarning)
        result = refine_poses(args.dataset, cfg, progress=prefixed(progress, "refine-poses"))
    for w in caught:  # one plain line each, never wrapped (rich would wrap at the terminal's width)
        print(f"WARNING: {' '.join(str(w.message).split())}", file=sys.stderr)
    print(f"refined {result.num_refined_frames}/{result.num_frames} frames ({result.reason}); "
          f"{result.num_pairs} pairs, {result.num_points3d} points, {result.seconds:.1f} s")
    if result.rot_error_before_deg is not None:
        print(f"pose error vs ground truth: rotation {result.rot_error_before_deg:.3f} -> {result.rot_error_after_deg:.3f} deg, "
              f"position {result.trans_error_before_mm:.2f} -> {result.trans_error_after_mm:.2f} mm")
    return 0


def run_mask(args: argparse.Namespace) -> int:
    from real2sim.capture.masks.methods import MaskConfig
    from real2sim.cli.progress import progress_display
    from real2sim.plumbing.outputs import output_lock
    from real2sim.capture.masks.stage import make_masks

    if args.mask_weights is not None and args.method != "maskrcnn":
        from real2sim.plumbing.errors import UserInputError

        raise UserInputError(f"--mask-weights is for --method maskrcnn, not --method {args.method}")
    cfg = MaskConfig(background_threshold=args.background_threshold, mask_weights=args.mask_weights, device=args.device,
                     maskrcnn_min_size_px=args.maskrcnn_min_size_px, maskrcnn_max_size_px=args.maskrcnn_max_size_px,
                     maskrcnn_max_instances=args.maskrcnn_max_instances)
    with output_lock(args.dataset, inside=True), progress_display() as progress:  # masks are written into the dataset
        result = make_masks(args.dataset, args.method, cfg, table_z_m=args.table_z_m, progress=progress,
                            may_replace="edited" if args.overwrite else "unchanged")
    line = f"masks: {result.num_frames} frames in {result.mask_dir}/, object covers {100 * result.mean_object_fraction:.1f}% of pixels"
    if result.mean_iou is not None:
        line += f"; IoU vs ground truth mean {result.mean_iou:.4f}, min {result.min_iou:.4f}"
    print(line)
    return 0


#: Flags of the robot capture that a handheld one has no use for, with their defaults.
_NOT_HANDHELD = {"pose_noise_mm": 5.0, "pose_noise_deg": 1.0, "with_background": False, "ring_elevation_deg": None,
                 "focal_px": None, "cut_off_fraction": 0.0, "no_table": False, "exposure_jitter_stops": 0.0,
                 "white_balance_jitter": 0.0}


def _run_handheld(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from real2sim.capture.phone.board import DEFAULT_BOARD
    from real2sim.capture.sim.handheld import HandheldConfig, capture_handheld
    from real2sim.cli.progress import progress_display
    from real2sim.plumbing.errors import UserInputError

    for name, default in _NOT_HANDHELD.items():
        if getattr(args, name) != default:
            raise UserInputError(f"--{name.replace('_', '-')} is not a handheld capture's setting (drop it or --handheld)")
    cfg = HandheldConfig(views=60 if args.views is None else args.views, width=args.width_px, height=args.height_px,
                         fov_deg=65.0 if args.fov_deg is None else args.fov_deg, seed=args.seed,
                         board=DEFAULT_BOARD if args.with_board else None, video=args.video,
                         fps=DEFAULT_FPS if args.fps is None else args.fps,
                         video_rotation_deg=int(args.video_rotation_deg), distortion_k1=args.distortion_k1,
                         jpeg_quality=args.jpeg_quality or DEFAULT_JPEG_QUALITY, room=args.room,
                         auto_exposure=args.auto_exposure, markers=args.markers,
                         table_texture_px=args.table_texture_px)
    if args.close_fraction is not None:  # asked for: close photos that do cut the object
        cfg = replace(cfg, close_fraction=args.close_fraction, close_cut=True)
    if args.close_factor is not None:
        cfg = replace(cfg, close_factor=args.close_factor)
    if (args.marker_mm is not None or args.marker_dictionary is not None) and not args.markers:
        raise UserInputError("--marker-mm and --marker-dictionary are for --markers N (how many to print)")
    if args.marker_mm is not None:
        cfg = replace(cfg, marker_mm=args.marker_mm)
    if args.marker_dictionary is not None:
        cfg = replace(cfg, marker_dictionary=args.marker_dictionary)
    cfg.validate()
    mesh = _checked_input(args)
    with progress_display() as progress:
        result = capture_handheld(mesh, args.out, cfg, progress=progress, overwrite=args.overwrite)
    what = "frames in clip.mp4" if cfg.video else "photos"
    print(f"handheld capture: {result.out_dir} ({result.num_views} {what}, rendered in {result.render_seconds:.1f} s; "
          "exact poses in ground_truth/)")
    return 0
