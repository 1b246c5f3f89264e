"""Point-contact material per representation (issue #32 part 4): the Table I protocol's point-contact rows
for several point-contact stiffnesses and Hunt-Crossley dissipations of the candidates, the reference
(the closed mesh, hydroelastic) keeping the asset's own material.

Point contact gives one contact point per pair of touching pieces, where the hydroelastic reference presses
a whole patch; how stiff and how lossy those points should be for a simplified geometry to move like the
object is a property of the representation, not of the object's material. This measures it.

    python benchmarks/bench_point_contact.py --work W              # W: a bench_table1.py --work folder
    python benchmarks/bench_point_contact.py --work W --specs coacd,ellipsoids_64 --settings 1e4:1,3e3:20

Each setting copies the assets of W (their representation folders rewritten with that material) into
W/point_contact/<setting>, and reuses W/results/reference_cache when it is there (the reference is the
same). Writes benchmarks/results/point_contact[_TAG].md.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import markdown_table, write_result  # noqa: E402

DEFAULT_SETTINGS = ("1e4:1", "1e4:20", "3e3:20", "3e4:20", "1e3:20")
SHARED_FILES = ("asset_config.json", "canonical_transform.json", "physical_properties.json")


def copy_assets(work: Path, dst: Path, specs: list[str], contact) -> list[Path]:
    """Copies of work/assets/<object> holding ``specs`` only, each representation's models written with
    ``contact``; asset_config.json is copied as it is, so the reference keeps the asset's material."""
    from real2sim.asset.build import VISUAL_RELPATH
    from real2sim.asset.export.writers import write_representation
    from real2sim.formats.collision import read_collision_json
    from real2sim.formats.physical import read_physical_properties

    out = []
    for src in sorted(p for p in (work / "assets").iterdir() if p.is_dir()):
        d = dst / src.name
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        for name in SHARED_FILES:
            shutil.copy(src / name, d / name)
        shutil.copytree(src / "visual", d / "visual")
        props = read_physical_properties(d / "physical_properties.json")
        for spec in specs:
            shutil.copytree(src / spec, d / spec)
            geometry = read_collision_json(d / spec / "collision.json")
            write_representation(d / spec, geometry, props, contact, visual_mesh_relpath=f"../{VISUAL_RELPATH}",
                                 formats=("urdf",), model_name=spec)
        out.append(d)
    return out


def seed_reference_cache(work: Path, results: Path) -> None:
    """Start the sweep's working folder with the reference trajectories of W's own sweep (same reference)."""
    cache = work / "results" / "reference_cache"
    partial = results.with_name(f".{results.name}.partial")
    if not cache.is_dir() or results.exists() or partial.exists():
        return
    from real2sim.plumbing.outputs import write_marker
    from real2sim.formats.results import RUN_COLUMNS

    partial.mkdir(parents=True)
    write_marker(partial, made_by="real2sim evaluate")
    shutil.copytree(cache, partial / "reference_cache")
    (partial / "runs.csv").write_text(",".join(RUN_COLUMNS) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, required=True, help="a bench_table1.py --work folder (assets built)")
    parser.add_argument("--specs", default="boxes_10,cylinders_10,spheres_128,ellipsoids_64,coacd",
                        help="representation folders to simulate (comma-separated)")
    parser.add_argument("--settings", default=",".join(DEFAULT_SETTINGS),
                        help="STIFFNESS_N_PER_M:DISSIPATION_S_PER_M pairs (comma-separated); a leading 'split@' "
                        "divides the stiffness among the pieces that touch a plane together")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--contact", default="point", choices=["point", "hydroelastic"],
                        help="the contact model of the rows (default point; hydroelastic shows what the same "
                        "dissipation does there)")
    parser.add_argument("--tag", default="")
    parser.add_argument("--full", action="store_true", help="(run_all.py) the default setting")
    args = parser.parse_args()

    from real2sim.evaluate.sweep import EvaluationConfig, evaluate
    from real2sim.formats.asset_config import read_asset_contact

    specs = args.specs.split(",")
    base = read_asset_contact(next(p for p in sorted((args.work / "assets").iterdir()) if p.is_dir()))
    rows, start = [], time.perf_counter()
    for setting in args.settings.split(","):
        split = setting.startswith("split@")
        stiffness, dissipation = (float(v) for v in setting.removeprefix("split@").split(":"))
        # Point rows simulate model.urdf here (no point-contact model), written with this setting.
        contact = dataclasses.replace(base, point_contact_stiffness_n_per_m=stiffness,
                                      hunt_crossley_dissipation_s_per_m=dissipation, point_dissipation_s_per_m=None,
                                      point_stiffness_per_piece=split)
        folder = (args.work / "point_contact" / ("" if args.contact == "point" else args.contact)
                  / setting.replace("@", "_").replace(":", "_"))
        assets = copy_assets(args.work, folder / "assets", specs, contact)
        results = folder / "results"
        seed_reference_cache(args.work, results)
        result = evaluate(assets, results, EvaluationConfig(tasks=("push", "ramp"), contact_models=(args.contact,),
                                                            runs=args.runs, seed=0))
        for r in sorted(result.summary, key=lambda r: r["representation"]):
            rows.append([setting, r["representation"], r["ocae_m"], r["ate_m"], r["cpd_m_per_s"],
                         r.get("cpd_paper", float("nan")), r["sim_time_s"]])
            print(rows[-1], flush=True)
    body = (
        f"Assets of `{args.work}` (bench_table1.py: bundled bottle and can unless that folder holds others). "
        f"{args.contact.capitalize()} contact only, push and ramp, {args.runs} runs per object and task (seed 0); the reference is the closed "
        "mesh with hydroelastic contact and the asset's own material "
        f"(point stiffness {base.point_contact_stiffness_n_per_m:g} N/m, dissipation "
        f"{base.hunt_crossley_dissipation_s_per_m:g} s/m). Setting = the candidates' point-contact stiffness "
        "(N/m) : Hunt-Crossley dissipation (s/m), written into each representation's model.urdf (no "
        "model_point.urdf here); `split@` divides the stiffness among the pieces that touch a "
        "plane together (`real2sim.asset.export.point_contact`). Sweep time "
        f"{(time.perf_counter() - start) / 60:.1f} min. ST is mean wall seconds per simulation: compare within "
        "one setting (a setting's sweep runs its rows side by side).\n\n"
        + markdown_table(["setting", "representation", "OCAE m", "ATE m", "CPD m/s", "cpd_paper m/sample", "ST s"],
                         rows) + "\n")
    command = "python benchmarks/bench_point_contact.py " + " ".join(sys.argv[1:])
    path = write_result("point_contact" + (f"_{args.tag}" if args.tag else ""),
                         "Point-contact material per representation", body, command.strip())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
