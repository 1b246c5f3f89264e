"""The evaluation's reliability contract (issue #14): inputs never deleted, torn rows rerun,
one sweep per output, bounded simulations, nothing left running, bad input refused whole,
no absolute paths in what is published.

Real Drake on the tiny box asset of test_sweep.py, with short scenes; the signal tests run
the real command line in a subprocess with a process pool.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trimesh

from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME
from real2sim.formats.results import CHECK_COLUMN, RUN_COLUMNS, load_runs_csv, read_runs_csv, read_summary_csv
from tests.evaluate.test_sweep import BOX_EXTENTS_M, SHORT_SCENE, make_box_asset

PUSH_POINT = EvaluationConfig(tasks=("push",), contact_models=("point",), runs=1, jobs=1, scene=SHORT_SCENE)
SRC = str(Path(__file__).resolve().parents[2] / "src")


def _cli(*args: str) -> tuple[int, str]:
    from real2sim.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, err.getvalue()


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    return make_box_asset(tmp_path_factory.mktemp("rel") / "box", reps=("boxes_1", "mesh"), broken=True)


@pytest.fixture(scope="module")
def finished(box, tmp_path_factory) -> Path:
    """A finished results folder: 3 representations x point contact, one push run."""
    out = tmp_path_factory.mktemp("finished") / "res"
    evaluate([box], out, PUSH_POINT)
    return out


# ------------------------------------------------------------------------------------------
# 1. --overwrite never deletes an input


def test_overwrite_never_deletes_inputs(box, tmp_path, monkeypatch):
    before = _snapshot(box)
    ref = tmp_path / "ref.obj"
    trimesh.creation.box(extents=BOX_EXTENTS_M).export(ref)
    for out, needle in ((box, "is the input"), (box / "boxes_1", "is the input"), (box / "visual", "is the input"),
                        (box / "boxes_1" / "res", "lies inside the input"), (box.parent, "contains the input")):
        with pytest.raises(UserInputError, match=needle):
            evaluate([box], out, PUSH_POINT, overwrite=True)
    with pytest.raises(UserInputError, match="is the input"):
        evaluate([box], ref, PUSH_POINT, reference_mesh=ref, overwrite=True)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserInputError, match="working folder"):
        evaluate([box], tmp_path, PUSH_POINT, overwrite=True)
    # A folder real2sim did not make is not replaced, even with --overwrite.
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(UserInputError, match="did not make"):
        evaluate([box], tmp_path / "mine", PUSH_POINT, overwrite=True)
    # The command line: one line, exit 2.
    code, err = _cli("evaluate", box, "--out", box, "--overwrite", "--tasks", "push", "--runs", "1")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "is the input" in err
    assert _snapshot(box) == before
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"
    assert not list(box.parent.glob(".*.lock")) and not list(box.parent.glob(".*.partial"))


def test_results_inside_the_asset_folder_as_real2sim_run_writes_them(box, tmp_path):
    import shutil

    asset = tmp_path / "box"
    shutil.copytree(box, asset)
    before = _snapshot(asset)
    for _ in range(2):  # real2sim run: ASSETDIR/results, with overwrite=True each time
        result = evaluate([asset], asset / "results", PUSH_POINT, overwrite=True)
        assert result.failed == 1 and (asset / "results" / MARKER_NAME).is_file()
    after = {k: v for k, v in _snapshot(asset).items() if not k.startswith("results/")}
    assert after == before
    assert not list(asset.glob(".*"))  # no working folder or lock left behind


def test_results_of_an_older_version_are_resumed_and_replaced_only_when_all_ours(finished, box, tmp_path):
    import shutil

    old = tmp_path / "old"
    shutil.copytree(finished, old)
    (old / MARKER_NAME).unlink()  # made before the marker existed
    result = evaluate([box], old, PUSH_POINT)
    assert result.skipped == 2 and (old / MARKER_NAME).is_file()  # resumed, and marked as ours
    (old / MARKER_NAME).unlink()
    (old / "my_notes.txt").write_text("mine")
    with pytest.raises(UserInputError, match="my_notes.txt"):
        evaluate([box], old, PUSH_POINT, overwrite=True)
    assert (old / "my_notes.txt").read_text() == "mine" and not (old / MARKER_NAME).exists()
    (old / "my_notes.txt").unlink()
    result = evaluate([box], old, PUSH_POINT, overwrite=True)
    assert result.skipped == 0 and result.simulated == 3


# ------------------------------------------------------------------------------------------
# 2. torn runs.csv rows


def _rewrite_runs(path: Path, edit) -> None:
    with open(path, newline="") as fh:
        records = list(csv.reader(fh))
    records = edit(records)
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(records)


def test_torn_row_is_rerun_and_left_out_of_the_report(finished, box, tmp_path):
    import shutil

    out = tmp_path / "res"
    shutil.copytree(finished, out)
    rows = read_runs_csv(out / "runs.csv")
    assert len(rows) == 3 and load_runs_csv(out / "runs.csv").verified
    good = next(i for i, r in enumerate(rows) if r["representation"] == "boxes_1")
    ate_col = RUN_COLUMNS.index("ate_m")

    def cut_mid_number(records):
        # "0.000861..." -> "0.00": the row still has its fields and parses, only the checksum knows.
        records[1 + good][ate_col] = records[1 + good][ate_col][:4]
        return records

    _rewrite_runs(out / "runs.csv", cut_mid_number)
    table = load_runs_csv(out / "runs.csv")
    assert table.torn_lines == (2 + good,) and len(table.rows) == 2

    # report: the torn row is left out, with one warning line; exit 0.
    code, err = _cli("report", out)
    assert code == 0 and err.count("warning") == 1 and f"line {2 + good}" in err, err
    assert "boxes_1_point" not in {r["representation"] for r in read_summary_csv(out / "summary.csv")}

    # resume: the torn row is simulated again (and the failed one); the complete one is kept.
    result = evaluate([box], out, PUSH_POINT)
    assert result.simulated == 2 and result.skipped == 1
    redone = {r["representation"]: r for r in result.runs}
    assert not redone["boxes_1"]["error"] and redone["boxes_1"]["ate_m"] == pytest.approx(rows[good]["ate_m"])
    assert load_runs_csv(out / "runs.csv").torn_lines == ()

    # A row with a field missing, or a number that does not parse, is torn too.
    _rewrite_runs(out / "runs.csv", lambda rec: [rec[0], rec[1][:-3], *rec[2:]])
    assert len(load_runs_csv(out / "runs.csv").torn_lines) == 1


def test_runs_csv_without_checksums_still_reads(finished, tmp_path):
    rows = read_runs_csv(finished / "runs.csv")
    legacy = tmp_path / "runs.csv"
    with open(legacy, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(RUN_COLUMNS)
        for r in rows:
            w.writerow([repr(r[c]) if isinstance(r[c], float) else r[c] for c in RUN_COLUMNS])
        w.writerow(["box", "boxes_1", "point", "push", "7", "0.1"])  # short: torn
    table = load_runs_csv(legacy)
    assert not table.verified and len(table.rows) == 3 and table.torn_lines == (5,)
    with open(finished / "runs.csv", newline="") as fh:
        assert next(csv.reader(fh))[-1] == CHECK_COLUMN


def test_report_refuses_damaged_results_whole(finished, tmp_path):
    import shutil

    out = tmp_path / "res"
    shutil.copytree(finished, out)

    def refused(needle: str) -> None:
        before = _snapshot(out)
        code, err = _cli("report", out)
        assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
        assert _snapshot(out) == before  # nothing half-updated
        assert not [p for p in out.rglob("*") if ".tmp" in p.name] and not list(tmp_path.glob(".*"))

    config = (out / "config.json").read_bytes()
    (out / "config.json").write_text("{ not json")
    refused("config.json")
    (out / "config.json").write_bytes(config)
    (out / "pareto_ate_vs_time.png").unlink()
    (out / "pareto_ate_vs_time.png").mkdir()  # an output's name taken by a folder
    refused("pareto_ate_vs_time.png")
    (out / "pareto_ate_vs_time.png").rmdir()
    runs = (out / "runs.csv").read_bytes()
    (out / "runs.csv").unlink()
    (out / "runs.csv").mkdir()
    refused("runs.csv")
    (out / "runs.csv").rmdir()
    (out / "runs.csv").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe binary")
    refused("runs.csv")
    (out / "runs.csv").write_bytes(runs)
    code, err = _cli("report", out)
    assert code == 0 and not err, err
    assert (out / "pareto_ate_vs_time.png").is_file()


def test_resume_from_a_binary_runs_csv_is_refused_with_nothing_written(finished, box, tmp_path):
    import shutil

    out = tmp_path / "res"
    shutil.copytree(finished, out)
    (out / "runs.csv").write_bytes(bytes(range(256)) * 4)
    before = _snapshot(out)
    code, err = _cli("evaluate", box, "--out", out, "--tasks", "push", "--contact", "point", "--runs", "1",
                     "--jobs", "1", "--duration-scale", "0.2")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "runs.csv" in err, err
    assert _snapshot(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["res"]


# ------------------------------------------------------------------------------------------
# 4. nothing runs forever


def test_simulation_past_its_time_limit_is_a_timeout_row_and_the_sweep_goes_on(box, tmp_path):
    config = EvaluationConfig(tasks=("push",), contact_models=("point",), runs=1, jobs=1, scene=SHORT_SCENE,
                              sim_timeout_s=1e-3)
    result = evaluate([box], tmp_path / "res", config)
    assert len(result.runs) == 3 and result.failed == 3
    assert all(r["error"].startswith("timeout:") for r in result.runs), [r["error"] for r in result.runs]
    with pytest.raises(UserInputError, match="sim-timeout-s"):
        EvaluationConfig(sim_timeout_s=math.inf)


def test_candidate_timeout_inside_the_simulation_loop(box):
    from real2sim.evaluate.simulate import SimulationTimeout, simulate_candidate, simulate_reference
    from real2sim.evaluate.scene.tasks import make_run_specs
    from real2sim.formats.physical import read_physical_properties

    spec = make_run_specs("push", 1, 0)[0]
    props = read_physical_properties(box / "physical_properties.json")
    ref = simulate_reference(box / "visual" / "model.obj", props, spec, SHORT_SCENE, timeout_s=600)
    t0 = time.monotonic()
    with pytest.raises(SimulationTimeout, match="^timeout: boxes_1 point push run 0"):
        simulate_candidate(box / "boxes_1" / "model.urdf", "point", spec, SHORT_SCENE, ref, timeout_s=0.02)
    assert time.monotonic() - t0 < 5


def _open_half_shell(path: Path) -> Path:
    """The upper half of a sphere around the box: an open surface, the box's CoM on its rim plane."""
    s = trimesh.creation.icosphere(2, radius=0.05)
    trimesh.Trimesh(s.vertices, s.faces[s.triangles_center[:, 2] > 0], process=False).export(path)
    return path


