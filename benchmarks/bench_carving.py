"""Photo-consistent carving's visibility test: Embree on the solid's surface, or rays walked through
the voxels with torch (``CarvingConfig.visibility``: "mesh" / "voxels"; "auto" takes the mesh on a
CPU and the voxels on a GPU).

For each object: the field's starting density as ``reconstruct`` makes it (the visual hull on the
field's coarse grid, photo carving with both passes: ``train.hull_density``), once per visibility
test, on all views of a capture (100 views at 320x240, exact poses, when captured here). Reported:
wall seconds of the whole step, the voxels carved, and how many voxels the two tests' carvings
disagree on.

    python benchmarks/bench_carving.py                                  # mug, captured here, on the CPU
    python benchmarks/bench_carving.py --datasets DIR --device cuda     # DIR/mug ... captured earlier
    python benchmarks/bench_carving.py --datasets DIR --device cuda --reconstruct   # the whole reconstruction
    python benchmarks/bench_carving.py --datasets DIR --objects mug,bowl --ratios 1.5,1.25,1.0:3,1.25:2:0   # the hollow prior

Writes benchmarks/results/carving_visibility[_TAG].md, with --ratios carving_ratio[_TAG].md (machine and date included).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

HEADER = ["object", "device", "visibility", "hull and carving s", "carved voxels", "rounds",
          "voxels the two disagree on"]


def carve_both(dataset: Path, device: str, methods: tuple[str, ...]) -> list[list]:
    """The rows of one dataset: ``train.hull_density`` with each visibility test."""
    import torch

    from real2sim.multiview.hull import object_region
    from real2sim.multiview.voxel_grid import VoxelGrid
    from real2sim.reconstruct.field.train import FieldConfig, hull_density
    from real2sim.multiview.views import load_views

    views = load_views(dataset)
    config = FieldConfig()
    lo, hi = object_region(views, outlier_fraction=config.hull_outlier_fraction, table_z_m=0.0)
    grid = VoxelGrid.covering(lo, hi, config.coarse_voxels, 0.0)
    rows, carved = [], {}
    for method in methods:
        run_config = replace(config, carving=replace(config.carving, visibility=method))
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        start = time.perf_counter()
        _, carved[method], result = hull_density(views, grid, run_config, device=device)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        seconds = time.perf_counter() - start
        rows.append([dataset.name, device, method, round(seconds, 2), int(carved[method].sum()),
                     result.rounds if result is not None else "-", ""])
    if len(methods) == 2:
        rows[-1][-1] = int((carved[methods[0]] ^ carved[methods[1]]).sum())
    return rows


RECONSTRUCT_HEADER = ["object", "device", "visibility", "wall s", "hull and carving s", "carved voxels",
                      "Chamfer mm", "IoU", "concave"]


def timed_reconstructions(dataset: Path, device: str, configs) -> Iterator[tuple[float, dict]]:
    """(wall seconds, report) of ``reconstruct`` with each of ``configs`` on ``dataset``, seed 0, in one
    process, yielded as each finishes; on a GPU the one-off imports (torch.optim pulls in dynamo) stay outside the timings and each
    timing waits for the device."""
    import torch

    from real2sim.reconstruct.stage import reconstruct

    cuda = device.startswith("cuda")
    if cuda:
        torch.optim.Adam([torch.zeros(1, device=device, requires_grad=True)])
    for config in configs:
        if cuda:
            torch.cuda.synchronize()
        start = time.perf_counter()
        report = reconstruct(dataset, config, device=device, seed=0).report
        if cuda:
            torch.cuda.synchronize()
        yield time.perf_counter() - start, report


def reconstruct_both(dataset: Path, device: str, methods: tuple[str, ...]) -> list[list]:
    """The rows of one dataset: the whole field reconstruction (``reconstruct``'s defaults, judged
    against the dataset's ground truth) with each visibility test, in one process."""
    from real2sim.reconstruct.carving.photo import CarvingConfig
    from real2sim.reconstruct.stage import ReconstructConfig
    from real2sim.reconstruct.field.train import FieldConfig

    configs = [ReconstructConfig(field=FieldConfig(carving=CarvingConfig(visibility=method))) for method in methods]
    rows = []
    for method, (seconds, report) in zip(methods, timed_reconstructions(dataset, device, configs)):
        truth = report.get("truth", {})
        rows.append([dataset.name, device, method, round(seconds, 2),
                     round(report.get("hull_and_carving_seconds", float("nan")), 2), report.get("photo_carved_voxels"),
                     round(truth.get("chamfer_mm", float("nan")), 3), round(truth.get("iou", float("nan")), 4),
                     round(truth["concave_recovered"], 3) if truth.get("concave_recovered") is not None else "-"])
    return rows


RATIO_HEADER = ["object", "device", "ratio", "wall voxels", "depth test voxels", "wall s", "Chamfer mm", "hull / concave mm", "IoU",
                "F@1mm", "concave", "carved voxels", "opened voxels"]


def parse_ratios(text: str) -> tuple[tuple[float, float, float], ...]:
    """``"1.5,1.25:2,1.0:3:0"`` -> ((1.5, W, D), (1.25, 2.0, D), (1.0, 3.0, 0.0)): the hollow prior's
    ``min_spread_to_contrast``, after a colon its ``min_wall_voxels`` and after a second its
    ``depth_test_voxels`` (each by default CarvingConfig's: W 2, D 2; a D of 0 turns the depth test off)."""
    from real2sim.reconstruct.carving.photo import CarvingConfig

    default = CarvingConfig()
    settings = []
    for item in text.split(","):
        ratio, wall, depth = (item.split(":") + ["", ""])[:3]
        settings.append((float(ratio), float(wall) if wall else default.min_wall_voxels,
                         float(depth) if depth else default.depth_test_voxels))
    return tuple(settings)


def reconstruct_ratios(dataset: Path, device: str, ratios: tuple[tuple[float, float, float], ...],
                       visibility: str = "mesh") -> list[list]:
    """The rows of one dataset: the whole field reconstruction with each (ratio, wall, depth test) of the
    hollow prior (``CarvingConfig.min_spread_to_contrast``, ``min_wall_voxels``, ``depth_test_voxels``),
    judged against the truth."""
    from real2sim.reconstruct.stage import ReconstructConfig

    base = ReconstructConfig()
    configs = [replace(base, field=replace(base.field, carving=replace(
        base.field.carving, min_spread_to_contrast=ratio, min_wall_voxels=wall, depth_test_voxels=depth,
        visibility=visibility))) for ratio, wall, depth in ratios]
    rows = []
    for (ratio, wall, depth), (seconds, report) in zip(ratios, timed_reconstructions(dataset, device, configs)):
        truth = report.get("truth", {})
        concave_mm = truth.get("chamfer_concave_mm")
        rows.append([dataset.name, device, ratio, wall, depth, round(seconds, 1),
                     round(truth.get("chamfer_mm", float("nan")), 3),
                     f"{truth.get('chamfer_hull_mm', float('nan')):.3g} / "
                     + ("-" if concave_mm is None else f"{concave_mm:.3g}"),
                     round(truth.get("iou", float("nan")), 3), round(truth.get("fscore_1mm", float("nan")), 3),
                     "-" if truth.get("concave_recovered") is None else round(truth["concave_recovered"], 3),
                     report.get("photo_carved_voxels"), report.get("photo_carving_opened_voxels")])
        print(markdown_table(RATIO_HEADER, rows[-1:]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="mug")
    ap.add_argument("--datasets", type=Path, default=None, metavar="DIR",
                    help="DIR/<object>: datasets captured earlier (a GPU machine has no Drake)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--methods", default="mesh,voxels")
    ap.add_argument("--tag", default="")
    ap.add_argument("--reconstruct", action="store_true",
                    help="time and judge the whole field reconstruction with each test instead")
    ap.add_argument("--ratios", default=None, metavar="R[:W[:D]],...",
                    help="judge the whole reconstruction at each hollow-prior ratio (min_spread_to_contrast) and "
                         "wall (min_wall_voxels, default 2) and depth test (depth_test_voxels, default CarvingConfig's; 0: off), "
                         "visibility by mesh; writes carving_ratio[_TAG].md")
    args = ap.parse_args(argv)
    if args.ratios:
        ratios = parse_ratios(args.ratios)
        header, measure = RATIO_HEADER, lambda dataset, device, _methods: reconstruct_ratios(dataset, device, ratios)
    elif args.reconstruct:
        header, measure = RECONSTRUCT_HEADER, reconstruct_both
    else:
        header, measure = HEADER, carve_both
    rows = []
    for name in args.objects.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            dataset = args.datasets / name if args.datasets else Path(tmp) / name
            if args.datasets is None:
                from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
                from real2sim.geometry.objects import make_textured_object

                capture(make_textured_object(name), dataset, CaptureConfig(views=100, width=320, height=240,
                                                                       pose_noise_mm=0, pose_noise_deg=0))
            rows += measure(dataset, args.device, tuple(args.methods.split(",")))
        print(markdown_table(header, rows), flush=True)
    suffix = f"_{args.tag}" if args.tag else ""
    command = "python benchmarks/bench_carving.py " + " ".join(argv if argv is not None else sys.argv[1:])
    if args.ratios:
        body = ("The hollow prior's ratio (`CarvingConfig.min_spread_to_contrast`: a concavity's voxel goes where its "
                "views disagree at least this many times as much as the image varies there) and wall guard "
                "(`min_wall_voxels`) and depth test (`depth_test_voxels`: a voxel also goes where its views would agree "
                "as well about a surface that many voxels deeper; 0: off), the rest `reconstruct`'s defaults with photo carving's visibility by mesh (the "
                "CPU's default), every 10th view held out, judged against the true object (`hull / concave`: the "
                "Chamfer of the parts a silhouette can judge and of the concave parts; `concave`: the share of the "
                "true concave space left open).\n\n" + markdown_table(header, rows))
        path = write_result(f"carving_ratio{suffix}", "Photo carving: the hollow prior's ratio", body, command.strip())
        print(f"wrote {path}")
        return 0
    body = ("Photo carving's visibility test, Embree on the solid's marching-cubes surface (`mesh`, rebuilt each "
            "round) or the rays walked through the voxels with torch (`voxels`, `reconstruct.voxel_rays`); "
            "`CarvingConfig.visibility` \"auto\" takes the mesh on a CPU and the voxels on a GPU. The step timed is the "
            "field's starting density as `reconstruct` makes it (`train.hull_density`: the visual hull on the coarse "
            "grid, both carving passes and the masks' re-checks), on every view of the dataset"
            + (" (with --reconstruct: the whole field reconstruction, `reconstruct`'s defaults, every 10th view held "
               "out, judged against the true object)" if args.reconstruct else "") + ".\n\n"
            + markdown_table(header, rows))
    path = write_result(f"carving_visibility{suffix}", "Photo carving: visibility by mesh or by voxels", body,
                         command.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
