"""Wall time of `real2sim demo` (the README's `make demo`) and `--quick` (what CI runs).

    python benchmarks/bench_demo.py [--quick-only]

Writes docs/benchmarks/demo.md with the demo's own summary table.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_section  # noqa: E402


def run_demo(out: Path, quick: bool) -> float:
    cmd = [sys.executable, "-m", "real2sim", "demo", "--out", str(out), "--overwrite"] + (["--quick"] if quick else [])
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick-only", action="store_true")
    parser.add_argument("--full", action="store_true", help="accepted for run_all.py; same as the default")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_demo-"))
    rows, table = [], ""
    for quick in (True,) if args.quick_only else (True, False):
        out = work / ("quick" if quick else "full")
        seconds = run_demo(out, quick)
        rows.append(["real2sim demo --quick" if quick else "real2sim demo", seconds / 60])
        with open(out / "results" / "summary.csv") as f:
            summary = [[r["representation"], float(r["ocae_m"]), float(r["ate_m"]), float(r["cpd_m_per_s"]),
                        float(r["sim_time_s"])] for r in csv.DictReader(f)]
        table = markdown_table(["representation", "OCAE m", "ATE m", "CPD m/s", "ST s"], summary)
    body = (markdown_table(["command", "wall minutes"], rows)
            + "\n\nThe last demo's summary (bundled bottle, its own closed mesh as the reference):\n\n" + table)
    print(write_section("demo", "Demo wall time", body, "python benchmarks/bench_demo.py " + " ".join(sys.argv[1:])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
