"""The evaluation sweep (paper V-C): every representation of every asset against its reference.

For each asset folder, task and run, the *reference* (the asset's own closed mesh,
or ``--reference MESH``, simulated with hydroelastic contact) is simulated once;
then every ``(representation, contact model)`` is simulated on the same
:class:`~real2sim.evaluate.tasks.RunSpec` and scored against it with
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

import dataclasses
import json
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from real2sim.evaluate.discovery import (Asset, Representation, discover_assets, discover_representations,
                                         place_reference_mesh, read_canonical_transform)
from real2sim.evaluate.executors import EXECUTORS, _default_jobs, _make_executor, _Retry
from real2sim.evaluate.jobs import CandidateJob, ReferenceJob, _reference_cache_name, _row, run_candidate_job, run_reference_job
from real2sim.evaluate.scene_config import SceneConfig
from real2sim.evaluate.tasks import TASKS, make_run_specs
from real2sim.formats.contact import CONTACT_MODELS
from real2sim.formats.errors import UserInputError
from real2sim.formats.outputs import publish_dir
from real2sim.formats.results import RUN_COLUMNS, read_runs_csv, row_key, write_csv_atomic


# Settings that change the meaning of a row: a resumed sweep must use the same ones.
_PINNED_SETTINGS = ("seed", "scene", "simulation_error", "reference", "reference_contact")


@dataclass(frozen=True)
class EvaluationConfig:
    """What to simulate and how.

    tasks: subset of ("push", "ramp"); contact_models: subset of ("point", "hydroelastic");
    runs: runs per (object, task) -- the paper uses 10; seed: seeds the run
    randomisation (:func:`real2sim.evaluate.tasks.make_run_specs`); jobs: parallel
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
class EvaluationResult:
    out_dir: Path
    runs: tuple[dict, ...]
    summary: tuple[dict, ...]
    plots: tuple[Path, ...]
    report_path: Path
    simulated: int  # candidate rows simulated in this call
    skipped: int  # candidate rows found done in runs.csv
    failed: int  # rows with an error after this call


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
        "reference_contact": {a.name: dataclasses.asdict(a.contact) if a.contact else "defaults (no asset_config.json)"
                              for a in assets},
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
        rows = {row_key(r): r for r in read_runs_csv(runs_path)}
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

    all_rows = sorted(rows.values(), key=row_key)
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
        write_csv_atomic(runs_path, sorted(rows.values(), key=row_key), RUN_COLUMNS)


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
                           cache, asset.contact)
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
                    write_csv_atomic(runs_path, sorted(rows.values(), key=row_key), RUN_COLUMNS)
                    last_write = now
    return simulated


__all__ = ["EvaluationConfig", "EvaluationResult", "evaluate"]
