"""Benchmark: simulated capture (render time), COLMAP pose refinement (time, errors), background masks.

1. Capture of the bundled bottle: VIEWS views at WIDTHxHEIGHT (default 200 at 640x480),
   Drake VTK colour + depth + label, PNG writing included; target < 60 s on 2 cores.
2. refine-poses on that capture (default: all its views), 5 mm / 1 deg RMS pose noise:
   wall and CPU time (target < 5 min) and mean rotation / position error vs the exact
   poses before and after (target: after <= half of before).
3. (--masks) background-difference masks of the three bundled objects vs the rendered
   masks (IoU), MASK_VIEWS views each.

Wall times on a shared machine are inflated by other processes; CPU seconds of this
process (all threads) are reported beside them.

    python benchmarks/bench_capture.py                   # 200 views, 640x480, refine all
    python benchmarks/bench_capture.py --views 120 --masks
    python benchmarks/bench_capture.py --quick           # 40 views at 320x240

Writes benchmarks/results/capture.md via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--object", default="bottle")
    ap.add_argument("--no-refine", action="store_true")
    ap.add_argument("--masks", action="store_true", help="also measure background-difference masks (IoU)")
    ap.add_argument("--mask-views", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="40 views at 320x240")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.quick:
        args.views, args.width, args.height = 40, 320, 240

    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.capture.masks.methods import compute_masks
    from real2sim.geometry.objects import make_textured_object
    from real2sim.capture.poses.refinement import RefineConfig, refine_poses

    load_before = os.getloadavg()
    rows_capture, rows_refine, rows_mask = [], [], []
    with tempfile.TemporaryDirectory(prefix="bench-capture-") as tmp:
        root = Path(tmp) / "ds"
        mesh = make_textured_object(args.object)
        cfg = CaptureConfig(views=args.views, width=args.width, height=args.height, seed=args.seed)
        c0, t0 = _cpu_s(), time.perf_counter()
        res = capture(mesh, root, cfg)
        wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
        rows_capture.append([args.object, args.views, f"{args.width}x{args.height}", round(res.render_seconds, 1),
                             round(wall, 1), round(cpu, 1), round(1000 * res.render_seconds / args.views, 1)])
        print(markdown_table(["object", "views", "size", "render+write wall s", "total wall s", "total CPU s",
                              "ms / view"], rows_capture), flush=True)

        if not args.no_refine:
            c0, t0 = _cpu_s(), time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("always")
                r = refine_poses(root, RefineConfig(seed=args.seed))
            wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
            tm = r.timings_s
            rows_refine.append([args.views, f"{args.width}x{args.height}", "yes" if r.refined else f"no ({r.reason})",
                                f"{r.num_refined_frames}/{r.num_frames}", r.num_pairs, r.num_points3d,
                                round(r.mean_reproj_error_px or float("nan"), 3),
                                round(r.rot_error_before_deg, 3), round(r.rot_error_after_deg, 3),
                                round(r.trans_error_before_mm, 2), round(r.trans_error_after_mm, 2),
                                round(wall, 1), round(cpu, 1),
                                " / ".join(f"{tm.get(k, float('nan')):.0f}" for k in
                                           ("features_s", "matching_s", "triangulation_ba_s"))])
            print(markdown_table(["views", "size", "refined", "frames", "pairs", "points", "reproj px",
                                  "rot before deg", "rot after deg", "pos before mm", "pos after mm",
                                  "wall s", "CPU s", "features / matching / tri+BA wall s"], rows_refine), flush=True)

        if args.masks:
            for name in ("bottle", "can", "mug"):
                d = Path(tmp) / f"mask_{name}"
                capture(make_textured_object(name), d, CaptureConfig(views=args.mask_views, width=args.width,
                                                                     height=args.height, with_background=True,
                                                                     seed=args.seed))
                t0 = time.perf_counter()
                m = compute_masks(d, "background")
                rows_mask.append([name, args.mask_views, f"{args.width}x{args.height}", round(m.mean_iou, 4),
                                  round(m.min_iou, 4), round(time.perf_counter() - t0, 1)])
            print(markdown_table(["object", "views", "size", "mean IoU", "min IoU", "wall s"], rows_mask), flush=True)

    load_after = os.getloadavg()
    body = [
        f"Machine load average before / after: {load_before[0]:.1f} / {load_after[0]:.1f} "
        "(shared machine: wall times are inflated by other processes; CPU s counts this process's threads).",
        "",
        "### Simulated capture (Drake VTK: colour + depth + label, PNGs written)",
        "",
        "Target: 200 views at 640x480 in < 60 s on 2 cores.",
        "",
        markdown_table(["object", "views", "size", "render+write wall s", "total wall s", "total CPU s", "ms / view"],
                       rows_capture),
    ]
    if rows_refine:
        body += [
            "",
            "### refine-poses (COLMAP via pycolmap, CPU; 5 mm / 1 deg RMS noise on the robot poses)",
            "",
            "Errors are means over frames against the exact poses (ground_truth/). "
            "Targets: < 5 min; errors after <= half of before.",
            "",
            markdown_table(["views", "size", "refined", "frames", "pairs", "points", "reproj px", "rot before deg",
                            "rot after deg", "pos before mm", "pos after mm", "wall s", "CPU s",
                            "features / matching / tri+BA wall s"], rows_refine),
        ]
    if rows_mask:
        body += [
            "",
            "### Background-difference masks vs rendered masks",
            "",
            markdown_table(["object", "views", "size", "mean IoU", "min IoU", "wall s"], rows_mask),
        ]
    cmd = "python benchmarks/bench_capture.py " + " ".join(argv if argv is not None else sys.argv[1:])
    path = write_result("capture", "Capture, pose refinement and masks (benchmarks/bench_capture.py)",
                         "\n".join(body), cmd.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
