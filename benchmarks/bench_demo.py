"""Wall and CPU time of `real2sim demo` (the README's `make demo`) and `--quick` (what CI runs).

    python benchmarks/bench_demo.py [--quick-only]

Writes benchmarks/results/demo.md: the times, each demo's truth numbers (its asset against the
true bottle, from truth.json) and the last demo's summary table. CPU minutes: user + system
time of the demo process and its children (the simulation workers).
"""

from __future__ import annotations

import argparse
import csv
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402


def run_demo(out: Path, quick: bool) -> tuple[float, float]:
    """(wall seconds, CPU seconds) of one demo."""
    cmd = [sys.executable, "-m", "real2sim", "demo", "--out", str(out), "--overwrite"] + (["--quick"] if quick else [])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def truth_row(out: Path) -> list:
    truth = json.loads((out / "bottle_asset" / "truth.json").read_text())
    rec, phys, poses = truth["reconstruction"], truth["physical_properties"], truth["camera_poses"]
    before, after = poses["before_refinement"], poses["after_refinement"]
    return [rec["chamfer_mm"], rec["iou"], phys["com_error_mm"], 100 * phys["inertia_eigenvalue_max_rel_error"],
            f"{before['trans_mean_mm']:.2f} mm / {before['rot_mean_deg']:.2f} deg",
            f"{after['trans_mean_mm']:.2f} mm / {after['rot_mean_deg']:.2f} deg" if after else "(not refined)",
            best_primitive_against_truth(out)]


def best_primitive_against_truth(out: Path) -> str:
    """The lowest OCAE of a fitted-primitive row of the sweep against the true bottle (results_truth/), m."""
    with open(out / "bottle_asset" / "results_truth" / "summary.csv") as f:
        rows = [r for r in csv.DictReader(f)
                if not r["representation"].startswith(("coacd", "vhacd", "mesh", "bound"))]
    best = min(rows, key=lambda r: float(r["ocae_m"]))
    return f"{float(best['ocae_m']):.4g} ({best['representation']})"


def write_demo_result(rows: list, truths: list, table: str, note: str) -> None:
    body = ((note + "\n\n" if note else "") + markdown_table(["command", "wall minutes", "CPU minutes"], rows)
            + "\n\nAgainst the true bottle (truth.json; pose error = mean camera error before -> after refinement):\n\n"
            + markdown_table(["command", "Chamfer mm", "IoU", "CoM error mm", "inertia eigenvalue error %",
                              "pose error before", "pose error after", "best primitive OCAE m vs truth"], truths)
            + "\n\nThe last demo's summary (bundled bottle from a simulated capture; the reference is the "
            "asset's own closed reconstructed mesh, the paper's protocol):\n\n" + table)
    print(write_result("demo", "Demo: wall and CPU time, errors against the true bottle", body, "python benchmarks/bench_demo.py " + " ".join(sys.argv[1:])))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick-only", action="store_true")
    parser.add_argument("--full", action="store_true", help="accepted for run_all.py; same as the default")
    parser.add_argument("--note", default="", help="a line about the conditions (e.g. a machine shared with other work)")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_demo-"))
    rows, truths, table = [], [], ""
    for quick in (True,) if args.quick_only else (True, False):
        out = work / ("quick" if quick else "full")
        wall, cpu = run_demo(out, quick)
        command = "real2sim demo --quick" if quick else "real2sim demo"
        rows.append([command, wall / 60, cpu / 60])
        truths.append([command] + truth_row(out))
        with open(out / "bottle_asset" / "results" / "summary.csv") as f:
            summary = [[r["representation"], float(r["ocae_m"]), float(r["ate_m"]), float(r["cpd_m_per_s"]),
                        float(r["sim_time_s"])] for r in csv.DictReader(f)]
        table = markdown_table(["representation", "OCAE m", "ATE m", "CPD m/s", "ST s"], summary)
        write_demo_result(rows, truths, table, args.note)  # after each demo: a cut-off full run still leaves the quick numbers
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
