"""Mass properties identified from joint torques against the truth (issue #30, "Targets").

For each bundled object (bottle, can, mug) at a mass in 0.3-0.6 kg, uniform and with a point mass
of a third of its body's mass placed off-centre inside it: `excite` (simulated arm, default torque
noise) then `identify`, both through their Python functions as the verbs call them. Reported:
mass error (%), centre-of-mass error (mm), inertia-about-the-CoM error (largest relative principal-
moment error, %), the same two for uniform density (what `asset --mass-kg` assumes), and the wall
seconds of excite and identify. A noise sweep (0.01, 0.05, 0.2 N m) on the non-uniform can, and
with ``--evaluate`` the Drake evaluation of the non-uniform can's asset with identified and with
uniform-density properties against a reference that has the true ones.

    python benchmarks/bench_identify.py                      # every object, case and noise level
    python benchmarks/bench_identify.py --objects can --no-sweep --evaluate

Writes benchmarks/results/identify.md (machine, date, command).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import markdown_table, write_result  # noqa: E402

from real2sim.identify.stage import errors_against_truth  # noqa: E402

MASSES_KG = {"bottle": 0.45, "can": 0.35, "mug": 0.30}


def _extra_point(mesh) -> np.ndarray:
    """A point inside the object, off its centre: a third of the way from the centroid towards the
    box corner (+x, +y, low), moved back inwards until it is inside (a mug's wall, a bottle's shoulder)."""
    centre = np.asarray(mesh.center_mass)
    lo, hi = mesh.bounds
    target = np.array([hi[0], hi[1], lo[2] + 0.25 * (hi[2] - lo[2])])
    for f in np.linspace(0.6, 0.05, 12):
        p = centre + f * (target - centre)
        if mesh.contains([p])[0]:
            return p
    return centre


def _uniform_errors(mesh, mass_kg: float, truth: dict) -> tuple[float, float]:
    """(CoM error m, inertia error) of uniform density at the payload's total mass against the truth."""
    volume = float(mesh.volume)
    com = np.asarray(mesh.center_mass)
    inertia = np.asarray(mesh.moment_inertia) * (truth["mass_kg"] / volume)
    true_i = np.linalg.eigvalsh(np.asarray(truth["inertia_kg_m2"]))
    return (float(np.linalg.norm(com - np.asarray(truth["com_m"]))),
            float(np.max(np.abs(np.linalg.eigvalsh(inertia) - true_i) / true_i)))


def one_case(obj: str, extra: bool, noise: float, work: Path, seed: int = 0, duration_s: float | None = None) -> dict:
    from real2sim.geometry.objects import make_object
    from real2sim.identify.excitation import DEFAULT_DURATION_S, periods_for
    from real2sim.identify.stage import ExciteConfig, run_excite, run_identify

    mesh = make_object(obj)
    body = MASSES_KG[obj] / (1.5 if extra else 1.0)
    extra_kg = body / 2.0 if extra else 0.0  # a third of the total
    at = tuple(_extra_point(mesh)) if extra else None
    log_dir = work / f"{obj}_{'point' if extra else 'uniform'}_{noise:g}"
    saved = work / f"{log_dir.name}.json"
    if saved.is_file():  # --work of an earlier run: its results are kept, not recomputed
        return json.loads(saved.read_text())
    start = time.perf_counter()
    periods = periods_for(duration_s or DEFAULT_DURATION_S)
    truth = run_excite(mesh, ExciteConfig(mass_kg=body, extra_mass_kg=extra_kg, extra_mass_at_m=at, torque_noise_n_m=noise,
                                          seed=seed, periods=periods), log_dir, overwrite=True, say=lambda *_: None)
    excite_s = time.perf_counter() - start
    start = time.perf_counter()
    result, props = run_identify(log_dir)
    identify_s = time.perf_counter() - start
    err = errors_against_truth(props, truth)
    u_com, u_inertia = _uniform_errors(mesh, truth["mass_kg"], truth)
    case = {"object": obj, "case": "point mass" if extra else "uniform", "noise": noise, **err,
            "uniform_com_m": u_com, "uniform_inertia_rel": u_inertia, "excite_s": excite_s, "identify_s": identify_s,
            "condition": result.condition_number, "log": str(log_dir), "props": props, "truth": truth}
    saved.write_text(json.dumps(case))
    return case


