"""Animations of one run of each task: the reference and a chosen representation side by side.

Each animation is a self-contained HTML page written by Drake's Meshcat
(``Meshcat.StaticHtml``: the viewer's JavaScript and every mesh are inlined, so it
opens with no network). The reference's trajectory comes from the sweep's reference
cache; the representation is simulated once more from the same initial state as a
**free roll-out** (no equation-error resets, which would pull it back onto the
reference every 0.1 s and hide how it differs). Both are replayed kinematically: the
object, the pusher (push) or the tilting table (ramp), side by side along +x.

``RESULTS/animations/<task>.html``, linked from report.html.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Mapping

import numpy as np

from real2sim.evaluate.discovery import Representation

ANIMATION_DIRNAME = "animations"
FRAMES_PER_SECOND = 30
SIDE_BY_SIDE_OFFSET_M = 1.0  # the candidate's scene sits this far along +x (the ramp is 0.8 m wide)
REFERENCE_RGBA = (0.75, 0.75, 0.78, 1.0)
CANDIDATE_RGBA = (0.90, 0.45, 0.10, 1.0)


def _pose(position, quaternion_wxyz, offset_x_m: float = 0.0):
    from pydrake.common.eigen_geometry import Quaternion
    from pydrake.math import RigidTransform

    q = np.asarray(quaternion_wxyz, dtype=float)
    q = q / np.linalg.norm(q)
    return RigidTransform(Quaternion(q), np.asarray(position, dtype=float) + [offset_x_m, 0.0, 0.0])


def _drake_shape(shape, rep_dir: Path):
    from pydrake.geometry import Box, Capsule, Convex, Cylinder, Ellipsoid, Mesh, Sphere

    s = shape.size_m
    if shape.kind == "box":
        return Box(*s)
    if shape.kind == "sphere":
        return Sphere(s[0])
    if shape.kind == "cylinder":
        return Cylinder(s[0], s[1])
    if shape.kind == "capsule":
        return Capsule(s[0], s[1])
    if shape.kind == "ellipsoid":
        return Ellipsoid(*s)
    path = str(rep_dir / shape.mesh_file)
    return Convex(path) if shape.kind == "convex" else Mesh(path)


def _environment(meshcat, task: str, scene, prefix: str) -> None:
    """The task's moving part under ``prefix`` (placed each frame by :func:`_environment_pose`)."""
    from pydrake.geometry import Box, Rgba, Sphere
    from pydrake.math import RigidTransform

    if task == "push":
        meshcat.SetObject(f"{prefix}/pusher", Sphere(scene.pusher_radius_m), Rgba(0.2, 0.4, 0.9, 1.0))
    else:
        lx, ly, lz = scene.table_size_m
        meshcat.SetObject(f"{prefix}/table/slab", Box(lx, ly, lz), Rgba(0.55, 0.45, 0.35, 1.0))
        meshcat.SetTransform(f"{prefix}/table/slab", RigidTransform([0.0, -ly / 2, -lz / 2]))


def _environment_pose(task: str, scene, actuated: np.ndarray, offset_x_m: float):
    from pydrake.math import RigidTransform, RollPitchYaw

    if task == "push":
        height = scene.pusher_radius_m + scene.pusher_clearance_m
        return "pusher", RigidTransform([actuated[0] + offset_x_m, actuated[1], height])
    return "table", RigidTransform(RollPitchYaw(float(actuated[0]), 0.0, 0.0), [offset_x_m, 0.0, scene.hinge_height_m])


