"""The collision fits of one asset build: side by side in worker processes (``--fit-workers``; by default
as many as the threads this process may use when the fits are long), so that processes times threads
never exceeds those threads, or one after another (why: docs/design-notes/asset.md#fits-side-by-side). Every fit is seeded
on its own, so which process fits a SPEC, and in which order they finish, changes no result.
"""

from __future__ import annotations

import json
import os
import pickle
import queue
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch
import trimesh

from real2sim.asset.config import AssetConfig
from real2sim.collision.fit.config import FitConfig
from real2sim.formats.collision import CollisionGeometry, write_collision_json
from real2sim.formats.spec import CollisionSpec
from real2sim.plumbing.progress import ProgressFn, null_progress, prefixed

#: Seconds between two looks at whether a busy worker still lives, while no message comes.
POLL_S = 0.2
#: Decompositions that use every thread they are given (CoACD's OpenMP: the bundled mug 71.9 s on one
#: thread, 47.7 s on two; V-HACD 6.0 s on both): with fits side by side they run after them, in the
#: build's process with all its threads, not in a worker's share (docs/design-notes/asset.md#fits-side-by-side).
THREADED_BASELINES = ("coacd",)


@dataclass(frozen=True)
class Fitted:
    """One SPEC's collision geometry, its fitting report and its fidelity against the solid."""

    geometry: CollisionGeometry
    report: dict
    fidelity: dict


def build_collision(
    mesh_canonical: trimesh.Trimesh, spec: CollisionSpec, rep_dir: Path, config: AssetConfig,
    sdf_cache_dir: Path | str | None = None, progress: ProgressFn | None = None,
) -> tuple[CollisionGeometry, dict]:
    """One collision representation of the canonical mesh, with its fitting report.

    Baselines and superquadric fits write their convex pieces under ``rep_dir/pieces``;
    a primitive fit reports its SDF sampling and iterations to ``progress``. CoACD and V-HACD
    decompose the closed solid the mesh bounds (:func:`real2sim.asset.bottom.closed_solid`: an open
    scan is remeshed closed first, and ``input_closed_by`` in the report says so); primitive fits
    read the mesh's winding number, which holes do not upset.
    """
    start = time.perf_counter()
    if spec.baseline is not None:
        from real2sim.collision.decomposition import decompose

        closed_by = None
        if spec.baseline in ("coacd", "vhacd"):
            from real2sim.asset.bottom import closed_solid

            mesh_canonical = closed_solid(mesh_canonical)
            closed_by = mesh_canonical.metadata["closed_by"]
            if closed_by != "as is" and progress is not None:
                progress(f"the mesh is not closed: {spec.baseline} decomposes it remeshed closed", 0, 0)
        kwargs = {}
        if progress is not None:  # a decomposition reports nothing while it works: its time is named here
            progress(f"decomposing the solid with {spec.baseline}", 0, 0)
        if spec.baseline == "coacd" and config.coacd_config is not None:
            kwargs["coacd_config"] = config.coacd_config
        if spec.baseline == "vhacd" and config.vhacd_config is not None:
            kwargs["vhacd_config"] = config.vhacd_config
        geometry = decompose(mesh_canonical, spec.baseline, rep_dir, seed=config.seed, **kwargs)
        report = {"method": spec.baseline, "final_loss": None, "device": "cpu"}
        if closed_by is not None:
            report["input_closed_by"] = closed_by
    else:
        from real2sim.collision.fit.stage import fit_collision

        geometry, report = fit_collision(
            mesh_canonical,
            spec,
            fit_config=config.fit_config or FitConfig(),
            cache_dir=sdf_cache_dir,
            rep_dir=rep_dir,
            device=config.device,
            seed=config.seed,
            progress=progress,
        )
        report = dict(report)
        report.setdefault("method", "primitive fit (paper IV-C3)")
    report["fit_seconds"] = round(time.perf_counter() - start, 3)
    return geometry, report


