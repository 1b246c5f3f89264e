"""Where the sweep's jobs run: this process, a local process pool, or Ray.

Each executor offers submit(fn, arg) -> handle, wait(handles) -> finished handles,
result(handle), shutdown(abort=False); the rows are the same on every executor.

Nothing is left running: ``shutdown(abort=True)`` (the sweep calls it when it ends by an
exception, KeyboardInterrupt included -- the command line turns SIGTERM into one) cancels
what is queued and terminates the workers instead of waiting for their simulations. If the
sweep's process is killed outright (SIGKILL), each pool worker notices: on Linux the kernel
kills it with its parent (``PR_SET_PDEATHSIG``), elsewhere a watcher thread sees the parent
change within a second. Once the workers are gone, multiprocessing's resource tracker (which
holds the same pipe and stderr) sees its pipe close and exits too.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Callable

from real2sim.evaluate.jobs import one_line, run_reference_job, runs_row
from real2sim.plumbing.errors import UserInputError

EXECUTORS = ("local", "ray")
#: Why every simulation fails when the pool's workers die before they run anything: the usual cause.
WORKERS_DO_NOT_START = ("the simulations' worker processes die as they start, before running anything: a script "
                        "that calls evaluate() (or run) with jobs > 1 must do so under `if __name__ == \"__main__\":`"
                        ", since each worker imports the script again; or pass jobs=1 (EvaluationConfig.jobs, --jobs 1)")


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

    def shutdown(self, abort: bool = False) -> None:
        pass


def _set_parent_death_signal() -> bool:
    """Ask Linux to SIGKILL this process when its parent dies; False where that is unavailable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent_pid: int, period_s: float = 1.0) -> None:
    while True:
        time.sleep(period_s)
        if os.getppid() != parent_pid:
            os._exit(1)


def _init_worker(parent_pid: int) -> None:
    """Pool worker initializer: die with the sweep's process, and leave Ctrl-C to it.

    A terminal's Ctrl-C reaches the whole process group; the parent then terminates the
    workers itself (a worker that died of KeyboardInterrupt would only break the pool).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    armed = _set_parent_death_signal()
    if os.getppid() != parent_pid:  # the parent died before the request above took effect
        os._exit(1)
    if not armed:
        threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watch").start()


def _terminate_pool(pool) -> None:
    """Cancel what ``pool`` has queued and end its workers now (SIGTERM, then SIGKILL)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + 5.0
    for p in processes:
        # join() returns when the worker's sentinel pipe closes, which can be a moment before
        # the kernel lets its exit status be collected: poll until it is.
        while p.exitcode is None and time.monotonic() < deadline:
            p.join(timeout=0.05)
        if p.exitcode is None:
            p.kill()
            p.join(timeout=1.0)


