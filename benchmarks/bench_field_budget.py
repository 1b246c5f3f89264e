"""The field's training budget against its accuracy (issue 67, part 3): rays per step and steps per grid.

Each capture is reconstructed with the stage's defaults (``reconstruct``, seed 0) and with each variant of
``FieldConfig`` given on the command line, one after another in this process; per run: steps trained per
grid and why each ended, the training steps' wall seconds, Chamfer and IoU against the capture's
``ground_truth/``, the held-out PSNR of the field and of the textured mesh, and the mesh's volume centroid
against the true one's (the columns of ``bench_field_convergence.py``, whose captures and rows this reuses).

    python benchmarks/bench_field_budget.py --variant rays2048=rays_per_step=2048
    python benchmarks/bench_field_budget.py --variant rays2048=rays_per_step=2048 \\
        --variant coarse200=coarse_steps=200 --objects bottle,mug,can

Writes benchmarks/results/field_budget.md and .json (or field_budget_TAG), stamped with machine, date and
command. Seeded, but not bit for bit on a CPU: the grid's scatter-adds sum in thread order, so the loss the
convergence rule reads, and with it the step a grid stops at, varies a little from run to run (the can's fine
grid: 320 and 440 steps in two runs); seconds are wall time: run it alone.
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
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the real2sim program does

from bench_field_convergence import OBJECTS, capture_refined, run_row  # noqa: E402
from common import dataclass_settings, markdown_table, write_result  # noqa: E402


def parse_variant(text: str) -> tuple[str, list[str]]:
    """``NAME=FIELD=VALUE[,FIELD=VALUE...]`` as (NAME, ["FIELD=VALUE", ...])."""
    name, _, settings = text.partition("=")
    if not name or not settings:
        raise ValueError(f"--variant {text!r}: expected NAME=FIELD=VALUE[,FIELD=VALUE...]")
    return name, settings.split(",")


def main(argv: list[str] | None = None) -> int:
    from real2sim.reconstruct.config import ReconstructConfig
    from real2sim.reconstruct.field.train import FieldConfig

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default=",".join(OBJECTS), help="bundled objects to capture (default: %(default)s)")
    parser.add_argument("--variant", action="append", default=[], metavar="NAME=FIELD=VALUE[,FIELD=VALUE]",
                        help="a FieldConfig variant to run beside the defaults (repeatable)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tag", default="", help="write field_budget_TAG instead of field_budget")
    args = parser.parse_args(argv)
    base = ReconstructConfig()
    variants = {"default": base.field}
    try:
        for text in args.variant:
            name, items = parse_variant(text)
            variants[name] = replace(base.field, **dataclass_settings(FieldConfig, items, "--variant"))
            variants[name].validate()
    except ValueError as error:
        parser.error(str(error))
    work = Path(tempfile.mkdtemp(prefix="bench_field_budget-"))
    rows, figures = [], {}
    try:
        for name in args.objects.split(","):
            dataset = capture_refined(name, work / name, args.seed)
            for variant, field in variants.items():
                row, figures[name, variant] = run_row(name, dataset, variant, replace(base, field=field), args.seed)
                row.insert(-1, figures[name, variant]["psnr_mesh_db"])  # before the centroid column
                rows.append(row)
                print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row), flush=True)
            path = _write(args, argv, variants, rows, figures)  # after each capture: a stopped run keeps it
            print(f"wrote {path}", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def _write(args, argv, variants: dict, rows: list, figures: dict) -> Path:
    """The rows so far and each variant against the defaults, per capture done and on average."""
    summary = []
    for variant in list(variants)[1:]:
        per = [(figures[o, "default"], figures[o, variant]) for o, v in figures if v == variant]
        if per:
            mean = lambda change: sum(change(o, n) for o, n in per) / len(per)
            summary.append([variant, len(per), mean(lambda o, n: 1 - n["steps_s"] / o["steps_s"]),
                            mean(lambda o, n: n["chamfer_mm"] / o["chamfer_mm"] - 1),
                            max(n["chamfer_mm"] / o["chamfer_mm"] - 1 for o, n in per),
                            mean(lambda o, n: n["iou"] - o["iou"]),
                            mean(lambda o, n: n["psnr_field_db"] - o["psnr_field_db"]),
                            mean(lambda o, n: n["psnr_mesh_db"] - o["psnr_mesh_db"])])
    changed = {name: {k: v for k, v in vars(field).items() if v != vars(variants["default"])[k]}
               for name, field in list(variants.items())[1:]}
    body = ("Each capture (the demo's kind: 100 views at 320x240, 5 mm / 1 deg robot poses, refined) reconstructed "
            "by `reconstruct` with its defaults (seed %d) and with each variant of FieldConfig: %s. Steps: trained "
            "per grid (voxels along its longest side: steps (why it ended)). Steps s: the training steps alone; "
            "train s: all of train_field; wall seconds, the benchmark alone on the machine. Chamfer and IoU against "
            "the capture's true mesh; PSNR on the held-out views, of the field and of the textured mesh; centroid: the mesh's volume centroid "
            "against the true mesh's, mm.\n\n" % (args.seed, "; ".join(f"`{n}`: {c}" for n, c in changed.items()))
            + markdown_table(["capture", "variant", "steps", "per grid", "steps s", "train s", "Chamfer mm", "IoU",
                              "field PSNR dB", "mesh PSNR dB", "centroid mm"], rows)
            + "\n\n### Each variant against the defaults (mean over the captures)\n\n"
            + markdown_table(["variant", "captures", "fewer steps s", "Chamfer change", "worst Chamfer change",
                              "IoU change", "field PSNR change dB", "mesh PSNR change dB"], summary))
    command = "python benchmarks/bench_field_budget.py " + " ".join(argv if argv is not None else sys.argv[1:])
    return write_result("field_budget" + (f"_{args.tag}" if args.tag else ""),
                        "The field's training budget: rays and steps against accuracy", body, command.strip())


if __name__ == "__main__":
    sys.exit(main())
