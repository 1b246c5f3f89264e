"""What one simulation step costs Drake per representation, and what the cost is made of.

Issue #32 asks for primitive rows of Table I both faster and more accurate than CoACD. This
benchmark measures where a row's time goes, on the Table I scenes (push and ramp, run 0 of seed
0, one rollout without resets, the bundled bottle and can, assets built as `bench_table1.py`
builds them): wall milliseconds per 1 ms step of the bare rollout, and, from a second rollout
read every 10th step, how many pieces touch (hydroelastic contact surfaces, or point pairs) and
how many polygons the surfaces hold (each polygon is one contact constraint of Drake's discrete
solver). Hydroelastic rows are measured at each ``--hints`` resolution hint (Drake meshes
compliant spheres, cylinders and ellipsoids at it; boxes and convex pieces do not depend on
it), and with ``--polytopes`` the ellipsoid fits once more as compliant convex pieces (the
288-vertex polytopes of ``model_portable.urdf``) instead of Drake's own ellipsoid meshes.

    python benchmarks/bench_contact_cost.py
    python benchmarks/bench_contact_cost.py --objects bottle --specs coacd ellipsoids:16 --hints 0.01

Assets are kept in benchmarks/out/contact_cost. Writes benchmarks/results/contact_cost.md (or
contact_cost_TAG.md), machine, date and command included. Run it on an idle machine: the
milliseconds are wall time.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, markdown_table, write_result  # noqa: E402

SPECS = ("coacd", "boxes:10", "boxes:50", "cylinders:10", "spheres:128", "ellipsoids:16", "ellipsoids:64",
         "superquadrics:10")
HEADER = ["object", "representation", "contact", "hint m", "task", "ms per step", "pieces touching",
          "polygons", "polygons max"]


def one_sphere_representation(rep_dir: Path, out_dir: Path, contact) -> None:
    """``out_dir``: the body of ``rep_dir`` (same mass properties) whose only collision is one sphere, its
    radius a quarter of the smallest horizontal extent of ``rep_dir``'s pieces, resting where their lowest
    point is. Not a fit: the cost of the rest of the scene plus one touching piece, which no
    representation of the object can undercut by much."""
    from dataclasses import replace

    from bench_table1 import write_variant

    from real2sim.geometry.collision_mesh import union_mesh
    from real2sim.formats.collision import CollisionShape, read_collision_json

    geometry = read_collision_json(rep_dir / "collision.json")
    lo, hi = union_mesh(geometry, rep_dir).bounds
    radius = 0.25 * float(min(hi[:2] - lo[:2]))
    centre = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), float(lo[2]) + radius)
    write_variant(out_dir, replace(geometry, shapes=(CollisionShape("sphere", (radius,), centre),)), contact)


def step_cost(asset: Path, rep: str, contact: str, task: str) -> list:
    """(ms per step, mean pieces touching, mean polygons, max polygons) of run 0 of ``task``."""
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.simulate import _advance, _started, candidate_initial_state
    from real2sim.evaluate.scene.tasks import make_run_specs, run_steps
    from real2sim.evaluate.scene.world import build_scene, urdf_object_adder

    cfg = SceneConfig()
    spec = make_run_specs(task, 1, 0)[0]
    urdf = asset / rep / ("model.urdf" if contact == "hydroelastic" else "model_point.urdf")
    scene = build_scene(task, contact, urdf_object_adder(urdf), spec, cfg)
    initial = candidate_initial_state(scene, urdf, spec, cfg)
    steps = run_steps(task, cfg)
    simulator, _ = _started(scene, initial, rep)
    start = time.perf_counter()
    _advance(simulator, steps, cfg.time_step_s, rep)
    ms_per_step = 1000 * (time.perf_counter() - start) / steps
    simulator, context = _started(scene, initial, rep)
    port = scene.plant.get_contact_results_output_port()
    touching, polygons = [], []
    for i in range(0, steps, 10):
        _advance(simulator, i + 1, cfg.time_step_s, rep)
        results = port.Eval(context)
        faces = [results.hydroelastic_contact_info(k).contact_surface().num_faces()
                 for k in range(results.num_hydroelastic_contacts())]
        touching.append(len(faces) + results.num_point_pair_contacts())
        polygons.append(sum(faces))
    return [round(ms_per_step, 3), round(float(np.mean(touching)), 1), round(float(np.mean(polygons)), 1),
            int(max(polygons))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="bottle,can")
    parser.add_argument("--specs", nargs="+", default=list(SPECS))
    parser.add_argument("--contact", nargs="+", default=["point", "hydroelastic"], choices=["point", "hydroelastic"])
    parser.add_argument("--hints", default="0.01,0.02,0.04", help="hydroelastic resolution hints, m (comma-separated)")
    parser.add_argument("--polytopes", action="store_true", help="ellipsoid fits also as compliant convex polytopes")
    parser.add_argument("--floor", action="store_true",
                        help="also the object's body with one sphere as its only collision (the scene's cost floor)")
    parser.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "out" / "contact_cost")
    parser.add_argument("--tag", default=None)
    args = parser.parse_args()

    from bench_table1 import build_assets, polytope_representation

    from real2sim.asset.build import rewrite_models
    from real2sim.formats.contact import ContactProperties
    from real2sim.formats.spec import parse_spec

    objects = tuple(args.objects.split(","))
    hints = [float(h) for h in args.hints.split(",")]
    assets = build_assets(args.work, tuple(args.specs), 0, objects=objects)
    reps = [parse_spec(s).name for s in args.specs]
    rows = []
    for asset in assets:
        variants = []  # (contact, hint, asset folder, representation)
        if args.floor:
            one_sphere_representation(asset / reps[0], asset / "one_sphere", ContactProperties())
            reps_here = [*reps, "one_sphere"]
        else:
            reps_here = reps
        if "point" in args.contact:
            variants += [("point", "-", asset, rep) for rep in reps_here]
        for hint in hints if "hydroelastic" in args.contact else []:
            hinted = args.work / "hinted" / f"{asset.name}_{hint:g}"
            if not hinted.exists():
                shutil.copytree(asset, hinted)
            if args.floor and not (hinted / "one_sphere").exists():
                shutil.copytree(asset / "one_sphere", hinted / "one_sphere")
            rewrite_models(hinted, ContactProperties(resolution_hint_m=hint))
            variants += [("hydroelastic", f"{hint:g}", hinted, rep) for rep in reps_here]
            if args.polytopes:
                for rep in [r for r in reps if r.startswith("ellipsoids_")]:
                    polytope_representation(hinted / rep, hinted / f"{rep}_polytopes",
                                            ContactProperties(resolution_hint_m=hint))
                    variants.append(("hydroelastic", f"{hint:g}", hinted, f"{rep}_polytopes"))
        for task in ("push", "ramp"):
            for contact, hint, folder, rep in variants:
                rows.append([asset.name, rep, contact, hint, task, *step_cost(folder, rep, contact, task)])
                print(markdown_table(HEADER, rows[-1:]).splitlines()[-1], flush=True)
    body = ("Table I's scenes, run 0 of seed 0 of each task, one rollout without resets (`SceneConfig()`), the assets "
            "`bench_table1.py` builds. ms per step: wall time of the bare rollout over its steps. Pieces touching: "
            "hydroelastic contact surfaces plus point pairs, polygons: the surfaces' faces (one contact constraint "
            "each), both averaged over every 10th step of a second rollout. hint: the compliant shapes' "
            "`mesh_resolution_hint` (boxes and convex pieces do not use it); `_polytopes`: the ellipsoids as the "
            "convex polytopes of `model_portable.urdf`; `one_sphere` (`--floor`): the object's body with one sphere as its "
            "only collision, the cost of the rest of the scene plus one touching piece.\n\n" + markdown_table(HEADER, rows))
    section = "contact_cost" + (f"_{args.tag}" if args.tag else "")
    write_result(section, "What a simulation step costs, per representation", body,
                  "python benchmarks/bench_contact_cost.py " + " ".join(sys.argv[1:]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
