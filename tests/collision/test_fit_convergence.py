"""The fit's plateau schedule (issue 67): it stops a fit that has converged, not one whose loss still falls,
says why it stopped, and is deterministic for a seed."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh

from real2sim.collision.fit.config import FitConfig
from real2sim.collision.fit.loop import fit_primitives
from real2sim.collision.fit.schedule import StepSchedule

# Small and fast: few samples, small batches; a patience short enough to converge in a few hundred steps.
QUICK = FitConfig(lr_schedule="plateau", batch_size=2048, max_iterations=3000, min_iterations=0, decay_patience=30, revive_dead=False)


@pytest.fixture(scope="module")
def sphere_samples():
    """Near-surface and uniform samples of a sphere of radius 0.4 at (0.1, 0, -0.05) (unit sphere)."""
    rng = np.random.default_rng(3)
    centre, radius = np.array([0.1, 0.0, -0.05]), 0.4
    d = rng.normal(size=(8000, 3))
    surface = centre + radius * d / np.linalg.norm(d, axis=1, keepdims=True)
    points = np.vstack([surface + rng.normal(size=surface.shape) * 0.02, rng.uniform(-1, 1, size=(300, 3))])
    return points.astype(np.float32), (np.linalg.norm(points - centre, axis=1) - radius).astype(np.float32), centre, radius


def test_schedule_holds_the_step_while_the_loss_falls_and_stops_on_its_floor_plateau():
    config = FitConfig(lr_schedule="plateau", min_iterations=0, decay_patience=10, lr_decay=0.5, final_lr_fraction=0.1)
    falling = StepSchedule(config)
    assert all(falling.step(i, 0.99 ** i) == "" for i in range(1, 2001)) and falling.lr == config.lr
    flat = StepSchedule(config)
    stops = [flat.step(i, 1.0) for i in range(1, 2001)]
    # the first step sets the best; a cut after each 10 flat steps (lr/2, lr/4, lr/8, then the floor lr/10 at
    # step 41), the stop 10 steps later
    assert stops.index("converged") + 1 == 51 and flat.lr == pytest.approx(config.lr * 0.1)
    floor = StepSchedule(dataclasses.replace(config, min_iterations=300))
    assert [floor.step(i, 1.0) for i in range(1, 301)].index("converged") + 1 == 300  # never before min_iterations


def test_a_converged_fit_stops_before_the_cap_and_says_so(sphere_samples):
    points, sdf, centre, radius = sphere_samples
    result = fit_primitives(points, sdf, (("spheres", 1),), QUICK)
    assert result.stop_reason == "converged" and result.iterations < QUICK.max_iterations
    (row,) = result.parameters
    np.testing.assert_allclose(row[:3], centre, atol=0.01)
    assert abs(row[3] - radius) < 0.01


def test_a_fit_whose_loss_still_falls_runs_to_the_cap(sphere_samples):
    points, sdf, _, _ = sphere_samples
    # a step so small that the sphere is still growing towards the target after the cap
    config = dataclasses.replace(QUICK, learning_rate=2e-4, max_iterations=300, init="random")
    result = fit_primitives(points, sdf, (("spheres", 1),), config)
    assert result.stop_reason == "max_iterations" and result.iterations == 300
    early, late = np.mean(result.history[:5]), np.mean(result.history[-5:])
    assert late < 0.85 * early  # it was still falling


def test_same_seed_same_fit_and_stop(sphere_samples):
    points, sdf, _, _ = sphere_samples
    config = dataclasses.replace(QUICK, revive_dead=True, revive_every=50)
    one, two = (fit_primitives(points, sdf, (("spheres", 3),), config, seed=5) for _ in range(2))
    assert one.iterations == two.iterations and one.stop_reason == two.stop_reason
    assert one.parameters == two.parameters and one.history == two.history


def test_fit_report_json_records_the_iterations_and_the_stop(tmp_path):
    from real2sim.asset.build import AssetConfig, build_asset
    from real2sim.formats.spec import parse_spec

    mesh_path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.05, 0.04, 0.08)).apply_translation((0, 0, 0.04)).export(mesh_path)
    config = AssetConfig(mass_kg=0.2, specs=(parse_spec("boxes:1"),), fit_config=QUICK)
    build_asset(mesh_path, tmp_path / "asset", config)
    report = json.loads((tmp_path / "asset" / "boxes_1" / "fit_report.json").read_text())
    assert report["stop_reason"] == "converged" and report["iterations"] < QUICK.max_iterations
    assert report["iou"] > 0.95
