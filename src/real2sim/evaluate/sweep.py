"""The evaluation sweep (paper V-C): every representation of every asset against its reference.

For each asset folder, task and run, the *reference* (the asset's own closed mesh,
or ``--reference MESH``, simulated with hydroelastic contact) is simulated once;
then every ``(representation, contact model)`` is simulated on the same
:class:`~real2sim.evaluate.scenes.RunSpec` and scored against it with
:mod:`real2sim.evaluate.metrics` (equation error: the candidate is reset to the reference
state every 0.1 s, unless ``simulation_error`` asks for free roll-outs).

Independent simulations run in parallel on a local process pool (default) or on
Ray; the rows are the same either way (only the measured wall times differ).

Results folder (written by :func:`evaluate`)::

    RESULTS/
      runs.csv        one row per simulation (RUN_COLUMNS)
      summary.csv     one row per <representation>_<contactmodel> (SUMMARY_COLUMNS; Table I layout first)
      config.json     protocol, scene parameters, reference meshes, software versions
      pareto_*.png    trade-off plots (paper Figs. 9, 11-13)
      report.html     everything above on one page
      reference_meshes/  the transformed ``--reference`` meshes (only with --reference)
      reference_cache/   reference trajectories (.npz), so a resumed or extended sweep
                         does not simulate a reference twice

Crash safety and resuming: the sweep works in a hidden sibling folder
``.RESULTS.partial`` and rewrites its ``runs.csv`` atomically after every finished
simulation; ``RESULTS`` itself is replaced (rename) only when the sweep is complete,
so it is always whole. Running again with the same ``--out`` resumes: rows already
in runs.csv without an ``error`` are kept and not simulated again (key: object,
representation, contact_model, task, run); rows that failed are retried. The
settings that change what a row means (seed, scene, simulation/equation error,
reference meshes) must match those stored in ``config.json``, otherwise the sweep
refuses to mix them (use ``overwrite=True`` / ``--overwrite``). Tasks, contact
models, runs and assets may change between calls (that is how a sweep is extended);
summary.csv, the plots and the report always cover every row in runs.csv.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from real2sim.formats.errors import UserInputError
from real2sim.formats.outputs import publish_dir
from real2sim.evaluate.scenes import RunSpec, SceneConfig, make_run_specs

TASKS = ("push", "ramp")
CONTACT_MODELS = ("point", "hydroelastic")
EXECUTORS = ("local", "ray")
RUN_COLUMNS = (
    "object", "representation", "contact_model", "task", "run", "ate_m", "ocae_m", "cpd_m_per_s",
    "cpd_force_weighted_m_per_s", "sim_time_s", "sim_duration_s", "real_time_factor", "error",
)
# Added after the first release: a runs.csv without them still reads (as NaN).
_OPTIONAL_RUN_COLUMNS = ("cpd_force_weighted_m_per_s",)
KEY_COLUMNS = ("object", "representation", "contact_model", "task", "run")
FLOAT_COLUMNS = ("ate_m", "ocae_m", "cpd_m_per_s", "cpd_force_weighted_m_per_s", "sim_time_s", "sim_duration_s",
                 "real_time_factor")
SUMMARY_COLUMNS = (
    "representation", "ocae_m", "ate_m", "cpd_m_per_s", "sim_time_s",  # the layout of the paper's Table I
    "cpd_force_weighted_m_per_s", "collision", "contact_model", "sim_duration_s", "real_time_factor",
    "runs_ok", "runs_failed",
)
# Settings that change the meaning of a row: a resumed sweep must use the same ones.
_PINNED_SETTINGS = ("seed", "scene", "simulation_error", "reference")


def _default_jobs() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class EvaluationConfig:
    """What to simulate and how.

    tasks: subset of ("push", "ramp"); contact_models: subset of ("point", "hydroelastic");
    runs: runs per (object, task) -- the paper uses 10; seed: seeds the run
    randomisation (:func:`real2sim.evaluate.scenes.make_run_specs`); jobs: parallel
    simulations (local pool size, or Ray tasks in flight); executor: "local" or "ray";
    ray_address: Ray cluster address (None: ``$RAY_ADDRESS``, else a local Ray);
    simulation_error: free roll-outs instead of equation error (resets every 0.1 s);
    scene: task scene parameters (durations, sizes, time step).
    """

    tasks: tuple[str, ...] = TASKS
    contact_models: tuple[str, ...] = CONTACT_MODELS
    runs: int = 10
    seed: int = 0
    jobs: int = field(default_factory=_default_jobs)
    executor: str = "local"
    ray_address: str | None = None
    simulation_error: bool = False
    scene: SceneConfig = field(default_factory=SceneConfig)

    def __post_init__(self) -> None:
        if not self.tasks or any(t not in TASKS for t in self.tasks):
            raise UserInputError(f"unknown task in {','.join(self.tasks) or '(none)'}; choose from {','.join(TASKS)}")
        if not self.contact_models or any(c not in CONTACT_MODELS for c in self.contact_models):
            raise UserInputError(
                f"unknown contact model in {','.join(self.contact_models) or '(none)'}; "
                f"choose from {','.join(CONTACT_MODELS)}"
            )
        if len(set(self.tasks)) != len(self.tasks) or len(set(self.contact_models)) != len(self.contact_models):
            raise UserInputError("tasks and contact models must not repeat")
        if not isinstance(self.runs, int) or self.runs < 1:
            raise UserInputError(f"--runs must be a whole number >= 1, got {self.runs}")
        if not isinstance(self.jobs, int) or self.jobs < 1:
            raise UserInputError(f"--jobs must be a whole number >= 1, got {self.jobs}")
        if self.executor not in EXECUTORS:
            raise UserInputError(f"unknown executor {self.executor!r}; choose local or ray")


@dataclass(frozen=True)
class Asset:
    """One asset folder: its name in the results (``object``), physical properties, reference mesh."""

    name: str
    asset_dir: Path
    physical_properties_path: Path
    reference_mesh_path: Path


@dataclass(frozen=True)
class Representation:
    """One collision representation of an asset: a subfolder of the asset holding ``model.urdf``."""

    object: str
    name: str
    urdf_path: Path


@dataclass(frozen=True)
class EvaluationResult:
    out_dir: Path
    runs: tuple[dict, ...]
    summary: tuple[dict, ...]
    plots: tuple[Path, ...]
    report_path: Path
    simulated: int  # candidate rows simulated in this call
    skipped: int  # candidate rows found done in runs.csv
    failed: int  # rows with an error after this call


# ---------------------------------------------------------------------------------------
# Discovery and inputs


def _asset_reference_mesh(asset_dir: Path) -> Path:
    """The asset's own reference: the closed solid the fitter saw, else the visual mesh."""
    closed = asset_dir / "visual" / "collision_reference.obj"
    return closed if closed.is_file() else asset_dir / "visual" / "model.obj"


