"""`real2sim batch`: many datasets through `run`, in parallel, into one catalogue folder.

Each object is one task: :func:`run_object` calls :func:`real2sim.pipeline.run.run_pipeline` on its
dataset into ``CATALOGUE/<name>/`` (an ordinary asset folder, with run's own ``.run/`` cache), so the
stages of one object keep their order while different objects run side by side. Tasks run on a local
process pool (:class:`real2sim.evaluate.executors.PoolExecutor`: a worker that dies breaks the pool,
its jobs are resubmitted, and a job that breaks a second pool is run alone) or on Ray
(:class:`RayObjects`: one task per object and one CPU; Ray retries a task whose worker died once).
Where the run uses ``cuda`` and the Ray cluster has GPUs, an object's stages are split into three
tasks that follow each other (:data:`PHASES`): the stages before the reconstruction on a CPU, the
reconstruction and the asset's fitting (:data:`GPU_STAGES`) with a GPU, and the rest (truth, the
evaluation's simulations) on a CPU again, so a GPU is held only while its stages run. Each task is
`run` on the same folder: it skips the stages an earlier task recorded and stops before the next
task's first stage (``run_pipeline``'s ``pause``).

Datasets and results move through paths on a folder every node reads and writes
(why: docs/design-notes/pipeline.md#shared-folder).

Resume: a rerun skips an object whose outcome :mod:`.catalogue` recorded as "done" under the same key
(the dataset's files and the run settings), and runs every other one again, which resumes it from run's
cache. The catalogue is written at the end, also after an interruption.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

from real2sim.plumbing.cores import usable_cores
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import make_output_dir, output_lock
from real2sim.plumbing.progress import ProgressFn, null_progress
from real2sim.pipeline import manifest as mf
from real2sim.pipeline.catalogue import (BATCH_DIRNAME, MADE_BY, check_catalogue, finished_before, record_outcome,
                                         state_path, write_catalogue)
from real2sim.plumbing import digests

EXECUTORS = ("local", "ray")
#: what a worker that died (killed, or a crash in native code) leaves as its object's reason
WORKER_DIED = "the worker process died (killed, or a crash in native code)"

#: The stages a GPU speeds up: the radiance field, and the primitives' fitting in the asset stage.
GPU_STAGES = frozenset({"reconstruct", "asset"})
#: An object's tasks when its stages are split by the resources they need, in order.
PHASES = ("before_gpu", "gpu", "after_gpu")


def phase_pause(phase: str) -> Callable[[str], bool] | None:
    """``run_pipeline``'s ``pause`` for one of :data:`PHASES` ("all": None, every stage)."""
    if phase == "before_gpu":
        return lambda stage: stage in GPU_STAGES
    if phase == "gpu":
        reached: list[str] = []

        def pause(stage: str) -> bool:  # the stages before are current by now: skipped, not paused at
            if stage in GPU_STAGES:
                reached.append(stage)
                return False
            return bool(reached)

        return pause
    return None


@dataclass(frozen=True)
class ObjectJob:
    """One object of the batch. ``config`` None: it cannot run, ``reason`` says why (no mass).
    ``threads``: torch CPU threads in its worker (0: leave torch's choice); ``gpu``: ask Ray for one.
    ``phase``: which of its stages this task runs ("all", or one of :data:`PHASES`)."""

    name: str
    dataset: Path
    asset_dir: Path
    config: Any = None  # RunConfig
    reason: str = ""
    threads: int = 0
    gpu: bool = False
    log: Path | None = None
    phase: str = "all"


@dataclass(frozen=True)
class BatchConfig:
    """Where a batch's objects run, and how many at once."""

    executor: str = "local"
    """Where the objects run: "local" (a process pool on this machine) or "ray"."""
    ray_address: str | None = None
    """The Ray cluster's address (``executor`` "ray" only); None: a private local Ray on the loopback address."""
    workers: int | None = None
    """Objects at once, >= 1; None: this process's CPUs, at most the objects to run."""
    ray_timeout_s: float = 30.0
    """How long to wait for the Ray cluster at ``ray_address`` to answer, s; > 0."""

    def __post_init__(self) -> None:
        if self.executor not in EXECUTORS:
            raise UserInputError(f"unknown executor {self.executor!r}; choose local or ray")
        if self.ray_address is not None and self.executor != "ray":
            raise UserInputError("--ray-address is for --executor ray")