def test_open_surface_reference_is_refused_up_front(box, tmp_path):
    from real2sim.evaluate.scene.placement import stable_rotations

    shell = _open_half_shell(tmp_path / "shell.obj")
    t0 = time.monotonic()
    with pytest.raises(UserInputError, match="centre of mass .* open surface"):
        evaluate([box], tmp_path / "res", PUSH_POINT, reference_mesh=shell)
    # Below the up-front check, the placement fails at once instead of looping forever.
    with pytest.raises(ValueError, match="not inside the convex hull"):
        stable_rotations(trimesh.load(shell, process=False).vertices, com_m=(0.0, 0.0, 0.0))
    assert time.monotonic() - t0 < 20
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shell.obj"]


def test_object_of_absurd_size_is_refused_up_front(box, tmp_path):
    huge = tmp_path / "huge.obj"
    trimesh.creation.box(extents=BOX_EXTENTS_M * 12500).export(huge)  # 1000 m long
    with pytest.raises(UserInputError, match=r"1000 m across .* 0.005 m to 1 m"):
        evaluate([box], tmp_path / "res", PUSH_POINT, reference_mesh=huge)
    assert not (tmp_path / "res").exists()


def test_unreachable_ray_cluster_fails_fast(box, tmp_path):
    pytest.importorskip("ray")
    # A closed port: refused at once, before Ray is started at all.
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = EvaluationConfig(tasks=("push",), contact_models=("point",), runs=1, jobs=1, executor="ray",
                              ray_address=f"127.0.0.1:{port}", ray_timeout_s=2, scene=SHORT_SCENE)
    t0 = time.monotonic()
    with pytest.raises(UserInputError, match="could not reach the Ray cluster"):
        evaluate([box], tmp_path / "res", config)
    assert time.monotonic() - t0 < 10 and not (tmp_path / "res").exists()
    assert not list(tmp_path.glob(".*"))


