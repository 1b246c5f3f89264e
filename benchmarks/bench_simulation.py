"""Benchmark: Drake simulation speed of collision representations (paper Table I "ST").

Builds a bottle asset (the bundled squeeze bottle, canonicalized, exact uniform-density
inertia) with cheap stand-in representations of the sizes the paper compares
(voxel boxes, voxel spheres, z-slab cylinders, the mesh itself: no fitting, so the
benchmark measures the simulator, not the fitter), simulates the reference once per task
and each representation with point and hydroelastic contact under equation error, and
reports wall seconds per simulated second of the bare timed run, the per-step logging
overhead of the instrumented run, and the ATE against the reference.

    python benchmarks/bench_simulation.py            # push + ramp, default scene durations
    python benchmarks/bench_simulation.py --quick    # 0.5 s scenes

Writes benchmarks/results/simulation.md and .json (machine, date, command) via benchmarks/common.py.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from real2sim.asset.export.writers import write_representation
from real2sim.asset.canonical import canonicalize
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.contact import ContactProperties
from real2sim.geometry.inside import inside_mask
from real2sim.geometry.objects import OBJECTS, make_object
from real2sim.formats.physical import PhysicalProperties
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import make_run_specs, run_duration_s
from real2sim.evaluate.simulate import simulate_candidate, simulate_reference

IDENTITY_Q = (1.0, 0.0, 0.0, 0.0)


def _voxel_centres(mesh: trimesh.Trimesh, count: int) -> tuple[np.ndarray, float]:
    """Filled-voxel centres of ``mesh`` with a pitch chosen so there are about ``count``."""
    pitch = (mesh.volume / count) ** (1 / 3)
    for _ in range(12):
        centres = mesh.voxelized(pitch).fill().points
        centres = centres[inside_mask(mesh, centres)]  # keep stand-ins from bulging far out
        if abs(len(centres) - count) <= 0.1 * count:
            break
        pitch *= (len(centres) / count) ** (1 / 3)
    return centres, pitch


def stand_in_representations(mesh: trimesh.Trimesh, root: Path, props: PhysicalProperties) -> dict[str, Path]:
    """Write representation folders under ``root``; returns name -> model.urdf."""
    contact = ContactProperties()
    reps: dict[str, tuple[CollisionShape, ...]] = {}
    for n in (10, 150):
        centres, pitch = _voxel_centres(mesh, n)
        reps[f"boxes_{len(centres)}"] = tuple(
            CollisionShape("box", (pitch, pitch, pitch), tuple(c), IDENTITY_Q) for c in centres)
    centres, pitch = _voxel_centres(mesh, 128)
    reps[f"spheres_{len(centres)}"] = tuple(
        CollisionShape("sphere", (0.62 * pitch,), tuple(c), IDENTITY_Q) for c in centres)
    # Cylinders: 10 slabs along the asset z axis, radius = the slab's largest radial extent.
    pts, _ = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    edges = np.linspace(pts[:, 2].min(), pts[:, 2].max(), 11)
    cyl = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = pts[(pts[:, 2] >= lo) & (pts[:, 2] <= hi)]
        r = float(np.median(np.linalg.norm(inside[:, :2], axis=1)))
        cyl.append(CollisionShape("cylinder", (r, hi - lo), (0.0, 0.0, (lo + hi) / 2), IDENTITY_Q))
    reps["cylinders_10"] = tuple(cyl)
    out = {}
    for name, shapes in reps.items():
        d = root / name
        write_representation(d, CollisionGeometry(name, name, shapes), props, contact)
        out[name] = d / "model.urdf"
    d = root / "mesh"
    d.mkdir()
    mesh.export(d / "mesh.obj")
    write_representation(d, CollisionGeometry("mesh", "mesh", (
        CollisionShape("mesh", (), (0.0, 0.0, 0.0), IDENTITY_Q, "mesh.obj"),)), props, contact)
    out["mesh"] = d / "model.urdf"
    return out


def bottle_asset(root: Path) -> tuple[Path, PhysicalProperties, dict[str, Path]]:
    mesh, _ = canonicalize(make_object("bottle"))
    mass = OBJECTS["bottle"].mass_kg
    (root / "visual").mkdir(parents=True)
    mesh_path = root / "visual" / "model.obj"
    mesh.export(mesh_path)
    # A watertight mesh's exact uniform-density mass properties.
    scaled = mesh.copy()
    scaled.density = mass / mesh.volume
    props = PhysicalProperties(mass, tuple(scaled.center_mass),
                               tuple(map(tuple, scaled.moment_inertia)), method="trimesh exact")
    return mesh_path, props, stand_in_representations(mesh, root, props)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="0.5 s scenes instead of the defaults")
    ap.add_argument("--tasks", default="push,ramp")
    args = ap.parse_args(argv)
    cfg = SceneConfig()
    if args.quick:
        cfg = dataclasses.replace(cfg, settle_s=0.1, push_duration_s=0.4, pusher_start_distance_m=0.15,
                                  hold_s=0.05, tilt_time_s=0.35, total_duration_s=0.5)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        mesh_path, props, reps = bottle_asset(Path(tmp) / "bottle")
        n_faces = len(trimesh.load(mesh_path, force="mesh").faces)
        for task in args.tasks.split(","):
            spec = make_run_specs(task, 1, seed=0)[0]
            ref = simulate_reference(mesh_path, props, spec, cfg)
            rows.append(("reference (mesh, rigid hydro)", "hydroelastic", task, ref, float("nan")))
            print(f"{task} reference: {ref.instrumented_time_s / ref.sim_duration_s:.2f} s/s (instrumented; a reference is not timed)", flush=True)
            for name, urdf in reps.items():
                for cm in ("point", "hydroelastic"):
                    try:
                        tr = simulate_candidate(urdf, cm, spec, cfg, reference=ref)
                    except Exception as e:  # report, keep benchmarking the others
                        print(f"{task} {name} {cm}: FAILED {e}", flush=True)
                        continue
                    ate = float(np.linalg.norm(tr.object_position_m - ref.object_position_m, axis=1).mean())
                    rows.append((name, cm, task, tr, ate))
                    print(f"{task} {name:>12} {cm:>12}: {tr.sim_time_s / tr.sim_duration_s:.2f} s/s  "
                          f"logging x{tr.instrumented_time_s / tr.sim_time_s:.2f}  ATE {ate * 1e3:.2f} mm",
                          flush=True)
    header = ("| representation | contact | task | wall s / sim s (timed) | instrumented / timed | "
              "equation-error ATE (mm) |\n|---|---|---|---|---|---|")
    # a reference is not timed: its row gives the instrumented run's rate
    lines = [f"| {n} | {cm} | {task} | "
             + (f"{t.instrumented_time_s / t.sim_duration_s:.2f} (instrumented) | |" if np.isnan(t.sim_time_s) else
                f"{t.sim_time_s / t.sim_duration_s:.2f} | {t.instrumented_time_s / t.sim_time_s:.2f} |")
             + f" {'' if np.isnan(a) else f'{a * 1e3:.2f}'} |"
             for n, cm, task, t, a in rows]
    table = header + "\n" + "\n".join(lines)
    print(table)
    load = os.getloadavg()
    text = f"""Load average at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (on a shared machine wall times are
inflated and noisy).

