"""The field's training with a fixed step count against the convergence rule (issue 67, part 3), per capture.

Each capture is reconstructed twice with the stage's defaults (``reconstruct``, seed 0): once with the fixed
schedule (``FieldConfig.convergence`` off: 400 coarse and 800 fine steps, the rate decaying by the count) and
once with the rule on (:mod:`real2sim.reconstruct.field.convergence`: a stage ends once its smoothed loss
stops improving, the steps being caps). Per run: steps trained per grid and why each ended, the training
steps' seconds, Chamfer and IoU against the capture's ``ground_truth/``, the field's held-out PSNR, and how
far the mesh's volume centroid is from the true one's (uniform density; the asset's centre of mass before
its flat bottom).

    python benchmarks/bench_field_convergence.py                   # captures bottle, mug, can (100 views, 320x240, refined)
    python benchmarks/bench_field_convergence.py --datasets demo=/tmp/demo_base/capture,mug=/tmp/fieldconv/mug
    python benchmarks/bench_field_convergence.py --rule rel_tolerance=0.02 --tag tol2

Writes benchmarks/results/field_convergence.md and .json (or field_convergence_TAG), stamped with machine,
date and command. Steps and quality are seeded but vary a little run to run on a CPU (bench_field_budget.py says
why); seconds are wall time on whatever else
the machine runs: say so when you cite them.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# as the real2sim program does: torch's OpenMP spin-wait stalls small ops on 2 busy cores
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import dataclass_settings, markdown_table, write_result  # noqa: E402

OBJECTS = ("bottle", "mug", "can")


def capture_refined(name: str, out: Path, seed: int) -> Path:
    """The demo's kind of capture of a bundled object (100 views, 320x240, 5 mm / 1 deg pose noise), refined."""
    import warnings

    from real2sim.capture.poses.refinement import RefineConfig, refine_poses
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.objects import make_textured_object

    capture(make_textured_object(name), out, CaptureConfig(views=100, width=320, height=240, seed=seed))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        refine_poses(out, RefineConfig(seed=seed))
    return out


def centroid_error_mm(mesh, truth) -> float:
    """Distance (mm) between the volume centroids of ``mesh`` and ``truth`` (world frame); nan when ``mesh``
    is not closed."""
    import numpy as np

    if not mesh.is_watertight:
        return float("nan")
    return float(1000.0 * np.linalg.norm(np.asarray(mesh.center_mass) - np.asarray(truth.center_mass)))


def run_row(name: str, dataset: Path, schedule: str, config, seed: int) -> tuple[list, dict]:
    """One reconstruction: its table row and the figures the summary compares."""
    from real2sim.reconstruct.stage import reconstruct
    from real2sim.reconstruct.truth import load_truth

    result = reconstruct(dataset, config, seed=seed)
    report = result.report
    stages = report["field_stages"]
    steps = sum(s["steps"] for s in stages)
    phases = report["train_field_phase_seconds"]
    steps_s = sum(v for k, v in phases.items() if k.endswith("_steps"))
    truth = report["truth"]
    com_mm = centroid_error_mm(result.mesh, load_truth(dataset))
    ended = ", ".join(f"{s['voxels']}: {s['steps']} ({s['ended']})" for s in stages)
    row = [name, schedule, steps, ended, steps_s, report["stages"]["train_field"]["seconds"], truth["chamfer_mm"],
           truth["iou"], report.get("psnr_field_held_out_db", float("nan")), com_mm]
    return row, {"steps": steps, "steps_s": steps_s, "chamfer_mm": truth["chamfer_mm"], "iou": truth["iou"],
                 "com_mm": com_mm, "psnr_field_db": report.get("psnr_field_held_out_db", float("nan")),
                 "psnr_mesh_db": report.get("psnr_mesh_held_out_db", float("nan"))}