def test_silent_ray_address_times_out_with_one_line(box, tmp_path):
    """A port that accepts connections and never answers: Ray itself would retry for minutes."""
    pytest.importorskip("ray")
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        proc = subprocess.run([sys.executable, "-m", "real2sim", "evaluate", str(box), "--out", str(tmp_path / "res"),
                               "--executor", "ray", "--ray-address", f"127.0.0.1:{port}", "--ray-timeout-s", "3",
                               "--tasks", "push", "--runs", "1"], capture_output=True, text=True, timeout=90,
                              env={**os.environ, "PYTHONPATH": SRC})
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "within 3 s" in lines[0], proc.stderr
    assert not (tmp_path / "res").exists() and not list(tmp_path.glob(".*"))


# ------------------------------------------------------------------------------------------
# 6. bad input refused whole, naming the file


def _broken_copy(box: Path, root: Path, edit) -> Path:
    import shutil

    asset = root / "box"
    shutil.copytree(box, asset)
    shutil.rmtree(asset / "broken")
    edit(asset)
    return asset


@pytest.mark.parametrize("edit, needle", [
    (lambda a: (a / "physical_properties.json").write_text("{\"mass_kg\": 0.3, \"com_m\": [0, 0"),
     "physical_properties.json is not a readable"),
    (lambda a: (a / "physical_properties.json").write_text(
        (a / "physical_properties.json").read_text().replace("\"mass_kg\": 0.3", "\"mass_kg\": NaN")),
     "mass_kg must be a finite number > 0, got nan"),
    (lambda a: (a / "physical_properties.json").write_text(json.dumps(
        {**json.loads((a / "physical_properties.json").read_text()), "inertia_kg_m2": [[1, 0, 0], [0, 1, 0], [0, 0, 5]]})),
     "not a physical inertia"),
    (lambda a: (a / "visual" / "model.obj").write_text("v 1 2\nf 1 2 3\ngarbage"), "model.obj"),
    (lambda a: (a / "mesh" / "mesh.obj").unlink(), "names the mesh mesh.obj, which is missing"),
])
def test_unusable_asset_is_refused_before_anything_is_written(box, tmp_path, edit, needle):
    asset = _broken_copy(box, tmp_path, edit)
    code, err = _cli("evaluate", asset, "--out", tmp_path / "res", "--tasks", "push", "--runs", "1", "--jobs", "1")
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box"]


