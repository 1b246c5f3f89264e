"""Collision fits side by side (real2sim.asset.fits): sized to the threads the build may use, the same
results as one after another, and a worker's failure raised in the build's process."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from real2sim.asset.config import AssetConfig
from real2sim.asset.fits import SIDE_BY_SIDE_MIN_ITERATIONS, THREADED_BASELINES, fit_all, fit_processes
from real2sim.collision.fit.config import FitConfig, iteration_limits
from real2sim.formats.spec import parse_spec
from real2sim.plumbing.errors import UserInputError

SPECS = tuple(parse_spec(s) for s in ("cylinders:2", "spheres:4", "boxes:2", "coacd"))


@pytest.fixture
def threads():
    """Set torch's CPU threads for one test, and put back what was there."""
    before = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(before)


def config(**kw) -> AssetConfig:
    return AssetConfig(mass_kg=0.3, specs=SPECS, fit_config=FitConfig(**iteration_limits(60)), **kw)


def test_processes_never_exceed_the_threads_the_build_may_use(threads):
    threads(1)
    assert fit_processes(config(), 3) == 1
    threads(4)
    assert fit_processes(config(), 3) == 1  # short fits: a process's start would cost more than it saves
    assert fit_processes(config(fit_workers=2), 3) == 2
    assert fit_processes(config(fit_workers=8), 3) == 3  # at most one per fit
    threads(2)
    assert fit_processes(config(fit_workers=8), 3) == 2  # and one per thread
    assert fit_processes(config(device="cuda"), 3) == 1  # CUDA does not survive a fork; one GPU is one fit


def test_long_fits_go_side_by_side_by_default(threads):
    long_fits = AssetConfig(mass_kg=0.3, specs=SPECS, fit_config=FitConfig(max_iterations=SIDE_BY_SIDE_MIN_ITERATIONS))
    threads(2)
    assert fit_processes(long_fits, 3) == 2
    assert fit_processes(AssetConfig(mass_kg=0.3, specs=SPECS), 3) == 2  # the default fit is long
    threads(8)
    assert fit_processes(long_fits, 3) == 3  # one per fit
    threads(1)
    assert fit_processes(long_fits, 3) == 1
    assert fit_processes(replace(long_fits, fit_workers=1), 3) == 1  # asked: one after another


def test_fit_workers_must_be_a_whole_number():
    with pytest.raises(UserInputError, match="--fit-workers"):
        config(fit_workers=0)


def test_side_by_side_fits_as_one_after_another(tmp_path, threads):
    threads(2)
    solid = trimesh.creation.capsule(height=0.06, radius=0.02, count=[12, 12])
    reports, geometry = {}, {}
    for workers in (1, 2):
        folder = tmp_path / f"w{workers}"
        for spec in SPECS:
            (folder / spec.name).mkdir(parents=True)
        messages, finished = [], []
        # three primitive SPECs on two workers: one worker fits a second SPEC when done with its first
        fitted = fit_all(solid, solid, list(SPECS), folder, config(fit_workers=workers), tmp_path / "sdf",
                         progress=lambda m, d, t: messages.append(m),
                         on_fitted=lambda spec, f: finished.append((spec.text, len(messages), f)))
        assert list(fitted) == [s.text for s in SPECS]
        assert sorted(t for t, _, _ in finished) == sorted(fitted)  # each once, with its result
        assert all(fitted[t] is f for t, _, f in finished)
        assert any("fit" in m and "cylinders:2" in m for m in messages)
        reports[workers] = {t: (f.fidelity["iou"], f.fidelity["chamfer_mm"]) for t, f in fitted.items()}
        geometry[workers] = {s.text: json.loads((folder / s.name / "collision.json").read_text()) for s in SPECS}
        assert not (folder / ".fit_jobs").exists()
    assert any("in 2 processes" in m for m in messages)  # the second build ran side by side
    # CoACD uses every thread it is given: after the side-by-side fits, in this process, not in a worker's share
    assert "coacd" in THREADED_BASELINES and finished[-1][0] == "coacd"
    decomposing = next(i for i, m in enumerate(messages) if m.startswith("collision coacd: decomposing"))
    assert decomposing >= max(i for t, i, _ in finished[:-1])  # (i: the messages before its hand-over)
    # the first result was handed over while another fit still reported its progress
    assert finished[0][1] < max(i for i, m in enumerate(messages) if not m.startswith("collision coacd"))
    for text in reports[1]:
        assert np.allclose(reports[1][text], reports[2][text], rtol=1e-6, atol=1e-9), text
    assert len(geometry[1]["coacd"]["shapes"]) == len(geometry[2]["coacd"]["shapes"])
    for one, two in zip(geometry[1]["cylinders:2"]["shapes"] + geometry[1]["spheres:4"]["shapes"],
                        geometry[2]["cylinders:2"]["shapes"] + geometry[2]["spheres:4"]["shapes"]):
        assert one["type"] == two["type"]
        assert np.allclose(one["pose"]["xyz"], two["pose"]["xyz"], atol=1e-7)
        assert np.allclose(list(one["parameters"].values()), list(two["parameters"].values()), rtol=1e-5, atol=1e-7)


def test_a_workers_failure_is_raised_in_the_build(tmp_path, threads):
    threads(2)
    solid = trimesh.creation.box((0.05, 0.04, 0.03))
    specs = [parse_spec("spheres:1"), parse_spec("cylinders:1")]  # no folders made for them: the workers fail
    with pytest.raises(OSError):
        fit_all(solid, solid, specs, tmp_path, config(fit_workers=2), None)
    assert not (tmp_path / ".fit_jobs").exists()
