"""`real2sim asset`: mesh -> simulation asset folder (URDF/SDFormat, inertia, collision geometry)."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.options import SEED_MAX, cache_dir, device, integer, number, positive, seed

DEFAULT_SPECS = ("cylinders:10",)


def add_contact_arguments(p: argparse.ArgumentParser) -> None:
    """Drake proximity properties written into every collision element (see real2sim.formats.contact)."""
    g = p.add_argument_group("contact properties (Drake proximity properties of the object)")
    g.add_argument("--hydroelastic", choices=["compliant", "rigid", "none"], default="compliant",
                   help="hydroelastic type of the collision shapes (default: compliant, as the paper)")
    g.add_argument("--hydroelastic-modulus-pa", type=number(1.0e3, 1.0e12), default=1.0e7, metavar="PA",
                   help="hydroelastic modulus, Pa (default 1e7)")
    g.add_argument("--point-stiffness-n-per-m", type=positive(1.0e9), default=1.0e4, metavar="N_PER_M",
                   help="point-contact stiffness, N/m (default 1e4), of every collision piece (see "
                        "--point-stiffness-per-piece)")
    g.add_argument("--point-stiffness-per-piece", action=argparse.BooleanOptionalAction, default=True,
                   help="make --point-stiffness-n-per-m the body's: each piece gets it divided by the mean number of "
                        "pieces that touch a plane laid on the hull, so a union of primitives rests as stiffly "
                        "as one piece (default on; --no-point-stiffness-per-piece gives every piece all of it: "
                        "docs/design-notes/asset.md#point-stiffness-per-piece)")
    g.add_argument("--dissipation-s-per-m", type=positive(100.0), default=1.0, metavar="S_PER_M",
                   help="Hunt-Crossley dissipation, s/m (default 1.0)")
    g.add_argument("--point-dissipation-s-per-m", type=number(0.0, 100.0), default=20.0, metavar="S_PER_M",
                   help="Hunt-Crossley dissipation of each representation's model_point.urdf, the model for "
                        "Drake's point contact, s/m (default 20; 0 writes none, and point contact then uses "
                        "model.urdf with --dissipation-s-per-m)")
    g.add_argument("--mu-static", type=positive(10.0), default=0.5, help="static friction coefficient (default 0.5)")
    g.add_argument("--mu-dynamic", type=positive(10.0), default=0.5,
                   help="dynamic friction coefficient, at most --mu-static (default 0.5)")
    g.add_argument("--resolution-hint-m", type=number(1.0e-4, 1.0), default=0.01, metavar="M",
                   help="edge length Drake meshes curved compliant primitives with, m (default 0.01)")
    g.add_argument("--cylinder-flat-depth-m", type=positive(0.01), default=None, metavar="M",
                   help="give each compliant cylinder its own, finer resolution hint so that the flats of "
                        "Drake's polygon around its circle lie at most M inside it (default: off). At the "
                        "default hint a 34 mm cylinder is a 22-gon with flats 0.35 mm deep, and a rolling "
                        "object rolls on them: on the bundled can 1e-5 cut cylinders:10's ramp OCAE by 39 %%, "
                        "at about 3x the simulation time; on the oval bottle it gained nothing (docs/truth.md)")


#: The keys of ``real2sim.geometry.mesh_io.MESH_UNITS_M``, spelled here because importing that
#: module pulls in trimesh, which `--help` must not pay for (tests/cli/test_asset.py checks they agree).
MESH_UNITS = ("m", "cm", "mm", "in")


def add_mesh_units_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mesh-units", choices=MESH_UNITS, default="m",
                   help="units of the mesh file's coordinates (default m; scans and CAD exports are often mm)")


def add_asset_arguments(p: argparse.ArgumentParser, *, seed_max: int = SEED_MAX) -> None:
    """Flags shared by `asset` and verbs that build assets (demo, run); ``seed_max``: the largest --seed."""
    from real2sim.formats.physical import MAX_MASS_KG  # one mass range for --mass-kg and properties files

    p.add_argument("--mass-kg", type=positive(MAX_MASS_KG), metavar="KG",
                   help="measured mass of the object, kg (required unless --properties gives it)")
    p.add_argument("--properties", type=Path, metavar="FILE",
                   help="mass, centre of mass and inertia measured rather than assumed: the props.json of "
                   "`real2sim identify` (object mesh frame) or a physical_properties.json (asset frame); "
                   "default: uniform density for --mass-kg")
    p.add_argument("--collision", action="append", metavar="SPEC",
                   help="collision representation, repeatable: spheres:128, boxes:100, rotated_boxes:50, "
                   "cylinders:10, ellipsoids:64, capsules:16, superquadrics:2 (written as convex mesh pieces), "
                   "mixes like boxes:20+cylinders:20, or the "
                   f"baselines coacd, vhacd, mesh (default: {' '.join(DEFAULT_SPECS)})")
    p.add_argument("--flat-bottom", action="store_true",
                   help="crop below the support plane and close the bottom flat (paper IV-C1)")
    p.add_argument("--support-height-m", type=number(-100.0, 100.0), default=0.0, metavar="M",
                   help="support (table) height in the input mesh frame, +z up, m (default 0); it must cut the mesh "
                   "or lie just below it")
    p.add_argument("--pca-up", action="store_true",
                   help="make the longest principal axis the asset's +z, as the paper does (default: the input's +z "
                   "stays up, so an object stands in the asset as it stood in the mesh or on the table)")
    p.add_argument("--format", action="append", choices=["urdf", "sdf", "mjcf", "usd"], dest="formats",
                   help="model formats to write (repeatable; model.urdf for Drake and model_portable.urdf for "
                   "PyBullet and other URDF readers always): sdf writes model.sdf, mjcf model.xml + scene.xml "
                   "for MuJoCo, usd model.usda for Isaac Sim (docs/formats.md)")
    p.add_argument("--seed", type=seed(seed_max), default=0, help="random seed of sampling and fitting (default 0)")
    p.add_argument("--device", type=device, default="cpu", help="torch device for primitive fitting: cpu, cuda, cuda:N (default cpu)")
    g = p.add_argument_group("primitive fitting (paper IV-C3)")
    g.add_argument("--iterations", type=integer(1, 100_000), default=None, metavar="N", help="maximum fitting iterations (default 1000)")
    g.add_argument("--fit-workers", type=integer(1, 1024), default=None, metavar="N",
                   help="processes fitting the SPECs side by side (default: one per thread this command may use, "
                   "see --threads, when --iterations is at least 500, else 1; at most one per SPEC)")
    g.add_argument("--fit-parameterization", choices=["direct", "network"], default=None,
                   help="optimise the primitive parameters directly (default, measured better) or through the "
                   "paper's over-parameterized network g_theta()")
    g.add_argument("--fit-paper-loss", action="store_true",
                   help="use eq. 9's linear hinge inside the object instead of the squared hinge (default)")
    g.add_argument("--contact-weight", type=number(0.0, 1000.0), default=None, metavar="GAIN",
                   help="weight 1 + GAIN for the signed-distance samples near the convex hull (the surfaces the "
                   "object stands, rolls and tips on); 0 is the paper's plain fit (default: 5 for cylinders and "
                   "ellipsoids alone, 0 for the other families: docs/design-notes/collision.md#contact-aware-fitting)")
    g.add_argument("--fill-cavities-m", type=number(1e-4, 10.0), default=None, metavar="M",
                   help="fit every collision SPEC (CoACD's included) to the solid with its cavities and holes "
                   "narrower than a ball of radius M metres filled: a cup's inside, a handle's hole. For "
                   "pushing, tilting and placing, where nothing enters them; not for grasping by a rim. Mass "
                   "properties and the visual stay those of the true object (default: off)")
    g.add_argument("--sdf-cache", type=cache_dir, default=None, metavar="DIR",
                   help="cache signed-distance samples across runs in DIR ('auto': $REAL2SIM_CACHE or "
                   "~/.cache/real2sim); default: within this build only")
    p.add_argument("--coacd-threshold", type=number(0.01, 1.0), default=0.05,
                   help="CoACD concavity threshold (default 0.05, the paper's setting)")
    p.add_argument("--coacd-max-hulls", type=integer(1, 1000, also=(-1,)), default=-1, help="CoACD maximum convex hulls (-1: no limit)")
    p.add_argument("--vhacd-max-hulls", type=integer(1, 1000), default=32, help="V-HACD maximum convex hulls (default 32)")
    add_contact_arguments(p)


def register(sub) -> None:
    p = sub.add_parser(
        "asset",
        help="turn an object mesh into a simulation asset folder (URDF, inertia, collision geometry)",
        description="Build a simulation asset from a mesh (OBJ, PLY, STL, GLB, OFF; metres): canonical pose, "
        "optional flat bottom, mass properties for the given mass (uniform density), and one folder per "
        "collision representation with model.urdf (Drake loads it as it is), collision.json and fit_report.json.",
        epilog="example: real2sim objects export bottle bottle.obj && "
        "real2sim asset bottle.obj --mass-kg 0.6 --out bottle_asset --collision coacd --collision cylinders:10",
    )
    p.add_argument("mesh", type=Path, help="object mesh (metres, or --mesh-units)")
    p.add_argument("--out", type=Path, required=True, metavar="ASSETDIR", help="output asset folder (must not exist)")
    p.add_argument("--overwrite", action="store_true", help="replace ASSETDIR if it exists")
    add_mesh_units_argument(p)
    add_asset_arguments(p)
    options.finish(p)
    options.declare_paths(p, reads=("mesh", "properties"), writes=("out",), cache=("sdf_cache",))
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace):
    """AssetConfig from parsed flags; raises UserInputError on a bad SPEC."""
    from real2sim.asset.build import AssetConfig
    from real2sim.formats.contact import ContactProperties
    from real2sim.formats.spec import parse_spec

    specs = tuple(parse_spec(s) for s in (args.collision or DEFAULT_SPECS))
    if args.mu_dynamic > args.mu_static:
        from real2sim.plumbing.errors import UserInputError

        raise UserInputError(f"--mu-dynamic {args.mu_dynamic:g} is greater than --mu-static {args.mu_static:g}; "
                             "Drake needs dynamic friction <= static friction")
    if args.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            from real2sim.plumbing.errors import UserInputError

            raise UserInputError(f"--device {args.device} asked for, but torch sees no CUDA GPU here; use --device cpu")
    contact = ContactProperties(
        hydroelastic=args.hydroelastic,
        hydroelastic_modulus_pa=args.hydroelastic_modulus_pa,
        point_contact_stiffness_n_per_m=args.point_stiffness_n_per_m,
        point_stiffness_per_piece=args.point_stiffness_per_piece,
        hunt_crossley_dissipation_s_per_m=args.dissipation_s_per_m,
        point_dissipation_s_per_m=args.point_dissipation_s_per_m or None,
        mu_static=args.mu_static,
        mu_dynamic=args.mu_dynamic,
        resolution_hint_m=args.resolution_hint_m,
        cylinder_flat_depth_m=args.cylinder_flat_depth_m,
    )
    fit_config = coacd_config = vhacd_config = None
    fit_overrides = {}
    if args.iterations is not None:
        if args.iterations < 1:
            from real2sim.plumbing.errors import UserInputError

            raise UserInputError(f"--iterations must be at least 1, got {args.iterations}")
        from real2sim.collision.fit.config import iteration_limits

        fit_overrides.update(iteration_limits(args.iterations))
    if args.fit_parameterization:
        fit_overrides["parameterization"] = args.fit_parameterization
    if args.fit_paper_loss:
        fit_overrides["inside_loss"] = "hinge"
    if args.contact_weight is not None:
        fit_overrides["contact_weight"] = args.contact_weight
    if any(s.is_primitive_fit for s in specs) and fit_overrides:
        from real2sim.collision.fit.config import FitConfig

        fit_config = FitConfig(**fit_overrides)
    if any(s.baseline == "coacd" for s in specs):
        from real2sim.collision.decomposition import CoacdConfig

        coacd_config = CoacdConfig(threshold=args.coacd_threshold, max_convex_hull=args.coacd_max_hulls)
    if any(s.baseline == "vhacd" for s in specs):
        from real2sim.collision.decomposition import VhacdConfig

        vhacd_config = VhacdConfig(max_convex_hulls=args.vhacd_max_hulls)
    formats = tuple(dict.fromkeys(["urdf", *(args.formats or [])]))
    from real2sim.plumbing.errors import UserInputError

    given, frame, source = None, "asset", ""
    if getattr(args, "properties", None) is not None:
        from real2sim.formats.physical import read_given_properties

        given, frame = read_given_properties(args.properties)
        source = str(args.properties)
    if args.mass_kg is None and given is None:
        raise UserInputError("--mass-kg KG is required (or --properties FILE with the measured mass properties)")
    return AssetConfig(
        mass_kg=args.mass_kg if args.mass_kg is not None else given.mass_kg,
        given_properties=given, given_properties_frame=frame, given_properties_source=source,
        specs=specs,
        flat_bottom=args.flat_bottom,
        support_height_m=args.support_height_m,
        pca_up=args.pca_up,
        mesh_units=getattr(args, "mesh_units", "m"),
        formats=formats,
        seed=args.seed,
        device=args.device,
        contact=contact,
        fit_config=fit_config,
        fit_workers=args.fit_workers,
        coacd_config=coacd_config,
        vhacd_config=vhacd_config,
        sdf_cache_dir=args.sdf_cache,
        fill_cavities_m=getattr(args, "fill_cavities_m", None),
    )


def run(args: argparse.Namespace) -> int:
    from real2sim.asset.build import build_asset
    from real2sim.cli.progress import progress_display
    from real2sim.plumbing.outputs import check_output_dir

    config = config_from_args(args)
    check_output_dir(args.out, args.overwrite, inputs=[args.mesh])  # fail before any heavy work
    with progress_display() as progress:
        result = build_asset(args.mesh, args.out, config, overwrite=args.overwrite, progress=progress)
    print(f"asset: {result.asset_dir}")
    for rep in result.representations:
        print(f"  {rep.name:28s} {rep.urdf_path}")
    return 0