# ------------------------------------------------------------------------------------------
# 7. no absolute paths in what is published


def test_config_and_report_record_no_absolute_paths(finished, box):
    cfg = json.loads((finished / "config.json").read_text())
    assert cfg["assets"]["box"] == os.path.relpath(box, finished) and cfg["reference"] == "asset"
    assert (finished / cfg["reference_meshes"]["box"]).resolve() == (box / "visual" / "model.obj").resolve()
    for name in ("config.json", "report.html", "runs.csv"):
        text = (finished / name).read_text()
        assert str(box.parent) not in text and str(finished) not in text, name
    broken = [r for r in read_runs_csv(finished / "runs.csv") if r["representation"] == "broken"]
    assert broken and all(r["error"] for r in broken)


# ------------------------------------------------------------------------------------------
# 3 and 5. one sweep per output; signals end the workers and keep the finished rows


def _descendants(pid: int) -> set[int]:
    """Pids of every live process below ``pid`` (from /proc)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        if fields[0] != "Z":
            parents[int(stat.parent.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text()
        except OSError:
            continue
        if state[state.rindex(")") + 2] != "Z":
            alive.add(pid)
    return alive


def _row_count(path: Path) -> int:
    try:
        return len(read_runs_csv(path))
    except (OSError, UserInputError):
        return 0


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process tree from /proc")
def test_signals_end_the_workers_and_a_second_sweep_is_locked_out(tmp_path):
    asset = make_box_asset(tmp_path / "box", reps=("boxes_1", "mesh"))
    out = tmp_path / "res"
    partial = tmp_path / ".res.partial"
    cmd = [sys.executable, "-m", "real2sim", "evaluate", str(asset), "--out", str(out), "--tasks", "push,ramp",
           "--runs", "6", "--jobs", "2", "--duration-scale", "0.2", "--no-animations"]
    env = {**os.environ, "PYTHONPATH": SRC}
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        before = _row_count(partial / "runs.csv")
        # stdout and stderr are pipes: communicate() returns only when no process holds them.
        # Its own process group, so that freezing the group below reaches every worker, even one the pool
        # starts after the children are listed. SIGINT at its default: a test run started in the
        # background (`pytest &`) ignores SIGINT, a child inherits that, and Python keeps it ignored (as
        # for any background job); the sweep then finished all its rows and exited 0.
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        deadline = time.monotonic() + 90
        while _row_count(partial / "runs.csv") <= before and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, f"{sig.name}: the sweep ended before the signal: {proc.communicate()}"
        children = _descendants(proc.pid)
        assert len(children) >= 2, children  # the pool's workers (and the resource tracker)
        if sig == signal.SIGINT:
            # 3. While this sweep holds the output (frozen, so it surely does), a second one is refused.
            # Its workers are frozen too: left running on a loaded machine, they once finished the
            # whole sweep while the second one started, and the SIGINT below came after a clean exit.
            os.killpg(proc.pid, signal.SIGSTOP)
            try:
                second = subprocess.run(cmd, capture_output=True, text=True, timeout=90, env=env)
            finally:
                # The SIGINT goes in while the sweep is still frozen, so it is pending when the sweep
                # wakes: sent after the SIGCONT, it once came after a sweep that finished its last
                # rows in between (a worker the freeze missed had done them) and exited cleanly.
                proc.send_signal(sig)
                os.killpg(proc.pid, signal.SIGCONT)
            assert second.returncode == 2, second.stderr
            lines = second.stderr.strip().splitlines()
            assert len(lines) == 1 and "another real2sim process is writing" in lines[0], lines
        else:
            proc.send_signal(sig)
        try:
            _stdout, stderr = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"{sig.name}: something still holds the sweep's output pipes: {_alive(children)}")
        deadline = time.monotonic() + 5
        while _alive(children) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(children), f"{sig.name}: still running: {_alive(children)}"
        if sig == signal.SIGINT:
            assert proc.returncode == 130 and "interrupted" in stderr, (proc.returncode, stderr[-500:])
        elif sig == signal.SIGTERM:
            assert proc.returncode == 143 and "terminated" in stderr, (proc.returncode, stderr[-500:])
        assert _row_count(partial / "runs.csv") > before  # the finished rows are kept
        assert not out.exists()
    kept = _row_count(partial / "runs.csv")
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"{kept} already done" in done.stdout
    rows = read_runs_csv(out / "runs.csv")
    keys = [(r["representation"], r["contact_model"], r["task"], r["run"]) for r in rows]
    # Every row exactly once. Six runs leave rows for all three signals even on an idle machine, where
    # a box simulation takes a few milliseconds and two runs were sometimes all done before the last.
    assert len(keys) == len(set(keys)) == 2 * 2 * 2 * 6
    assert not any(r["error"] for r in rows), [r["error"] for r in rows if r["error"]]
    assert not partial.exists() and not list(tmp_path.glob(".*.lock"))


def test_pool_abort_ends_busy_workers_at_once():
    from real2sim.evaluate.executors import PoolExecutor

    executor = PoolExecutor(2)
    handles = [executor.submit(time.sleep, 60.0) for _ in range(3)]
    deadline = time.monotonic() + 60
    while len(executor._pool._processes or {}) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    workers = list(executor._pool._processes.values())
    t0 = time.monotonic()
    executor.shutdown(abort=True)
    assert time.monotonic() - t0 < 10 and handles
    assert not any(p.is_alive() for p in workers)


def test_a_script_without_a_main_guard_is_told_why_every_simulation_fails(box, tmp_path):
    """Spawned workers import the script again; unguarded, its evaluate() kills each one as it starts.
    That is named in one error, not left as one "worker process died" row per simulation."""
    script = tmp_path / "unguarded.py"
    script.write_text(
        "from pathlib import Path\n"
        "from real2sim.evaluate.sweep import EvaluationConfig, evaluate\n"
        "from tests.evaluate.test_sweep import SHORT_SCENE\n"
        f"evaluate([Path({str(box)!r})], Path({str(tmp_path / 'res')!r}), EvaluationConfig(tasks=('push',), "
        "contact_models=('point',), runs=1, jobs=2, scene=SHORT_SCENE))\n")
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([SRC, root])}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, env=env,
                          cwd=tmp_path)
    assert done.returncode != 0
    assert 'if __name__ == "__main__":' in done.stderr.splitlines()[-1], done.stderr[-2000:]


def test_a_local_ray_started_for_the_sweep_stays_up():
    """Ray ties the processes it starts to the starting thread (a parent-death signal): a local Ray
    started in a helper thread died as soon as that thread ended, and the sweep failed a minute later."""
    ray = pytest.importorskip("ray")
    from ray._private import worker

    from real2sim.evaluate.executors import _RayExecutor

    if ray.is_initialized():
        ray.shutdown()
    _RayExecutor(1, None, 30.0)
    try:
        time.sleep(2.0)
        node = worker._global_node
        processes = [p.process for group in node.all_processes.values() for p in group]
        assert processes and all(p.poll() is None for p in processes)
        assert ray.get(ray.remote(lambda: 41 + 1).remote(), timeout=60) == 42
    finally:
        ray.shutdown()