Object: the bundled squeeze bottle (0.6 kg, canonical frame), reference = its mesh
({n_faces} faces) as a rigid hydroelastic body. Stand-in representations of the paper's sizes
(voxel boxes and spheres, 10 z-slab cylinders, the mesh itself) instead of fitted ones, so
the numbers measure Drake, not the fitter. One run per task; scene durations
{run_duration_s('push', cfg):.2f} s (push) and {run_duration_s('ramp', cfg):.2f} s (ramp); time step
{cfg.time_step_s * 1e3:g} ms, `{cfg.discrete_contact_approximation}` approximation, equation error
(resets every {cfg.reset_interval_s} s).

"wall s / sim s" is the bare timed run (`Trajectory.sim_time_s / sim_duration_s`, resets included);
"instrumented / timed" is the wall-time ratio of the per-step logging run (state + contact
results read from Python every step) to the timed run. The ATE column is a sanity check
of the reset machinery (the mesh with hydroelastic contact is the reference itself: 0 by
construction), not a comparison of representations: the stand-ins are crude (voxel boxes
and spheres bulge past the surface; circular cylinders do not fit the bottle's oval
section), so they start each interval interpenetrating the floor. Fitted representations
are compared by `real2sim evaluate`.

{table}
"""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import write_result

    command = "python benchmarks/bench_simulation.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(f"wrote {write_result('simulation', 'Simulation speed (benchmarks/bench_simulation.py)', text, command.strip())}")
    return 0


if __name__ == "__main__":
    t0 = time.time()
    rc = main()
    print(f"total {time.time() - t0:.0f} s")
    sys.exit(rc)
