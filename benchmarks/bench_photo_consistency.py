"""Can colour tell a true surface from a false one? What stops photo-consistent carving.

For each object: a capture (100 views at 320x240, exact poses, as the carving tests'
captures but full size), its visual hull and photo-consistent carving's first pass, the
colour test, on an 80-voxel grid (the field's defaults; the second pass, the hollow prior,
is off: it decides by a prior where colour cannot). Then every surface voxel that the first
pass left is tested once more, and grouped by its distance from the true surface:

* on it (within one voxel): the colours the views see there are those of one point;
* far from it (more than four voxels): a surface the object does not have (on the mug,
  what is left of the lid across its cavity). Each view sees a different point behind it.

Reported per group: how many voxels, and the quantiles of the colour *spread* (the
75th percentile of the views' RGB distances from their median, RGB in [0, 1]) that
carving compares with its threshold, and of the hue spread. Where the far group's
spreads are as low as the true group's, no threshold on colour can carve it without
carving the true surface as well.

    python benchmarks/bench_photo_consistency.py             # mug and can
    python benchmarks/bench_photo_consistency.py --objects mug

Writes benchmarks/results/photo_consistency.md (machine and date included).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

GROUPS = (("on the true surface (< 1 voxel)", 0.0, 1.0), ("1-4 voxels off", 1.0, 4.0),
          ("false surface (> 4 voxels off)", 4.0, np.inf))


def measure(name: str, work: Path, views_count: int, width: int, height: int, seed: int) -> tuple[list[list], dict]:
    """Rows (group, voxels, spread quantiles, hue quantiles) and carving facts for one object."""
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.geometry.fidelity import surface_distance_m
    from real2sim.geometry.objects import make_textured_object
    from real2sim.multiview.hull import carve, object_region
    from real2sim.multiview.voxel_grid import VoxelGrid, surface_from_grid, voxel_footprint_px
    from real2sim.reconstruct.carving.photo import CarvingConfig, _blurred, _spread, _surface, photo_carve
    from real2sim.reconstruct.truth import load_truth
    from real2sim.multiview.views import load_views

    dataset = work / name
    capture(make_textured_object(name), dataset, CaptureConfig(views=views_count, width=width, height=height,
                                                              pose_noise_mm=0, pose_noise_deg=0, seed=seed))
    views = load_views(dataset)
    config = CarvingConfig(hollow_prior=False)
    grid = VoxelGrid.covering(*object_region(views), config.voxels, 0.0)
    hull = carve(views, grid) >= 0.5
    start = time.perf_counter()
    solid = photo_carve(views, grid, hull, config).solid
    seconds = time.perf_counter() - start
    idx = np.argwhere(_surface(solid))
    images = _blurred(views.rgb, config.blur_voxels * voxel_footprint_px(views, grid))
    mesh = surface_from_grid(solid.astype(np.float32), grid, 0.5, float(grid.bounds_m[0, 2]))
    verdict = _spread(views, images, grid, idx, mesh, hull & ~solid, config)
    spread, hue, seen = verdict.spread, verdict.hue_spread, verdict.seen
    off_voxels = surface_distance_m(grid.origin_m + idx * grid.voxel_m, load_truth(dataset)) / grid.voxel_m
    judged = seen >= config.min_views
    rows = []
    for label, lo, hi in GROUPS:
        part = judged & (off_voxels >= lo) & (off_voxels < hi)
        if not part.any():
            rows.append([name, label, 0, "-", "-", "-", "-"])
            continue
        q = lambda values, p: float(np.quantile(values[part], p))  # noqa: E731
        rows.append([name, label, int(part.sum()), q(spread, 0.1), q(spread, 0.5), q(spread, 0.9),
                     f"{q(hue, 0.5):.3f} / {q(hue, 0.9):.3f}"])
    facts = {"object": name, "voxel_mm": 1000 * grid.voxel_m, "carved": int((hull & ~solid).sum()),
             "seconds": seconds, "max_spread": config.max_spread}
    return rows, facts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="mug,can")
    parser.add_argument("--views", type=int, default=100)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rows, facts = [], []
    with tempfile.TemporaryDirectory(prefix="bench-photo-") as tmp:
        for name in args.objects.split(","):
            object_rows, object_facts = measure(name, Path(tmp), args.views, args.width, args.height, args.seed)
            rows += object_rows
            facts.append(object_facts)
            print(object_rows, object_facts, flush=True)
    body = (
        f"{args.views} views at {args.width}x{args.height}, exact poses; visual hull and photo-consistent carving's "
        "first pass (the colour test) with the field's defaults (80 voxels along the longest side; the hollow prior "
        "off). Every surface voxel it left, seen by at "
        "least 4 views, grouped by its distance from the true surface. `spread`: the 75th percentile of the views' "
        f"RGB distances from their median colour (RGB in [0, 1]), which carving compares with "
        f"{facts[0]['max_spread']}; `hue`: the same for colour over brightness (median / 90th percentile).\n\n"
        + markdown_table(["object", "surface voxels", "count", "spread q10", "spread median", "spread q90",
                          "hue median / q90"], rows)
        + "\n\n"
        + markdown_table(["object", "voxel mm", "voxels carved", "carving s"],
                         [[f["object"], f["voxel_mm"], f["carved"], f["seconds"]] for f in facts])
        + "\n\nWhere the false surface's spreads are as low as the true surface's, the views agree about a surface "
        "the object does not have, and no threshold on colour can carve it without carving true surface too.\n"
    )
    command = "python benchmarks/bench_photo_consistency.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(write_result("photo_consistency", "What colour can tell (benchmarks/bench_photo_consistency.py)", body,
                        command.strip()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
