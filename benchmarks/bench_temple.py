"""Benchmark: the real Middlebury temple photographs (``../shared/data/real/temple_ring``), reconstructed.

19 calibrated 640x480 photographs from one level ring over 135 degrees, fx 1520 px, thresholded masks,
no table (the temple's lowest point is z = 0). Reported per backend: each side of the mesh's bounding
box against the authors' tight box (``truth_bbox.json``), held-out PSNR (the field's and the textured
mesh's), faces and wall seconds. Issue #28's target: every side within 2 mm.

    python benchmarks/bench_temple.py                   # hull and field, default settings
    python benchmarks/bench_temple.py --backends hull   # the fast one alone

Writes benchmarks/results/temple.md via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import ROOT, markdown_table, write_result  # noqa: E402

TEMPLE = ROOT.parent / "shared" / "data" / "real" / "temple_ring"
SIDES = ("x min", "y min", "z min", "x max", "y max", "z max")


def box_errors_mm(bounds_m: np.ndarray, truth: dict) -> np.ndarray:
    """Signed errors (mm) of each side of ``bounds_m`` (2, 3) against the true box, in SIDES' order;
    positive: the reconstruction reaches further out than the truth."""
    lo, hi = np.asarray(bounds_m)
    return 1000.0 * np.concatenate([np.asarray(truth["bbox_min_m"]) - lo, hi - np.asarray(truth["bbox_max_m"])])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", default="hull,field")
    ap.add_argument("--dataset", type=Path, default=TEMPLE)
    args = ap.parse_args(argv)
    from real2sim.reconstruct.stage import ReconstructConfig, reconstruct, write_reconstruction

    truth = json.loads((args.dataset / "truth_bbox.json").read_text())
    rows = []
    for backend in args.backends.split(","):
        start = time.perf_counter()
        result = reconstruct(args.dataset, ReconstructConfig(backend=backend))
        seconds = time.perf_counter() - start
        with tempfile.TemporaryDirectory() as tmp:  # the mesh is written as `reconstruct` would
            write_reconstruction(result, Path(tmp) / "mesh")
        errors = box_errors_mm(result.mesh.bounds, truth)
        report = result.report
        rows.append([backend, *[round(float(e), 2) for e in errors], round(float(np.abs(errors).max()), 2),
                     report.get("psnr_field_held_out_db", float("nan")), report.get("psnr_mesh_held_out_db", float("nan")),
                     report["mesh"]["faces"], round(seconds, 1)])
        print(markdown_table(["backend", *[f"{s} (mm)" for s in SIDES], "worst (mm)", "field PSNR (dB)",
                              "mesh PSNR (dB)", "faces", "seconds"], rows[-1:]), flush=True)
    body = ("Bounding-box side errors against the authors' tight box (positive: the mesh reaches further out), "
            "held-out PSNR (views 5 and 15 of 19), 2-core wall seconds.\n\n"
            + markdown_table(["backend", *[f"{s} (mm)" for s in SIDES], "worst (mm)", "field PSNR (dB)",
                              "mesh PSNR (dB)", "faces", "seconds"], rows))
    write_result("temple", "Real photographs: the Middlebury temple ring", body,
                  "python benchmarks/bench_temple.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