def noise_spread(obj: str, work: Path, draws: int, noise: float = 0.05, duration_s: float | None = None) -> list[dict]:
    """The inertia error over ``draws`` independent draws of the torque noise on one motion: the object
    with its point mass simulated once without noise, then identified with fresh noise each time."""
    import dataclasses

    from real2sim.formats.joint_log import ROBOT_FILE, read_joint_log
    from real2sim.identify.arm import load_arm
    from real2sim.identify.solve import identify

    saved = work / f"{obj}_spread_{draws}.json"
    if saved.is_file():
        return json.loads(saved.read_text())
    clean_case = one_case(obj, True, 0.0, work, duration_s=duration_s)
    log_dir = Path(clean_case["log"])
    clean = read_joint_log(log_dir)
    arm = load_arm(log_dir / ROBOT_FILE, clean.flange_frame, clean.flange_from_object)
    rng = np.random.default_rng(1000)
    out = []
    for _ in range(draws):
        noisy = dataclasses.replace(clean, tau_n_m=clean.tau_n_m + rng.normal(scale=noise, size=clean.tau_n_m.shape))
        mass, com, inertia = identify(arm, noisy).properties()
        out.append(errors_against_truth({"mass_kg": mass, "com_m": com.tolist(), "inertia_kg_m2": inertia.tolist()},
                                        clean_case["truth"]))
    saved.write_text(json.dumps(out))
    return out


def evaluate_case(case: dict, work: Path, runs: int, spec: str = "cylinders:10") -> list[list]:
    """OCAE of the non-uniform object's asset with identified and with uniform properties, against a reference
    with the true ones (hydroelastic, push and ramp)."""
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.evaluate.sweep import EvaluationConfig, evaluate
    from real2sim.formats.physical import PhysicalProperties, moved_properties, write_physical_properties
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import export_object

    mesh_path = export_object(case["object"], work / f"{case['object']}.obj")
    truth = case["truth"]
    given = PhysicalProperties(case["props"]["mass_kg"], tuple(case["props"]["com_m"]),
                               tuple(map(tuple, case["props"]["inertia_kg_m2"])), "identified")
    rows = []
    for label, props in (("identified", given), ("uniform density", None)):
        config = AssetConfig(mass_kg=props.mass_kg if props else truth["mass_kg"], specs=(parse_spec(spec),),
                             given_properties=props, given_properties_frame="mesh", given_properties_source="bench")
        tag = f"{case['object']}_{label.replace(' ', '_')}_{spec.replace(':', '')}"
        asset = work / f"asset_{tag}"
        build_asset(mesh_path, asset, config, overwrite=True)
        transform = np.asarray(json.loads((asset / "canonical_transform.json").read_text())["T_asset_from_input"])
        true_props = PhysicalProperties(truth["mass_kg"], tuple(truth["com_m"]), tuple(map(tuple, truth["inertia_kg_m2"])))
        reference = work / f"reference_{tag}.json"
        write_physical_properties(moved_properties(true_props, transform), reference)
        result = evaluate([asset], work / f"results_{tag}",
                          EvaluationConfig(tasks=("push", "ramp"), contact_models=("hydroelastic",), runs=runs),
                          reference_properties=reference, overwrite=True)
        for r in result.summary:
            for task in ("push", "ramp"):
                done = [x for x in result.runs if x["task"] == task and x["representation"] == r["collision"]
                        and not x.get("error")]
                rows.append([case["object"], label, r["representation"], task, _mean(done, "ocae_m"),
                             _mean(done, "ate_m")])
            rows.append([case["object"], label, r["representation"], "both", r["ocae_m"], r["ate_m"]])
    return rows


