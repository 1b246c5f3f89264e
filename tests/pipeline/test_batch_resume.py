"""`real2sim batch` killed mid-object (issue 31): a worker killed with SIGKILL costs only the stage it was in
(the batch goes on and resumes that object from run's cache), and killing the whole batch and running the
same command again gives the same catalogue.csv, byte for byte, as a batch never interrupted."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.pipeline.test_batch import FAST, capture, run_json


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("batch_resume_ds")
    return [capture(root / "can_ds", "can"), capture(root / "mug_ds", "mug")]


def _batch(datasets, out: Path, *extra) -> subprocess.Popen:
    argv = [sys.executable, "-m", "real2sim", "batch", *map(str, datasets), "--mass-kg", "0.3", "--out", str(out),
            *FAST, *extra]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONWARNINGS": "ignore"})


def _children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (Linux /proc)."""
    out = []
    try:
        kids = [int(k) for t in os.listdir(f"/proc/{pid}/task")
                for k in Path(f"/proc/{pid}/task/{t}/children").read_text().split()]
    except (OSError, ValueError):
        return out
    for kid in kids:
        out += [kid, *_children(kid)]
    return out


def _workers(pid: int) -> list[int]:
    """The process pool's workers below the batch ``pid`` (multiprocessing's spawned children)."""
    found = []
    for kid in _children(pid):
        try:
            cmdline = Path(f"/proc/{kid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmdline:
            found.append(kid)
    return found


def _wait_for_stage(asset_dir: Path, stage: str, proc: subprocess.Popen, timeout_s: float = 600.0) -> dict:
    """run.json of ``asset_dir`` once ``stage`` is recorded in it."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            data = run_json(asset_dir)
        except (OSError, ValueError):
            data = {"stages": {}}
        if stage in data["stages"]:
            return data
        time.sleep(0.1)
    raise AssertionError(f"{stage} never finished in {asset_dir}")


def test_a_killed_worker_costs_only_its_stage_and_a_rerun_redoes_nothing(two, tmp_path):
    out = tmp_path / "cat"
    proc = _batch(two, out, "--workers", "1")  # one worker: the can first, then the mug
    try:
        before = _wait_for_stage(out / "can_ds", "reconstruct", proc)
        assert "asset" not in before["stages"], "the asset stage finished before the worker could be killed"
        workers = _workers(proc.pid)
        assert len(workers) == 1, workers
        os.kill(workers[0], signal.SIGKILL)  # in the can's asset stage
        stdout, stderr = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, (stdout, stderr)
    assert "can_ds: done (ran asset, truth)" in stdout  # resumed after its reconstruction, in the same batch
    assert "mug_ds: done (ran reconstruct, asset, truth)" in stdout
    after = run_json(out / "can_ds")
    assert after["stages"]["reconstruct"] == before["stages"]["reconstruct"]  # not redone
    rows = (out / "catalogue.csv").read_text().splitlines()
    assert [r.split(",")[:2] for r in rows[1:]] == [["can_ds", "done"], ["mug_ds", "done"]]
    manifests = {name: run_json(out / name) for name in ("can_ds", "mug_ds")}
    csv_bytes = (out / "catalogue.csv").read_bytes()

    rerun = _batch(two, out)
    stdout, stderr = rerun.communicate(timeout=600)
    assert rerun.returncode == 0, (stdout, stderr)
    assert "can_ds: finished before, skipped" in stdout and "mug_ds: finished before, skipped" in stdout
    assert {name: run_json(out / name) for name in manifests} == manifests
    assert (out / "catalogue.csv").read_bytes() == csv_bytes


@pytest.mark.slow
def test_killed_at_random_points_five_times_the_same_catalogue(two, tmp_path):
    """The issue's target: kill the whole batch five times at random points, rerun until it finishes; its
    catalogue.csv is byte for byte an uninterrupted batch's (minutes)."""
    import random

    whole = tmp_path / "whole"
    proc = _batch(two, whole, "--workers", "2")
    stdout, stderr = proc.communicate(timeout=1800)
    assert proc.returncode == 0, (stdout, stderr)
    out = tmp_path / "interrupted"
    rng = random.Random(31)
    for _kill in range(5):
        proc = _batch(two, out, "--workers", "2")
        time.sleep(rng.uniform(5.0, 40.0))
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)  # its workers die with it (PR_SET_PDEATHSIG)
        proc.communicate()
    proc = _batch(two, out, "--workers", "2")
    stdout, stderr = proc.communicate(timeout=1800)
    assert proc.returncode == 0, (stdout, stderr)
    assert (out / "catalogue.csv").read_bytes() == (whole / "catalogue.csv").read_bytes()
    assert json.loads((out / ".batch" / "can_ds.json").read_text())["status"] == "done"