@dataclass
class BatchResult:
    catalogue: Path
    outcomes: dict[str, dict] = field(default_factory=dict)  # name -> {"status", "reason", ...}
    skipped: list[str] = field(default_factory=list)  # finished by an earlier batch, not run again

    @property
    def failed(self) -> list[str]:
        return [n for n, o in self.outcomes.items() if o.get("status") != "done"]


def object_key(job: ObjectJob) -> str:
    """What an object's outcome depends on: every file of its dataset and the run settings."""
    files = digests.files_digest(job.dataset, digests.tree_files(job.dataset)) if job.dataset.is_dir() else str(job.dataset)
    return mf.stage_key({"dataset": files}, job.config, None)


def run_object(job: ObjectJob) -> dict:
    """A worker's task: `run` for one object. Never raises for the object's own failure: returns
    ``{"name", "status": "done"|"failed"|"paused" (before its next task's stages), "reason", "ran": [stages
    run now]}``; its progress and warnings go to ``job.log``."""
    from real2sim.pipeline.run import StageFailed, run_pipeline

    if job.threads:
        limit_threads(job.threads)
    log = open(job.log, "a", encoding="utf-8") if job.log else open(os.devnull, "w")
    with log, contextlib.redirect_stderr(log):
        def say(message: str, done: int, total: int) -> None:
            if total <= 0 or done >= total:
                print(f"{message}" + (f": {done}/{total}" if total > 0 else ""), file=log, flush=True)

        if job.phase != "all":
            print(f"{job.phase} stages, with {_assigned(job)}", file=log, flush=True)
        try:
            result = run_pipeline(job.dataset, job.asset_dir, job.config, progress=say, pause=phase_pause(job.phase))
            if result.paused_before is not None:
                print(f"paused before {result.paused_before}", file=log, flush=True)
        except (StageFailed, UserInputError) as exc:
            return _failed(job.name, str(exc), log)
        except Exception as exc:  # noqa: BLE001 -- one object's crash is its own row, not the batch's end
            text = str(exc).splitlines()[0] if str(exc) else ""
            return _failed(job.name, f"{type(exc).__name__}: {text}".rstrip(": "), log)
    ran = [stage for stage, status in result.statuses.items() if status == "ran"]
    if result.paused_before is not None:
        return {"name": job.name, "status": "paused", "reason": "", "ran": ran}
    return {"name": job.name, "status": "done", "reason": "", "ran": ran,
            "warnings": len(result.stage_warnings)}


#: The thread pools of the numeric libraries an object's stages load: OpenMP (torch, Open3D), OpenBLAS and MKL
#: (numpy, scipy).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def limit_threads(threads: int) -> None:
    """This worker process's numeric libraries to ``threads`` threads each. Called in a pool's worker before
    the stages import them: each library otherwise starts a thread per CPU, and two workers on two cores then
    run four busy threads (why: docs/design-notes/pipeline.md#worker-threads). Ray does the same for its tasks."""
    from threadpoolctl import threadpool_limits

    for name in THREAD_VARIABLES:  # the libraries not loaded yet
        os.environ[name] = str(threads)
    threadpool_limits(limits=threads)  # and those loaded already (numpy's OpenBLAS, with real2sim's first import)
    import torch

    torch.set_num_threads(threads)


def _assigned(job: ObjectJob) -> str:
    """What the task was given, as its log says: the GPUs Ray assigned it, or a CPU."""
    import sys

    ray = sys.modules.get("ray")
    if job.gpu and ray is not None and ray.is_initialized():
        return f"GPU {', '.join(map(str, ray.get_gpu_ids()))}"
    return "a CPU"


def _failed(name: str, reason: str, log) -> dict:
    print(f"failed: {reason}", file=log, flush=True)
    return {"name": name, "status": "failed", "reason": reason, "ran": []}


