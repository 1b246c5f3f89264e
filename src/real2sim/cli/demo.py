"""`real2sim demo`: the whole job on the bundled bottle, end to end, in minutes on a laptop CPU.

bundled bottle -> asset with several collision representations + CoACD ->
Drake evaluation against the bottle's own mesh (short protocol) -> Pareto plots
and report.html.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class DemoPlan:
    """What the demo builds and how hard it evaluates."""

    specs: tuple[str, ...]
    tasks: tuple[str, ...]
    contact_models: tuple[str, ...]
    runs: int


# Full: minutes on 2 cores (measured by benchmarks/bench_demo.py, docs/benchmarks.md); quick:
# about 1 (CI runs it).
FULL = DemoPlan(
    specs=("cylinders:10", "boxes:50", "spheres:64", "ellipsoids:32", "rotated_boxes:20", "superquadrics:5", "coacd"),
    tasks=("push", "ramp"),
    contact_models=("point", "hydroelastic"),
    runs=3,
)
QUICK = DemoPlan(specs=("cylinders:4", "spheres:16", "coacd"), tasks=("push", "ramp"), contact_models=("point", "hydroelastic"), runs=1)


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="build and evaluate assets of the bundled bottle (the whole job, minutes on a CPU)",
        description="Exports the bundled mustard-like bottle, builds an asset with several collision "
        "representations plus CoACD, evaluates each in Drake (planar pushing, actuated ramp; point and "
        "hydroelastic contact) against the bottle's full mesh, and writes Pareto plots and report.html. "
        "About 5 minutes on 2 CPU cores; --quick about 1.",
    )
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default demo_out)")
    p.add_argument("--quick", action="store_true", help="fewer, smaller representations and one run per task")
    p.add_argument("--overwrite", action="store_true", help="replace the output folder if it exists")
    p.add_argument("--jobs", type=int, default=None, help="parallel simulations (default: CPU cores)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    from rich.console import Console

    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.evaluate.sweep import EvaluationConfig, evaluate
    from real2sim.geometry.objects import OBJECTS, export_object
    from real2sim.formats.outputs import atomic_output_dir
    from real2sim.formats.spec import parse_spec

    plan = QUICK if args.quick else FULL
    console = Console(stderr=True)
    start = time.perf_counter()
    out: Path = args.out
    with atomic_output_dir(out, overwrite=args.overwrite) as tmp:
        mesh_path = export_object("bottle", tmp / "bottle" / "model.obj")
        console.log(f"exported the bundled bottle to {out / 'bottle' / 'model.obj'}")
        config = AssetConfig(mass_kg=OBJECTS["bottle"].mass_kg, specs=tuple(parse_spec(s) for s in plan.specs))
        with console.status("building the asset") as status:
            def log(msg: str) -> None:
                status.update(msg)
                console.log(msg)

            build_asset(mesh_path, tmp / "bottle_asset", config, log=log)
        eval_config = EvaluationConfig(
            tasks=plan.tasks, contact_models=plan.contact_models, runs=plan.runs,
            **({"jobs": args.jobs} if args.jobs else {}),
        )
        result = evaluate([tmp / "bottle_asset"], tmp / "results", eval_config, progress=True)
    minutes = (time.perf_counter() - start) / 60
    print(f"\ndemo finished in {minutes:.1f} min")
    print(f"  URDFs:   {out / 'bottle_asset'}/<representation>/model.urdf")
    for urdf in sorted((out / "bottle_asset").glob("*/model.urdf")):
        print(f"           {urdf}")
    print(f"  table:   {out / 'results' / 'summary.csv'}")
    print(f"  plots:   {out / 'results'}/pareto_*.png")
    print(f"  report:  {out / 'results' / 'report.html'}")
    del result
    return 0