def discover_assets(asset_dirs: Sequence[Path | str]) -> list[Asset]:
    """Check each asset folder and describe it; UserInputError for anything unusable."""
    if not asset_dirs:
        raise UserInputError("no asset folder given")
    assets: list[Asset] = []
    seen: dict[str, Path] = {}
    for raw in asset_dirs:
        d = Path(raw).resolve()
        if not d.is_dir():
            raise UserInputError(f"asset folder not found: {raw}")
        props = d / "physical_properties.json"
        if not props.is_file():
            raise UserInputError(f"{raw} is not an asset folder: physical_properties.json is missing")
        if d.name in seen and seen[d.name] != d:
            raise UserInputError(f"two asset folders share the name {d.name!r} ({seen[d.name]} and {d}); rename one")
        if d.name in seen:
            continue
        seen[d.name] = d
        assets.append(Asset(d.name, d, props, _asset_reference_mesh(d)))
    return assets


def discover_representations(asset_dirs: Sequence[Path | str]) -> list[Representation]:
    """Every representation (subfolder with ``model.urdf``) of every asset, sorted by object then name.

    UserInputError when a folder is not an asset (no physical_properties.json) or has no
    representation.
    """
    reps: list[Representation] = []
    for asset in discover_assets(asset_dirs):
        found = sorted(p for p in asset.asset_dir.iterdir() if p.is_dir() and (p / "model.urdf").is_file())
        if not found:
            raise UserInputError(f"{asset.asset_dir} holds no representation (no <name>/model.urdf)")
        reps.extend(Representation(asset.name, p.name, p / "model.urdf") for p in found)
    return reps