def fit_and_measure(solid: trimesh.Trimesh, fitted_solid: trimesh.Trimesh, spec: CollisionSpec, rep_dir: Path,
                    config: AssetConfig, sdf_cache: Path | str | None, progress: ProgressFn | None = None) -> Fitted:
    """``spec`` fitted to ``fitted_solid`` into ``rep_dir`` (its collision.json written), and its fidelity
    against ``solid`` (and against ``fitted_solid`` when that is another, cavity-filled solid)."""
    from real2sim.geometry.fidelity import measure_fidelity

    geometry, report = build_collision(fitted_solid, spec, rep_dir, config, sdf_cache, progress=progress)
    write_collision_json(geometry, rep_dir / "collision.json")
    if progress is not None:
        progress("measuring IoU and Chamfer against the solid", 0, 0)
    fidelity = measure_fidelity(solid, geometry, rep_dir, seed=config.seed)
    if fitted_solid is not solid:  # how well it fits what it was fitted to, beside the true solid
        to_filled = measure_fidelity(fitted_solid, geometry, rep_dir, seed=config.seed)
        fidelity["filled_solid"] = {"iou": to_filled["iou"], "chamfer_mm": to_filled["chamfer_mm"]}
    return Fitted(geometry, report, fidelity)


#: ``FitConfig.max_iterations`` from which fits go side by side by default: a worker process's start
#: (its imports, about 2 s) costs what some 200 iterations of a default fit do, so shorter fits gain
#: less than they pay (docs/design-notes/asset.md#fits-side-by-side).
SIDE_BY_SIDE_MIN_ITERATIONS = 500


def fit_processes(config: AssetConfig, fits: int) -> int:
    """How many processes fit side by side: ``config.fit_workers``, at most one per fit and one per
    thread this process may use (``torch.get_num_threads()``: ``--threads``, a batch worker's share).
    ``fit_workers`` None: as many as that allows when the fits are long (``max_iterations`` at least
    :data:`SIDE_BY_SIDE_MIN_ITERATIONS`), else one: a primitive fit is many small tensor operations
    that a second thread does not speed up, while a second process halves the wall time (why:
    docs/design-notes/asset.md#fits-side-by-side). A GPU fit stays in this process."""
    if config.device != "cpu":
        return 1
    budget = max(1, torch.get_num_threads())
    if config.fit_workers is not None:
        wanted = config.fit_workers
    else:
        long_fits = (config.fit_config or FitConfig()).max_iterations >= SIDE_BY_SIDE_MIN_ITERATIONS
        wanted = budget if long_fits else 1
    return max(1, min(wanted, fits, budget))


def fit_all(solid: trimesh.Trimesh, fitted_solid: trimesh.Trimesh, specs: list[CollisionSpec], folder: Path,
            config: AssetConfig, sdf_cache: Path | str | None, progress: ProgressFn | None = None,
            on_fitted: Callable[[CollisionSpec, Fitted], None] | None = None) -> dict[str, Fitted]:
    """Every SPEC of ``specs`` fitted into ``folder/<spec.name>`` (which must exist), by SPEC text;
    ``on_fitted(spec, fitted)`` is called in this process as each one is done, in the order they finish
    (a build writes a representation's files there while the other fits go on).

    With more than one process (:func:`fit_processes`) the fits run in that many ``python -m
    real2sim.asset.fit_worker`` processes, each with its share of the threads and taking the next SPEC
    when it is done with one (a subprocess rather than a multiprocessing pool, which would re-run a
    user's unguarded script), their progress coming back to ``progress`` line by line; a decomposition
    of :data:`THREADED_BASELINES` then runs here, with every thread. The signed-distance samples the
    primitive fits share are made once, here, while the workers start.
    """
    say = progress or null_progress
    done_with = on_fitted or (lambda spec, fitted: None)
    for spec in specs:
        say(f"collision {spec.text}: fitting", 0, 0)
    side_by_side = fit_processes(config, len(specs)) > 1
    threaded = [s for s in specs if side_by_side and s.baseline in THREADED_BASELINES]
    side = [s for s in specs if s not in threaded]
    workers = fit_processes(config, len(side))
    done = {} if workers == 1 else _fit_side_by_side(solid, fitted_solid, side, folder, config, sdf_cache, say,
                                                     done_with, workers)
    for spec in (side if workers == 1 else []) + threaded:
        done[spec.text] = fit_and_measure(solid, fitted_solid, spec, folder / spec.name, config, sdf_cache,
                                          progress=prefixed(say, f"collision {spec.text}"))
        done_with(spec, done[spec.text])
    return {spec.text: done[spec.text] for spec in specs}