class RayObjects:
    """One Ray task per object: one CPU, or one GPU for an object whose job asks for it (its
    reconstruction and fitting run on ``cuda``). Ray reruns a task whose worker died once; the rerun
    resumes from run's cache. ``ray_address`` None starts a private Ray on the loopback address."""

    def __init__(self, workers: int, address: str | None, timeout_s: float) -> None:
        import logging

        import ray

        from real2sim.evaluate.executors import init_ray_bounded, keeping_sigterm, probe_address

        self._ray = ray
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
        self._temp_dir = None
        self._owns = not ray.is_initialized()
        if address is not None:
            probe_address(address, timeout_s)
        elif self._owns:
            import tempfile

            # Its own session folder: Ray's shared default (/tmp/ray) holds other users' sessions; short,
            # because Ray's socket paths must fit in 107 characters.
            self._temp_dir = tempfile.mkdtemp(prefix="r2s_ray_", dir="/tmp" if os.path.isdir("/tmp") else None)
            kwargs.update(num_cpus=workers, _node_ip_address="127.0.0.1", _temp_dir=self._temp_dir)
        if self._owns:
            try:
                if address is not None:
                    init_ray_bounded(ray, address, kwargs, timeout_s)
                else:  # in this thread: Ray's processes die with the thread that started them (PR_SET_PDEATHSIG)
                    keeping_sigterm(lambda: ray.init(**kwargs))
            except BaseException as exc:  # SIGTERM and Ctrl-C too: what Ray started so far is stopped
                if address is None:
                    with contextlib.suppress(Exception):
                        keeping_sigterm(ray.shutdown)
                self._remove_temp_dir()
                if isinstance(exc, UserInputError) or not isinstance(exc, Exception):
                    raise
                raise UserInputError(f"could not start a local Ray: {str(exc).splitlines()[0] if str(exc) else exc!r}")
        self.gpus = float(ray.cluster_resources().get("GPU", 0.0))
        self._remote: dict[Callable, Any] = {}
        self._refs: dict[int, Any] = {}
        self._next = 0

    def submit(self, fn: Callable, job: ObjectJob, attempt: int = 0) -> int:
        gpu = 1 if job.gpu and self.gpus >= 1 else 0
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(fn)
        remote = self._remote[fn].options(num_cpus=1, num_gpus=gpu, max_retries=1)
        self._next += 1
        self._refs[self._next] = remote.remote(job)
        return self._next

    def wait(self, handles: set) -> set:
        from real2sim.evaluate.executors import sigterm_through_ray

        by_ref = {self._refs[h]: h for h in handles}
        done, _ = sigterm_through_ray(lambda: self._ray.wait(list(by_ref), num_returns=1))
        return {by_ref[r] for r in done}

    def result(self, handle: int) -> Any:
        from real2sim.evaluate.executors import sigterm_through_ray

        ref = self._refs.pop(handle)
        try:
            return sigterm_through_ray(lambda: self._ray.get(ref))
        except Exception:  # noqa: BLE001 -- the worker died twice (run_object catches the object's errors)
            return {"error": WORKER_DIED}

    def shutdown(self, abort: bool = False) -> None:
        if abort:
            for ref in self._refs.values():
                with contextlib.suppress(Exception):
                    self._ray.cancel(ref, force=True)
            self._refs.clear()
        if self._owns:
            from real2sim.evaluate.executors import keeping_sigterm

            keeping_sigterm(self._ray.shutdown)  # Ray leaves SIGTERM at the default: death without clean-up
        self._remove_temp_dir()

    def _remove_temp_dir(self) -> None:
        if self._temp_dir is not None:
            import shutil

            shutil.rmtree(self._temp_dir, ignore_errors=True)


def make_executor(config: BatchConfig, workers: int):
    """The executor for ``config``: UserInputError (one line, within ``timeout_s``) when Ray is not reachable."""
    if config.executor == "ray":
        return RayObjects(workers, config.ray_address, config.ray_timeout_s)
    from real2sim.evaluate.executors import PoolExecutor

    return PoolExecutor(workers)


def run_batch(jobs: list[ObjectJob], out: Path, config: BatchConfig, progress: ProgressFn | None = None,
              echo: Callable[[str], None] | None = None) -> BatchResult:
    """Run every job (see the module docstring) and write the catalogue; ``progress`` gets the whole
    batch's count, ``echo`` one line per finished object. Bad input raises UserInputError before
    anything is written; an interruption writes the catalogue of what finished, then re-raises."""
    progress, echo = progress or null_progress, echo or (lambda line: None)
    out = check_catalogue(out, [j.dataset for j in jobs])
    with output_lock(out):
        result = BatchResult(out)
        keys = {j.name: object_key(j) for j in jobs if j.config is not None}
        todo = [j for j in jobs if j.config is not None and not finished_before(out, j.name, j.asset_dir, keys[j.name])]
        result.skipped = [j.name for j in jobs if j.config is not None and j not in todo]
        workers = max(1, min(config.workers or usable_cores(), len(todo) or 1))
        executor = make_executor(config, workers) if todo else None  # Ray's refusal comes before any write
        make_output_dir(out, made_by=MADE_BY)
        (out / BATCH_DIRNAME).mkdir(exist_ok=True)
        for name in result.skipped:
            result.outcomes[name] = json.loads(state_path(out, name).read_text())
            echo(f"{name}: finished before, skipped")
        try:
            for job in jobs:
                if job.config is None:
                    _record(out, result, {"name": job.name, "status": "failed", "reason": job.reason}, "", echo)
            if executor is not None:
                _schedule(executor, todo, keys, out, result, progress, echo, len(jobs), workers)
        finally:
            if executor is not None:
                executor.shutdown(abort=len(result.outcomes) < len(jobs))
                release_stale_locks([j for j in todo if j.name in result.outcomes], wait_s=0.0)  # their workers ended
                release_stale_locks([j for j in todo if j.name not in result.outcomes])  # in flight: may be dying
            write_catalogue(out, jobs, result.outcomes)
    return result