def write_animation(reference, candidate, reference_mesh: Path, rep_dir: Path, scene, out_path: Path,
                    title: str) -> Path:
    """Write the side-by-side animation of ``reference`` and ``candidate`` (Trajectories of one run)
    to ``out_path`` (HTML, self-contained)."""
    from pydrake.geometry import Meshcat, MeshcatAnimation, MeshcatParams, Rgba
    from pydrake.geometry import Mesh as DrakeMesh

    from real2sim.formats.collision import read_collision_json
    from real2sim.plumbing.outputs import write_text_atomic

    drake_log = logging.getLogger("drake")
    level = drake_log.level
    drake_log.setLevel(logging.WARNING)  # "Meshcat listening at ..." is noise: nobody connects to it
    try:
        meshcat = Meshcat(MeshcatParams(host="localhost", port=None, show_stats_plot=False))
    finally:
        drake_log.setLevel(level)
    try:
        meshcat.SetObject("reference/object/mesh", DrakeMesh(str(reference_mesh)), Rgba(*REFERENCE_RGBA))
        geometry = read_collision_json(rep_dir / "collision.json")
        for k, shape in enumerate(geometry.shapes):
            path = f"candidate/object/collision_{k:04d}"
            meshcat.SetObject(path, _drake_shape(shape, rep_dir), Rgba(*CANDIDATE_RGBA))
            meshcat.SetTransform(path, _pose(shape.position_m, shape.quaternion_wxyz))
        task = reference.task
        _environment(meshcat, task, scene, "reference")
        _environment(meshcat, task, scene, "candidate")
        animation = MeshcatAnimation(FRAMES_PER_SECOND)
        duration = min(float(reference.times_s[-1]), float(candidate.times_s[-1]))
        for frame in range(int(duration * FRAMES_PER_SECOND) + 1):
            t = frame / FRAMES_PER_SECOND
            for name, traj, offset in (("reference", reference, 0.0), ("candidate", candidate, SIDE_BY_SIDE_OFFSET_M)):
                i = min(int(np.searchsorted(traj.times_s, t)), len(traj.times_s) - 1)
                animation.SetTransform(frame, f"{name}/object",
                                       _pose(traj.object_position_m[i], traj.object_quaternion_wxyz[i], offset))
                part, pose = _environment_pose(task, scene, traj.actuated_positions[i], offset)
                animation.SetTransform(frame, f"{name}/{part}", pose)
        mid_x = SIDE_BY_SIDE_OFFSET_M / 2
        if task == "push":
            meshcat.SetCameraPose([mid_x, -1.3, 0.7], [mid_x, 0.0, 0.05])
        else:
            meshcat.SetCameraPose([mid_x + 0.3, -2.6, 1.6], [mid_x, -0.5, 0.3])
        meshcat.SetAnimation(animation)
        html = meshcat.StaticHtml()
    finally:
        del meshcat  # closes its server
    html = html.replace("<title>", f"<title>{title} &mdash; ", 1) if "<title>" in html else html
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_path, html)
    return out_path


def write_animations(results_dir: Path | str, summary: list[Mapping], preference: str = "accuracy",
                     timeout_s: float | None = 600.0) -> dict[str, Path]:
    """One animation per task of ``results_dir`` (run 0 of its first asset): the reference beside the
    representation recommended for ``preference``. Returns {task: HTML path}; {} when the sweep
    has no usable row or no cached reference."""
    from real2sim.evaluate.scene.scene_config import SceneConfig
    from real2sim.evaluate.simulate import simulate_candidate
    from real2sim.evaluate.scene.tasks import make_run_specs
    from real2sim.formats.trajectory import load_trajectory
    from real2sim.report.pareto import recommend

    results_dir = Path(results_dir)
    config = json.loads((results_dir / "config.json").read_text())
    chosen = recommend(summary, preference, simulator="drake")  # the animation is Drake's Meshcat
    assets = config.get("assets") or {}
    if chosen is None or not assets:
        return {}
    asset_name = sorted(assets)[0]
    asset_dir = (results_dir / assets[asset_name]).resolve()
    rep_dir = asset_dir / str(chosen["collision"])
    reference_mesh = (results_dir / config["reference_meshes"][asset_name]).resolve()
    fields = {f.name for f in dataclasses.fields(SceneConfig)}
    scene = SceneConfig(**{k: tuple(v) if isinstance(v, list) else v
                           for k, v in config["scene"].items() if k in fields})
    free = dataclasses.replace(scene, reset_interval_s=None)
    written = {}
    for task in config.get("tasks", []):
        cached = sorted((results_dir / "reference_cache").glob(f"{asset_name}_{task}_0_*.npz"))
        if not cached or not (rep_dir / "model.urdf").is_file() or not reference_mesh.is_file():
            continue
        reference = load_trajectory(cached[0])
        run_spec = make_run_specs(task, 1, int(config.get("seed", 0)))[0]
        model = Representation.at(asset_name, rep_dir).urdf_for(str(chosen["contact_model"]))
        candidate = simulate_candidate(model, str(chosen["contact_model"]), run_spec, free,
                                       reference, timeout_s=timeout_s, timed=False)  # shown, not timed
        title = (f"{task}: reference (grey) and {chosen['collision']} with {chosen['contact_model']} contact "
                 f"(orange, free roll-out)")
        written[task] = write_animation(reference, candidate, reference_mesh, rep_dir, scene,
                                        results_dir / ANIMATION_DIRNAME / f"{task}.html", title)
    return written
