"""The evaluation sweep (paper V-C): every representation of every asset against its reference.

For each asset folder, task and run, the *reference* (the asset's own closed mesh,
or ``--reference MESH``, simulated with hydroelastic contact in Drake) is simulated once;
then every ``(representation, contact model, simulator)`` is simulated on the same
:class:`~real2sim.evaluate.scene.tasks.RunSpec` and scored against it with
:mod:`real2sim.evaluate.metrics` (equation error: the candidate is reset to the reference
state every 0.1 s, unless ``simulation_error`` asks for free roll-outs). The simulators
(``simulators``): Drake with each contact model, and MuJoCo (point contacts only) on the same
tasks rebuilt around each representation's ``model.xml`` (:mod:`real2sim.evaluate.mujoco`), both
judged against the one Drake reference.

Independent simulations run in parallel on a local process pool (default) or on
Ray; the rows are the same either way (only the measured wall times differ).

Results folder (written by :func:`evaluate`)::

    RESULTS/
      runs.csv        one row per simulation (RUN_COLUMNS)
      summary.csv     one row per <representation>_<contactmodel>[_<simulator>] (SUMMARY_COLUMNS; Table I layout first)
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
representation, contact_model, simulator, task, run); rows that failed are retried. The
settings that change what a row means (seed, scene, simulation/equation error,
reference meshes, MuJoCo's settings) must match those stored in ``config.json``, otherwise the sweep
refuses to mix them (use ``overwrite=True`` / ``--overwrite``). Tasks, contact
models, simulators, runs and assets may change between calls (that is how a sweep is extended);
summary.csv, the plots and the report always cover every row in runs.csv. A row that
was torn (cut mid-number by a crash or a full disk: its checksum does not match, see
:mod:`real2sim.formats.results`) counts as not done and is simulated again.

Safety (docs/reliability.md): ``--out`` may not be, contain or lie in what the sweep
reads, nor hold the working folder, and ``--overwrite`` replaces only folders real2sim
made (:mod:`real2sim.evaluate.workdir`); the output's lock is held from the first check
to the publication, so a second sweep into the same ``--out`` is refused at once; every
asset is checked before anything is written (:mod:`real2sim.evaluate.inputs`); each
simulation has a wall-clock limit (``sim_timeout_s``: the row records a "timeout" and the
sweep goes on); an interrupt (Ctrl-C, SIGTERM) ends the workers and keeps every finished
row for the resume. config.json records paths relative to the results folder only.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from real2sim.evaluate.discovery import (Asset, Representation, discover_assets, discover_representations,
                                         place_reference_mesh, read_canonical_transform)
from real2sim.evaluate.executors import EXECUTORS, make_executor
from real2sim.evaluate.inputs import check_inputs
from real2sim.formats.contact import MujocoConfig
from real2sim.evaluate.record import check_resume_settings, config_record
from real2sim.evaluate.schedule import run_simulations
from real2sim.evaluate.scene.scene_config import SceneConfig
from real2sim.evaluate.scene.tasks import TASKS, make_run_specs
from real2sim.evaluate.workdir import (check_partial, check_results_dir, fresh_partial, partial_dir, protected_inputs,
                                       resolve_target)
from real2sim.formats.contact import CONTACT_MODELS
from real2sim.plumbing.cores import usable_cores
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import output_lock, publish_dir, write_json_atomic
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.formats.results import (SIMULATOR_CONTACT_MODELS, SIMULATORS, describe_torn, load_runs_csv, row_key,
                                      write_runs_csv)


@dataclass(frozen=True)
class EvaluationConfig:
    """What the sweep simulates and how: the tasks, contact models and runs, where the simulations run,
    and the scenes' physical parameters."""

    tasks: tuple[str, ...] = TASKS
    """The tasks to simulate: a non-empty subset of ("push", "ramp"), no repeats."""
    contact_models: tuple[str, ...] = CONTACT_MODELS
    """The candidates' contact models: a non-empty subset of ("point", "hydroelastic"), no repeats."""
    simulators: tuple[str, ...] = ("drake",)
    """The simulators the candidates run in: a non-empty subset of ("drake", "mujoco"), no repeats. Each
    simulates the contact models of ``contact_models`` it has (MuJoCo: point only); the reference is
    Drake's in every case, so all rows are judged against one truth."""
    mujoco: MujocoConfig = field(default_factory=MujocoConfig)
    """MuJoCo's contact and integration settings (read when "mujoco" is in ``simulators``)."""
    runs: int = 10
    """Seeded runs per (object, task); a whole number >= 1 (the paper uses 10)."""
    seed: int = 0
    """Seeds the runs' initial conditions (:func:`real2sim.evaluate.scene.tasks.make_run_specs`)."""
    jobs: int = field(default_factory=usable_cores)
    """Simulations at once (the local pool's size, or Ray tasks in flight); >= 1 (default: this process's CPUs)."""
    executor: str = "local"
    """Where the simulations run: "local" (this process for ``jobs`` 1, else a process pool) or "ray"."""
    ray_address: str | None = None
    """The Ray cluster's address; None: ``$RAY_ADDRESS``, else a local Ray."""
    simulation_error: bool = False
    """True: free roll-outs (simulation error) instead of equation error (resets every
    ``scene.reset_interval_s``)."""
    scene: SceneConfig = field(default_factory=SceneConfig)
    """The scenes' physical parameters (durations, sizes, materials, time step)."""
    sim_timeout_s: float = 600.0
    """Wall-clock limit of one simulation (reference or candidate), s; finite, > 0. Past it the row
    records the reason "timeout" and the sweep goes on (why so long: docs/design-notes/evaluate.md#timeouts)."""
    ray_timeout_s: float = 30.0
    """How long to wait for the Ray cluster at ``ray_address`` to answer, s; finite, > 0."""

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
        if not self.simulators or any(s not in SIMULATORS for s in self.simulators):
            raise UserInputError(f"unknown simulator in {','.join(self.simulators) or '(none)'}; "
                                 f"choose from {','.join(SIMULATORS)}")
        if len(set(self.simulators)) != len(self.simulators):
            raise UserInputError("simulators must not repeat")
        for sim in self.simulators:
            if not self.contact_models_of(sim):
                raise UserInputError(f"{sim} has no contact model of --contact {','.join(self.contact_models)} "
                                     f"(it has {','.join(SIMULATOR_CONTACT_MODELS[sim])})")
        if not isinstance(self.runs, int) or self.runs < 1:
            raise UserInputError(f"--runs must be a whole number >= 1, got {self.runs}")
        if not isinstance(self.jobs, int) or self.jobs < 1:
            raise UserInputError(f"--jobs must be a whole number >= 1, got {self.jobs}")
        if self.executor not in EXECUTORS:
            raise UserInputError(f"unknown executor {self.executor!r}; choose local or ray")
        for name in ("sim_timeout_s", "ray_timeout_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise UserInputError(f"--{name.replace('_', '-')} must be a finite number of seconds > 0, got {value}")

    def contact_models_of(self, simulator: str) -> tuple[str, ...]:
        """The contact models of ``contact_models`` that ``simulator`` simulates, in their order."""
        return tuple(c for c in self.contact_models if c in SIMULATOR_CONTACT_MODELS[simulator])


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


def _reference_mesh_paths(assets: Sequence[Asset], reference_mesh: Path | str | None, partial: Path) -> dict[str, Path]:
    """Reference mesh per asset: its own, or where the placed ``--reference`` goes in the working folder."""
    if reference_mesh is None:
        return {a.name: a.reference_mesh_path for a in assets}
    return {a.name: partial / "reference_meshes" / f"{a.name}.obj" for a in assets}


def evaluate(
    asset_dirs: Sequence[Path | str],
    out_dir: Path | str,
    config: EvaluationConfig = EvaluationConfig(),
    reference_mesh: Path | str | None = None,
    progress: ProgressFn | None = None,
    overwrite: bool = False,
    reference_properties: Path | str | None = None,
    animations: bool = False,
    skip_representations: Sequence[str] = (),
) -> EvaluationResult:
    """Run the sweep and write the results folder (see the module docstring).

    asset_dirs: asset folders (each: physical_properties.json, visual/, <representation>/model.urdf).
    reference_mesh: None -> each asset's own closed mesh (``visual/collision_reference.obj``,
        else ``visual/model.obj``); a mesh file -> that mesh, given in the frame of the mesh
        each asset was built from and moved into the asset frame with its canonical_transform.json.
    overwrite: start afresh, discarding the results (and working folder) at ``out_dir``; only
        folders the evaluation made are ever deleted (:mod:`real2sim.evaluate.workdir`).
    reference_properties: None -> the reference has the asset's mass, CoM and inertia
        (physical_properties.json); a physical_properties.json file (asset frame) -> the
        reference has those instead, e.g. the true object's (one asset only). With
        ``reference_mesh`` this simulates a different object altogether: the truth.
    skip_representations: representation folder names not to simulate (e.g. ``mesh`` when it is
        the reference itself).
    progress: the sweep's messages (``total`` 0) and its count of reference and candidate
        simulations.
    animations: also write RESULTS/animations/<task>.html, the reference beside the representation
        recommended for accuracy (:mod:`real2sim.evaluate.animation`), linked from report.html.

    UserInputError, with nothing written, for unusable assets or reference, an ``out_dir``
    that is not ours to write, or another sweep writing ``out_dir`` now.
    """
    say = progress or null_progress
    reps = [r for r in discover_representations(asset_dirs) if r.name not in set(skip_representations)]
    if not reps:
        raise UserInputError("no representation left to evaluate")
    assets = discover_assets(asset_dirs)
    if reference_mesh is not None:
        for a in assets:
            read_canonical_transform(a.asset_dir)
    check_inputs(assets, reps, reference_mesh, reference_properties)
    target = resolve_target(out_dir)
    inputs = protected_inputs(assets, target, reference_mesh)
    target = check_results_dir(target, overwrite, inputs)
    with output_lock(target):  # one sweep per --out, from here to the publication
        return _evaluate_locked(reps, assets, target, inputs, config, reference_mesh, overwrite, say,
                                Path(reference_properties).resolve() if reference_properties else None, animations)


def _evaluate_locked(reps, assets, target: Path, inputs, config: EvaluationConfig, reference_mesh,
                     overwrite: bool, say: ProgressFn,
                     reference_properties: Path | None = None, animations: bool = False) -> EvaluationResult:
    partial = partial_dir(target)
    if check_partial(partial, overwrite, inputs):
        source: Path | None = partial  # an interrupted sweep: resume it
    elif not overwrite and (target / "runs.csv").is_file():
        source = target  # a finished sweep: extend it
    else:
        source = None
    # Read what is to be resumed before anything is written: a damaged runs.csv or config.json is refused.
    table = load_runs_csv(source / "runs.csv") if source is not None else None
    if config.simulation_error:
        config = dataclasses.replace(config, scene=dataclasses.replace(config.scene, reset_interval_s=None))
    reference_meshes = _reference_mesh_paths(assets, reference_mesh, partial)
    record = config_record(config, assets, reference_meshes, Path(reference_mesh) if reference_mesh else None,
                           target, partial, reference_properties)
    if source is not None:
        check_resume_settings(source, target, record)

    # Rows already done (resume); failed and torn rows are simulated again.
    rows: dict[tuple, dict] = {row_key(r): r for r in table.rows} if table is not None else {}
    if table is not None and table.torn_lines:
        say(f"warning: {describe_torn(table, 'runs.csv')}: simulated again", 0, 0)
    _check_simulator_inputs(reps, config)
    todo, spec_by, skipped = _plan(reps, config, rows)
    n_candidates = sum(len(v) for v in todo.values())
    for sim in config.simulators:
        left_out = [c for c in config.contact_models if c not in config.contact_models_of(sim)]
        if left_out:  # the simulator's nature, not a fallback: said once, never silent
            say(f"{sim}: {', '.join(left_out)} contact is not a {sim} contact model; {sim} rows are "
                f"{', '.join(config.contact_models_of(sim))} only", 0, 0)
    say(f"{len(reps)} representations of {len(assets)} assets: {n_candidates} simulations to run, {skipped} already done",
        0, 0)

    created = source is not partial
    executor = None
    try:
        executor = make_executor(config) if todo else None  # a Ray that cannot be reached fails here
        if created:
            fresh_partial(partial, copy_of=source)
        if reference_mesh is not None:
            for a in assets:
                place_reference_mesh(reference_mesh, a.asset_dir, reference_meshes[a.name])
        write_json_atomic(partial / "config.json", record)
    except BaseException:
        if executor is not None:
            executor.shutdown(abort=True)
        if created:  # nothing of ours worth keeping: leave no hidden folder behind
            shutil.rmtree(partial, ignore_errors=True)
        raise

    runs_path = partial / "runs.csv"
    simulated = 0
    if executor is not None:
        asset_by_name = {a.name: a for a in assets}
        try:
            simulated = run_simulations(executor, todo, spec_by, asset_by_name, reference_meshes, config, partial,
                                        rows, runs_path, say, target, reference_properties)
        except BaseException:  # KeyboardInterrupt (Ctrl-C, SIGTERM) included: end the workers now
            executor.shutdown(abort=True)
            raise
        executor.shutdown()

    all_rows = sorted(rows.values(), key=row_key)
    write_runs_csv(runs_path, all_rows)
    if animations:
        _write_animations(partial, all_rows, config, say)
    from real2sim.report.html import build_outputs

    summary, plots, report_path = build_outputs(partial, all_rows)
    publish_dir(partial, target, made_by="real2sim evaluate")
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


def _check_simulator_inputs(reps, config: EvaluationConfig) -> None:
    """Every representation has the model file each simulator reads (before anything is written)."""
    if "mujoco" in config.simulators:
        missing = [r for r in reps if not r.mjcf_path.is_file()]
        if missing:
            more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
            raise UserInputError(f"{missing[0].mjcf_path} is missing{more}: --simulator mujoco reads each "
                                 "representation's model.xml (build the asset with --format mjcf)")


def _plan(reps, config: EvaluationConfig, rows: dict[tuple, dict]
          ) -> tuple[dict[tuple[str, str, int], list[tuple[Representation, str, str]]], dict, int]:
    """The simulations still to run, (representation, contact model, simulator) grouped by reference
    (object, task, run); each run's spec; and how many rows are done already (failed rows are run again)."""
    done = {k for k, r in rows.items() if not r["error"]}
    specs = {task: make_run_specs(task, config.runs, config.seed) for task in config.tasks}
    todo: dict[tuple[str, str, int], list[tuple[Representation, str, str]]] = {}
    skipped = 0
    for rep in reps:
        for task in config.tasks:
            for spec in specs[task]:
                for sim in config.simulators:
                    for cm in config.contact_models_of(sim):
                        key = (rep.object, rep.name, cm, sim, task, int(spec.run))
                        if key in done:
                            skipped += 1
                            continue
                        todo.setdefault((rep.object, task, int(spec.run)), []).append((rep, cm, sim))
    spec_by = {(task, int(s.run)): s for task in config.tasks for s in specs[task]}
    return todo, spec_by, skipped


def _write_animations(partial: Path, rows: list[dict], config: EvaluationConfig, say: ProgressFn) -> None:
    """The animations are a view of the results, not a result: a failure is one warning line."""
    from real2sim.evaluate.animation import ANIMATION_DIRNAME, write_animations
    from real2sim.formats.results import summarize

    shutil.rmtree(partial / ANIMATION_DIRNAME, ignore_errors=True)  # those of an earlier sweep may be stale
    try:
        written = write_animations(partial, summarize(rows), timeout_s=config.sim_timeout_s)
    except Exception as exc:  # noqa: BLE001
        say(f"warning: no animations ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})", 0, 0)
        return
    if written:
        say(f"animations: {', '.join(sorted(written))} ({ANIMATION_DIRNAME}/)", 0, 0)


__all__ = ["EvaluationConfig", "EvaluationResult", "evaluate"]
