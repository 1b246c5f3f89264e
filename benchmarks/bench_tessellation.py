"""How much the tessellation of a round object moves its simulated trajectory.

A bundled object's surfaces of revolution are polygons; their flats lie a sagitta
``r (1 - cos(pi / n))`` inside the circle. This benchmark builds the object as bundled, at
several sagittas (``make_object(name, rolling_sagitta_m=...)``), and round
(``ROUND_SAGITTA_M``) but 50 um wider (a difference no camera here resolves). Each is
simulated as its own mesh (rigid hydroelastic, `--collision mesh`) and scored against the
object at a much finer sagitta with that object's own mass properties (`real2sim evaluate
--reference FINE --reference-inertia mesh`, equation error as in every evaluation). It
measures the floor under any comparison with a true object: two descriptions of the same
round body differ by this much.

    python benchmarks/bench_tessellation.py                       # the can, 4 runs per task
    python benchmarks/bench_tessellation.py --objects bottle --sagittas-um none --reference-sagitta-um 2.5 --tag bottle

Writes benchmarks/results/tessellation.md, or tessellation_TAG.md (machine, date and command included).
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402


def _variants(name: str, sagittas_m: list[float]) -> dict:
    """Label -> watertight trimesh of each candidate description of object ``name``."""
    from real2sim.geometry.objects import ROUND_SAGITTA_M, make_object

    out = {"as bundled": make_object(name)}
    out.update({f"flats {s * 1e6:g} um inside": make_object(name, rolling_sagitta_m=s) for s in sagittas_m})
    wider = make_object(name, rolling_sagitta_m=ROUND_SAGITTA_M).copy()
    centre = wider.vertices[:, :2].mean(axis=0)
    extent = np.linalg.norm(wider.vertices[:, :2] - centre, axis=1).max()
    # +50 um at the widest radius, proportionally less inward: a uniform scale in x and y.
    wider.vertices[:, :2] = centre + (wider.vertices[:, :2] - centre) * (1 + 50e-6 / extent)
    out[f"flats {ROUND_SAGITTA_M * 1e6:g} um inside, 50 um wider"] = wider
    return out


def _score(name: str, label: str, mesh, reference: Path, work: Path, runs: int) -> list[dict]:
    """runs.csv rows of ``mesh`` as an asset (mesh collision) against ``reference``."""
    from real2sim.cli import main as cli
    from real2sim.geometry.objects import OBJECTS

    slug = "".join(c if c.isalnum() else "_" for c in label)
    source = work / f"{name}_{slug}.obj"
    mesh.export(source)
    asset, results = work / f"{name}_{slug}_asset", work / f"{name}_{slug}_results"
    if cli(["asset", str(source), "--mass-kg", str(OBJECTS[name].mass_kg), "--collision", "mesh", "--out", str(asset)]):
        raise RuntimeError(f"asset failed for {label}")
    if cli(["evaluate", str(asset), "--out", str(results), "--reference", str(reference), "--reference-inertia",
            "mesh", "--runs", str(runs), "--contact", "hydroelastic", "--no-animations"]):
        raise RuntimeError(f"evaluate failed for {label}")
    with open(results / "runs.csv", newline="") as f:
        return list(csv.DictReader(f))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="can")
    parser.add_argument("--runs", type=int, default=4, help="seeded runs per task (default 4)")
    parser.add_argument("--sagittas-um", default="8.1,2.5",
                        help="candidate sagittas besides the bundled object's, um, or none (the bundled can's "
                             "72 sections leave flats 32.4 um deep)")
    parser.add_argument("--reference-sagitta-um", type=float, default=0.16)
    parser.add_argument("--tag", default="", help="write benchmarks/results/tessellation_TAG.md instead")
    args = parser.parse_args()
    from real2sim.geometry.objects import make_object

    sagittas = [] if args.sagittas_um == "none" else [float(s) * 1e-6 for s in args.sagittas_um.split(",")]
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_tessellation-") as tmp:
        work = Path(tmp)
        for name in args.objects.split(","):
            fine = make_object(name, rolling_sagitta_m=args.reference_sagitta_um * 1e-6)
            reference = work / f"{name}_reference.obj"
            fine.export(reference)
            for label, mesh in _variants(name, sagittas).items():
                runs = _score(name, label, mesh, reference, work, args.runs)
                by_task = {t: [float(r["ocae_m"]) for r in runs if r["task"] == t and not r["error"]]
                           for t in ("push", "ramp")}
                rows.append([name, label, len(mesh.faces), len(fine.faces), np.mean(by_task["push"]),
                             np.mean(by_task["ramp"]), np.mean(by_task["push"] + by_task["ramp"]), len(runs)])
                print(rows[-1], flush=True)
            body = (f"Each description of the object is simulated as its own mesh (rigid hydroelastic) against the "
                    f"same object with flats {args.reference_sagitta_um:g} um inside the circle "
                    f"and that mesh's own mass properties; equation "
                    f"error (resets every 0.1 s), {args.runs} seeded run(s) per task, hydroelastic contact.\n\n"
                    + markdown_table(["object", "description", "faces", "reference faces", "OCAE push m", "OCAE ramp m",
                                      "OCAE mean m", "simulations"], rows))
            print(write_result("tessellation" + (f"_{args.tag}" if args.tag else ""),
                                "What tessellation does to a rolling object (bench_tessellation.py)",
                                body, "python benchmarks/bench_tessellation.py " + " ".join(sys.argv[1:])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
