"""Why point contact gets its own stiffness: OCAE, contact fraction and CPD of a fitted
representation under point contact for several point_contact_stiffness values
(None = Drake's default) and Hunt-Crossley dissipations, push and ramp runs, against
the hydroelastic reference.

    python benchmarks/bench_point_stiffness.py [--object bottle] [--spec spheres:64] [--runs 2]

Writes benchmarks/results/point_stiffness.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402

STIFFNESSES = (None, 3.0e3, 1.0e4, 3.0e4, 1.0e5)
DISSIPATIONS_S_PER_M = (1.0, 5.0, 20.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", default="bottle")
    parser.add_argument("--spec", default="spheres:64")
    parser.add_argument("--runs", type=int, default=2, help="seeded runs per task (default 2)")
    parser.add_argument("--full", action="store_true", help="accepted for run_all.py; same as the default")
    args = parser.parse_args()

    from real2sim.asset.build import AssetConfig, build_asset, rewrite_models
    from real2sim.formats.contact import ContactProperties
    from real2sim.evaluate.metrics import cpd_m_per_s, ocae_m
    from real2sim.geometry.objects import OBJECTS, export_object
    from real2sim.formats.physical import read_physical_properties
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.scene.tasks import make_run_specs
    from real2sim.evaluate.simulate import simulate_candidate, simulate_reference
    from real2sim.formats.spec import parse_spec

    spec = parse_spec(args.spec)
    work = Path(tempfile.mkdtemp(prefix="bench_point_stiffness-"))
    mesh = export_object(args.object, work / "object" / "model.obj")
    asset = work / "asset"
    build_asset(mesh, asset, AssetConfig(mass_kg=OBJECTS[args.object].mass_kg, specs=(spec,)))
    props = read_physical_properties(asset / "physical_properties.json")
    scene = SceneConfig()
    references = {}
    for task in ("push", "ramp"):
        for run in make_run_specs(task, args.runs, 0):
            references[(task, run.run)] = (run, simulate_reference(asset / "visual" / "collision_reference.obj",
                                                                    props, run, scene))

    rows = []
    for stiffness in STIFFNESSES:
        for dissipation in DISSIPATIONS_S_PER_M:
            if stiffness is None and dissipation != ContactProperties().hunt_crossley_dissipation_s_per_m:
                continue  # Drake's default stiffness is the baseline; one row of it
            kwargs = {"hunt_crossley_dissipation_s_per_m": dissipation}
            if stiffness is not None:
                kwargs["point_contact_stiffness_n_per_m"] = stiffness
            [urdf] = rewrite_models(asset, ContactProperties(**kwargs))
            if stiffness is None:  # Drake's default: drop the element
                text = urdf.read_text()
                urdf.write_text("\n".join(line for line in text.splitlines() if "point_contact_stiffness" not in line))
            per_task: dict[str, list[tuple[float, float, float]]] = {"push": [], "ramp": []}
            for (task, _), (run, ref) in references.items():
                cand = simulate_candidate(urdf, "point", run, scene, reference=ref)
                breaks = np.asarray(cand.reset_steps, dtype=int) + 1
                per_task[task].append((
                    ocae_m(ref.object_position_m, ref.object_quaternion_wxyz,
                           cand.object_position_m, cand.object_quaternion_wxyz),
                    float(np.mean([len(p) > 0 for p in cand.contact_points_object_m])),
                    cpd_m_per_s(cand.contact_points_object_m, scene.time_step_s, breaks),
                ))
            row = ["Drake default" if stiffness is None else f"{stiffness:.0e}", f"{dissipation:g}"]
            for task in ("push", "ramp"):
                vals = np.array(per_task[task], dtype=float)
                row += [float(np.mean(vals[:, 0])), float(np.mean(vals[:, 1])), float(np.nanmean(vals[:, 2]))]
            rows.append(row)
            print(row, flush=True)
    ref_contact = {t: float(np.mean([np.mean([len(p) > 0 for p in r.contact_points_object_m])
                                     for (tt, _), (_, r) in references.items() if tt == t]))
                   for t in ("push", "ramp")}
    body = (
        f"Object: bundled {args.object}, collision `{args.spec}`, point contact, {args.runs} seeded runs of each task, "
        f"equation error against the hydroelastic reference (whose contact fraction is push "
        f"{ref_contact['push']:.2f}, ramp {ref_contact['ramp']:.2f}). Contact fraction = share of steps with any "
        "contact; a low one means the object bounces. CPD as in the paper (m/s). The defaults of "
        "`ContactProperties` are 1e4 N/m and 1 s/m; the dissipation also acts on hydroelastic contact, so "
        "changing its default changes every row of Table I.\n\n"
        + markdown_table(["point stiffness N/m", "dissipation s/m", "push OCAE m", "push contact", "push CPD m/s",
                          "ramp OCAE m", "ramp contact", "ramp CPD m/s"], rows)
    )
    path = write_result("point_stiffness", "Point-contact stiffness", body,
                         "python benchmarks/bench_point_stiffness.py " + " ".join(sys.argv[1:]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
