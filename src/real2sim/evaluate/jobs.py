"""One reference simulation or one candidate simulation, as a picklable job.

Jobs are module-level functions over frozen dataclasses so that they run unchanged in
this process, in a spawned worker or on Ray. A job never raises: a failure becomes the
error text of its rows.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from real2sim.evaluate.discovery import Asset
from real2sim.formats.contact import ContactProperties, MujocoConfig
from real2sim.evaluate.scene.placement import StablePoseCache
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import RunSpec
from real2sim.evaluate.scoring import score
from real2sim.evaluate.simulate import SimulationTimeout
from real2sim.formats.results import FLOAT_COLUMNS, KEY_COLUMNS
from real2sim.formats.trajectory import load_trajectory, save_trajectory


@dataclass(frozen=True)
class ReferenceJob:
    object: str
    task: str
    run: int
    mesh_path: Path
    physical_properties_path: Path
    run_spec: RunSpec
    scene: SceneConfig
    cache_path: Path | None = None
    contact: ContactProperties | None = None  # the asset's own material, so the reference is the same object
    sim_timeout_s: float | None = None  # wall-clock limit of the simulation (None: none)
    stable_poses: StablePoseCache | None = None  # the object's resting poses, found once by the sweep


@dataclass(frozen=True)
class CandidateJob:
    object: str
    representation: str
    contact_model: str
    task: str
    run: int
    urdf_path: Path
    run_spec: RunSpec
    scene: SceneConfig
    simulation_error: bool
    reference: Any  # Trajectory
    sim_timeout_s: float | None = None  # wall-clock limit of the simulation (None: none)
    simulator: str = "drake"  # "drake": urdf_path in Drake; "mujoco": model_xml_path in MuJoCo
    model_xml_path: Path | None = None  # the representation's MuJoCo model (simulator "mujoco")
    mujoco: MujocoConfig | None = None  # MuJoCo's settings (simulator "mujoco"; None: the defaults)

    @property
    def key(self) -> tuple:
        return (self.object, self.representation, self.contact_model, self.simulator, self.task, self.run)


def one_line(exc: BaseException) -> str:
    """``exc`` as one line of at most 500 characters, for a row's error text: a timeout's own message
    (it starts with "timeout:", the reason the row records), any other prefixed by its type."""
    text = str(exc) if isinstance(exc, SimulationTimeout) else f"{type(exc).__name__}: {exc}"
    return text.strip().replace("\r", " ").replace("\n", " | ")[:500]


def run_reference_job(job: ReferenceJob) -> tuple[str, Any]:
    """Simulate (or load from the cache) one reference trajectory: ("ok", Trajectory) or ("error", text)."""
    try:
        if job.cache_path is not None and job.cache_path.is_file():
            try:
                return "ok", load_trajectory(job.cache_path)
            except Exception:
                pass  # a damaged cache file is simulated again
        from real2sim.formats.physical import read_physical_properties
        from real2sim.evaluate.simulate import simulate_reference

        props = read_physical_properties(job.physical_properties_path)
        traj = simulate_reference(job.mesh_path, props, job.run_spec, job.scene, object_contact=job.contact,
                                  timeout_s=job.sim_timeout_s, stable_poses=job.stable_poses)
        if job.cache_path is not None:
            save_trajectory(traj, job.cache_path)
        return "ok", traj
    except Exception as exc:  # recorded in the rows of every candidate of this run
        return "error", one_line(exc)


def runs_row(job_key: tuple, **values) -> dict:
    """A runs.csv row: ``job_key``'s key columns, every float column (NaN where ``values`` has none)
    and the ``error`` text ("" where none)."""
    row = dict(zip(KEY_COLUMNS, job_key))
    for col in FLOAT_COLUMNS:
        row[col] = float(values.get(col, math.nan))
    row["error"] = values.get("error", "")
    return row


def run_candidate_job(job: CandidateJob) -> dict:
    """Simulate one (representation, contact model, simulator, task, run) and score it: a runs.csv row.

    Never raises: a failure becomes the row's ``error`` text (one line).
    """
    try:
        # The candidate always starts from the reference's initial state; simulation error is
        # the same call with resets switched off (``job.scene`` has reset_interval_s None then).
        if job.simulator == "mujoco":
            from real2sim.evaluate.mujoco.simulate import simulate_candidate_mujoco

            traj = simulate_candidate_mujoco(job.model_xml_path, job.run_spec, job.scene, job.reference,
                                             job.mujoco or MujocoConfig(), timeout_s=job.sim_timeout_s,
                                             representation=job.representation)
        else:
            from real2sim.evaluate.simulate import simulate_candidate

            traj = simulate_candidate(job.urdf_path, job.contact_model, job.run_spec, job.scene, job.reference,
                                      timeout_s=job.sim_timeout_s)
        values = score(job.reference, traj)
        return runs_row(job.key, **values)
    except Exception as exc:
        return runs_row(job.key, error=one_line(exc))


def _sha1_file(path: Path) -> str:
    h = hashlib.sha1()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def reference_cache_name(asset: Asset, mesh_path: Path, spec: RunSpec, scene: SceneConfig,
                         properties_path: Path | None = None) -> str:
    """The file name of a reference trajectory in RESULTS/reference_cache/: the object, task and run,
    and a digest of everything the trajectory depends on (mesh and properties files, run spec, scene,
    the asset's contact material), so a changed input never reads a stale trajectory."""
    h = hashlib.sha1()
    properties_path = properties_path or asset.physical_properties_path
    for part in (_sha1_file(mesh_path), _sha1_file(properties_path), repr(spec), repr(scene),
                 repr(asset.contact)):
        h.update(part.encode())
    return f"{asset.name}_{spec.task}_{spec.run}_{h.hexdigest()[:12]}.npz"
