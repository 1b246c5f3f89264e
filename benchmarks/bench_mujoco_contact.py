"""Benchmark: MuJoCo's contact settings for the evaluation, chosen by accuracy against the Drake reference.

Builds the bundled bottle and can with a few representations (URDF + MJCF), simulates each
object's Drake hydroelastic reference once per (task, run) and then, for every setting below,
every representation in MuJoCo under the evaluation's equation-error protocol
(:func:`real2sim.evaluate.mujoco.simulate.simulate_candidate_mujoco`), scored by the evaluation's
own code. The settings change one thing at a time from MuJoCo's defaults (Euler, pyramidal cone,
condim 3, solref 0.02 1, solimp 0.9 0.95 0.001 0.5 2, 1 ms), then combine the first round's best. The pick is the lowest mean OCAE over
every representation, object, task and run (ties: time) among the settings under which no resting
representation of any object sinks more than 1 mm into the floor (a softer contact damps the rolling by
sinking, which the object does not do), the rule that picked MujocoConfig's defaults on the can (over the
shape set a curved body's rest breaks it: docs/design-notes/evaluate.md#mujoco-beyond-the-can, where the
defaults are kept, and the results name them beside the pick); each object's own pick by
the same rule is listed beside it, to show whether one setting serves every shape.
``--assets`` takes asset folders already built (by ``bench_table1.py``, say: the shape set, the round
references) instead of building the bundled objects.

Then the speed target of issue #66: the same candidates with the picked setting in MuJoCo and with
Drake's point contact, back to back on this machine, each sweep's wall time (building, simulating
and scoring every row) and its summed ``sim_time_s``.

    python benchmarks/bench_mujoco_contact.py                      # 2 runs, push and ramp
    python benchmarks/bench_mujoco_contact.py --runs 3 --specs boxes:10 cylinders:10 coacd
    python benchmarks/bench_mujoco_contact.py --assets /work/t1shapes/assets/* --specs coacd boxes:10 cylinders:10

Work (assets, reference trajectories) is kept in benchmarks/out/mujoco_contact. Writes
benchmarks/results/mujoco_contact.md (machine and date included; load average at start and end).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, markdown_table, write_result  # noqa: E402

SPECS = ("boxes:10", "cylinders:10", "coacd")
OBJECTS = ("bottle", "can")
MUJOCO_DEFAULTS = dict(integrator="Euler", cone="pyramidal", condim=3, solref_timeconst_s=0.02, solref_dampratio=1.0,
                       solimp=(0.9, 0.95, 0.001, 0.5, 2.0), timestep_s=1e-3)
#: name -> what changes from MuJoCo's defaults.
SETTINGS = {
    "mujoco defaults": {},
    "implicitfast": {"integrator": "implicitfast"},
    "elliptic cone": {"cone": "elliptic"},
    "condim 4 (torsional)": {"condim": 4},
    "condim 6 (rolling)": {"condim": 6},
    "solref 0.005 s": {"solref_timeconst_s": 0.005},
    "solref 0.01 s": {"solref_timeconst_s": 0.01},
    "solref 0.04 s": {"solref_timeconst_s": 0.04},
    "dampratio 0.5": {"solref_dampratio": 0.5},
    "solimp hard (0.95 0.99)": {"solimp": (0.95, 0.99, 0.001, 0.5, 2.0)},
    "timestep 0.5 ms": {"timestep_s": 5e-4},
    # second round, around the first round's best (a softer solref, the elliptic cone)
    "solref 0.08 s": {"solref_timeconst_s": 0.08},
    "solref 0.04 s + elliptic": {"solref_timeconst_s": 0.04, "cone": "elliptic"},
    "solref 0.08 s + elliptic": {"solref_timeconst_s": 0.08, "cone": "elliptic"},
}


def build_assets(work: Path, specs: tuple[str, ...], objects: tuple[str, ...] = OBJECTS) -> list[Path]:
    """One asset per bundled object holding every SPEC, URDF and MJCF (kept in ``work``)."""
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import OBJECTS as BUNDLED
    from real2sim.geometry.objects import export_object

    assets = []
    for name in objects:
        asset = work / "assets" / name
        if not asset.is_dir():  # an asset kept in the work folder is used as it is (its representations)
            mesh = export_object(name, work / "objects" / name / "model.obj")
            start = time.perf_counter()
            build_asset(mesh, asset, AssetConfig(mass_kg=BUNDLED[name].mass_kg, specs=tuple(parse_spec(s) for s in specs),
                                                 formats=("urdf", "mjcf"), pca_up=True), overwrite=True)
            print(f"built {name} in {time.perf_counter() - start:.0f} s", flush=True)
        assets.append(asset)
    return assets


def references(assets: list[Path], tasks, runs: int, scene, work: Path) -> dict:
    """{(object, task, run): (RunSpec, Trajectory)}: Drake's hydroelastic reference, cached as .npz."""
    from real2sim.evaluate.discovery import discover_assets
    from real2sim.evaluate.jobs import reference_cache_name
    from real2sim.evaluate.scene.tasks import make_run_specs
    from real2sim.evaluate.simulate import simulate_reference
    from real2sim.formats.physical import read_physical_properties
    from real2sim.formats.trajectory import load_trajectory, save_trajectory

    out = {}
    for asset in discover_assets(assets):
        props = read_physical_properties(asset.physical_properties_path)
        for task in tasks:
            for spec in make_run_specs(task, runs, 0):
                cache = work / "reference_cache" / reference_cache_name(asset, asset.reference_mesh_path, spec, scene)
                if cache.is_file():
                    traj = load_trajectory(cache)
                else:
                    start = time.perf_counter()
                    traj = simulate_reference(asset.reference_mesh_path, props, spec, scene, object_contact=asset.contact)
                    save_trajectory(traj, cache)
                    print(f"reference {asset.name} {task} {spec.run}: {time.perf_counter() - start:.1f} s", flush=True)
                out[(asset.name, task, spec.run)] = (spec, traj)
    return out