class PoolExecutor:
    """A spawn-context process pool (spawn: Drake and rich's refresh thread do not mix with fork).

    A worker that dies in native code breaks the whole pool, failing every job in
    flight. Those jobs are resubmitted to a fresh pool; a job caught in a second break
    is run alone in its own process, and only if that process dies too is the job
    reported as failed -- so a crashing simulation costs its own row and no other.
    """

    def __init__(self, jobs: int) -> None:
        self._jobs = jobs
        # spawn re-imports the parent's __main__ from its file; a script read from stdin or
        # typed interactively has none, and there fork is the only way.
        main_file = getattr(sys.modules.get("__main__"), "__file__", None)
        method = "spawn" if main_file is None or os.path.exists(main_file) else "fork"
        self._ctx = multiprocessing.get_context(method)
        self._pool = self._new_pool(jobs)
        self._solo = None  # one-worker pool for jobs caught in two pool breaks
        self._start_ok: bool | None = None  # see _workers_start
        self._futures: dict[int, Any] = {}
        self._calls: dict[int, tuple[Callable, Any, int]] = {}
        self._next = 0

    def submit(self, fn: Callable, arg: Any, attempt: int = 0) -> int:
        self._next += 1
        self._futures[self._next] = self._pool.submit(fn, arg)
        self._calls[self._next] = (fn, arg, attempt)
        return self._next

    def _new_pool(self, workers: int) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=workers, mp_context=self._ctx, initializer=_init_worker,
                                   initargs=(os.getpid(),))

    def wait(self, handles: set) -> set:
        by_future = {self._futures[h]: h for h in handles}
        done, _ = wait_futures(list(by_future), return_when=FIRST_COMPLETED)
        return {by_future[f] for f in done}

    def result(self, handle: int) -> Any:
        future = self._futures.pop(handle)
        fn, arg, attempt = self._calls.pop(handle)
        try:
            return future.result()
        except BrokenProcessPool:
            self._renew_pool()
            if attempt >= 1:
                return self._run_isolated(fn, arg)
            return Retry(fn, arg, attempt + 1)

    def _run_isolated(self, fn: Callable, arg: Any) -> Any:
        """Run one job alone in a one-worker pool: if that dies too, the job is the culprit."""
        if self._solo is None:
            self._solo = self._new_pool(1)
        try:
            return self._solo.submit(fn, arg).result()
        except BrokenProcessPool:
            self._solo.shutdown(wait=False, cancel_futures=True)
            self._solo = None
            if not self._workers_start():
                raise UserInputError(WORKERS_DO_NOT_START) from None
            return _failed_result(fn, arg, "the simulation's worker process died (crash in native code)")

    def _workers_start(self) -> bool:
        """Whether a fresh worker runs a job that does nothing (asked once, after a job's own process died):
        when it does not, the fault is the workers' start-up, not the job's simulation."""
        if self._start_ok is None:
            probe, self._start_ok = self._new_pool(1), False
            with contextlib.suppress(BrokenProcessPool):
                self._start_ok = probe.submit(os.getpid).result() > 0
            probe.shutdown(wait=False, cancel_futures=True)
        return self._start_ok

    def _renew_pool(self) -> None:
        # Only replace a pool that is actually broken (several futures report the same break).
        if getattr(self._pool, "_broken", False):
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool(self._jobs)

    def shutdown(self, abort: bool = False) -> None:
        """Wait for the workers to exit; ``abort``: end them now, dropping what they were doing."""
        pools = [p for p in (self._pool, self._solo) if p is not None]
        self._solo = None
        for pool in pools:
            if abort:
                _terminate_pool(pool)
            else:
                pool.shutdown(wait=True, cancel_futures=True)


def probe_address(address: str, timeout_s: float) -> None:
    """Fail fast when a ``host:port`` (or ``ray://host:port``) address does not accept connections."""
    import socket

    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or "/" in hostport:
        return  # "auto", "local" and other forms: left to ray.init, under the timeout
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise UserInputError(f"could not reach the Ray cluster at {address} within {timeout_s:g} s "
                             f"({exc.strerror or type(exc).__name__}); check --ray-address / $RAY_ADDRESS, or "
                             "raise --ray-timeout-s") from None


def keeping_sigterm(call: Callable[[], Any]) -> Any:
    """``call()`` (``ray.init``, ``ray.shutdown``, a wait for either), then SIGTERM given back to the
    handler Python had on record before it.

    ``ray.init`` installs two handlers of its own (Ray 2.60): in Python, ``sys.exit(15)`` (main thread
    only), and through its C++ core worker, in any thread and behind Python's back, a native one that
    prints a stack dump twice; ``ray.shutdown`` then leaves SIGTERM at the kernel's default (death, no
    clean-up). Importing ray installs nothing. A SIGTERM that Ray's Python handler caught during the
    call (a ``SystemExit(15)``) is handed on to the handler we had.
    """
    import threading

    before = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    if before is None:  # not the main thread, or a handler set outside Python: nothing we could put back
        return call()
    try:
        return call()
    except SystemExit as exc:
        if exc.code != signal.SIGTERM or not callable(before):
            raise
        signal.signal(signal.SIGTERM, before)
        before(signal.SIGTERM, None)  # ours raises (the command line's Terminated); if not, Ray's exit stands
        raise
    finally:
        signal.signal(signal.SIGTERM, before)  # sets the native handler too, whatever Ray left there


def sigterm_through_ray(call: Callable[[], Any]) -> Any:
    """``call()``, a Ray call that blocks (``ray.wait``, ``ray.get``), with a SIGTERM during it still raising
    what our handler raises: Ray runs the handler inside, catches the exception and raises a plain
    KeyboardInterrupt instead, so the command line would say "interrupted" (exit 143 all the same)."""
    import threading

    ours = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    if not callable(ours):
        return call()
    seen: list[int] = []

    def recording(signum, frame) -> None:
        seen.append(signum)
        ours(signum, frame)

    signal.signal(signal.SIGTERM, recording)
    try:
        return call()
    except KeyboardInterrupt:
        if not seen:
            raise
        ours(signal.SIGTERM, None)  # raises ours again, outside Ray; if it does not, Ray's stands
        raise
    finally:
        signal.signal(signal.SIGTERM, ours)


