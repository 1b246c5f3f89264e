"""`real2sim reconstruct`: posed, masked images -> textured mesh in the dataset's world frame."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.options import device, existing_file, integer, number, seed

#: Training steps, grid voxels along the object's longest side, texture image side (px).
STEPS = integer(1, 100_000)
VOXELS = integer(16, 512)
TEXTURE_PX = integer(64, 8192)
IMAGE_PX = integer(16, 16384)
#: Table-top height in the dataset's frame, m.
TABLE_Z_M = number(-100.0, 100.0)
TABLE_Z_HELP = ("height of the table top in the dataset's frame, +z up, metres (default 0; a robot capture "
                "whose base is not on the table sets it)")


def register(sub) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="reconstruct a textured mesh from a posed, masked dataset (radiance field or visual hull)",
        description="Reconstruction from posed images (the paper's IV-B). --backend field (default): a voxel "
        "radiance field, bounded by the masks' visual hull, trained on the masked images (CPU or CUDA), then a "
        "surface by marching cubes on its density (--extraction density, default) or by TSDF fusion of rendered "
        "depth (--extraction tsdf, the paper's way), textured from the field. --backend hull: the visual hull of "
        "the masks, textured from the images. Writes MESHDIR/mesh.obj (+ .mtl, .png) in the dataset's world frame "
        "(metres, table top z = 0) and MESHDIR/report.json (stage times, memory, held-out PSNR, and the error "
        "against ground_truth/ when the dataset has it). With --from-mesh, imports a mesh exported by nerfstudio "
        "instead, undoing its normalisation with --dataparser-transforms.",
        epilog="example: real2sim reconstruct bottle_ds --out bottle_mesh",
    )
    p.add_argument("dataset", type=Path, help="dataset folder (transforms.json, images/, masks/)")
    p.add_argument("--out", type=Path, required=True, metavar="MESHDIR", help="output folder (must not exist)")
    p.add_argument("--overwrite", action="store_true", help="replace MESHDIR if it exists")
    p.add_argument("--backend", choices=["field", "hull"], default="field", help="reconstruction method (default field)")
    p.add_argument("--device", type=device, default="cpu", help="cpu (default), cuda or cuda:N")
    p.add_argument("--seed", type=seed(), default=0, help="random seed of the field's training (default 0)")
    p.add_argument("--steps", type=STEPS, default=None,
                   help="fine-grid training steps (default from the field settings); the coarse grid gets half; "
                        "a GPU takes half as many steps of twice the rays")
    p.add_argument("--voxels", type=VOXELS, default=None,
                   help="fine-grid voxels along the object's longest side (default from the field settings)")
    p.add_argument("--texture-px", type=TEXTURE_PX, default=1024, help="texture image size, px (default 1024)")
    p.add_argument("--max-image-px", type=IMAGE_PX, default=640,
                   help="work on images reduced to this many px on their longer side (default 640; larger "
                        "photos cost memory and time the field's grid cannot use)")
    p.add_argument("--table-z-m", type=TABLE_Z_M, default=0.0, metavar="M", help=TABLE_Z_HELP)
    add_field_arguments(p)
    p.add_argument("--from-mesh", type=existing_file, default=None, metavar="MESH",
                   help="import this mesh exported by nerfstudio instead of reconstructing")
    p.add_argument("--dataparser-transforms", type=existing_file, default=None, metavar="JSON",
                   help="nerfstudio's dataparser_transforms.json for --from-mesh")
    options.finish(p)
    options.declare_paths(p, reads=("dataset", "from_mesh", "dataparser_transforms"), writes=("out",))
    p.set_defaults(func=run_reconstruct)


def add_field_arguments(p) -> None:
    """The field backend's extraction and carving choices (``reconstruct`` and ``run``)."""
    # choices written out: importing the stage's tuples here would load torch for every command
    p.add_argument("--extraction", choices=["density", "tsdf"], default="density",
                   help="field backend: surface by marching cubes on the density (default) or TSDF fusion")
    p.add_argument("--mask-edges", choices=["auto", "colour", "as-given"], default="auto",
                   help="both backends: colour moves each mask's edge, by at most a few pixels (4 at 640x480), to "
                        "where the image's colours change from object to background, when a dozen views show the "
                        "masks miss them (thresholded masks keep a halo of blur and shadow, network masks miss "
                        "rims); as-given uses the masks as they are; auto (default) is colour, except for masks "
                        "`run --mask parallax` makes, which come from the images already")
    p.add_argument("--no-silhouette-poses", dest="silhouette_poses", action="store_false",
                   help="both backends: take the poses of frames refine-poses could not refine as they are; by "
                        "default they are moved onto the refined views' visual hull by their masks, and when "
                        "none was refined every view is aligned to the others (minutes: 1-2 s per view and "
                        "round, 3 rounds; see docs/reconstruct.md)")
    p.add_argument("--surface-level", choices=["silhouettes", "half-light"], default="silhouettes",
                   help="density extraction: cut the density where the masks' edges say (default) or at ln 2 "
                        "per voxel")
    p.add_argument("--no-photo-carving", dest="photo_carving", action="store_false",
                   help="field backend: train from the visual hull as it is, without opening the concavities "
                        "the views disagree about (see docs/reconstruct.md)")
    p.add_argument("--field-poses", dest="field_poses", action=argparse.BooleanOptionalAction, default=True,
                   help="field backend: correct each view's pose while the field trains on its coarse grid (a "
                        "small rotation and a shift of a few millimetres; the corrections are in report.json); on "
                        "by default: it brings a few bad views among good ones back, and sharpens refined poses "
                        "(the can: field PSNR +0.9 dB); --no-field-poses takes the poses as they are")
    p.add_argument("--no-field-colours", dest="field_colours", action="store_false",
                   help="field backend: no per-view colour correction (a gain and an offset per channel "
                        "that absorb each photo's exposure and white balance)")
    p.add_argument("--no-hollow-prior", dest="hollow_prior", action="store_false",
                   help="field backend: leave filled the space behind an opened concavity that the images "
                        "cannot place a surface in (a flat-coloured inside); by default it is taken as "
                        "empty within the walls the silhouettes show (see docs/reconstruct.md)")