def main(argv: list[str] | None = None) -> int:
    from real2sim.reconstruct.config import ReconstructConfig
    from real2sim.reconstruct.field.convergence import ConvergenceConfig

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default=",".join(OBJECTS), help="bundled objects to capture (default: %(default)s)")
    parser.add_argument("--datasets", default="", help="NAME=DIR,...: captures already made and refined, used "
                        "instead of capturing (each with ground_truth/)")
    parser.add_argument("--rule", nargs="*", default=[], metavar="FIELD=VALUE",
                        help="ConvergenceConfig settings of the rule's runs (enabled is set)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tag", default="", help="write field_convergence_TAG instead of field_convergence")
    args = parser.parse_args(argv)
    try:
        rule = replace(ConvergenceConfig(), enabled=True,
                       **dataclass_settings(ConvergenceConfig, args.rule, "--rule"))
    except ValueError as error:
        parser.error(str(error))
    rule.validate()
    datasets = {}
    work = Path(tempfile.mkdtemp(prefix="bench_field_convergence-"))
    try:
        if args.datasets:
            for item in args.datasets.split(","):
                name, _, path = item.partition("=")
                if not (Path(path) / "ground_truth").is_dir():
                    parser.error(f"--datasets {item!r}: {path} has no ground_truth/ to judge against")
                datasets[name] = Path(path)
        else:
            for name in args.objects.split(","):
                datasets[name] = capture_refined(name, work / name, args.seed)
        base = ReconstructConfig()
        rows, figures = [], {}
        for name, dataset in datasets.items():
            for schedule, field in (("fixed", base.field), ("converged", replace(base.field, convergence=rule))):
                row, figures[name, schedule] = run_row(name, dataset, schedule, replace(base, field=field), args.seed)
                rows.append(row)
                print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row), flush=True)
            path = _write(args, argv, rule, datasets, rows, figures)  # after each capture: a stopped run keeps it
            print(f"wrote {path}", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def _write(args, argv, rule, datasets: dict, rows: list, figures: dict) -> Path:
    """Write the result with the rows so far and the rule-against-fixed summary of the captures done."""
    summary = []
    for name in datasets:
        if (name, "converged") in figures:
            old, new = figures[name, "fixed"], figures[name, "converged"]
            summary.append([name, 1 - new["steps"] / old["steps"], 1 - new["steps_s"] / old["steps_s"],
                            new["chamfer_mm"] / old["chamfer_mm"] - 1, new["iou"] - old["iou"]])
    summary.append(["mean", *[sum(r[i] for r in summary) / len(summary) for i in (1, 2, 3, 4)]])
    settings = ", ".join(f"{k} {v}" for k, v in vars(rule).items())
    body = ("Each capture reconstructed by `reconstruct` with its defaults (seed %d), the field trained with the fixed "
            "schedule and with the convergence rule (%s). Steps: trained per grid (voxels along its longest side: "
            "steps (why it ended)). Steps s: the training steps alone; train s: all of train_field (rays' pool, hull, "
            "photo carving, both grids); both wall seconds under contention with other work on the machine. "
            "Chamfer and IoU against the capture's true mesh; PSNR: the field on the held-out views; centroid: the "
            "mesh's volume centroid against the true mesh's, mm.\n\n" % (args.seed, settings)
            + markdown_table(["capture", "schedule", "steps", "per grid", "steps s", "train s", "Chamfer mm", "IoU",
                              "held-out PSNR dB", "centroid mm"], rows)
            + "\n\n### Rule against the fixed schedule\n\n"
            + markdown_table(["capture", "fewer steps", "fewer steps s", "Chamfer change", "IoU change"], summary)
            + "\n\nDatasets: " + ", ".join(f"`{n}`: {p if args.datasets else 'captured here'}"
                                           for n, p in datasets.items()))
    command = "python benchmarks/bench_field_convergence.py " + " ".join(argv if argv is not None else sys.argv[1:])
    return write_result("field_convergence" + (f"_{args.tag}" if args.tag else ""),
                        "The field's training: fixed steps against the convergence rule", body, command.strip())

if __name__ == "__main__":
    sys.exit(main())
