"""Benchmark: parallax masks (``mask --method parallax``) against the rendered masks, and what they give.

For each object: capture VIEWS views at WIDTHxHEIGHT with 5 mm / 1 deg RMS robot-pose noise (as the
demo does), refine the poses with COLMAP, then make parallax masks from the refined images and poses
alone. Reported: mask IoU against ``ground_truth/masks`` (mean, 5th percentile, min), the masks' wall
seconds, and the reconstruction (visual hull backend, and with ``--field`` the radiance field) from the
parallax masks beside the same reconstruction from the rendered masks, against the true object.

    python benchmarks/bench_masks.py                          # bottle, can, mug; 100 views, 320x240
    python benchmarks/bench_masks.py --objects box,bowl       # shapes of bench_shapes.py too
    python benchmarks/bench_masks.py --field                  # also the radiance field (minutes per object)

Writes benchmarks/results/masks.md via benchmarks/common.py (after each object).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import markdown_table, write_result  # noqa: E402


def _object(name: str):
    from real2sim.geometry.objects import OBJECTS, make_textured_object

    if name in OBJECTS:
        return make_textured_object(name)
    from bench_shapes import make_shape  # box, bowl, bin, torus, rod

    return make_shape(name)


def _mask_ious(ds: Path) -> np.ndarray:
    from real2sim.capture.masks.methods import iou
    from real2sim.formats.dataset import load_mask, read_dataset

    data = read_dataset(ds)
    return np.array([iou(load_mask(ds / f.mask_path), load_mask(ds / "ground_truth" / "masks" / Path(f.mask_path).name))
                     for f in data.frames])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="bottle,can,mug")
    ap.add_argument("--views", type=int, default=100)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--field", action="store_true", help="also reconstruct with the radiance field")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tag", default="", help="write benchmarks/results/masks_TAG.md instead")
    args = ap.parse_args(argv)

    from real2sim.capture.poses.refinement import RefineConfig, refine_poses
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.capture.masks.stage import make_masks
    from real2sim.reconstruct.stage import ReconstructConfig, reconstruct

    backends = ["hull"] + (["field"] if args.field else [])
    mask_rows, recon_rows = [], []
    with tempfile.TemporaryDirectory(prefix="bench-masks-") as tmp:
        for name in args.objects.split(","):
            given = Path(tmp) / name
            capture(_object(name), given, CaptureConfig(views=args.views, width=args.width, height=args.height,
                                                        seed=args.seed))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ref = refine_poses(given, RefineConfig(seed=args.seed))
            parallax = Path(tmp) / f"{name}_parallax"
            shutil.copytree(given, parallax)
            t0 = time.perf_counter()
            result = make_masks(parallax, "parallax", seed=args.seed)
            mask_s = time.perf_counter() - t0
            ious = _mask_ious(parallax)
            mask_rows.append([name, f"{ref.num_refined_frames}/{ref.num_frames}", ref.rot_error_after_deg,
                              ref.trans_error_after_mm, float(ious.mean()), float(np.percentile(ious, 5)),
                              float(ious.min()), 100.0 * result.mean_object_fraction, mask_s])
            print(mask_rows[-1], flush=True)
            for backend in backends:
                for label, ds in (("rendered", given), ("parallax", parallax)):
                    t0 = time.perf_counter()
                    recon = reconstruct(ds, ReconstructConfig(backend=backend), seed=args.seed)
                    t = recon.report.get("truth", {})
                    concave = t.get("concave_recovered")
                    recon_rows.append([name, backend, label, t.get("chamfer_mm"), t.get("iou"), t.get("fscore_1mm"),
                                       "-" if concave is None else f"{concave:.3f}", time.perf_counter() - t0])
                    print(recon_rows[-1], flush=True)
            _write(args, argv, mask_rows, recon_rows)
    return 0


def _write(args, argv, mask_rows: list, recon_rows: list) -> None:
    body = (
        f"{args.views} views at {args.width}x{args.height} per object, 5 mm / 1 deg RMS robot-pose noise refined by "
        "refine-poses (COLMAP); then `mask --method parallax` on the refined dataset, which reads only its images "
        "and poses. IoU is against the rendered masks in `ground_truth/masks` (mean, 5th percentile and worst view). "
        f"Load average when written: {os.getloadavg()[0]:.1f}.\n\n"
        + markdown_table(["object", "poses refined", "rot error deg", "pos error mm", "mask IoU mean", "IoU p5",
                          "IoU min", "object % of pixels", "masks wall s"], mask_rows)
        + "\n\nReconstruction from each set of masks, against the true object (`concave`: share of the true "
        "object's concave space left open, as in reconstruct.md):\n\n"
        + markdown_table(["object", "backend", "masks", "Chamfer mm", "IoU", "F@1mm", "concave", "wall s"], recon_rows)
    )
    command = "python benchmarks/bench_masks.py " + " ".join(argv if argv is not None else sys.argv[1:])
    tag = f"_{args.tag}" if args.tag else ""
    print(write_result(f"masks{tag}", "Parallax masks (benchmarks/bench_masks.py" + (f", {args.tag})" if tag else ")"),
                        body, command.strip()))


if __name__ == "__main__":
    raise SystemExit(main())
