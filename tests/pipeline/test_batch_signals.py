"""`real2sim batch` stopped by a signal, and refused at once (issue 69).

SIGTERM and Ctrl-C of a batch leave no lock file in CATALOGUE (a pool worker ended by its parent never
removes its object's `.NAME.lock`: the parent does, once no live process holds it); a private Ray gives
SIGTERM back to the command line, so the batch unwinds, stops Ray and removes its session folder; a second
batch on a held catalogue is refused before the datasets are read; a masses.csv with a third field and a
`"mass_kg": true` are refused. Real processes, real Ray, the smallest captures (8 views at 64x48, hull).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from tests.cli_helpers import run_cli
from tests.pipeline.test_batch import FAST, capture

#: Ray's native failure handler's stack dump, which must never reach the user.
NATIVE_DUMP = ("*** SIGTERM received", "Aborted at")


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("batch_signals_ds")
    return [capture(root / "can_ds", "can"), capture(root / "mug_ds", "mug")]


def _batch(datasets, out: Path, *extra, group: bool = False) -> subprocess.Popen:
    argv = [sys.executable, "-m", "real2sim", "batch", *map(str, datasets), "--mass-kg", "0.4", "--out", str(out),
            *FAST, *extra]
    # SIGINT at its default, as under a terminal: a test run started in the background (`make test &`) ignores
    # SIGINT, a child inherits that and Python keeps it ignored, and the batch then finished and exited 0
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONWARNINGS": "ignore"}, start_new_session=group,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _locks(out: Path) -> list[str]:
    """Every lock file of the catalogue: the objects' inside it and the catalogue's own beside it."""
    inside = sorted(p.name for p in out.glob(".*.lock")) if out.is_dir() else []
    return inside + ([f"../.{out.name}.lock"] if out.with_name(f".{out.name}.lock").exists() else [])


def _wait_for_objects(proc: subprocess.Popen, out: Path, count: int, timeout_s: float = 240.0) -> None:
    """Until ``count`` objects are being run (their workers hold their locks)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        if len(list(out.glob(".*.lock"))) >= count:
            return
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"{count} objects never started: {proc.communicate()}")


@pytest.mark.parametrize("sig, workers", [(signal.SIGTERM, 1), (signal.SIGTERM, 2), (signal.SIGINT, 1),
                                          (signal.SIGINT, 2)], ids=["sigterm-1", "sigterm-2", "sigint-1", "sigint-2"])
def test_a_signalled_local_batch_leaves_no_lock_file(two, tmp_path, sig, workers):
    out = tmp_path / "cat"
    # SIGINT as a terminal's Ctrl-C sends it, to the whole process group (the workers ignore it); SIGTERM as
    # `kill PID` does, to the batch alone: either way the parent ends the workers, which never clean up
    proc = _batch(two, out, "--workers", str(workers), group=sig == signal.SIGINT)
    _wait_for_objects(proc, out, workers)
    started = time.monotonic()
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    word = "terminated" if sig == signal.SIGTERM else "interrupted"
    assert proc.returncode == 128 + sig, err
    assert _locks(out) == [], err
    assert "Traceback" not in err and sum(word in line for line in err.splitlines()) == 1, err
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name], err  # nor a run's temporary folder
    assert time.monotonic() - started < 30, err


def test_a_lock_a_live_process_holds_is_never_removed(tmp_path):
    from real2sim.pipeline.batch import ObjectJob, release_stale_locks

    out = tmp_path / "cat"
    out.mkdir()
    job = ObjectJob(name="can_ds", dataset=tmp_path / "can_ds", asset_dir=out / "can_ds")
    lock = out / ".can_ds.lock"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import time\nfrom real2sim.plumbing.outputs import output_lock\n"
         f"with output_lock({str(job.asset_dir)!r}):\n    print('held', flush=True)\n    time.sleep(120)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        assert release_stale_locks([job], wait_s=0.3) == ["can_ds"]
        assert lock.exists()  # another live process's: kept
    finally:
        holder.kill()  # SIGKILL: its lock file stays behind, as a killed worker's does
        holder.wait()
    assert lock.exists()
    assert release_stale_locks([job], wait_s=0.0) == []
    assert not lock.exists()


_RAY_SIGTERM = textwrap.dedent("""
    import ctypes, os, signal, threading, time, types

    libc = ctypes.CDLL(None)

    class Action(ctypes.Structure):
        _fields_ = [("handler", ctypes.c_void_p), ("mask", ctypes.c_ulong * 16), ("flags", ctypes.c_int),
                    ("restorer", ctypes.c_void_p)]

    def native():  # the handler the kernel calls: Ray sets its own behind Python's back
        action = Action()
        libc.sigaction(signal.SIGTERM, None, ctypes.byref(action))
        return action.handler

    class Terminated(KeyboardInterrupt):
        pass

    def ours(signum, frame):
        raise Terminated()

    def nap(job):
        time.sleep(60)

    signal.signal(signal.SIGTERM, ours)
    before = native()
    from real2sim.pipeline.batch import RayObjects

    ray = RayObjects(1, None, 30.0)
    print("after init", signal.getsignal(signal.SIGTERM) is ours, native() == before, flush=True)
    session = ray._temp_dir
    try:
        handle = ray.submit(nap, types.SimpleNamespace(gpu=False))
        threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM)).start()
        ray.wait({handle})  # inside Ray, which turns what a handler raises into a plain KeyboardInterrupt
        print("not terminated", flush=True)
    except Terminated:
        print("terminated", flush=True)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
    finally:
        ray.shutdown(abort=True)
    print("after shutdown", signal.getsignal(signal.SIGTERM) is ours, native() == before,
          os.path.exists(session), flush=True)
""")


