"""The primitive fits' stop on convergence: iterations, fit seconds, IoU and Chamfer, old schedule against new.

Each object is built with ``build_asset`` twice, once per schedule, with the demo's six primitive SPECs:
"old" is the cosine schedule over ``max_iterations`` (the default: on the demo's bottle every fit ran
its 1000 iterations), "new" the plateau schedule (issue 67: ``lr_schedule="plateau"``, which stops once
its smallest step size makes no more progress) with FitConfig's other defaults. Both share one signed-distance cache per object, so
they fit the same samples. Objects: the bundled bottle, can and mug, a few shapes of the shape set,
and the demo's reconstructed bottle (the solid its fits were fitted to, ``visual/collision_reference.obj``
of its asset folder, already in the asset frame).

    python benchmarks/bench_fit_convergence.py                          # the whole table
    python benchmarks/bench_fit_convergence.py --objects can --specs spheres:64 --tag quick
    python benchmarks/bench_fit_convergence.py --new decay_patience=80 --work /tmp/fc   # another setting

Writes benchmarks/results/fit_convergence.md and .json (or fit_convergence_TAG), stamped with machine,
date and command. IoU and Chamfer are deterministic for the seed and thread count, so they hold on a
busy machine; fit seconds are wall seconds on whatever else the machine runs (say so when you cite
them): the iteration counts are the speed measure.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import dataclass_settings, markdown_table, write_result  # noqa: E402

SPECS = ("cylinders:10", "boxes:50", "spheres:64", "ellipsoids:32", "rotated_boxes:20", "superquadrics:5")
OBJECTS = ("bottle", "can", "mug", "gear", "l_bracket", "torus", "demo_bottle")
DEMO_ASSET = Path("/tmp/demo_base/bottle_asset")
#: The demo's mass (its asset_config.json); the mass changes no fit.
DEMO_MASS_KG = 0.6


def variant_configs(new_settings: dict) -> dict:
    """{"old": the cosine schedule (the default), "new": the plateau schedule with ``new_settings``}."""
    from real2sim.collision.fit.config import FitConfig

    return {"old": FitConfig(lr_schedule="cosine"),
            "new": dataclasses.replace(FitConfig(), lr_schedule="plateau", **new_settings)}


def object_mesh(name: str, work: Path) -> tuple[Path, float]:
    """The mesh of ``name`` (exported once into ``work``) and its mass."""
    if name == "demo_bottle":
        mesh = DEMO_ASSET / "visual" / "collision_reference.obj"
        if not mesh.exists():
            raise SystemExit(f"error: {mesh} not found (the demo's asset folder; leave demo_bottle out of --objects)")
        return mesh, DEMO_MASS_KG
    from real2sim.geometry.objects import OBJECTS as BUNDLED, export_object

    mesh = work / "objects" / name / "model.obj"
    if not mesh.exists():
        export_object(name, mesh)
    return mesh, BUNDLED[name].mass_kg


def build_reports(name: str, specs: list[str], fit_config, work: Path, seed: int) -> dict[str, dict]:
    """fit_report.json of each SPEC of one build of ``name`` with ``fit_config`` (read back when a kept
    ``work`` folder already holds that build)."""
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec

    key = hashlib.sha1(json.dumps([dataclasses.asdict(fit_config), specs, seed], sort_keys=True).encode()).hexdigest()[:10]
    out = work / "build" / name / key
    parsed = [parse_spec(s) for s in specs]
    reports = [out / spec.name / "fit_report.json" for spec in parsed]
    if not all(p.exists() for p in reports):
        mesh, mass_kg = object_mesh(name, work)
        # pca_up=False: every mesh rests on z = 0 as given; one SDF cache per object, shared by both schedules.
        config = AssetConfig(mass_kg=mass_kg, specs=tuple(parsed), seed=seed, fit_config=fit_config,
                             sdf_cache_dir=work / "sdf_cache" / name)
        build_asset(mesh, out, config, overwrite=True)
    return {text: json.loads(p.read_text()) for text, p in zip(specs, reports)}


def summary(rows: list[list]) -> list[list]:
    """[measure, mean, worst] over ``rows`` (the per-fit table)."""
    iters = [(r[2] - r[3]) / r[2] for r in rows]
    d_iou = [r[7] - r[6] for r in rows]
    d_ch = [(r[9] - r[8]) / r[8] for r in rows]
    worst = min(range(len(rows)), key=lambda i: d_iou[i])
    worst_ch = max(range(len(rows)), key=lambda i: d_ch[i])
    least = min(range(len(rows)), key=lambda i: iters[i])
    mean = lambda v: sum(v) / len(v)  # noqa: E731
    return [["iterations saved", f"{100 * mean(iters):.1f} %", f"{100 * iters[least]:.1f} % ({rows[least][0]} {rows[least][1]})"],
            ["IoU change", f"{mean(d_iou):+.4f}", f"{d_iou[worst]:+.4f} ({rows[worst][0]} {rows[worst][1]})"],
            ["Chamfer change", f"{100 * mean(d_ch):+.1f} %", f"{100 * d_ch[worst_ch]:+.1f} % ({rows[worst_ch][0]} {rows[worst_ch][1]})"],
            ["old iterations, mean", f"{mean([r[2] for r in rows]):.0f}", ""],
            ["new iterations, mean", f"{mean([r[3] for r in rows]):.0f}", ""]]


def main(argv: list[str] | None = None) -> int:
    from real2sim.collision.fit.config import FitConfig

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default=",".join(OBJECTS), help=f"comma-separated (default: {','.join(OBJECTS)})")
    parser.add_argument("--specs", nargs="+", default=list(SPECS), help=f"SPECs (default: {' '.join(SPECS)})")
    parser.add_argument("--new", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="FitConfig settings of the new schedule beyond its defaults (exploring)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=None,
                        help="keep the builds here and read back the ones already there (default: a temporary folder)")
    parser.add_argument("--tag", default="", help="write fit_convergence_TAG instead of fit_convergence")
    args = parser.parse_args(argv)
    try:
        new_settings = dataclass_settings(FitConfig, args.new, "--new")
    except ValueError as exc:
        parser.error(str(exc))
    names = [n for n in args.objects.split(",") if n]
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_fit_convergence-"))
    configs = variant_configs(new_settings)
    rows = []
    try:
        for name in names:
            old = build_reports(name, args.specs, configs["old"], work, args.seed)
            new = build_reports(name, args.specs, configs["new"], work, args.seed)
            for spec in args.specs:
                o, n = old[spec], new[spec]
                rows.append([name, spec, int(o["iterations"]), int(n["iterations"]), float(o["fit_seconds"]),
                             float(n["fit_seconds"]), float(o["iou"]), float(n["iou"]), float(o["chamfer_mm"]),
                             float(n["chamfer_mm"]), n.get("stop_reason", "")])
                print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in rows[-1]), flush=True)
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    new_fields = {f: getattr(configs["new"], f) for f in ("lr_schedule", "lr_decay", "decay_patience",
                                                           "plateau_tolerance", "final_lr_fraction", "min_iterations",
                                                           "max_iterations")}
    body = ("Each object built with `build_asset` (seed %d) once per schedule, every SPEC in one build, both on the "
            "same signed-distance samples. Old: `lr_schedule=\"cosine\"` over `max_iterations`; new: %s. "
            "IoU and Chamfer against the object's solid (fit_report.json); fit s: wall seconds of the fit, "
            "on a shared machine (the iteration counts are the speed measure).\n\n" % (
                args.seed, ", ".join(f"`{k}={v!r}`" for k, v in new_fields.items()))
            + markdown_table(["object", "spec", "iters old", "iters new", "fit s old", "fit s new", "IoU old",
                              "IoU new", "Chamfer mm old", "Chamfer mm new", "stop"], rows)
            + "\n\nOver the table (Chamfer change: the mean of each fit's relative change):\n\n"
            + markdown_table(["measure", "mean", "worst"], summary(rows)))
    command = "python benchmarks/bench_fit_convergence.py " + " ".join(argv if argv is not None else sys.argv[1:])
    path = write_result("fit_convergence" + (f"_{args.tag}" if args.tag else ""),
                        "The primitive fits' stop on convergence: old schedule against new", body, command.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
