"""`real2sim run` on shapes that are not the bundled objects, judged against the truth.

The bundled bottle, can and mug are what the pipeline was built on; these are not. Each shape is
made here with trimesh (no texture: `capture` gives it a procedural one), captured as the demo
captures (100 views at 320x240 px, robot poses with 5 mm / 1 deg RMS noise), and run with pose
refinement, the radiance field and three representations (no evaluation):

* ``box``: 9 x 5 x 3.5 cm, turned 23 degrees about z: flat faces, sharp edges, a squat object
  whose longest side is horizontal;
* ``bowl``: an open spherical bowl, 12.6 cm wide, 4 cm deep, 8 mm wall: a wide concavity
  every high view looks into;
* ``bin``: an open box, 10 x 7 x 6 cm, 4 mm walls and floor: a concavity with thin walls, whose
  rim carving can lower (the masks' re-check then has to grow the rim back, not lay a lid);
* ``torus``: a ring lying flat, 12 cm across: a through-hole;
* ``rod``: a cylinder 2.4 cm wide and 20 cm tall: thin and tall;
* ``box`` again with the robot's poses as they are (``--refine-poses`` left out): what pose
  noise does to the reconstruction (photo carving's silhouette guard).

Reported from ASSETDIR/truth.json, ASSETDIR/.run/ and the asset: the reconstruction's Chamfer
(total, and its hull / concave parts), IoU, F@1mm, the share of the concave space left open,
photo-carved and restored voxels, the asset's CoM and inertia errors, the angle between the
asset's +z and the table's normal, and the reconstruct stage's wall time.

    python benchmarks/bench_shapes.py                   # every shape, full settings
    python benchmarks/bench_shapes.py --shapes box,rod
    python benchmarks/bench_shapes.py --shapes bin --tag bin  # benchmarks/results/shapes_TAG.md, TAG bin
    python benchmarks/bench_shapes.py --quick           # 60 noise-free views at 160x120, visual hull

Writes benchmarks/results/shapes.md (machine and date included), after each shape.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

SHAPES = ("box", "bowl", "bin", "torus", "rod", "box_unrefined")
SPECS = ("cylinders:10", "ellipsoids:16", "coacd")
MASS_KG = 0.2


def make_shape(name: str):
    """The shape ``name`` as a trimesh in metres, standing on z = 0."""
    import trimesh
    from trimesh.transformations import rotation_matrix

    if name.startswith("box"):
        mesh = trimesh.creation.box((0.09, 0.05, 0.035))
        mesh.apply_transform(rotation_matrix(0.4, [0, 0, 1]))
    elif name == "bowl":
        outer = trimesh.creation.icosphere(subdivisions=4, radius=0.07)
        inner = trimesh.creation.icosphere(subdivisions=4, radius=0.062)
        above = trimesh.creation.box((0.3, 0.3, 0.3))
        above.apply_translation([0, 0, 0.12])  # keeps z < -0.03: a 4 cm deep cap of the shell
        mesh = outer.difference(inner).difference(above)
    elif name == "bin":
        inside = trimesh.creation.box((0.092, 0.062, 0.066))
        inside.apply_translation([0, 0, 0.007])  # from 4 mm above the floor's underside up through the top
        mesh = trimesh.creation.box((0.1, 0.07, 0.06)).difference(inside)
    elif name == "torus":
        mesh = trimesh.creation.torus(major_radius=0.045, minor_radius=0.015)
    elif name == "rod":
        mesh = trimesh.creation.cylinder(radius=0.012, height=0.2, sections=48)
    else:
        raise ValueError(name)
    mesh.apply_translation([0, 0, -mesh.bounds[0, 2]])
    return mesh


def run_shape(name: str, work: Path, quick: bool) -> dict:
    """One shape's capture + run; the row's numbers."""
    from real2sim.asset.build import AssetConfig
    from real2sim.capture.poses.refinement import RefineConfig
    from real2sim.capture.sim.wrist_camera import CaptureConfig, capture
    from real2sim.formats.spec import parse_spec
    from real2sim.pipeline.run import RunConfig, run_pipeline
    from real2sim.reconstruct.stage import ReconstructConfig

    refine = not (quick or name.endswith("unrefined"))
    noise = (0.0, 0.0) if quick else (5.0, 1.0)
    capture_cfg = CaptureConfig(views=60 if quick else 100, width=160 if quick else 320, height=120 if quick else 240,
                                pose_noise_mm=noise[0], pose_noise_deg=noise[1])
    dataset = work / f"{name}_capture"
    capture(make_shape(name), dataset, capture_cfg)
    config = RunConfig(asset=AssetConfig(mass_kg=MASS_KG, specs=tuple(parse_spec(s) for s in SPECS)),
                       reconstruct=ReconstructConfig(backend="hull" if quick else "field"),
                       refine=RefineConfig() if refine else None)
    asset = work / f"{name}_asset"
    start = time.perf_counter()
    run_pipeline(dataset, asset, config)
    wall = time.perf_counter() - start
    truth = json.loads((asset / "truth.json").read_text())
    report = json.loads((asset / ".run" / "reconstruct" / "report.json").read_text())
    manifest = json.loads((asset / ".run" / "run.json").read_text())
    transform = np.asarray(json.loads((asset / "canonical_transform.json").read_text())["T_asset_from_input"])
    up = transform[:3, :3] @ [0.0, 0.0, 1.0]
    rec, phys = truth["reconstruction"], truth["physical_properties"]
    concave = rec.get("concave_recovered")
    return {
        "row": [name, "yes" if refine else "no", rec["chamfer_mm"],
                f"{rec['chamfer_hull_mm']:.3g} / " + ("-" if rec.get("chamfer_concave_mm") is None
                                                      else f"{rec['chamfer_concave_mm']:.3g}"),
                rec["iou"], rec["fscore_1mm"], "-" if concave is None else f"{concave:.2f}",
                report.get("photo_carved_voxels", "-"), report.get("photo_carving_restored_voxels", "-"),
                phys["com_error_mm"], 100 * phys["inertia_eigenvalue_max_rel_error"],
                float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0)))),
                manifest["stages"]["reconstruct"]["wall_seconds"], wall],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", default=",".join(SHAPES))
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--full", action="store_true", help="(run_all.py) the default setting")
    parser.add_argument("--note", default="", help="a line about the conditions (e.g. a machine shared with other work)")
    parser.add_argument("--tag", default="", help="write benchmarks/results/shapes_TAG.md instead of shapes.md")
    parser.add_argument("--keep", type=Path, default=None,
                        help="write the captures and assets here (kept) instead of a temporary folder")
    args = parser.parse_args()
    names = args.shapes.split(",")
    unknown = [n for n in names if n not in SHAPES]
    if unknown:
        parser.error(f"unknown shapes {unknown} (choose from {', '.join(SHAPES)})")
    rows = []
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    with contextlib.nullcontext(args.keep) if args.keep else tempfile.TemporaryDirectory(prefix="bench_shapes-") as tmp:
        for name in names:
            rows.append(run_shape(name, Path(tmp), args.quick)["row"])
            body = ((args.note + "\n\n" if args.note else "")
                    + ("Quick settings: 60 noise-free views at 160x120, visual hull.\n\n" if args.quick else
                       "100 views at 320x240 px with 5 mm / 1 deg RMS robot-pose noise, refined by COLMAP unless "
                       "the row says not; radiance field; " + ", ".join(SPECS) + f"; {MASS_KG} kg.\n\n")
                    + "`concave`: share of the true concave space (inside the true convex hull, outside the "
                    "object) the reconstruction leaves empty. `up error`: angle between the asset's +z and the "
                    "table's normal (`run` keeps them equal). CoM and inertia against the true shape at the same "
                    "mass.\n\n"
                    + markdown_table(["shape", "poses refined", "Chamfer mm", "hull / concave mm", "IoU", "F@1mm",
                                      "concave", "photo-carved voxels", "restored voxels", "CoM error mm",
                                      "inertia error %", "up error deg", "reconstruct wall s", "run wall s"], rows))
            section = "shapes" + (f"_{args.tag}" if args.tag else "")
            print(write_result(section, "Shapes that are not the bundled objects (bench_shapes.py)", body,
                                "python benchmarks/bench_shapes.py " + " ".join(sys.argv[1:])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
