"""`real2sim identify`: the payload's mass, centre of mass and inertia from a joint log."""

from __future__ import annotations

import argparse
from pathlib import Path

from real2sim.cli import options


def register(sub) -> None:
    p = sub.add_parser(
        "identify",
        help="identify the held object's mass, centre of mass and inertia from an arm's joint torques",
        description="Reads LOG (written by `real2sim excite` or exported from a real robot: docs/identify.md), builds "
        "the payload regressor from Drake's inverse dynamics of LOG/robot.urdf, and solves a weighted least-squares "
        "problem with the payload physically consistent (4x4 pseudo-inertia positive semidefinite) and joint "
        "friction alongside, as a semidefinite program with an open solver. Writes props.json in the object's own "
        "mesh frame, inertia about the centre of mass, with standard errors; give it to `asset --properties` or "
        "`run --properties`.",
        epilog="example: real2sim identify can_log --out props.json --shape can_asset",
    )
    p.add_argument("log", type=Path, metavar="LOG", help="joint log folder")
    p.add_argument("--out", type=Path, required=True, metavar="FILE", help="output properties (JSON)")
    p.add_argument("--shape", type=Path, default=None, metavar="ASSETDIR",
                   help="an asset of the same mesh: its mass must lie inside the object's bounding ellipsoid, and "
                   "parameters the log cannot resolve fall back towards its uniform-density estimate")
    p.add_argument("--solver", choices=("clarabel", "scs"), default="clarabel", help="SDP solver (default clarabel)")
    p.add_argument("--overwrite", action="store_true", help="replace FILE if it exists")
    options.finish(p)
    options.declare_paths(p, reads=("log", "shape"), writes=("out",))
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from real2sim.plumbing.errors import UserInputError
    from real2sim.plumbing.outputs import check_output_path, check_replaceable, write_text_atomic
    from real2sim.identify.stage import errors_against_truth, read_truth, run_identify

    out = check_output_path(args.out, what="--out")
    if out.exists() and not args.overwrite:
        raise UserInputError(f"{out} exists; pass --overwrite to replace it")
    if out.is_dir():
        raise UserInputError(f"{out} is a folder; --out names a JSON file")
    check_replaceable(out, what="--out")
    if args.shape is not None and not Path(args.shape).is_dir():
        raise UserInputError(f"--shape {args.shape} is not an asset folder")
    # Everything identify reads is checked before the solve, so that a bad input never leaves --out written.
    truth = read_truth(args.log)
    result, props = run_identify(args.log, shape_dir=args.shape, solver=args.solver)
    write_text_atomic(out, json.dumps(props, indent=1))
    se = result.standard_errors
    print(f"mass {props['mass_kg']:.4f} +- {se[0]:.4f} kg, CoM {', '.join(f'{v:.4f}' for v in props['com_m'])} m "
          f"(mesh frame), residual {max(result.residual_rms_n_m):.3g} N m rms, condition {result.condition_number:.2f}")
    if truth is not None:
        err = errors_against_truth(props, truth)
        print(f"against LOG/truth.json: mass {100 * err['mass_rel']:.2f} %, CoM {1000 * err['com_m']:.2f} mm, "
              f"inertia {100 * err['inertia_rel']:.1f} % (largest principal-moment error)")
    print(f"wrote {out}; use it with: real2sim asset MESH --properties {out} ...")
    return 0
