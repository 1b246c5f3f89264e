"""Benchmark: MuJoCo simulation speed of each representation of the bottle, beside Drake's.

Builds the bundled bottle's asset with the demo's representations (flat bottom, URDF +
MJCF; or uses ``--asset DIR``, an asset built with ``--format mjcf``), then for every
representation:

* MuJoCo, resting: dropped 1 mm onto a floor plane, 1 s simulated;
* MuJoCo, pushed: a kinematic (mocap) sphere of the evaluation's pusher radius moves
  through the object's place at the pusher's speed for the push task's duration;
* Drake, pushed, point contact: the evaluation's push task, run 0 (one rollout, no
  reference), timed by the simulator itself (``sim_time_s``).

Both simulators step at the evaluation's 1 ms. Reported: wall seconds per simulated
second (lower is faster). MuJoCo's number is the bare ``mj_step`` loop; Drake's is its
timed run without logging (see real2sim.evaluate.simulate).

    python benchmarks/bench_mujoco.py            # builds the asset (about a minute)
    python benchmarks/bench_mujoco.py --asset ASSETDIR

Writes benchmarks/results/mujoco.md (machine and date included).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import markdown_table, write_result  # noqa: E402

SPECS = ("cylinders:10", "boxes:50", "spheres:64", "ellipsoids:32", "rotated_boxes:20", "superquadrics:5", "coacd",
         "mesh")


def build_bottle_asset(out: Path) -> Path:
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec
    from real2sim.geometry.objects import OBJECTS, export_object

    mesh = export_object("bottle", out / "bottle_mesh" / "bottle.obj")
    config = AssetConfig(mass_kg=OBJECTS["bottle"].mass_kg, specs=tuple(parse_spec(s) for s in SPECS),
                         flat_bottom=True, formats=("urdf", "mjcf"))
    return build_asset(mesh, out / "bottle_asset", config,
                       progress=lambda m, done, total: total or print(m, flush=True)).asset_dir


def mujoco_rates(model_xml: Path, pusher_radius_m: float, pusher_speed_m_per_s: float, push_s: float,
                 time_step_s: float) -> dict:
    """Wall seconds per simulated second resting (1 s) and pushed (``push_s``), and the push's travel."""
    import mujoco

    from real2sim.asset.export.mjcf import lowest_collision_z

    def scene(with_pusher: bool):
        spec = mujoco.MjSpec.from_file(str(model_xml))
        spec.option.timestep = time_step_s
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2.0, 2.0, 0.01])
        if with_pusher:
            pusher = spec.worldbody.add_body(name="pusher", mocap=True)
            pusher.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[pusher_radius_m, 0, 0])
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        data.qpos[2] += 0.001 - lowest_collision_z(model, data)
        mujoco.mj_forward(model, data)
        return model, data

    model, data = scene(False)
    t0 = time.perf_counter()
    while data.time < 1.0:
        mujoco.mj_step(model, data)
    rest = (time.perf_counter() - t0) / data.time

    model, data = scene(True)
    start_x = -(0.12 + pusher_radius_m)  # centre 12 cm + radius behind the object's origin, along +x
    data.mocap_pos[0] = [start_x, 0.0, pusher_radius_m + 0.002]
    x0 = data.qpos[:3].copy()
    t0 = time.perf_counter()
    while data.time < push_s:
        data.mocap_pos[0, 0] = start_x + pusher_speed_m_per_s * data.time
        mujoco.mj_step(model, data)
    push = (time.perf_counter() - t0) / data.time
    return {"rest": rest, "push": push, "travel_mm": 1000 * float(np.linalg.norm(data.qpos[:2] - x0[:2]))}


def drake_push_rate(urdf: Path) -> float:
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.simulate import simulate_candidate
    from real2sim.evaluate.scene.tasks import make_run_specs, run_duration_s

    cfg = SceneConfig()
    run = make_run_specs("push", 1, 0)[0]
    traj = simulate_candidate(urdf, "point", run, cfg)
    return traj.sim_time_s / run_duration_s("push", cfg)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", type=Path, default=None, help="an asset folder built with --format mjcf")
    args = parser.parse_args()
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.scene.tasks import run_duration_s

    cfg = SceneConfig()
    with tempfile.TemporaryDirectory() as tmp:
        asset = args.asset or build_bottle_asset(Path(tmp))
        rows = []
        for rep in sorted(p.parent for p in Path(asset).glob("*/model.xml")):
            mj = mujoco_rates(rep / "model.xml", cfg.pusher_radius_m, cfg.pusher_speed_m_per_s,
                              run_duration_s("push", cfg), cfg.time_step_s)
            drake = drake_push_rate(rep / "model.urdf")
            print(f"{rep.name}: MuJoCo rest {mj['rest']:.4f}, push {mj['push']:.4f}; Drake point push {drake:.4f} "
                  "wall s per sim s", flush=True)
            rows.append([rep.name, mj["rest"], mj["push"], drake, drake / mj["push"], mj["travel_mm"]])
    body = (
        "Wall seconds per simulated second (lower is faster) of each representation of the bundled bottle "
        "(flat bottom, the demo's SPECs plus `mesh`), both simulators at a 1 ms step. MuJoCo resting: "
        "dropped 1 mm onto a plane, 1 s. MuJoCo pushed: a kinematic sphere of the evaluation's pusher "
        f"radius ({cfg.pusher_radius_m} m) moving at {cfg.pusher_speed_m_per_s} m/s for the push task's "
        f"{run_duration_s('push', cfg):g} s. Drake: the evaluation's push task (run 0, point contact, one rollout). "
        "MuJoCo's `mesh` row is the mesh's convex hull (MuJoCo collides meshes as hulls).\n\n"
        + markdown_table(["representation", "MuJoCo rest", "MuJoCo push", "Drake push (point)",
                          "Drake / MuJoCo (push)", "MuJoCo push travel (mm)"], rows)
    )
    path = write_result("mujoco", "MuJoCo vs Drake simulation speed per representation (bench_mujoco.py)", body,
                         "python benchmarks/bench_mujoco.py" + (f" --asset {args.asset}" if args.asset else ""))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
