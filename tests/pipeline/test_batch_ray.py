"""`real2sim batch --executor ray` (issue 31): the batch starts a private Ray cluster on the loopback address,
runs one task per object on it and stops it; the catalogue is the local pool's, byte for byte."""

from __future__ import annotations

import csv
import shutil
import tempfile

import pytest

from tests.cli_helpers import run_cli
from tests.pipeline.test_batch import FAST, capture, run_json

ray = pytest.importorskip("ray")


def _rows(out):
    with open(out / "catalogue.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_one_object_on_a_local_ray_cluster(capsys, tmp_path):
    ds = capture(tmp_path / "can_ds", "can")
    out = tmp_path / "cat"
    code, stdout, err = run_cli(capsys, "batch", ds, "--mass-kg", "0.35", "--out", out, "--executor", "ray", *FAST)
    assert code == 0, (stdout, err)
    assert "can_ds: done (ran reconstruct, asset, truth)" in stdout
    assert not ray.is_initialized()  # the batch stopped the cluster it started
    (row,) = _rows(out)
    assert row["status"] == "done" and row["accuracy_representation"] == "spheres_4"
    assert set(run_json(out / "can_ds")["stages"]) == {"reconstruct", "asset", "truth"}


@pytest.mark.slow
def test_three_objects_on_ray_and_on_the_local_pool_give_the_same_catalogue(capsys, tmp_path):
    datasets = [capture(tmp_path / f"{name}_ds", name) for name in ("can", "mug", "bottle")]
    masses = tmp_path / "masses.csv"
    masses.write_text("name,mass_kg\ncan_ds,0.35\nmug_ds,0.3\nbottle_ds,0.6\n")
    csvs = []
    for executor in ("local", "ray"):
        out = tmp_path / executor
        code, stdout, err = run_cli(capsys, "batch", *datasets, "--masses", masses, "--out", out,
                                    "--executor", executor, "--workers", "2", *FAST)
        assert code == 0, (stdout, err)
        assert [r["status"] for r in _rows(out)] == ["done"] * 3
        csvs.append((out / "catalogue.csv").read_bytes())
    assert csvs[0] == csvs[1]


@pytest.mark.slow
def test_an_object_that_asks_for_a_gpu_holds_it_only_for_its_gpu_stages(tmp_path):
    """With a GPU in the cluster (declared here: Ray schedules by the resources a node says it has), an
    object whose run uses cuda is three tasks: the stages before the reconstruction on a CPU, the
    reconstruction and the fitting with the GPU, the truth on a CPU. The run itself is on the CPU here
    (this machine's torch has no CUDA): what is checked is what each task was given and that the three
    make the same asset as one task."""
    from dataclasses import replace

    from real2sim.cli import build_parser
    from real2sim.cli.batch import plan
    from real2sim.pipeline.batch import run_batch

    ds = capture(tmp_path / "can_ds", "can")
    out = tmp_path / "cat"
    args = build_parser().parse_args(["batch", str(ds), "--mass-kg", "0.35", "--out", str(out), "--executor", "ray",
                                      *FAST])
    jobs, out, batch = plan(args)
    jobs = [replace(job, gpu=True) for job in jobs]  # as --device cuda makes them
    session = tempfile.mkdtemp(prefix="r2s_ray_", dir="/tmp")  # short: Ray's socket paths fit in 107 bytes
    ray.init(num_cpus=2, num_gpus=1, include_dashboard=False, _node_ip_address="127.0.0.1", _temp_dir=session,
             log_to_driver=False)
    lines: list[str] = []
    try:
        result = run_batch(jobs, out, batch, echo=lines.append)
    finally:
        ray.shutdown()
        shutil.rmtree(session, ignore_errors=True)
    assert result.outcomes["can_ds"]["status"] == "done", result.outcomes
    assert lines == ["can_ds: done (ran reconstruct, asset, truth)"]
    log = (out / ".batch" / "can_ds.log").read_text().splitlines()
    tasks = [line for line in log if line.endswith(("stages, with a CPU", "stages, with GPU 0"))]
    assert tasks == ["before_gpu stages, with a CPU", "gpu stages, with GPU 0", "after_gpu stages, with a CPU"]
    assert [line for line in log if line.startswith("paused before")] == ["paused before reconstruct",
                                                                          "paused before truth"]
    assert set(run_json(out / "can_ds")["stages"]) == {"reconstruct", "asset", "truth"}
