"""Run every benchmark in this folder (each writes its latest result to benchmarks/results/).

Usage: python benchmarks/run_all.py [--full]   (default: each benchmark's quick setting)
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    extra = ["--full"] if "--full" in sys.argv[1:] else []
    failed = []
    for script in sorted(HERE.glob("bench_*.py")):
        print(f"== {script.name}", flush=True)
        # --full goes only to the benchmarks that have a quick and a full setting; the others have one
        args = extra if '"--full"' in script.read_text() else []
        if subprocess.run([sys.executable, str(script), *args]).returncode != 0:
            failed.append(script.name)
    if failed:
        print("failed: " + ", ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