def reconstruct_config(args: argparse.Namespace, field_voxels: int | None):
    """The ReconstructConfig the flags ask for (``field_voxels``: the field's fine grid, None for its default)."""
    from dataclasses import replace

    from real2sim.reconstruct.stage import ReconstructConfig
    from real2sim.reconstruct.field.train import FieldConfig

    field = FieldConfig().with_budget(args.steps, field_voxels).with_carving(args.photo_carving, args.hollow_prior)
    field = replace(field, pose_refinement=getattr(args, "field_poses", True),
                    colour_correction=getattr(args, "field_colours", True))
    return ReconstructConfig(backend=args.backend, extraction=args.extraction, surface_level=args.surface_level,
                             field=field, texture_px=args.texture_px, max_image_side_px=args.max_image_px,
                             table_z_m=args.table_z_m, mask_edges=getattr(args, "mask_edges", "auto"),
                             silhouette_poses=getattr(args, "silhouette_poses", True))


def run_reconstruct(args: argparse.Namespace) -> int:
    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import check_output_dir, output_lock

    if args.seed < 0 or args.seed >= 2**63:
        raise UserInputError(f"--seed must be in 0..2^63-1 (got {args.seed})")
    inputs = [p for p in (args.dataset, args.from_mesh, args.dataparser_transforms) if p is not None]
    out = check_output_dir(args.out, args.overwrite, inputs=inputs)
    with output_lock(out):  # held from the start: a second writer learns now, not after training
        return _reconstruct(args, out)


def _reconstruct(args: argparse.Namespace, out: Path) -> int:
    from real2sim.plumbing.errors import UserInputError
    from real2sim.reconstruct.stage import ReconstructConfig, import_external, reconstruct, write_reconstruction

    if (args.from_mesh is None) != (args.dataparser_transforms is None):
        raise UserInputError("--from-mesh and --dataparser-transforms go together")
    from real2sim.pipeline.manifest import recorded_warnings

    with recorded_warnings() as raised:
        if args.from_mesh is not None:
            result = import_external(args.dataset, args.from_mesh, args.dataparser_transforms,
                                     config=ReconstructConfig(table_z_m=args.table_z_m))
        else:
            config = reconstruct_config(args, args.voxels)
            config.validate()
            from real2sim.cli.progress import progress_display

            with progress_display() as progress:
                result = reconstruct(args.dataset, config, device=args.device, seed=args.seed, progress=progress)
    if raised:  # what degraded on the way, in report.json too: judge the mesh with it
        result.report["warnings"] = list(raised)
    out = write_reconstruction(result, out, overwrite=args.overwrite,
                               inputs=tuple(p for p in (args.dataset, args.from_mesh) if p is not None))
    print(summary_line(out, result.report))
    for text in raised:  # printed when it happened, and again here where the result is read
        print(f"WARNING: {text}")
    return 0


def summary_line(out: Path, report: dict) -> str:
    parts = [f"mesh: {out / 'mesh.obj'}", f"{report['mesh']['faces']} faces", f"{report['total_seconds']:.0f} s"]
    if "psnr_field_held_out_db" in report:
        parts.append(f"field PSNR {report['psnr_field_held_out_db']:.1f} dB")
    if "psnr_mesh_held_out_db" in report:
        parts.append(f"mesh PSNR {report['psnr_mesh_held_out_db']:.1f} dB")
    truth = report.get("truth")
    if truth:
        parts.append(f"vs truth: Chamfer {truth['chamfer_mm']:.2f} mm, IoU {truth['iou']:.3f}, "
                     f"F@1mm {truth['fscore_1mm']:.3f}")
    return "; ".join(parts)
