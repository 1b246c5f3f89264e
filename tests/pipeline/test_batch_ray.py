"""`real2sim batch --executor ray` (issue 31): the batch starts a private Ray cluster on the loopback address,
runs one task per object on it and stops it; the catalogue is the local pool's, byte for byte."""

from __future__ import annotations

import csv

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
    code, stdout, err = run_cli(capsys, "batch", ds, "--mass", "0.35", "--out", out, "--executor", "ray", *FAST)
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
