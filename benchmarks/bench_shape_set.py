"""CoACD's hull count and wall time on each shape of the shape set, beside a couple of primitive SPECs.

Each shape (``real2sim objects``: the ones marked shape set) is exported as bundled (textured OBJ,
its round parts within their stated chord error) and built with ``build_asset`` once per SPEC, alone,
so each wall time is that SPEC's whole build (canonicalisation, mass properties, fit or
decomposition, writing). Issue #66: on the bottle and can CoACD keeps 1-2 hulls; these shapes are
where decomposition needs many.

    python benchmarks/bench_shape_set.py                              # every shape, coacd spheres:64 boxes:50
    python benchmarks/bench_shape_set.py --objects gear,hammer --tag two   # a quick check

Writes benchmarks/results/shape_set.md and .json (or shape_set_TAG), stamped with machine, date and command.
Timings are wall seconds on whatever else the machine runs: say so when you cite them.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

SPECS = ("coacd", "spheres:64", "boxes:50")


def build_row(name: str, spec_text: str, work: Path, seed: int) -> list:
    """[shape, spec, faces, pieces, fit s, wall s, IoU] of one build of ``name`` with ``spec_text``."""
    import trimesh

    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import OBJECTS, export_object

    mesh = work / "objects" / name / "model.obj"
    if not mesh.exists():
        export_object(name, mesh)
    faces = len(trimesh.load(mesh, force="mesh").faces)
    spec = parse_spec(spec_text)
    out = work / "build" / name / spec.name
    start = time.perf_counter()
    # pca_up=False: the shapes rest on z = 0 as built, as the bottle and can are captured.
    result = build_asset(mesh, out, AssetConfig(mass_kg=OBJECTS[name].mass_kg, specs=(spec,), seed=seed),
                         overwrite=True)
    wall_s = time.perf_counter() - start
    report = result.representations[0].fit_report
    return [name, spec_text, faces, int(report["num_primitives"]), float(report.get("fit_seconds", float("nan"))),
            wall_s, float(report.get("iou", float("nan")))]


def main(argv: list[str] | None = None) -> int:
    from real2sim.geometry.objects import OBJECTS

    shapes = [n for n, o in OBJECTS.items() if o.shape_set]
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default=",".join(shapes), help=f"shapes, comma-separated (default: {','.join(shapes)})")
    parser.add_argument("--specs", nargs="+", default=list(SPECS), help=f"SPECs (default: {' '.join(SPECS)})")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=None, help="keep the builds here (default: a temporary folder)")
    parser.add_argument("--tag", default="", help="write shape_set_TAG instead of shape_set")
    args = parser.parse_args(argv)
    names = [n for n in args.objects.split(",") if n]
    unknown = [n for n in names if n not in OBJECTS]
    if unknown:
        parser.error(f"unknown objects {unknown}; known: {', '.join(OBJECTS)}")
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_shape_set-"))
    rows = []
    try:
        for name in names:
            for spec_text in args.specs:
                rows.append(build_row(name, spec_text, work, args.seed))
                print(" | ".join(str(v) if not isinstance(v, float) else f"{v:.4g}" for v in rows[-1]), flush=True)
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    describe = {n: f"{OBJECTS[n].description} (chord error <= {OBJECTS[n].chord_m * 1e6:g} um)" for n in names}
    body = ("Each SPEC built alone with `build_asset` (seed %d); pieces: CoACD's hulls, or the primitives fitted. "
            "Wall s: the whole build; fit s: the fit or decomposition alone. IoU against the shape.\n\n" % args.seed
            + markdown_table(["shape", "spec", "faces", "pieces", "fit s", "wall s", "IoU"], rows)
            + "\n\nShapes:\n\n" + "\n".join(f"- `{n}`: {d}" for n, d in describe.items()))
    command = "python benchmarks/bench_shape_set.py " + " ".join(argv if argv is not None else sys.argv[1:])
    path = write_result("shape_set" + (f"_{args.tag}" if args.tag else ""), "CoACD's hull count and time on the shape set",
                        body, command.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