def read_canonical_transform(asset_dir: Path) -> np.ndarray:
    """The 4x4 ``T_asset_from_input`` of an asset (p_asset = T @ p_input, metres)."""
    path = Path(asset_dir) / "canonical_transform.json"
    if not path.is_file():
        raise UserInputError(f"{asset_dir} has no canonical_transform.json, needed to place --reference")
    data = json.loads(path.read_text())
    matrix = data.get("T_asset_from_input", data.get("matrix", data)) if isinstance(data, dict) else data
    t = np.asarray(matrix, dtype=float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise UserInputError(f"{path} does not hold a 4x4 transform")
    return t


def place_reference_mesh(reference_mesh: Path | str, asset_dir: Path, out_path: Path) -> Path:
    """Write ``reference_mesh`` (given in the frame of the mesh the asset was built from) into
    the asset frame, as an .obj with normals at ``out_path``."""
    from real2sim.formats.mesh_io import load_mesh

    mesh = load_mesh(reference_mesh).copy()
    mesh.apply_transform(read_canonical_transform(asset_dir))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(f".{out_path.name}.tmp.obj")
    mesh.export(tmp, include_normals=True)
    tmp.replace(out_path)
    return out_path


# ---------------------------------------------------------------------------------------
# Scoring


def _align(reference: Any, candidate: Any) -> tuple[np.ndarray, ...]:
    """Reference and candidate poses on the reference's time steps (candidate interpolated if needed)."""
    t_ref = np.asarray(reference.times_s, dtype=float)
    t_c = np.asarray(candidate.times_s, dtype=float)
    p_ref = np.asarray(reference.object_position_m, dtype=float)
    q_ref = np.asarray(reference.object_quaternion_wxyz, dtype=float)
    p_c = np.asarray(candidate.object_position_m, dtype=float)
    q_c = np.asarray(candidate.object_quaternion_wxyz, dtype=float)
    if t_c.shape == t_ref.shape and np.allclose(t_c, t_ref, atol=1e-9):
        return p_ref, q_ref, p_c, q_c
    # Different sampling: compare on the common time span, candidate linearly interpolated
    # (quaternions sign-aligned, lerped and renormalised; steps are 1 ms, so this is exact enough).
    keep = (t_ref >= t_c[0] - 1e-9) & (t_ref <= t_c[-1] + 1e-9)
    if keep.sum() < 2:
        raise RuntimeError("candidate and reference trajectories do not overlap in time")
    t = t_ref[keep]
    q_c = _sign_continuous(q_c)
    p_i = np.stack([np.interp(t, t_c, p_c[:, k]) for k in range(3)], axis=1)
    q_i = np.stack([np.interp(t, t_c, q_c[:, k]) for k in range(4)], axis=1)
    q_i /= np.linalg.norm(q_i, axis=1, keepdims=True)
    return p_ref[keep], q_ref[keep], p_i, q_i


def _sign_continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternion signs so consecutive ones are in the same hemisphere (for interpolation)."""
    # Flipping q[i] flips its dot product with q[i+1] too, hence the running product of signs.
    d = np.sum(q[1:] * q[:-1], axis=1)
    signs = np.concatenate([[1.0], np.where(d < 0, -1.0, 1.0)]).cumprod()
    return q * signs[:, None]


def score(reference: Any, candidate: Any, lever_m: float = 1.0) -> dict[str, float]:
    """ATE, OCAE (m) of ``candidate`` against ``reference``, and the candidate's CPD (m/s), as the
    paper defines it and force-weighted (:func:`real2sim.evaluate.metrics.cpd_m_per_s`)."""
    from real2sim.evaluate.metrics import ate_m, cpd_m_per_s, ocae_m, real_time_factor

    p_ref, q_ref, p_c, q_c = _align(reference, candidate)
    times = np.asarray(candidate.times_s, dtype=float)
    dt_s = float(np.median(np.diff(times))) if len(times) > 1 else float("nan")
    # Sample r + 1 holds the contacts of the first step after the reset at step r: cut the
    # contact series there, so that the reset's jump does not count as a discontinuity.
    breaks = np.asarray(getattr(candidate, "reset_steps", ()), dtype=int) + 1
    cpd = cpd_m_per_s(candidate.contact_points_object_m, dt_s, breaks) if math.isfinite(dt_s) else float("nan")
    forces = getattr(candidate, "contact_forces_object_n", None)
    cpd_fw = (cpd_m_per_s(candidate.contact_points_object_m, dt_s, breaks, contact_forces_n=forces)
              if forces and math.isfinite(dt_s) else float("nan"))
    return {
        "ate_m": ate_m(p_ref, p_c),
        "ocae_m": ocae_m(p_ref, q_ref, p_c, q_c, lever_m=lever_m),
        "cpd_m_per_s": cpd,
        "cpd_force_weighted_m_per_s": cpd_fw,
        "sim_time_s": float(candidate.sim_time_s),
        "sim_duration_s": float(candidate.sim_duration_s),
        "real_time_factor": real_time_factor(candidate.sim_duration_s, candidate.sim_time_s),
    }


# ---------------------------------------------------------------------------------------
# Jobs (module-level functions over picklable dataclasses: they run in worker processes)


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

    @property
    def key(self) -> tuple:
        return (self.object, self.representation, self.contact_model, self.task, self.run)


def _one_line(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".strip().replace("\r", " ").replace("\n", " | ")
    return text[:500]


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
        traj = simulate_reference(job.mesh_path, props, job.run_spec, job.scene)
        if job.cache_path is not None:
            save_trajectory(traj, job.cache_path)
        return "ok", traj
    except Exception as exc:  # recorded in the rows of every candidate of this run
        return "error", _one_line(exc)


def _row(job_key: tuple, **values) -> dict:
    row = dict(zip(KEY_COLUMNS, job_key))
    for col in FLOAT_COLUMNS:
        row[col] = float(values.get(col, math.nan))
    row["error"] = values.get("error", "")
    return row


def run_candidate_job(job: CandidateJob) -> dict:
    """Simulate one (representation, contact model, task, run) and score it: a runs.csv row.

    Never raises: a failure becomes the row's ``error`` text (one line).
    """
    try:
        from real2sim.evaluate.simulate import simulate_candidate

        # The candidate always starts from the reference's initial state; simulation error is
        # the same call with resets switched off (``job.scene`` has reset_interval_s None then).
        traj = simulate_candidate(job.urdf_path, job.contact_model, job.run_spec, job.scene, job.reference)
        values = score(job.reference, traj)
        return _row(job.key, **values)
    except Exception as exc:
        return _row(job.key, error=_one_line(exc))


# ---------------------------------------------------------------------------------------
# Trajectory cache


def save_trajectory(traj: Any, path: Path) -> None:
    """Save a Trajectory dataclass (arrays, scalars, lists of per-step arrays) to .npz, atomically."""
    arrays: dict[str, np.ndarray] = {}
    for f in dataclasses.fields(traj):
        value = getattr(traj, f.name)
        if isinstance(value, (list, tuple)):  # per-step point lists (contact points)
            parts = [np.asarray(v, dtype=float).reshape(-1, 3) for v in value]
            arrays[f"{f.name}__counts"] = np.array([len(p) for p in parts], dtype=np.int64)
            arrays[f"{f.name}__stack"] = np.concatenate(parts) if parts else np.zeros((0, 3))
        else:
            arrays[f.name] = np.asarray(value)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def load_trajectory(path: Path) -> Any:
    from real2sim.evaluate.simulate import Trajectory

    data = np.load(path)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(Trajectory):
        if f"{f.name}__counts" in data:
            counts = data[f"{f.name}__counts"]
            kwargs[f.name] = list(np.split(data[f"{f.name}__stack"], np.cumsum(counts)[:-1])) if len(counts) else []
        elif f.name in data:
            v = data[f.name]
            kwargs[f.name] = v.item() if v.ndim == 0 else v
    return Trajectory(**kwargs)


def _sha1_file(path: Path) -> str:
    h = hashlib.sha1()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _reference_cache_name(asset: Asset, mesh_path: Path, spec: RunSpec, scene: SceneConfig) -> str:
    h = hashlib.sha1()
    for part in (_sha1_file(mesh_path), _sha1_file(asset.physical_properties_path), repr(spec), repr(scene)):
        h.update(part.encode())
    return f"{asset.name}_{spec.task}_{spec.run}_{h.hexdigest()[:12]}.npz"


# ---------------------------------------------------------------------------------------
# Executors: submit(fn, arg) -> handle; wait(handles) -> finished handles; result(handle)


class _SerialExecutor:
    """Runs jobs in this process, one at a time (jobs == 1): same rows, no process start-up."""

    def __init__(self) -> None:
        self._queue: dict[int, tuple[Callable, Any]] = {}
        self._results: dict[int, Any] = {}
        self._next = 0

    def submit(self, fn: Callable, arg: Any) -> int:
        self._next += 1
        self._queue[self._next] = (fn, arg)
        return self._next

    def wait(self, handles: set) -> set:
        h = min(handles)
        fn, arg = self._queue.pop(h)
        self._results[h] = fn(arg)
        return {h}

    def result(self, handle: int) -> Any:
        return self._results.pop(handle)

    def shutdown(self) -> None:
        pass


class _PoolExecutor:
    """A spawn-context process pool (spawn: Drake and rich's refresh thread do not mix with fork).

    A worker that dies in native code breaks the whole pool, failing every job in
    flight. Those jobs are resubmitted to a fresh pool; a job caught in a second break
    is run alone in its own process, and only if that process dies too is the job
    reported as failed -- so a crashing simulation costs its own row and no other.
    """

    def __init__(self, jobs: int) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        import sys

        self._jobs = jobs
        # spawn re-imports the parent's __main__ from its file; a script read from stdin or
        # typed interactively has none, and there fork is the only way.
        main_file = getattr(sys.modules.get("__main__"), "__file__", None)
        method = "spawn" if main_file is None or os.path.exists(main_file) else "fork"
        self._ctx = multiprocessing.get_context(method)
        self._make = lambda: ProcessPoolExecutor(max_workers=jobs, mp_context=self._ctx)
        self._pool = self._make()
        self._solo = None  # one-worker pool for jobs caught in two pool breaks
        self._futures: dict[int, Any] = {}
        self._calls: dict[int, tuple[Callable, Any, int]] = {}
        self._next = 0

    def submit(self, fn: Callable, arg: Any, attempt: int = 0) -> int:
        self._next += 1
        self._futures[self._next] = self._pool.submit(fn, arg)
        self._calls[self._next] = (fn, arg, attempt)
        return self._next

    def wait(self, handles: set) -> set:
        from concurrent.futures import FIRST_COMPLETED
        from concurrent.futures import wait as fwait

        by_future = {self._futures[h]: h for h in handles}
        done, _ = fwait(list(by_future), return_when=FIRST_COMPLETED)
        return {by_future[f] for f in done}

    def result(self, handle: int) -> Any:
        from concurrent.futures.process import BrokenProcessPool

        future = self._futures.pop(handle)
        fn, arg, attempt = self._calls.pop(handle)
        try:
            return future.result()
        except BrokenProcessPool:
            self._renew_pool()
            if attempt >= 1:
                return self._run_isolated(fn, arg)
            return _Retry(fn, arg, attempt + 1)

    def _run_isolated(self, fn: Callable, arg: Any) -> Any:
        """Run one job alone in a one-worker pool: if that dies too, the job is the culprit."""
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool

        if self._solo is None:
            self._solo = ProcessPoolExecutor(max_workers=1, mp_context=self._ctx)
        try:
            return self._solo.submit(fn, arg).result()
        except BrokenProcessPool:
            self._solo.shutdown(wait=False, cancel_futures=True)
            self._solo = None
            return _failed_result(fn, arg, "the simulation's worker process died (crash in native code)")

    def _renew_pool(self) -> None:
        # Only replace a pool that is actually broken (several futures report the same break).
        if getattr(self._pool, "_broken", False):
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._make()

    def shutdown(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        if self._solo is not None:
            self._solo.shutdown(wait=True)


class _RayExecutor:
    """Ray tasks, one CPU each; ``address`` None starts (or joins) a local Ray."""

    def __init__(self, jobs: int, address: str | None) -> None:
        try:
            import ray
        except ImportError:  # pragma: no cover - ray is a dependency
            raise UserInputError("--executor ray needs the 'ray' package (pip install ray)") from None
        self._ray = ray
        address = address or os.environ.get("RAY_ADDRESS") or None
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if address is None:
                kwargs["num_cpus"] = jobs
            try:
                ray.init(address=address, **kwargs)
            except Exception as exc:
                raise UserInputError(f"could not start or reach Ray at {address or 'local'}: {_one_line(exc)}") from None
            self._owns_ray = True
        else:
            self._owns_ray = False
        self._remote = {}
        self._refs: dict[int, Any] = {}
        self._next = 0

    def _remote_fn(self, fn: Callable):
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(num_cpus=1, max_retries=1)(fn)
        return self._remote[fn]

    def submit(self, fn: Callable, arg: Any, attempt: int = 0) -> int:
        self._next += 1
        self._refs[self._next] = (self._remote_fn(fn).remote(arg), fn, arg)
        return self._next

    def wait(self, handles: set) -> set:
        by_ref = {self._refs[h][0]: h for h in handles}
        done, _ = self._ray.wait(list(by_ref), num_returns=1)
        return {by_ref[r] for r in done}

    def result(self, handle: int) -> Any:
        ref, fn, arg = self._refs.pop(handle)
        try:
            return self._ray.get(ref)
        except Exception as exc:  # the worker died (our functions catch their own errors)
            return _failed_result(fn, arg, f"ray task failed: {_one_line(exc)}")

    def shutdown(self) -> None:
        if self._owns_ray:
            self._ray.shutdown()


@dataclass(frozen=True)
class _Retry:
    fn: Callable
    arg: Any
    attempt: int


def _failed_result(fn: Callable, arg: Any, message: str) -> Any:
    if fn is run_reference_job:
        return "error", message
    key = getattr(arg, "key", None)
    return _row(key, error=message) if key is not None else {"error": message}


def _make_executor(config: EvaluationConfig):
    if config.executor == "ray":
        return _RayExecutor(config.jobs, config.ray_address)
    if config.jobs == 1:
        return _SerialExecutor()
    return _PoolExecutor(config.jobs)


# ---------------------------------------------------------------------------------------
# CSV files


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


def write_csv_atomic(path: Path, rows: Iterable[dict], columns: Sequence[str]) -> None:
    """Write ``rows`` to ``path`` via a temporary file and a rename (never half-written)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_fmt(row.get(c, "")) for c in columns])
    tmp.replace(path)