def release_stale_locks(jobs: list[ObjectJob], wait_s: float = 5.0) -> list[str]:
    """Remove the lock files (and run's temporary folders) that the objects' workers left, once the executor
    is shut down: a pool worker ended by SIGTERM, or a Ray worker killed, never ran its own clean-up. Only a
    lock no live process holds is removed (its flock is taken first): one still held, by a worker still dying
    (waited for up to ``wait_s``) or by a `real2sim run` of the user's on that folder, is kept. Returns the
    names whose lock is still held."""
    from real2sim.pipeline.run_folder import remove_stale_temporaries

    left = [job for job in jobs if job.asset_dir.with_name(f".{job.asset_dir.name}.lock").exists()]
    deadline = time.monotonic() + wait_s
    while True:
        held = []
        for job in left:
            try:
                with output_lock(job.asset_dir):  # taken: nobody holds it; its release removes the file
                    if job.asset_dir.is_dir():
                        remove_stale_temporaries(job.asset_dir)
            except UserInputError:
                held.append(job)
        left = held
        if not left or time.monotonic() >= deadline:
            return [job.name for job in left]
        time.sleep(0.1)


def _schedule(executor, todo: list[ObjectJob], keys: dict, out: Path, result: BatchResult, progress: ProgressFn,
              echo: Callable[[str], None], total: int, workers: int) -> None:
    from real2sim.evaluate.executors import Retry

    started, before = time.monotonic(), len(result.outcomes)
    if getattr(executor, "gpus", 0) >= 1:  # split where a GPU is asked for and the cluster has one
        todo = [replace(job, phase=PHASES[0], gpu=False) if job.gpu else job for job in todo]
    ran: dict[str, list[str]] = {}
    handles = {executor.submit(run_object, job): job for job in todo}
    show = lambda: _show(progress, result, len(handles), total, workers, time.monotonic() - started,  # noqa: E731
                         len(result.outcomes) - before)
    show()
    while handles:
        for handle in executor.wait(set(handles)):
            job = handles.pop(handle)
            outcome = executor.result(handle)
            if isinstance(outcome, Retry):  # the pool broke under it: again, resuming from run's cache
                handles[executor.submit(outcome.fn, outcome.arg, outcome.attempt)] = job
                continue
            if "name" not in outcome:  # the executor's own failure row: its worker died
                outcome = {"name": job.name, "status": "failed", "reason": WORKER_DIED, "ran": []}
            ran.setdefault(job.name, []).extend(outcome.get("ran") or [])
            if outcome["status"] == "paused" and job.phase in PHASES[:-1]:  # its next stages, with their resources
                following = PHASES[PHASES.index(job.phase) + 1]
                after = replace(job, phase=following, gpu=following == "gpu")
                handles[executor.submit(run_object, after)] = after
                continue
            _record(out, result, {**outcome, "ran": ran.pop(job.name)}, keys[job.name], echo)
        show()


def _record(out: Path, result: BatchResult, outcome: dict, key: str, echo: Callable[[str], None]) -> None:
    state = result.outcomes[outcome["name"]] = record_outcome(out, outcome, key)
    if outcome["status"] == "done":
        ran = outcome.get("ran") or []
        echo(f"{outcome['name']}: done ({'ran ' + ', '.join(ran) if ran else 'all stages unchanged'})")
    else:
        echo(f"{outcome['name']}: FAILED: {state['reason']}")


def _show(progress: ProgressFn, result: BatchResult, left: int, total: int, workers: int, elapsed_s: float,
          finished_now: int) -> None:
    """The whole batch on one line: done, running, queued, failed, and an ETA from this run's pace."""
    finished, failed = len(result.outcomes), len(result.failed)
    running = min(left, workers)
    eta = f", about {elapsed_s / finished_now * left / 60:.0f} min left" if finished_now and left else ""
    progress(f"batch: {finished - failed} done, {running} running, {left - running} queued, {failed} failed{eta}",
             finished, total)
