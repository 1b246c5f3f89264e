"""Benchmark the primitive fitter on the bundled bottle and can (paper Table I SPECs).

For each object: canonicalize, sample the SDF once (cached), then fit every SPEC and
measure fidelity against the canonical mesh: volumetric IoU, symmetric Chamfer (mm),
pieces kept, fit seconds. ``--ablations`` adds the switches beyond the paper on one
object/SPEC (k-means vs random init, network vs direct, dead removal, interior fill,
inside loss). Prints tables and writes ``benchmarks/results/fitting.md`` (or ``fitting_TAG.md``) and its .json via benchmarks/common.py.

    python benchmarks/bench_fitting.py                 # quick: targets of the issue
    python benchmarks/bench_fitting.py --full          # the Table I SPECs (hours on 2 cores)
    python benchmarks/bench_fitting.py --ablations --iterations 500
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

QUICK_SPECS = ("boxes:100", "spheres:128", "cylinders:10")
FULL_SPECS = (
    "spheres:64", "spheres:128", "spheres:256",
    "boxes:1", "boxes:3", "boxes:5", "boxes:10", "boxes:20", "boxes:50", "boxes:100", "boxes:150",
    "boxes:200", "boxes:300", "boxes:400", "boxes:500",
    "rotated_boxes:5", "rotated_boxes:10", "rotated_boxes:20", "rotated_boxes:50", "rotated_boxes:100", "rotated_boxes:150",
    "cylinders:1", "cylinders:3", "cylinders:10", "cylinders:50", "cylinders:100",
    "ellipsoids:64", "ellipsoids:128",
    "boxes:20+cylinders:20", "boxes:50+cylinders:50", "boxes:100+cylinders:50",
)  # fmt: skip
TARGETS = {"boxes:100": 0.95, "spheres:128": 0.90, "cylinders:10": 0.90}


def _prepare(name: str, sampling_seed: int):
    import numpy as np

    from real2sim.asset.canonical import canonicalize
    from real2sim.geometry.objects import make_object
    from real2sim.collision.sdf_sampling import SdfSamplingConfig, sample_sdf

    mesh, _ = canonicalize(make_object(name))
    t0 = time.perf_counter()
    samples = sample_sdf(mesh, SdfSamplingConfig(seed=sampling_seed))
    return mesh, samples, time.perf_counter() - t0, np


def _run_one(mesh, samples, spec_text: str, config, seed: int) -> dict:
    from real2sim.geometry.fidelity import measure_fidelity
    from real2sim.collision.fit.convert import to_collision_geometry
    from real2sim.collision.fit.loop import fit_primitives
    from real2sim.formats.spec import parse_spec

    spec = parse_spec(spec_text)
    res = fit_primitives(samples.points, samples.sdf, spec.parts, config, seed=seed)
    with tempfile.TemporaryDirectory() as rep_dir:  # superquadrics' mesh pieces live here
        geo = to_collision_geometry(res, samples.centre_m, samples.scale_m, spec, rep_dir)
        fid = measure_fidelity(mesh, geo, rep_dir, seed=seed)
    return {
        "spec": spec.text,
        "iou": fid["iou"],
        "iou_ci95": fid["iou_ci95"],
        "chamfer_mm": fid["chamfer_mm"],
        "pieces": fid["num_pieces"],
        "requested": res.requested_count,
        "fit_s": res.fit_seconds,
        "iterations": res.iterations,
        "loss": res.final_loss,
    }


def _table(rows: list[dict], extra: tuple[str, ...] = ()) -> list[str]:
    cols = extra + ("spec", "iou", "chamfer_mm", "pieces", "fit_s", "iterations", "loss")
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        cells = []
        for c in cols:
            v = r[c]
            if c == "iou":
                cells.append(f"{v:.3f} ± {r['iou_ci95']:.3f}")
            elif c == "pieces":
                cells.append(f"{v}/{r['requested']}")
            elif isinstance(v, float):
                cells.append(f"{v:.3g}" if c == "loss" else f"{v:.2f}")
            else:
                cells.append(str(v))
        out.append("| " + " | ".join(cells) + " |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="all Table I SPECs instead of the quick subset")
    ap.add_argument("--specs", default=None, help="comma-separated SPECs (overrides --full/quick)")
    ap.add_argument("--objects", default="bottle,can")
    ap.add_argument("--iterations", type=int, default=None, help="max iterations (default: FitConfig's)")
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ablations", action="store_true", help="also run the beyond-the-paper ablations")
    ap.add_argument("--ablation-spec", default="boxes:100")
    ap.add_argument("--ablation-only", default=None, metavar="PREFIX",
                    help="run only the default and the ablations whose label starts with PREFIX")
    ap.add_argument("--no-main", action="store_true", help="only the ablations")
    ap.add_argument("--tag", default="", help="write benchmarks/results/fitting_TAG.md instead (a named configuration)")
    args = ap.parse_args(argv)

    import torch

    from real2sim.collision.fit.config import FitConfig

    torch.set_num_threads(args.threads)
    base = FitConfig(device=args.device)
    if args.iterations is not None:
        base = dataclasses.replace(base, max_iterations=args.iterations, min_iterations=min(base.min_iterations, args.iterations))
    specs = tuple(args.specs.split(",")) if args.specs else (FULL_SPECS if args.full else QUICK_SPECS)
    objects = tuple(args.objects.split(","))

    lines = [
        f"Load average {' '.join(f'{x:.1f}' for x in os.getloadavg())} at start; {args.threads} torch threads, "
        f"device {args.device}.",
        "",
        f"FitConfig: `{base}`",
        "",
        "IoU: volumetric, Monte Carlo with 95 % half-width (`real2sim.geometry.fidelity.measure_fidelity`); Chamfer:"
        " symmetric, mm; pieces: kept / requested (dead primitives dropped); fit_s: wall seconds of the"
        " fit alone (the SDF sampling is cached and timed separately); loss: eq. 9 over all samples.",
        "",
    ]
    prepared = {}
    for name in objects:
        mesh, samples, sample_s, _ = _prepare(name, args.seed)
        prepared[name] = (mesh, samples)
        lines.append(f"- {name}: {len(samples.points)} SDF samples ({'cache' if samples.from_cache else f'{sample_s:.1f} s'})")
    lines.append("")

    if not args.no_main:
        rows = []
        for name in objects:
            mesh, samples = prepared[name]
            for spec in specs:
                r = {"object": name, **_run_one(mesh, samples, spec, base, args.seed)}
                target = TARGETS.get(spec)
                r["target"] = f"≥ {target}" if target else ""
                rows.append(r)
                print(f"{name:7s} {spec:24s} iou={r['iou']:.3f} chamfer={r['chamfer_mm']:.2f}mm pieces={r['pieces']}/{r['requested']} "
                      f"fit={r['fit_s']:.1f}s it={r['iterations']} loss={r['loss']:.3g}", flush=True)
        lines += ["## Fits", ""] + _table(rows, ("object",)) + [""]

    if args.ablations:
        variants = {
            "default": {},
            "init=random": {"init": "random"},
            "parameterization=direct": {"parameterization": "direct"},
            "parameterization=network": {"parameterization": "network"},
            "remove_dead=False": {"remove_dead": False},
            "revive_dead=False": {"revive_dead": False},
            "fill_interior=False": {"fill_interior": False},
            "inside_loss=hinge (paper)": {"inside_loss": "hinge"},
            "inside_loss=squared": {"inside_loss": "squared"},
        }
        if "superquadrics" in args.ablation_spec:
            variants.update({
                "superquadric_truncation=off": {"superquadric_truncation": 1e9},
                "superquadric_exponent_gain=1": {"superquadric_exponent_gain": 1.0},
                "superquadric_init_exponent=1 (ellipsoid)": {"superquadric_init_exponent": 1.0},
            })
        rows = []
        name = objects[0]
        mesh, samples = prepared[name]
        for label, change in variants.items():
            if args.ablation_only and label != "default" and not label.startswith(args.ablation_only):
                continue
            cfg = dataclasses.replace(base, **change)
            if label != "default" and cfg == base:
                continue  # same as the default
            r = {"variant": label, **_run_one(mesh, samples, args.ablation_spec, cfg, args.seed)}
            rows.append(r)
            print(f"ablation {label:28s} iou={r['iou']:.3f} chamfer={r['chamfer_mm']:.2f}mm pieces={r['pieces']}/{r['requested']} fit={r['fit_s']:.1f}s loss={r['loss']:.3g}", flush=True)
        lines += [f"## Ablations ({name}, {args.ablation_spec})", ""] + _table(rows, ("variant",)) + [""]

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import write_result

    command = "python benchmarks/bench_fitting.py " + " ".join(argv if argv is not None else sys.argv[1:])
    write_result("fitting" + (f"_{args.tag}" if args.tag else ""), "Primitive fitting benchmark", "\n".join(lines),
                 command.strip())
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