def read_runs_csv(path: Path) -> list[dict]:
    """runs.csv rows with floats parsed and ``run`` as int."""
    rows = []
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        missing = set(RUN_COLUMNS) - set(reader.fieldnames or ()) - set(_OPTIONAL_RUN_COLUMNS)
        if missing:
            raise UserInputError(f"{path} is not a runs.csv (missing columns {', '.join(sorted(missing))})")
        for raw in reader:
            row: dict[str, Any] = {c: raw.get(c, "") for c in RUN_COLUMNS}
            row["run"] = int(raw["run"])
            for c in FLOAT_COLUMNS:
                row[c] = float(raw.get(c) or "nan")
            row["error"] = raw["error"] or ""
            rows.append(row)
    return rows


def _sort_key(row: dict) -> tuple:
    return tuple(row[c] for c in KEY_COLUMNS)


def summarize(rows: Sequence[dict]) -> list[dict]:
    """One row per ``<representation>_<contactmodel>``: means over objects, tasks and runs.

    Only rows without an error enter the means (``runs_failed`` counts the others).
    ``sim_time_s`` is the mean wall-clock seconds per simulation, as the paper's ST;
    ``real_time_factor`` is total simulated time over total wall time. CPD ignores
    runs where it is undefined (no sustained contact).
    """
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["representation"], r["contact_model"]), []).append(r)
    out = []
    for (rep, cm), group in sorted(groups.items()):
        ok = [r for r in group if not r["error"]]

        def mean(col: str, src=ok) -> float:
            vals = np.array([r.get(col, math.nan) for r in src], dtype=float)
            vals = vals[np.isfinite(vals)]
            return float(np.mean(vals)) if len(vals) else math.nan

        total_time = float(np.nansum([r["sim_time_s"] for r in ok])) if ok else math.nan
        total_duration = float(np.nansum([r["sim_duration_s"] for r in ok])) if ok else math.nan
        out.append({
            "representation": f"{rep}_{cm}",
            "ocae_m": mean("ocae_m"),
            "ate_m": mean("ate_m"),
            "cpd_m_per_s": mean("cpd_m_per_s"),
            "sim_time_s": mean("sim_time_s"),
            "cpd_force_weighted_m_per_s": mean("cpd_force_weighted_m_per_s"),
            "collision": rep,
            "contact_model": cm,
            "sim_duration_s": mean("sim_duration_s"),
            "real_time_factor": total_duration / total_time if ok and total_time > 0 else math.nan,
            "runs_ok": len(ok),
            "runs_failed": len(group) - len(ok),
        })
    return out