def _mean(runs: list[dict], key: str) -> str:
    values = [float(x[key]) for x in runs]
    return f"{sum(values) / len(values):.4g}" if values else "-"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", default="bottle,can,mug")
    parser.add_argument("--no-sweep", action="store_true", help="skip the torque-noise sweep")
    parser.add_argument("--evaluate", action="store_true", help="also the Drake evaluation of the non-uniform can")
    parser.add_argument("--runs", type=int, default=3, help="evaluation runs per task (with --evaluate)")
    parser.add_argument("--representation", default="coacd",
                        help="collision geometry of the evaluated assets (default coacd: the nearest to the true "
                             "shape, so that what differs between the two assets is their mass properties)")
    parser.add_argument("--draws", type=int, default=10,
                        help="noise draws on one motion of the can with its point mass, for the spread (0: none)")
    parser.add_argument("--duration", type=float, default=None, help="seconds of exciting motion (default: excite's)")
    parser.add_argument("--note", default="", help="a line about the conditions (e.g. a shared machine)")
    parser.add_argument("--work", type=Path, default=None,
                        help="working folder (default: a new temporary one); cases already done there are reused")
    args = parser.parse_args()

    work = args.work or Path(tempfile.mkdtemp(prefix="bench_identify_"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("REAL2SIM_CACHE", str(work / "cache"))
    # each case its own noise draw (seed), so that the cases do not share their luck
    cases = [one_case(obj, extra, 0.05, work, seed=2 * i + extra, duration_s=args.duration)
             for i, obj in enumerate(args.objects.split(",")) for extra in (False, True)]
    sweep = [] if args.no_sweep else [one_case("can", True, noise, work, duration_s=args.duration) for noise in (0.01, 0.2)]
    trajectory = cases[0]["truth"]["trajectory"]
    duration_s = trajectory["periods"] * trajectory["period_s"] + 2 * trajectory["ramp_s"]
    target = lambda c: c["mass_rel"] <= 0.02 and c["com_m"] <= 2e-3 and c["inertia_rel"] <= 0.15  # noqa: E731
    rows = [[c["object"], c["case"], f"{MASSES_KG[c['object']]:.2f}", f"{100 * c['mass_rel']:.2f}",
             f"{1000 * c['com_m']:.2f}", f"{100 * c['inertia_rel']:.1f}", f"{1000 * c['uniform_com_m']:.2f}",
             f"{100 * c['uniform_inertia_rel']:.1f}", f"{c['excite_s']:.0f} + {c['identify_s']:.0f}",
             "yes" if target(c) else "no"] for c in cases]
    body = ("Identified against the truth (default torque noise 0.05 N m RMS, 1 kHz, friction, 2^20-count encoders; "
            f"a {duration_s:.0f} s exciting trajectory, designed for the smallest predicted inertia error; torques from a 2 kHz controller averaged over each 1 ms sample). Uniform density: what `asset --mass-kg` assumes, at the payload's true mass. "
            "Target: mass within 2 %, CoM within 2 mm, inertia within 15 %." + (f" {args.note}" if args.note else "")
            + "\n\n" + markdown_table(["object", "case", "mass kg", "mass err %", "CoM err mm", "inertia err %",
                                       "uniform CoM err mm", "uniform inertia err %", "excite + identify s",
                                       "target met"], rows) + "\n")
    if sweep:
        noise_rows = [[f"{c['noise']:g}", f"{100 * c['mass_rel']:.2f}", f"{1000 * c['com_m']:.2f}",
                       f"{100 * c['inertia_rel']:.1f}"]
                      for c in sorted(sweep + [c for c in cases if c["object"] == "can" and c["case"] == "point mass"],
                                      key=lambda c: c["noise"])]
        body += ("\nHow the errors grow with torque noise (the can with its point mass):\n\n"
                 + markdown_table(["torque noise N m", "mass err %", "CoM err mm", "inertia err %"], noise_rows) + "\n")
    if args.draws:
        spread = noise_spread("can", work, args.draws, duration_s=args.duration)
        inertia = np.array([d["inertia_rel"] for d in spread]) * 100
        com = np.array([d["com_m"] for d in spread]) * 1000
        body += (f"\nThe spread over noise: the can with its point mass simulated once without noise, identified under "
                 f"{len(spread)} independent draws of 0.05 N m noise: inertia error median {np.median(inertia):.1f} %, "
                 f"90th percentile {np.percentile(inertia, 90):.1f} %, largest {inertia.max():.1f} % "
                 f"({int(np.sum(inertia <= 15))} of {len(spread)} within 15 %); CoM error largest {com.max():.2f} mm.\n")
    command = "python benchmarks/bench_identify.py " + " ".join(sys.argv[1:])
    write_result("identify", "Mass properties identified from joint torques (issue #30)", body, command)
    if args.evaluate:
        rows = [row for c in cases if c["case"] == "point mass"
                for row in evaluate_case(c, work, args.runs, spec=args.representation)]
        body += (f"\nThe non-uniform objects in the evaluation ({args.representation}, hydroelastic, push and ramp, "
                 f"{args.runs} runs each) against a reference with the true mass properties:\n\n"
                 + markdown_table(["object", "properties", "representation", "task", "OCAE m", "ATE m"], rows) + "\n")
    print(write_result("identify", "Mass properties identified from joint torques (issue #30)", body, command))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