def sweep(reps, refs: dict, scene, simulate) -> tuple[list[dict], float]:
    """Every representation on every reference with ``simulate(rep, spec, reference)``: scored rows
    and the sweep's wall time, s."""
    from real2sim.evaluate.scoring import score

    rows = []
    start = time.perf_counter()
    for rep in reps:
        for (obj, task, run), (spec, reference) in sorted(refs.items()):
            if obj != rep.object:
                continue
            values = score(reference, simulate(rep, spec, reference))
            rows.append(dict(values, object=obj, representation=rep.name, task=task, run=run))
    return rows, time.perf_counter() - start


#: The pick's bound on how deep a resting object sinks into the floor, m: Drake's hydroelastic reference
#: rests well under a millimetre deep, and a softer contact that damps by sinking is not the object.
MAX_REST_SINK_M = 1e-3


def rest_sink_m(rep, spec, reference, scene, cfg) -> float:
    """How deep the representation rests in the floor after 0.5 s, m (its lowest collision point below
    z = 0), set down as the reference starts, the pusher parked 1 m away."""
    import mujoco

    from real2sim.asset.export.mjcf import lowest_collision_z
    from real2sim.evaluate.mujoco.scene import build_mujoco_scene
    from real2sim.evaluate.mujoco.simulate import mujoco_state

    parked = dataclasses.replace(scene, pusher_start_distance_m=1.0, pusher_speed_m_per_s=0.0)
    built = build_mujoco_scene(rep.mjcf_path, spec, parked, cfg)
    m, d = built.model, built.data
    d.qpos[built.object_qpos], d.qvel[built.object_dof] = mujoco_state(reference, 0)
    d.qpos[built.actuated_qpos] = built.set_points[0]
    while d.time < 0.5:
        d.ctrl[:] = built.set_points[0]
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    return -lowest_collision_z(m, d)


def default_line(per_setting: dict, default) -> str:
    """Which measured setting ``default`` (the MujocoConfig in use) is, with its mean OCAE and deepest sink."""
    for name, (cfg, m, _) in per_setting.items():
        if cfg == default:
            return f"**{name}**, mean OCAE {m['ocae_m']:.4g} m, deepest resting sink {1000 * m['sink_m']:.3g} mm."
    return f"`{default}`, not among the settings measured."