def read_summary_csv(path: Path) -> list[dict]:
    rows = []
    with open(path, newline="") as fh:
        for raw in csv.DictReader(fh):
            row: dict[str, Any] = dict(raw)
            for c in FLOAT_COLUMNS:
                if c in row:
                    row[c] = float(row[c]) if row[c] not in ("", None) else math.nan
            for c in ("runs_ok", "runs_failed"):
                if c in row and row[c] not in ("", None):
                    row[c] = int(row[c])
            rows.append(row)
    return rows


# ---------------------------------------------------------------------------------------
# The sweep


def _config_record(config: EvaluationConfig, assets: Sequence[Asset], reference_meshes: dict[str, Path],
                   reference_arg: Path | None) -> dict:
    import platform

    try:
        import pydrake

        drake_version = getattr(pydrake, "__version__", "unknown")
    except Exception:  # pragma: no cover
        drake_version = "unknown"
    scene = dataclasses.asdict(config.scene) if dataclasses.is_dataclass(config.scene) else repr(config.scene)
    return {
        "seed": config.seed,
        "scene": json.loads(json.dumps(scene, default=str)),
        "simulation_error": config.simulation_error,
        "reference": str(Path(reference_arg).resolve()) if reference_arg else "asset",
        "tasks": list(config.tasks),
        "contact_models": list(config.contact_models),
        "runs": config.runs,
        "jobs": config.jobs,
        "executor": config.executor,
        "assets": {a.name: str(a.asset_dir) for a in assets},
        "reference_meshes": {k: str(v) for k, v in reference_meshes.items()},
        "protocol": (
            "simulation error: free roll-outs from the same initial state"
            if config.simulation_error or not config.scene.reset_interval_s
            else f"equation error: candidate state reset to the reference state every "
            f"{config.scene.reset_interval_s:g} s (paper V-C: 0.1 s)"
        ),
        "metrics": {
            "ate_m": "mean Euclidean distance between reference and candidate object positions (eq. 17)",
            "ocae_m": "mean ATE of three points at 1 m along the object's x, y, z axes",
            "cpd_m_per_s": "mean |d/dt| (central differences) of the mean contact-point distance from the "
            "object origin, inside contiguous contact runs of >= 3 steps, cut at equation-error resets",
            "cpd_force_weighted_m_per_s": "as cpd_m_per_s, with the mean contact-point distance weighted by "
            "contact force magnitude (not in the paper)",
            "sim_time_s": "wall-clock seconds per candidate simulation (measured under the sweep's parallel load)",
        },
        "software": {"python": platform.python_version(), "drake": drake_version, "machine": platform.machine(),
                     "cpus": os.cpu_count()},
    }


