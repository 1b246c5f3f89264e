"""Contact-aware fitting (issue #32 part 3): how well fitted primitives hold the surfaces an object touches
things with, with and without weighting the samples near the convex hull (``FitConfig.contact_weight``).

For each object and SPEC, the samples are made as the asset build makes them (canonical pose, then
``fit_collision``'s SDF samples) and fitted once per gain; reported: the error of the fitted union's support
function (its farthest extent along a direction, exact per primitive) against the true mesh's over 500
directions, all of them, those within 30 degrees of straight down (the bottom it stands on) and those within
30 degrees of horizontal (the sides it rolls on); volumetric IoU and Chamfer; the fit's iterations and
seconds.

    python benchmarks/bench_contact_weights.py                        # bottle, can, mug; cylinders:10, boxes:10
    python benchmarks/bench_contact_weights.py --objects mug --specs cylinders:10 --gains 0,5 --band 0.04

Writes benchmarks/results/contact_weights[_TAG].md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402


def directions(n: int = 500) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def shape_support(shape, u: np.ndarray, rep_dir: Path) -> np.ndarray:
    """Support function (D,) of one collision shape along unit directions ``u`` (D, 3), asset frame, m."""
    from real2sim.formats.rotations import quaternion_to_matrix
    from real2sim.geometry.collision_mesh import load_piece_mesh

    v = u @ np.asarray(quaternion_to_matrix(np.asarray(shape.quaternion_wxyz, dtype=float)))  # shape frame
    s = np.asarray(shape.size_m, dtype=float)
    if shape.kind == "sphere":
        h = np.full(len(u), s[0])
    elif shape.kind == "box":
        h = np.abs(v) @ (0.5 * s)
    elif shape.kind == "ellipsoid":
        h = np.linalg.norm(v * s, axis=1)
    elif shape.kind == "cylinder":
        h = s[0] * np.sqrt(np.clip(1 - v[:, 2] ** 2, 0, None)) + 0.5 * s[1] * np.abs(v[:, 2])
    elif shape.kind in ("convex", "mesh"):
        h = (v @ np.asarray(load_piece_mesh(rep_dir / shape.mesh_file).vertices).T).max(axis=1)
    else:
        raise ValueError(f"no support function for {shape.kind}")
    return u @ np.asarray(shape.position_m) + h


def support_errors(mesh, geometry, rep_dir: Path, u: np.ndarray) -> dict[str, float]:
    """|fitted - true| support, mm: mean and max over all directions, the downward and the sideways ones."""
    true = (u @ np.asarray(mesh.vertices).T).max(axis=1)
    fit = np.max([shape_support(s, u, rep_dir) for s in geometry.shapes], axis=0)
    err = np.abs(1000.0 * (fit - true))
    down, side = u[:, 2] < -np.cos(np.radians(30)), np.abs(u[:, 2]) < np.sin(np.radians(30))
    return {"all": (err.mean(), err.max()), "down": (err[down].mean(), err[down].max()),
            "sides": (err[side].mean(), err[side].max())}


def canonical_mesh(name: str):
    """A bundled object as the asset build poses it (floaters dropped, canonical frame)."""
    from real2sim.asset.canonical import canonical_transform
    from real2sim.asset.floaters import without_floaters
    from real2sim.geometry.objects import make_object

    solid = without_floaters(make_object(name), seed=0)
    solid = solid.copy()
    solid.apply_transform(canonical_transform(solid))
    return solid


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="bottle,can,mug")
    parser.add_argument("--specs", default="cylinders:10,boxes:10")
    parser.add_argument("--gains", default="0,5", help="FitConfig.contact_weight values (comma-separated)")
    parser.add_argument("--band", type=float, default=0.02, help="FitConfig.contact_band (unit sphere)")
    parser.add_argument("--tag", default="")
    parser.add_argument("--full", action="store_true", help="(run_all.py) the default setting")
    args = parser.parse_args()

    from real2sim.collision.fit.config import FitConfig
    from real2sim.collision.fit.stage import fit_collision
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.fidelity import measure_fidelity

    u, rows = directions(), []
    with tempfile.TemporaryDirectory() as cache:
        for name in args.objects.split(","):
            mesh = canonical_mesh(name)
            for spec_text in args.specs.split(","):
                for gain in (float(g) for g in args.gains.split(",")):
                    with tempfile.TemporaryDirectory() as tmp:
                        geometry, report = fit_collision(
                            mesh, parse_spec(spec_text), fit_config=FitConfig(contact_weight=gain,
                                                                              contact_band=args.band),
                            cache_dir=Path(cache), rep_dir=Path(tmp), seed=0)
                        fid = measure_fidelity(mesh, geometry, Path(tmp), seed=0)
                        err = support_errors(mesh, geometry, Path(tmp), u)
                    rows.append([name, spec_text, f"{gain:g}", *(f"{err[k][0]:.2f} / {err[k][1]:.2f}"
                                                                 for k in ("all", "down", "sides")),
                                 round(fid["iou"], 3), round(fid["chamfer_mm"], 2), report["iterations"],
                                 round(report["fit_seconds"], 1)])
                    print(rows[-1], flush=True)
    body = (f"Support-function error of the fitted union against the true mesh (mm, mean / max over 500 "
            f"directions; down: within 30 deg of straight down; sides: within 30 deg of horizontal), band "
            f"{args.band:g} (unit sphere). Gain 0 is the fit without the weighting (the default). One seed per "
            "row: differences of about 0.1 mm are noise.\n\n"
            + markdown_table(["object", "SPEC", "gain", "all mm", "down mm", "sides mm", "IoU", "Chamfer mm",
                              "iterations", "fit s"], rows) + "\n")
    command = "python benchmarks/bench_contact_weights.py " + " ".join(sys.argv[1:])
    path = write_result("contact_weights" + (f"_{args.tag}" if args.tag else ""),
                         "Contact-aware fitting: the surfaces that touch", body, command.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