def init_ray_bounded(ray, address: str | None, kwargs: dict, timeout_s: float) -> None:
    """``ray.init`` with a wall-clock bound: it retries an unreachable address for minutes.

    It runs in a daemon thread so that the caller can give up; a call still stuck then is
    abandoned (the process exits with the error) rather than waited for.
    """
    outcome: dict[str, BaseException | None] = {}

    def start() -> None:
        try:
            ray.init(address=address, **kwargs)
            outcome["error"] = None
        except BaseException as exc:  # handed to the caller
            outcome["error"] = exc

    thread = threading.Thread(target=start, daemon=True, name="ray-init")
    thread.start()
    keeping_sigterm(lambda: thread.join(timeout_s))  # Ray's native handler, installed from the thread
    where = address or "a local Ray"
    if thread.is_alive():
        error = UserInputError(f"could not start or reach Ray at {where} within {timeout_s:g} s; check --ray-address "
                               "/ $RAY_ADDRESS, or raise --ray-timeout-s")
        # The abandoned call's C++ client keeps retrying, and warns on stderr a few seconds later if
        # the process is still finalising (slow on a loaded machine): the command line exits at once.
        error.exit_now = True
        raise error
    if outcome.get("error") is not None:
        raise UserInputError(f"could not start or reach Ray at {where}: {one_line(outcome['error'])}")


class _RayExecutor:
    """Ray tasks, one CPU each; ``address`` None starts (or joins) a local Ray.

    ``timeout_s`` bounds joining a cluster; a local Ray is started in the calling thread, unbounded.
    """

    def __init__(self, jobs: int, address: str | None, timeout_s: float = 30.0) -> None:
        try:
            import ray
        except ImportError:  # pragma: no cover - ray is a dependency
            raise UserInputError("--executor ray needs the 'ray' package (pip install ray)") from None
        self._ray = ray
        address = address or os.environ.get("RAY_ADDRESS") or None
        if not ray.is_initialized():
            import logging

            # Ray's own INFO/WARNING lines would break the one-line error contract of the command line.
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "logging_level": logging.ERROR}
            if address is None:
                # A local Ray is started in this thread: Ray ties the processes it starts to the
                # thread that starts them (they get a parent-death signal), so a helper thread's
                # exit would take the cluster down a minute into the sweep.
                kwargs["num_cpus"] = jobs
                keeping_sigterm(lambda: ray.init(**kwargs))
            else:
                probe_address(address, timeout_s)
                init_ray_bounded(ray, address, kwargs, timeout_s)
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
        done, _ = sigterm_through_ray(lambda: self._ray.wait(list(by_ref), num_returns=1))
        return {by_ref[r] for r in done}

    def result(self, handle: int) -> Any:
        ref, fn, arg = self._refs.pop(handle)
        try:
            return sigterm_through_ray(lambda: self._ray.get(ref))
        except Exception as exc:  # the worker died (our functions catch their own errors)
            return _failed_result(fn, arg, f"ray task failed: {one_line(exc)}")

    def shutdown(self, abort: bool = False) -> None:
        if abort:
            for ref, _fn, _arg in self._refs.values():
                try:
                    self._ray.cancel(ref, force=True)
                except Exception:  # already finished, or the cluster is gone
                    pass
            self._refs.clear()
        if self._owns_ray:
            keeping_sigterm(self._ray.shutdown)


@dataclass(frozen=True)
class Retry:
    """What ``result`` returns for a job whose pool broke under it: submit ``fn(arg)`` again with ``attempt``."""

    fn: Callable
    arg: Any
    attempt: int


def _failed_result(fn: Callable, arg: Any, message: str) -> Any:
    if fn is run_reference_job:
        return "error", message
    key = getattr(arg, "key", None)
    return runs_row(key, error=message) if key is not None else {"error": message}


def make_executor(config):
    """The executor ``config`` (an EvaluationConfig) asks for: Ray, this process (``jobs`` 1) or a process pool."""
    if config.executor == "ray":
        return _RayExecutor(config.jobs, config.ray_address, getattr(config, "ray_timeout_s", 30.0))
    if config.jobs == 1:
        return _SerialExecutor()
    return PoolExecutor(config.jobs)