def _check_resume_settings(partial: Path, record: dict) -> None:
    path = partial / "config.json"
    if not path.is_file():
        return
    old = json.loads(path.read_text())
    for key in _PINNED_SETTINGS:
        if key in old and old[key] != record[key]:
            raise UserInputError(
                f"{partial.name.removeprefix('.').removesuffix('.partial')} holds results made with a different {key}; "
                "pass --overwrite to start again, or choose another --out"
            )


def _prepare_workdir(out_dir: Path, overwrite: bool) -> tuple[Path, Path, bool]:
    """(target, working folder, whether this call created the working folder)."""
    target = Path(out_dir).resolve()
    partial = target.with_name(f".{target.name}.partial")
    if target.exists() and not target.is_dir():
        raise UserInputError(f"output path {target} exists and is not a folder")
    if overwrite:
        shutil.rmtree(partial, ignore_errors=True)
    elif partial.is_dir() and (partial / "runs.csv").is_file():
        return target, partial, False  # an interrupted sweep: resume it
    else:
        shutil.rmtree(partial, ignore_errors=True)
        if target.is_dir() and any(target.iterdir()):
            if not (target / "runs.csv").is_file():
                raise UserInputError(f"{target} exists and is not a results folder (no runs.csv); pass --overwrite")
            shutil.copytree(target, partial)
            return target, partial, True
    partial.mkdir(parents=True)
    return target, partial, True