def means(rows: list[dict]) -> dict:
    return {k: float(np.nanmean([r[k] for r in rows])) for k in ("ocae_m", "ate_m", "cpd_paper", "sim_time_s")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--tasks", default="push,ramp")
    parser.add_argument("--specs", nargs="+", default=list(SPECS))
    parser.add_argument("--objects", default=",".join(OBJECTS), help="comma-separated bundled objects")
    parser.add_argument("--duration-scale", type=float, default=1.0)
    parser.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "out" / "mujoco_contact")
    parser.add_argument("--settings", nargs="*", default=None, help="names of SETTINGS to try (default all)")
    parser.add_argument("--assets", type=Path, nargs="+", default=None,
                        help="asset folders already built (each named by its folder) instead of --objects")
    args = parser.parse_args()

    from real2sim.evaluate.discovery import discover_representations
    from real2sim.formats.contact import MujocoConfig
    from real2sim.evaluate.mujoco.simulate import simulate_candidate_mujoco
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.simulate import simulate_candidate

    load_start = os.getloadavg()
    k = args.duration_scale
    scene = SceneConfig()
    scene = dataclasses.replace(scene, push_duration_s=scene.push_duration_s * k, total_duration_s=scene.total_duration_s * k)
    tasks = tuple(args.tasks.split(","))
    from real2sim.formats.spec import parse_spec

    if args.assets:
        assets = list(args.assets)
        objects = tuple(a.name for a in assets)
    else:
        objects = tuple(args.objects.split(","))
        assets = build_assets(args.work, tuple(args.specs), objects)
    refs = references(assets, tasks, args.runs, scene, args.work)
    wanted = {parse_spec(s).name for s in args.specs}
    reps = [rep for rep in discover_representations(assets) if rep.name in wanted]
    pushes = {k[0]: v for k, v in sorted(refs.items(), reverse=True) if k[1] == "push"}  # each object's first push run

    table, per_setting = [], {}
    for name, change in SETTINGS.items():
        if args.settings and name not in args.settings:
            continue
        cfg = MujocoConfig(**{**MUJOCO_DEFAULTS, **change})
        rows, wall = sweep(reps, refs, scene,
                           lambda rep, spec, ref, cfg=cfg: simulate_candidate_mujoco(rep.mjcf_path, spec, scene, ref, cfg))
        m = means(rows)
        sinks = {o: max(rest_sink_m(rep, *pushes[o], scene, cfg) for rep in reps if rep.object == o) for o in pushes}
        sink = max(sinks.values()) if sinks else float("nan")
        m["sink_m"] = sink
        m["per_object"] = {o: (float(np.mean([r["ocae_m"] for r in rows if r["object"] == o])), sinks.get(o, np.nan))
                           for o in objects}
        per_setting[name] = (cfg, m, rows)
        by_task = {t: float(np.mean([r["ocae_m"] for r in rows if r["task"] == t])) for t in tasks}
        table.append([name, m["ocae_m"], *[by_task[t] for t in tasks], m["ate_m"], m["cpd_paper"], m["sim_time_s"], wall,
                      1000 * sink])
        print(f"{name}: OCAE {m['ocae_m']:.5f} m, ATE {m['ate_m']:.5f} m, sim {m['sim_time_s']:.4f} s, "
              f"sweep {wall:.1f} s", flush=True)
    allowed = [n for n in per_setting if not per_setting[n][1]["sink_m"] > MAX_REST_SINK_M] or list(per_setting)
    best = min(allowed, key=lambda n: (round(per_setting[n][1]["ocae_m"], 6), per_setting[n][1]["sim_time_s"]))
    chosen = per_setting[best][0]
    per_object = []  # each object's own pick by the same rule, and what the common pick costs it
    for o in objects:
        mine = [n for n in per_setting if not per_setting[n][1]["per_object"][o][1] > MAX_REST_SINK_M] or list(per_setting)
        own = min(mine, key=lambda n: per_setting[n][1]["per_object"][o][0])
        per_object.append([o, own, per_setting[own][1]["per_object"][o][0], per_setting[best][1]["per_object"][o][0],
                           per_setting["mujoco defaults"][1]["per_object"][o][0] if "mujoco defaults" in per_setting
                           else float("nan"), 1000 * per_setting[best][1]["per_object"][o][1]])

    # Back to back: the picked MuJoCo setting, then Drake's point contact, same candidates and references.
    mj_rows, mj_wall = sweep(reps, refs, scene, lambda rep, spec, ref: simulate_candidate_mujoco(
        rep.mjcf_path, spec, scene, ref, chosen))
    dk_rows, dk_wall = sweep(reps, refs, scene, lambda rep, spec, ref: simulate_candidate(
        rep.urdf_for("point"), "point", spec, scene, ref))
    load_end = os.getloadavg()
    mj, dk = means(mj_rows), means(dk_rows)
    per_rep = []
    for rep in sorted({(r["object"], r["representation"]) for r in mj_rows}):
        a = [r for r in mj_rows if (r["object"], r["representation"]) == rep]
        b = [r for r in dk_rows if (r["object"], r["representation"]) == rep]
        per_rep.append([*rep, means(a)["ocae_m"], means(b)["ocae_m"], means(a)["sim_time_s"], means(b)["sim_time_s"]])

    quiet = max(load_start[0], load_end[0]) < 1.5
    body = (
        f"Objects: {', '.join(objects)} ({'asset folders given' if args.assets else 'bundled'}). Representations: {', '.join(sorted({r.name for r in reps}))}. Tasks: {', '.join(tasks)}, "
        f"{args.runs} runs each (seed 0), duration scale {k:g}. Equation error (resets every 0.1 s) against Drake's "
        "hydroelastic simulation of the closed mesh, scored by the evaluation's code. Each setting changes one thing "
        "from MuJoCo's defaults, the last three combine the first round's best. Load average (1 min) at start "
        f"{load_start[0]:.1f}, at end {load_end[0]:.1f} on {os.cpu_count()} CPUs: "
        + ("a quiet machine." if quiet else "**under contention**: times are comparable only within this run.")
        + "\n\n"
        + markdown_table(["setting", "OCAE [m]", *[f"OCAE {t} [m]" for t in tasks], "ATE [m]", "cpd_paper",
                          "ST [s]", "sweep wall [s]", "rest sink [mm]"], table)
        + f"\n\nPicked (lowest mean OCAE among the settings whose resting sink, the deepest of every object's "
        f"representations after 0.5 s on the floor, stays within {1000 * MAX_REST_SINK_M:g} mm): **{best}** = `{chosen}`.\n\n"
        + f"MujocoConfig's defaults now: {default_line(per_setting, MujocoConfig())}\n\n"
        + "Each object's own pick by the same rule (its representations' mean OCAE, its own sink), beside the "
        "common pick and MuJoCo's defaults:\n\n"
        + markdown_table(["object", "own pick", "OCAE own pick [m]", f"OCAE {best} [m]", "OCAE defaults [m]",
                          f"rest sink {best} [mm]"], per_object)
        + "\n\n"
        + "Speed, back to back (the picked MuJoCo setting, then Drake point contact; every row built, simulated and "
        "scored in one process):\n\n"
        + markdown_table(["sweep", "rows", "wall [s]", "sum sim_time_s [s]", "mean OCAE [m]"],
                         [["MuJoCo", len(mj_rows), mj_wall, float(np.sum([r["sim_time_s"] for r in mj_rows])), mj["ocae_m"]],
                          ["Drake point", len(dk_rows), dk_wall, float(np.sum([r["sim_time_s"] for r in dk_rows])),
                           dk["ocae_m"]]])
        + f"\n\nDrake point / MuJoCo: wall x{dk_wall / mj_wall:.1f}, simulation time "
        f"x{np.sum([r['sim_time_s'] for r in dk_rows]) / np.sum([r['sim_time_s'] for r in mj_rows]):.1f} "
        "(issue #66's target: at least x5).\n\n"
        + markdown_table(["object", "representation", "OCAE MuJoCo [m]", "OCAE Drake point [m]", "ST MuJoCo [s]",
                          "ST Drake point [s]"], per_rep)
    )
    command = "python benchmarks/bench_mujoco_contact.py " + " ".join(sys.argv[1:])
    path = write_result("mujoco_contact", "MuJoCo contact settings against the Drake reference (bench_mujoco_contact.py)",
                        body, command.strip())
    print(body)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
