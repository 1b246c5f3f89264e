"""The field's training stages end once their loss has flattened (issue 67, part 3): the rule on its own
(a flat loss ends a stage, a falling one does not, the rate decays with the plateaus), and on a real,
tiny training of the shared can capture: a long cap is cut, a short one is not, the same seed gives
the same field."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from real2sim.multiview.hull import object_region
from real2sim.multiview.views import load_views
from real2sim.plumbing.errors import UserInputError
from real2sim.reconstruct.field.convergence import STOP_CAP, STOP_CONVERGED, ConvergenceConfig, StageSchedule
from real2sim.reconstruct.field.train import FieldConfig, train_field

RULE = ConvergenceConfig(enabled=True, window_steps=10, rel_tolerance=0.01, decays=3)
# a tiny field: a coarse grid of 16 voxels, a fine one of 24, few rays, no carving, no pose learning
TINY = FieldConfig(coarse_voxels=16, fine_voxels=24, coarse_steps=40, fine_steps=400, rays_per_step=512,
                   photo_carving=False, pose_refinement=False, convergence=RULE)


def _run(schedule: StageSchedule, losses) -> int:
    """Feed ``schedule`` one window mean per entry of ``losses``, after what it ran; the steps it ran."""
    for loss in losses:
        schedule.observe(loss, schedule.window, schedule.trained + schedule.window - 1)
        if schedule.stopped:
            break
    return schedule.trained


def test_a_flat_loss_decays_the_rate_then_ends_the_stage():
    schedule = StageSchedule(1000, RULE)
    assert schedule.fraction(0) == 0.0
    schedule.observe(1.0, 10, 9)
    schedule.observe(0.995, 10, 19)  # half a per cent: a plateau
    assert schedule.fraction(20) == pytest.approx(1 / 3)  # one of three decays, well ahead of 20/1000
    assert _run(schedule, [0.995] * 3) == 50 and schedule.stopped == STOP_CONVERGED  # the 4th plateau ends it
    assert schedule.fraction(50) == 1.0


def test_a_falling_loss_runs_to_its_cap_decaying_by_the_count():
    schedule = StageSchedule(200, RULE)
    assert _run(schedule, 0.95 ** np.arange(20)) == 200 and schedule.stopped == STOP_CAP
    assert schedule.plateaus == 0 and schedule.fraction(100) == 0.5
    fixed = StageSchedule(200, replace(RULE, enabled=False))  # the rule off: the old schedule, whatever the loss
    assert _run(fixed, [1.0] * 20) == 200 and fixed.stopped == STOP_CAP and fixed.fraction(50) == 0.25


def test_settings_are_checked_and_scaled_for_a_gpu():
    for bad in (replace(RULE, window_steps=1), replace(RULE, decays=0), replace(RULE, rel_tolerance=1.0)):
        with pytest.raises(UserInputError):
            replace(TINY, convergence=bad).validate()
    assert TINY.on_device("cuda").convergence.window_steps == 5  # device_batch_scale 2: windows of the same rays
    assert FieldConfig().convergence.enabled is True  # on by default (see the design note)


@pytest.fixture(scope="module")
def views_and_region(can_capture):
    views = load_views(can_capture)
    return views, object_region(views)


@pytest.fixture(scope="module")
def trained_and_lines(views_and_region):
    """The tiny field trained with the rule (seed 3), and its progress lines (text, i, n)."""
    views, region = views_and_region
    lines = []
    trained = train_field(views, region, TINY, seed=3, progress=lambda text, i, n: lines.append((text, i, n)))
    return trained, lines


def test_a_flattened_stage_ends_before_its_cap_and_a_falling_one_does_not(trained_and_lines):
    trained, lines = trained_and_lines
    (coarse, coarse_steps, coarse_end), (fine, fine_steps, fine_end) = trained.stages
    # the 40-step coarse stage still falls all along; the fine one flattens long before its 400 steps
    assert (coarse, coarse_steps, coarse_end) == (16, 40, STOP_CAP)
    assert fine == 24 and fine_end == STOP_CONVERGED and 5 * RULE.window_steps <= fine_steps < 400
    assert trained.loss_curve[-1][0] == coarse_steps + fine_steps  # the curve counts the steps trained
    # the loss it stopped at is no worse than a few per cent above its best window
    losses = [loss for _, loss in trained.loss_curve]
    assert losses[-1] <= 1.05 * min(losses)
    # the progress line: one per step trained, counting up, its last one at the caps' end (440/440)
    steps = [i for text, i, n in lines if text.startswith("training field")]
    assert len(steps) == coarse_steps + fine_steps and steps == sorted(steps) and steps[-1] == lines[-1][2] == 440


def test_the_same_seed_gives_the_same_field(trained_and_lines, views_and_region):
    first, _ = trained_and_lines
    again = train_field(*views_and_region, TINY, seed=3)
    assert first.stages == again.stages and first.loss_curve == again.loss_curve
    assert torch.equal(first.field.density_table, again.field.density_table)