def _prepare_inputs(assets: Sequence[Asset], config: EvaluationConfig, reference_mesh: Path | str | None,
                    partial: Path) -> tuple[EvaluationConfig, dict[str, Path]]:
    """Reference mesh per asset (placed ones written into ``partial``), the effective config,
    and config.json -- after checking that a resumed folder was made with the same settings."""
    reference_meshes: dict[str, Path] = {}
    for a in assets:
        if reference_mesh is None:
            if not a.reference_mesh_path.is_file():
                raise UserInputError(f"{a.asset_dir} has no visual/model.obj to use as the reference")
            reference_meshes[a.name] = a.reference_mesh_path
        else:
            reference_meshes[a.name] = partial / "reference_meshes" / f"{a.name}.obj"
    if config.simulation_error:
        config = dataclasses.replace(config, scene=dataclasses.replace(config.scene, reset_interval_s=None))
    record = _config_record(config, assets, reference_meshes, Path(reference_mesh) if reference_mesh else None)
    _check_resume_settings(partial, record)
    if reference_mesh is not None:
        for a in assets:
            place_reference_mesh(reference_mesh, a.asset_dir, reference_meshes[a.name])
    (partial / "config.json").write_text(json.dumps(record, indent=1))
    return config, reference_meshes


def evaluate(
    asset_dirs: Sequence[Path | str],
    out_dir: Path | str,
    config: EvaluationConfig = EvaluationConfig(),
    reference_mesh: Path | str | None = None,
    progress: bool = True,
    overwrite: bool = False,
    log: Callable[[str], None] | None = None,
) -> EvaluationResult:
    """Run the sweep and write the results folder (see the module docstring).

    asset_dirs: asset folders (each: physical_properties.json, visual/, <representation>/model.urdf).
    reference_mesh: None -> each asset's own closed mesh (``visual/collision_reference.obj``,
        else ``visual/model.obj``); a mesh file -> that mesh, given in the frame of the mesh
        each asset was built from and moved into the asset frame with its canonical_transform.json.
    """
    say = log or (lambda _m: None)
    reps = discover_representations(asset_dirs)
    assets = discover_assets(asset_dirs)
    if reference_mesh is not None:
        from real2sim.formats.mesh_io import load_mesh

        load_mesh(reference_mesh)  # UserInputError now for a missing file / not a mesh
        for a in assets:
            read_canonical_transform(a.asset_dir)
    target, partial, created = _prepare_workdir(Path(out_dir), overwrite)
    try:
        config, reference_meshes = _prepare_inputs(assets, config, reference_mesh, partial)
    except BaseException:
        if created:  # nothing of ours worth keeping: leave no hidden folder behind
            shutil.rmtree(partial, ignore_errors=True)
        raise

    # Rows already done (resume); failed rows are retried.
    runs_path = partial / "runs.csv"
    rows: dict[tuple, dict] = {}
    if runs_path.is_file():
        rows = {_sort_key(r): r for r in read_runs_csv(runs_path)}
    done = {k for k, r in rows.items() if not r["error"]}

    specs = {task: make_run_specs(task, config.runs, config.seed) for task in config.tasks}
    asset_by_name = {a.name: a for a in assets}
    todo: dict[tuple[str, str, int], list[tuple[Representation, str]]] = {}
    skipped = 0
    for rep in reps:
        for task in config.tasks:
            for spec in specs[task]:
                for cm in config.contact_models:
                    key = (rep.object, rep.name, cm, task, int(spec.run))
                    if key in done:
                        skipped += 1
                        continue
                    todo.setdefault((rep.object, task, int(spec.run)), []).append((rep, cm))
    spec_by = {(task, int(s.run)): s for task in config.tasks for s in specs[task]}
    n_candidates = sum(len(v) for v in todo.values())
    say(f"{len(reps)} representations of {len(assets)} assets: {n_candidates} simulations to run, {skipped} already done")

    executor = _make_executor(config) if todo else None
    simulated = 0
    try:
        if executor is not None:
            simulated = _run_sweep(executor, todo, spec_by, asset_by_name, reference_meshes, config, partial, rows,
                                   runs_path, progress)
    finally:
        if executor is not None:
            executor.shutdown()

    all_rows = sorted(rows.values(), key=_sort_key)
    write_csv_atomic(runs_path, all_rows, RUN_COLUMNS)
    from real2sim.report.html import build_outputs

    summary, plots, report_path = build_outputs(partial, all_rows)
    publish_dir(partial, target)
    failed = sum(1 for r in all_rows if r["error"])
    return EvaluationResult(
        out_dir=target,
        runs=tuple(all_rows),
        summary=tuple(summary),
        plots=tuple(target / p.name for p in plots),
        report_path=target / report_path.name,
        simulated=simulated,
        skipped=skipped,
        failed=failed,
    )


