"""Benchmark: voxel-particle spheres (GPU Gems 3 style) -- fidelity against particle count.

The baseline of the paper's appendix (Fig. 10): one sphere per voxel whose centre
is inside the mesh. For each bundled object and target count, reports the voxel
size, the particle count, the build time, the IoU of the union of spheres with
the mesh's solid (uniform samples in the padded bounding box, inside by winding
number) and the mean surface error (|SDF of the union| at area-uniform points on
the mesh surface), for touching particles (radius = voxel / 2, GPU Gems) and
voxel-covering ones (radius = voxel * sqrt(3) / 2). When ``real2sim.geometry.fidelity``
is present its ``measure_fidelity`` numbers (IoU, Chamfer) are added for up to
300 particles (it builds the union mesh of all spheres, which is slow beyond).

    python benchmarks/bench_particles.py            # 64 .. 10,000 particles
    python benchmarks/bench_particles.py --quick    # 64 .. 1,024

Writes benchmarks/results/particles.md via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from real2sim.geometry.inside import inside_mask
from real2sim.geometry.objects import make_object
from real2sim.collision.particles import COVERING, TOUCHING, particle_spheres, voxel_size_for_count


FIDELITY_MAX_PIECES = 300  # measure_fidelity meshes the union of all spheres: ~20 s at 257, ~80 s at 1024


def _measure(mesh, geometry, seed: int = 0) -> tuple[float, float]:
    lo, hi = mesh.bounds
    pad = 0.1 * (hi - lo).max()
    rng = np.random.default_rng(seed)
    pts = (lo - pad) + (hi - lo + 2 * pad) * rng.random((200_000, 3))
    in_mesh = inside_mask(mesh, pts)
    centres = np.array([s.position_m for s in geometry.shapes])
    radius = geometry.shapes[0].size_m[0]
    tree = cKDTree(centres)
    in_union = tree.query(pts)[0] <= radius
    iou = float((in_mesh & in_union).sum() / (in_mesh | in_union).sum())
    surface = mesh.sample(50_000, seed=seed)
    surface_error_mm = float(np.abs(tree.query(surface)[0] - radius).mean() * 1000)
    return iou, surface_error_mm


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="targets 64, 256, 1024 only")
    parser.add_argument("--full", action="store_true", help="(same as the default; accepted for run_all.py)")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args(argv)
    targets = [64, 256, 1024] if args.quick else [64, 256, 1024, 4096, 10_000]
    try:
        from real2sim.geometry.fidelity import measure_fidelity  # written by another stage; optional here
    except ImportError:
        measure_fidelity = None

    header = ["object", "target", "voxel mm", "particles", "build s", "IoU touching", "surface err mm touching",
              "IoU covering", "surface err mm covering"]
    if measure_fidelity is not None:
        header += ["fidelity IoU (touching)", "fidelity Chamfer mm (touching)"]
    rows = []
    for name in ("bottle", "can"):
        mesh = make_object(name)
        for target in targets:
            t0 = time.perf_counter()
            voxel, _ = voxel_size_for_count(mesh, target)
            touching = particle_spheres(mesh, voxel, radius_fraction=TOUCHING, spec=f"particles:{target}")
            build_s = time.perf_counter() - t0
            covering = particle_spheres(mesh, voxel, radius_fraction=COVERING, spec=f"particles:{target}")
            iou_t, err_t = _measure(mesh, touching)
            iou_c, err_c = _measure(mesh, covering)
            row = [name, target, round(voxel * 1000, 2), len(touching.shapes), round(build_s, 2),
                   round(iou_t, 3), round(err_t, 2), round(iou_c, 3), round(err_c, 2)]
            if measure_fidelity is not None and len(touching.shapes) <= FIDELITY_MAX_PIECES:
                with tempfile.TemporaryDirectory() as rep_dir:
                    try:
                        fidelity = measure_fidelity(mesh, touching, Path(rep_dir))
                        row += [round(fidelity["iou"], 3), round(fidelity["chamfer_mm"], 2)]
                    except Exception as exc:  # another stage's module: report, do not fail the benchmark
                        row += [f"error: {type(exc).__name__}", ""]
            elif measure_fidelity is not None:
                row += ["-", "-"]  # the union mesh of this many spheres takes too long to build
            rows.append(row)
            print(" | ".join(str(v) for v in row), flush=True)

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import markdown_table, write_result

    body = (
        "One sphere per voxel whose centre is inside the mesh (GPU Gems 3; the paper's Fig. 10 baseline). "
        "Touching: radius = voxel / 2 (fills at most pi/6 = 0.52 of the solid, so IoU saturates near 0.5); "
        "covering: radius = voxel * sqrt(3) / 2. IoU from 200k uniform samples in the padded bounding box; "
        "surface error = mean |SDF of the union| at 50k points on the mesh surface. Build time includes "
        "choosing the voxel size for the target count (a few voxelisations). The paper reports that 256 fitted "
        "spheres match the fidelity of about 10,000 particles; compare with `benchmarks/results/fitting.md`.\n\n"
        + markdown_table(header, rows)
    )
    if not args.no_write:
        path = write_result("particles", "Voxel-particle baseline", body,
                             "python benchmarks/bench_particles.py" + (" --quick" if args.quick else ""))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
