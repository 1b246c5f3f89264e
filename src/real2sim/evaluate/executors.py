"""Where the sweep's jobs run: this process, a local process pool, or Ray.

Each executor offers submit(fn, arg) -> handle, wait(handles) -> finished handles,
result(handle), shutdown(); the rows are the same on every executor.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Callable

from real2sim.evaluate.jobs import _one_line, _row, run_reference_job
from real2sim.formats.errors import UserInputError


EXECUTORS = ("local", "ray")


def _default_jobs() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


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


def _make_executor(config):
    if config.executor == "ray":
        return _RayExecutor(config.jobs, config.ray_address)
    if config.jobs == 1:
        return _SerialExecutor()
    return _PoolExecutor(config.jobs)