@contextmanager
def _checkpoint_on_exit(runs_path: Path, rows: dict):
    """Write runs.csv however the sweep ends (an interrupt keeps every finished row)."""
    try:
        yield
    finally:
        write_csv_atomic(runs_path, sorted(rows.values(), key=_sort_key), RUN_COLUMNS)


def _run_sweep(executor, todo, spec_by, asset_by_name, reference_meshes, config, partial, rows, runs_path,
               progress) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    n_refs = len(todo)
    n_candidates = sum(len(v) for v in todo.values())
    pending: dict[Any, tuple[str, Any, Any]] = {}  # handle -> (kind "ref" or "cand", row key, job)
    for (obj, task, run), _ in sorted(todo.items()):
        asset = asset_by_name[obj]
        spec = spec_by[(task, run)]
        cache = partial / "reference_cache" / _reference_cache_name(asset, reference_meshes[obj], spec, config.scene)
        job = ReferenceJob(obj, task, run, reference_meshes[obj], asset.physical_properties_path, spec, config.scene,
                           cache)
        pending[executor.submit(run_reference_job, job)] = ("ref", (obj, task, run), job)

    simulated = 0
    last_write = 0.0
    columns = (
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), disable=not progress, transient=False) as bar, \
            _checkpoint_on_exit(runs_path, rows):
        bar_refs = bar.add_task("references", total=n_refs)
        bar_cands = bar.add_task("simulations", total=n_candidates)
        while pending:
            for handle in executor.wait(set(pending)):
                kind, key, job = pending.pop(handle)
                result = executor.result(handle)
                if isinstance(result, _Retry):
                    pending[executor.submit(result.fn, result.arg, result.attempt)] = (kind, key, job)
                    continue
                if kind == "ref":
                    bar.advance(bar_refs)
                    status, payload = result
                    for rep, cm in todo[key]:
                        ckey = (rep.object, rep.name, cm, key[1], key[2])
                        if status != "ok":
                            rows[ckey] = _row(ckey, error=f"reference simulation failed: {payload}")
                            bar.advance(bar_cands)
                            simulated += 1
                            continue
                        cjob = CandidateJob(rep.object, rep.name, cm, key[1], key[2], rep.urdf_path, job.run_spec,
                                            config.scene, config.simulation_error, payload)
                        pending[executor.submit(run_candidate_job, cjob)] = ("cand", ckey, cjob)
                else:
                    rows[key] = result
                    simulated += 1
                    bar.advance(bar_cands)
                now = time.monotonic()
                if now - last_write > 1.0 or not pending:
                    write_csv_atomic(runs_path, sorted(rows.values(), key=_sort_key), RUN_COLUMNS)
                    last_write = now
    return simulated


__all__ = [
    "Asset", "CONTACT_MODELS", "EvaluationConfig", "EvaluationResult", "Representation", "RUN_COLUMNS",
    "SUMMARY_COLUMNS", "TASKS", "discover_assets", "discover_representations", "evaluate", "place_reference_mesh",
    "read_runs_csv", "read_summary_csv", "score", "summarize", "write_csv_atomic",
]
