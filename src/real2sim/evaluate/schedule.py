"""How the sweep's simulations run on an executor: every reference first, each one's candidates as soon
as it is done, and runs.csv rewritten as rows finish (:func:`real2sim.evaluate.sweep.evaluate` plans
them and publishes the results)."""

from __future__ import annotations

import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from real2sim.evaluate.executors import Retry
from real2sim.evaluate.jobs import (CandidateJob, ReferenceJob, reference_cache_name, run_candidate_job,
                                    run_reference_job, runs_row)
from real2sim.evaluate.scene.placement import StablePoseCache
from real2sim.formats.results import relative_paths_in_text, row_key, write_runs_csv
from real2sim.plumbing.progress import ProgressFn


@contextmanager
def _checkpoint_on_exit(runs_path: Path, rows: dict):
    """Write runs.csv however the sweep ends (an interrupt keeps every finished row)."""
    try:
        yield
    finally:
        write_runs_csv(runs_path, sorted(rows.values(), key=row_key))


def _private(row: dict, target: Path) -> dict:
    """``row`` with the absolute paths in its error text made relative to the results folder."""
    if row.get("error"):
        row = dict(row, error=relative_paths_in_text(row["error"], target))
    return row


def _reference_failed(payload: str) -> str:
    # A timeout keeps "timeout" as the reason the row records; its text names the reference.
    return payload if payload.startswith("timeout:") else f"reference simulation failed: {payload}"


def _stable_poses(mesh_path: Path, properties: Path) -> StablePoseCache:
    """The reference object's resting poses, found here once rather than in every reference job.
    A failure leaves the cache empty: each job then meets it again and records it in its rows."""
    cache = StablePoseCache()
    try:
        from real2sim.geometry.mesh_io import load_mesh
        from real2sim.formats.physical import read_physical_properties

        vertices = np.asarray(load_mesh(Path(mesh_path)).vertices, dtype=float)
        cache.rotations(vertices, read_physical_properties(properties).com_m)
    except Exception:  # noqa: BLE001 -- the job reports it, with the reference's name
        pass
    return cache


def _phase(pending: dict) -> str:
    """The sweep's progress label: whether a reference is still among the ``pending`` jobs."""
    if any(kind == "ref" for kind, _, _ in pending.values()):
        return "reference and candidate simulations"
    return "candidate simulations"


def run_simulations(executor, todo, spec_by, asset_by_name, reference_meshes, config, partial, rows, runs_path,
                    progress: ProgressFn, target: Path, reference_properties: Path | None = None) -> int:
    """Simulate every reference of ``todo`` (the sweep's plan: (representation, contact model, simulator)
    candidates by (object, task, run)), then
    its candidates, as ``executor`` finishes them; each finished row goes into ``rows`` and, at least
    once a second, into ``runs_path``. Returns how many candidate rows were written.

    ``progress`` counts both, references first: ("reference and candidate simulations", done, total)
    while a reference is still running (the candidates of finished ones run beside it), then
    ("candidate simulations", done, total), so a profile sees how long the references hold the sweep."""
    total = len(todo) + sum(len(v) for v in todo.values())
    pending: dict[Any, tuple[str, Any, Any]] = {}  # handle -> (kind "ref" or "cand", row key, job)
    resting: dict[tuple[Path, Path], StablePoseCache] = {}  # one per reference object, for this sweep
    for (obj, task, run), _ in sorted(todo.items()):
        asset = asset_by_name[obj]
        spec = spec_by[(task, run)]
        properties = reference_properties or asset.physical_properties_path
        cache = partial / "reference_cache" / reference_cache_name(asset, reference_meshes[obj], spec, config.scene,
                                                                   properties)
        poses = None
        if not cache.is_file():  # it will be simulated: its resting poses, found once per object
            poses = resting.get((reference_meshes[obj], properties))
            if poses is None:
                poses = resting[(reference_meshes[obj], properties)] = _stable_poses(reference_meshes[obj], properties)
        job = ReferenceJob(obj, task, run, reference_meshes[obj], properties, spec, config.scene,
                           cache, asset.contact, config.sim_timeout_s, poses)
        pending[executor.submit(run_reference_job, job)] = ("ref", (obj, task, run), job)

    simulated = done = 0
    last_write = 0.0
    progress(_phase(pending), 0, total)
    with _checkpoint_on_exit(runs_path, rows):
        while pending:
            for handle in executor.wait(set(pending)):
                kind, key, job = pending.pop(handle)
                result = executor.result(handle)
                if isinstance(result, Retry):
                    pending[executor.submit(result.fn, result.arg, result.attempt)] = (kind, key, job)
                    continue
                done += 1
                if kind == "ref":
                    status, payload = result
                    for rep, cm, sim in todo[key]:
                        ckey = (rep.object, rep.name, cm, sim, key[1], key[2])
                        if status != "ok":
                            rows[ckey] = _private(runs_row(ckey, error=_reference_failed(payload)), target)
                            done += 1
                            simulated += 1
                            continue
                        cjob = CandidateJob(rep.object, rep.name, cm, key[1], key[2], rep.urdf_for(cm), job.run_spec,
                                            config.scene, config.simulation_error, payload, config.sim_timeout_s,
                                            simulator=sim, model_xml_path=rep.mjcf_path, mujoco=config.mujoco)
                        pending[executor.submit(run_candidate_job, cjob)] = ("cand", ckey, cjob)
                else:
                    rows[key] = _private(result, target)
                    simulated += 1
                progress(_phase(pending), done, total)
                now = time.monotonic()
                if now - last_write > 1.0 or not pending:
                    write_runs_csv(runs_path, sorted(rows.values(), key=row_key))
                    last_write = now
    return simulated