def _fit_side_by_side(solid: trimesh.Trimesh, fitted_solid: trimesh.Trimesh, specs: list[CollisionSpec],
                      folder: Path, config: AssetConfig, sdf_cache: Path | str | None, say: ProgressFn,
                      done_with: Callable[[CollisionSpec, Fitted], None], workers: int) -> dict[str, Fitted]:
    """``specs`` fitted in ``workers`` worker processes (see :func:`fit_all`)."""
    threads = max(1, torch.get_num_threads() // workers)
    jobs = folder / ".fit_jobs"
    jobs.mkdir(exist_ok=True)
    waiting, done = list(specs), {}
    lines: queue.Queue = queue.Queue()
    procs: list[subprocess.Popen] = []
    busy: dict[int, CollisionSpec] = {}  # worker -> the SPEC it fits
    finished = False
    try:
        idle = []
        for k in range(workers):  # first: their imports go on while the samples are made
            proc = subprocess.Popen([sys.executable, "-m", "real2sim.asset.fit_worker", str(threads)],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                    env={**os.environ, "OMP_NUM_THREADS": str(threads)})
            threading.Thread(target=_forward, args=(proc.stdout, lines, k), daemon=True).start()
            procs.append(proc)
            idle.append(k)
        if sum(spec.baseline is None for spec in specs) > 1 and sdf_cache is not None:
            from real2sim.collision.sdf_sampling import SdfSamplingConfig, sample_sdf

            say("sampling the signed distance the primitive fits share", 0, 0)
            sample_sdf(fitted_solid, SdfSamplingConfig(), cache_dir=sdf_cache)
        say(f"fitting {len(specs)} collision SPECs in {workers} processes of {threads} thread(s) each", 0, 0)

        def dispatch() -> None:
            while waiting and idle:
                k, spec = idle.pop(0), waiting.pop(0)
                job = jobs / f"{spec.name}.pkl"
                job.write_bytes(pickle.dumps((solid, fitted_solid, spec, folder / spec.name, config, sdf_cache)))
                procs[k].stdin.write(f"{job}\n")
                procs[k].stdin.flush()
                busy[k] = spec

        while waiting or busy:
            dispatch()
            try:
                k, line = lines.get(timeout=POLL_S)
            except queue.Empty:
                for k, spec in busy.items():
                    if procs[k].poll() is not None:  # died without finishing its SPEC
                        raise RuntimeError(f"the fit worker for {spec.name} ended with exit status "
                                           f"{procs[k].returncode} before its result")
                continue
            if line is None:  # its output closed: it ended; the next poll says how
                continue
            try:
                message = json.loads(line)
            except ValueError:  # a library's own print, not ours
                continue
            if isinstance(message, dict):  # {"done": job}: the SPEC's result is beside its job
                spec = busy.pop(k)
                done[spec.text] = _result(jobs / f"{spec.name}.pkl")
                idle.append(k)
                dispatch()  # the worker's next SPEC before this one's files
                done_with(spec, done[spec.text])
            else:
                say(*message)
        finished = True
    finally:
        for proc in procs:
            try:
                proc.stdin.close()  # no more SPECs: an idle worker ends
            except OSError:
                pass
            if not finished:  # an error or an interrupt: what the others fit is not wanted
                proc.terminate()
        deadline = time.monotonic() + 10.0
        for proc in procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()
        shutil.rmtree(jobs, ignore_errors=True)
    return done


def _forward(stream, lines: queue.Queue, worker: int) -> None:
    for line in stream:
        lines.put((worker, line))
    lines.put((worker, None))


def _result(job: Path) -> Fitted:
    """A worker's Fitted for ``job``, or its exception raised here."""
    out = job.with_suffix(".out")
    if not out.exists():
        raise RuntimeError(f"the fit worker for {job.stem} said it was done and left no result")
    result = pickle.loads(out.read_bytes())
    if isinstance(result, BaseException):
        raise result
    return result


def work_on(jobs, threads: int) -> int:
    """What a worker process does (:mod:`real2sim.asset.fit_worker`): for each job path read from
    ``jobs`` (lines), fit it and write its Fitted (or its exception) beside it, then say so on stdout;
    its progress goes to stdout as JSON lines too. Ends when ``jobs`` does."""
    torch.set_num_threads(threads)  # a process of our own: its pool is ours to size

    def report(message: str, done: int, total: int) -> None:
        print(json.dumps([message, done, total]), flush=True)

    for line in jobs:
        job = Path(line.strip())
        solid, fitted_solid, spec, rep_dir, config, sdf_cache = pickle.loads(job.read_bytes())
        try:
            result: Fitted | BaseException = fit_and_measure(solid, fitted_solid, spec, rep_dir, config, sdf_cache,
                                                             progress=prefixed(report, f"collision {spec.text}"))
        except Exception as exc:  # raised again in the build's process, which reports it
            result = exc
        job.with_suffix(".out").write_bytes(pickle.dumps(result))
        print(json.dumps({"done": str(job)}), flush=True)
    return 0
