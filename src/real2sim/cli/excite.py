"""`real2sim excite`: a simulated arm holds the object, runs an exciting trajectory and logs its joints."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options
from real2sim.cli.options import nonnegative, number, positive, seed
from real2sim.formats.physical import MAX_MASS_KG

MASS_KG = positive(MAX_MASS_KG)
POSITION_M = number(-10.0, 10.0)


def register(sub) -> None:
    p = sub.add_parser(
        "excite",
        help="simulate an arm holding the object along an exciting trajectory; write a joint log for identify",
        description="Drake simulates our iiwa 14-like arm (or --robot URDF) holding the object rigidly at its flange, "
        "following a Fourier-series trajectory designed so the payload's inertial parameters are identifiable "
        "(cached per robot and grasp). The log is what a torque-sensing arm records at 1 kHz: quantised encoder "
        "positions, velocities from them, and motor torques with noise and joint friction. LOG/truth.json holds the "
        "payload's true mass properties. Real robots write the same layout (docs/identify.md).",
        epilog="example: real2sim excite can --mass-kg 0.4 --extra-mass-kg 0.15 --extra-mass-at-m 0.02 0 0.03 --out can_log",
    )
    p.add_argument("object", metavar="OBJECT|MESH", help="a bundled object (bottle, can, mug) or a closed mesh file")
    p.add_argument("--mass-kg", type=MASS_KG, required=True, metavar="KG", help="the object's body at uniform density, kg")
    p.add_argument("--extra-mass-kg", type=nonnegative(1000.0), default=0.0, metavar="KG",
                   help="a point mass inside the object, kg (the payload weighs --mass-kg + --extra-mass-kg)")
    p.add_argument("--extra-mass-at-m", type=POSITION_M, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="where the point mass is, metres, in the mesh's own frame")
    p.add_argument("--torque-noise-n-m", type=nonnegative(10.0), default=0.05, metavar="NM",
                   help="RMS joint torque noise, N m (default 0.05)")
    p.add_argument("--duration-s", type=number(8.0, 3600.0), default=None, metavar="S",
                   help="how long the arm moves, seconds (default 362, whole 6 s periods plus 2 s of rise and fall): "
                   "the rotational inertia's error falls with one over its square root")
    p.add_argument("--robot", type=Path, default=None, metavar="URDF",
                   help="arm model with a frame named 'flange' (default: our iiwa 14-like arm)")
    p.add_argument("--mesh-units", choices=("m", "cm", "mm", "in"), default="m", help="units of a mesh file (default m)")
    p.add_argument("--seed", type=seed(), default=0, help="trajectory design and noise seed (default 0)")
    p.add_argument("--out", type=Path, required=True, metavar="LOG", help="output log folder")
    p.add_argument("--overwrite", action="store_true", help="replace LOG if it is an earlier real2sim output")
    options.finish(p)
    options.declare_paths(p, reads=("object", "robot"), writes=("out",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import check_output_dir
    from real2sim.geometry.objects import OBJECTS, make_object
    from real2sim.cli.progress import progress_display
    from real2sim.identify.excitation import DEFAULT_DURATION_S, periods_for
    from real2sim.identify.stage import ExciteConfig, run_excite

    check_output_dir(args.out, args.overwrite)
    if args.object in OBJECTS:
        mesh = make_object(args.object)
    else:
        from real2sim.geometry.mesh_io import check_object_size, load_mesh

        mesh = load_mesh(args.object, args.mesh_units)
        check_object_size(mesh, args.object, args.mesh_units)
    if args.extra_mass_at_m is not None and args.extra_mass_kg == 0:
        raise UserInputError("--extra-mass-at-m needs --extra-mass-kg KG")
    config = ExciteConfig(mass_kg=args.mass_kg, extra_mass_kg=args.extra_mass_kg,
                          extra_mass_at_m=tuple(args.extra_mass_at_m) if args.extra_mass_at_m else None,
                          torque_noise_n_m=args.torque_noise_n_m, seed=args.seed, robot_urdf=args.robot,
                          periods=periods_for(args.duration_s if args.duration_s is not None else DEFAULT_DURATION_S))
    with progress_display() as progress:
        truth = run_excite(mesh, config, Path(args.out), overwrite=args.overwrite, progress=progress,
                           inputs=() if args.object in OBJECTS else (Path(args.object),))
    print(f"wrote {args.out} (payload {truth['mass_kg']:.4g} kg, CoM {', '.join(f'{v:.4f}' for v in truth['com_m'])} m "
          f"in the mesh frame); next: real2sim identify {args.out} --out props.json")
    return 0