def test_a_private_ray_gives_sigterm_back_to_the_command_line(tmp_path):
    """ray.init installs a Python handler (sys.exit(15)) and a native one that prints a stack dump; ray.shutdown
    leaves SIGTERM at the default (death, no clean-up). Ours is put back after both."""
    done = subprocess.run([sys.executable, "-c", _RAY_SIGTERM], capture_output=True, text=True, timeout=180,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["after init True True", "terminated", "after shutdown True True False"], \
        (done.stdout, done.stderr)
    assert not any(dump in done.stderr for dump in NATIVE_DUMP), done.stderr


def test_sigterm_of_a_batch_on_a_private_ray_exits_143_and_removes_rays_session(two, tmp_path):
    pytest.importorskip("ray")
    sessions = set(Path(tempfile.gettempdir()).glob("r2s_ray_*"))
    out = tmp_path / "cat"
    proc = _batch(two, out, "--executor", "ray", "--workers", "2")
    _wait_for_objects(proc, out, 1)
    proc.send_signal(signal.SIGTERM)
    stdout, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert not any(dump in stdout + err for dump in NATIVE_DUMP), err
    assert "Traceback" not in err and sum("terminated" in line for line in err.splitlines()) == 1, err
    assert set(Path(tempfile.gettempdir()).glob("r2s_ray_*")) <= sessions, err
    assert _locks(out) == [], err


def test_a_second_batch_on_a_held_catalogue_is_refused_at_once(two, tmp_path):
    out = tmp_path / "cat"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import time\nfrom real2sim.plumbing.outputs import output_lock\n"
         f"with output_lock({str(out)!r}):\n    print('held', flush=True)\n    time.sleep(120)"],
        stdout=subprocess.PIPE, text=True)
    not_ds = tmp_path / "photos_of_nothing"
    not_ds.mkdir()
    try:
        assert holder.stdout.readline().strip() == "held"
        started = time.monotonic()
        second = _batch(two, out)
        _, err = second.communicate(timeout=120)
        took = time.monotonic() - started
        assert second.returncode == 2 and "another real2sim process is writing" in err, err
        assert len(err.strip().splitlines()) == 1, err
        assert took < 3.0, f"refused after {took:.1f} s"  # before the datasets are read (~5-12 s before)
        # the lock is taken before any dataset is looked at: a folder that is none is not reached
        second = _batch([*two, not_ds], out)
        _, err = second.communicate(timeout=120)
        assert second.returncode == 2 and "another real2sim process is writing" in err, err
    finally:
        holder.kill()
        holder.wait()
    assert not out.exists()


def _refused(capsys, *argv) -> str:
    code, _out, err = run_cli(capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("text, expected", [
    ("name,mass_kg\ncan_ds,0.3,0.5\n", "line 2: 3 fields, the header has 2"),
    ("name,mass_kg\n\ncan_ds,0.3\nmug_ds,0.2,kg\n", "line 4: 3 fields"),  # the line in the file, blank ones counted
    ("name,mass_kg,density\ncan_ds,0.3,900\n", "line 1: the columns are name,mass_kg and nothing else (has 'density')"),
    ("name,mass_kg,mass_kg\ncan_ds,0.3,0.5\n", "line 1: the columns are name,mass_kg and nothing else"),
], ids=["third-field", "line-after-a-blank-one", "third-column", "mass-twice"])
def test_a_masses_file_with_a_third_field_is_refused(capsys, two, tmp_path, text, expected):
    masses = tmp_path / "masses.csv"
    masses.write_text(text)
    out = tmp_path / "cat"
    line = _refused(capsys, "batch", *two, "--masses", masses, "--out", out, *FAST)
    assert str(masses) in line and expected in line, line
    assert not out.exists()


@pytest.mark.parametrize("value, shown", [(True, "true"), ("0.3", '"0.3"'), (None, "null"), ([0.3], "[0.3]"),
                                          (10 ** 400, "> 0 and <= 1000")],
                         ids=["true", "string", "null", "list", "past-float"])
def test_a_mass_json_that_holds_no_number_is_that_objects_failure(capsys, two, tmp_path, value, shown):
    ds = tmp_path / "can_ds"
    shutil.copytree(two[0], ds)
    (ds / "mass.json").write_text(json.dumps({"mass_kg": value}))
    out = tmp_path / "cat"
    code, stdout, err = run_cli(capsys, "batch", ds, "--mass-from", "mass.json", "--out", out, *FAST)
    assert code == 1 and "Traceback" not in err, (stdout, err)
    assert "can_ds: FAILED: no mass:" in stdout and shown in stdout, stdout
    assert not (out / "can_ds").exists()  # nothing was run for it
