"""Why point contact gets its own stiffness: OCAE and contact fraction of a fitted
representation under point contact for several point_contact_stiffness values
(None = Drake's default), one push and one ramp run, against the hydroelastic reference.

    python benchmarks/bench_point_stiffness.py [--object bottle] [--spec spheres:64]

Writes docs/benchmarks/point_stiffness.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_section  # noqa: E402

STIFFNESSES = (None, 1.0e4, 3.0e4, 1.0e5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", default="bottle")
    parser.add_argument("--spec", default="spheres:64")
    parser.add_argument("--full", action="store_true", help="accepted for run_all.py; same as the default")
    args = parser.parse_args()

    from real2sim.asset import AssetConfig, build_asset, rewrite_models
    from real2sim.contact import ContactProperties
    from real2sim.metrics import ocae_m
    from real2sim.objects import OBJECTS, export_object
    from real2sim.physical import read_physical_properties
    from real2sim.scenes import SceneConfig, make_run_specs
    from real2sim.simulation import simulate_candidate, simulate_reference
    from real2sim.spec import parse_spec

    spec = parse_spec(args.spec)
    work = Path(tempfile.mkdtemp(prefix="bench_point_stiffness-"))
    mesh = export_object(args.object, work / "object" / "model.obj")
    asset = work / "asset"
    build_asset(mesh, asset, AssetConfig(mass_kg=OBJECTS[args.object].mass_kg, specs=(spec,)))
    props = read_physical_properties(asset / "physical_properties.json")
    scene = SceneConfig()
    references = {}
    for task in ("push", "ramp"):
        run = make_run_specs(task, 1, 0)[0]
        references[task] = (run, simulate_reference(asset / "visual" / "collision_reference.obj", props, run, scene))

    rows = []
    for stiffness in STIFFNESSES:
        contact = ContactProperties() if stiffness is None else ContactProperties(point_contact_stiffness_n_per_m=stiffness)
        [urdf] = rewrite_models(asset, contact)
        if stiffness is None:  # Drake's default: drop the element
            text = urdf.read_text()
            urdf.write_text("\n".join(line for line in text.splitlines() if "point_contact_stiffness" not in line))
        row = ["Drake default" if stiffness is None else f"{stiffness:.0e}"]
        for task, (run, ref) in references.items():
            cand = simulate_candidate(urdf, "point", run, scene, reference=ref)
            row.append(ocae_m(ref.object_position_m, ref.object_quaternion_wxyz,
                              cand.object_position_m, cand.object_quaternion_wxyz))
            row.append(float(np.mean([len(p) > 0 for p in cand.contact_points_object_m])))
        rows.append(row)
        print(row, flush=True)
    ref_contact = {t: float(np.mean([len(p) > 0 for p in r.contact_points_object_m])) for t, (_, r) in references.items()}
    body = (
        f"Object: bundled {args.object}, collision `{args.spec}`, point contact, seed-0 run of each task, "
        f"equation error against the hydroelastic reference (whose contact fraction is push "
        f"{ref_contact['push']:.2f}, ramp {ref_contact['ramp']:.2f}). Contact fraction = share of steps with any "
        "contact; a low one means the object bounces. The default chosen for `ContactProperties` is 1e4 N/m.\n\n"
        + markdown_table(["point stiffness N/m", "push OCAE m", "push contact", "ramp OCAE m", "ramp contact"], rows)
    )
    path = write_section("point_stiffness", "Point-contact stiffness", body,
                         "python benchmarks/bench_point_stiffness.py " + " ".join(sys.argv[1:]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
