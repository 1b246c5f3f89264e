"""Metrics on hand-made trajectories with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from real2sim.evaluate.metrics import (
    ate_m,
    contact_runs,
    cpd_m_per_s,
    cpd_paper,
    ocae_m,
    quaternion_wxyz_to_matrices,
    real_time_factor,
)


def _random_traj(rng: np.random.Generator, steps: int = 50):
    pos = rng.normal(size=(steps, 3))
    quat = rng.normal(size=(steps, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return pos, quat


def _yaw_quat(theta: float, steps: int) -> np.ndarray:
    return np.tile([math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)], (steps, 1))


def test_identical_trajectories_score_zero():
    pos, quat = _random_traj(np.random.default_rng(0))
    assert ate_m(pos, pos) == 0.0
    assert ocae_m(pos, quat, pos, quat) == pytest.approx(0.0, abs=1e-12)
    # q and -q are the same rotation.
    assert ocae_m(pos, quat, pos, -quat) == pytest.approx(0.0, abs=1e-12)


def test_constant_offset_gives_that_ate_and_ocae():
    pos, quat = _random_traj(np.random.default_rng(1))
    d = np.array([0.003, -0.004, 0.0])  # |d| = 5 mm
    assert ate_m(pos, pos + d) == pytest.approx(0.005)
    # With equal orientations every lever point moves by d too.
    assert ocae_m(pos, quat, pos + d, quat) == pytest.approx(0.005)


def test_ate_is_mean_not_rms():
    ref = np.zeros((4, 3))
    cand = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3.0]])
    assert ate_m(ref, cand) == pytest.approx(6.0 / 4)


@pytest.mark.parametrize("theta", [0.1, 0.5, 1.0, math.pi / 2, math.pi])
@pytest.mark.parametrize("lever", [1.0, 0.25])
def test_pure_yaw_matches_closed_form(theta, lever):
    steps = 7
    pos = np.zeros((steps, 3))
    ref_q = _yaw_quat(0.0, steps)
    cand_q = _yaw_quat(theta, steps)
    expected = (2.0 / 3.0) * 2.0 * math.sin(theta / 2.0) * lever  # x and y chords, z unmoved
    assert ocae_m(pos, ref_q, pos, cand_q, lever_m=lever) == pytest.approx(expected, rel=1e-9)
    assert ate_m(pos, pos) == 0.0


def test_quaternion_matrices_are_rotations():
    _, quat = _random_traj(np.random.default_rng(2))
    r = quaternion_wxyz_to_matrices(quat * 3.0)  # un-normalised input is normalised
    assert np.allclose(r @ np.swapaxes(r, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    # 90 degrees about z sends x to y.
    rz = quaternion_wxyz_to_matrices(_yaw_quat(math.pi / 2, 1))[0]
    assert np.allclose(rz @ [1, 0, 0], [0, 1, 0])


@settings(max_examples=30, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3))
def test_ocae_bounded_by_translation_plus_rotation(dx, dy, dz):
    # Translation-only: OCAE == ATE for any rigid offset.
    pos = np.zeros((3, 3))
    q = _yaw_quat(0.3, 3)
    cand = pos + [dx, dy, dz]
    assert ocae_m(pos, q, cand, q) == pytest.approx(ate_m(pos, cand), abs=1e-9)


def test_length_mismatch_is_an_error():
    with pytest.raises(ValueError):
        ate_m(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError):
        ocae_m(np.zeros((3, 3)), _yaw_quat(0, 3), np.zeros((3, 3)), _yaw_quat(0, 4))


def test_cpd_constant_contact_point_is_zero():
    pts = [np.array([[0.01, 0.02, -0.05], [-0.01, 0.02, -0.05]])] * 20
    assert cpd_m_per_s(pts, 0.001) == pytest.approx(0.0, abs=1e-12)


def test_cpd_linear_ramp_gives_slope():
    dt = 0.001
    slope = 0.4  # m/s
    pts = [np.array([[0.0, 0.0, 0.02 + slope * dt * t]]) for t in range(30)]
    assert cpd_m_per_s(pts, dt) == pytest.approx(slope, rel=1e-9)


def test_cpd_uses_mean_magnitude_of_the_contact_points():
    dt = 0.01
    # Two points whose magnitudes average to 0.1 + 0.2 t: slope 0.2 m/s per step / dt.
    pts = [np.array([[0.1 + 0.001 * t, 0, 0], [0, 0.1 + 0.003 * t, 0]]) for t in range(10)]
    assert cpd_m_per_s(pts, dt) == pytest.approx(0.002 / dt, rel=1e-9)


def test_cpd_gaps_are_not_fake_zeros():
    dt = 0.001
    empty = np.zeros((0, 3))
    # Contact at constant magnitude 0.05 m, a gap, contact again at 0.05 m: no discontinuity.
    pts = [np.array([[0.05, 0, 0]])] * 5 + [empty] * 4 + [np.array([[0, 0.05, 0]])] * 6
    assert cpd_m_per_s(pts, dt) == pytest.approx(0.0, abs=1e-12)
    # Runs shorter than 3 samples carry no gradient; one ramp run gives its slope exactly.
    ramp = [np.array([[0.0, 0.0, 0.03 + 0.2 * dt * t]]) for t in range(8)]
    pts = [np.array([[9.0, 0, 0]])] * 2 + [empty] + ramp + [empty] * 3 + [np.array([[0.0, 0, 0.5]])]
    assert cpd_m_per_s(pts, dt) == pytest.approx(0.2, rel=1e-9)
    # A jump inside one contact run does count.
    jump = [np.array([[0.05, 0, 0]])] * 5 + [np.array([[0.06, 0, 0]])] * 5
    # Central differences spread the 1 cm step over two samples of 0.01 / (2 dt) each.
    assert cpd_m_per_s(jump, dt) == pytest.approx(2 * (0.01 / (2 * dt)) / 10, rel=1e-9)


def test_cpd_without_contact_is_nan():
    assert math.isnan(cpd_m_per_s([np.zeros((0, 3))] * 10, 0.001))
    assert math.isnan(cpd_m_per_s([np.ones((1, 3))] * 2, 0.001))


def test_contact_runs():
    valid = np.array([1, 1, 1, 0, 1, 1, 0, 1, 1, 1, 1], dtype=bool)
    assert contact_runs(valid) == [(0, 3), (7, 11)]
    assert contact_runs(valid, min_length=2) == [(0, 3), (4, 6), (7, 11)]
    assert contact_runs(np.zeros(4, bool)) == []
    assert contact_runs(valid, breaks=[9]) == [(0, 3)]  # (7, 9) and (9, 11) are too short
    assert contact_runs(np.ones(10, bool), breaks=[4, 0, 10]) == [(0, 4), (4, 10)]


def test_cpd_breaks_cut_the_series_like_gaps():
    dt = 0.001
    # A 1 cm jump between samples 4 and 5: counted inside a run, ignored when cut there.
    jump = [np.array([[0.05, 0, 0]])] * 5 + [np.array([[0.06, 0, 0]])] * 5
    assert cpd_m_per_s(jump, dt) > 0.5
    assert cpd_m_per_s(jump, dt, breaks=[5]) == pytest.approx(0.0, abs=1e-12)


def test_real_time_factor():
    assert real_time_factor(2.0, 0.5) == pytest.approx(4.0)
    assert math.isnan(real_time_factor(2.0, 0.0))


def test_force_weighted_cpd_ignores_a_contact_that_carries_no_load():
    """A loaded contact at 0.05 m and a flickering one at 0.10 m: unweighted, every flicker
    is a jump of the mean; weighted by force, a zero-load flicker changes nothing."""
    dt = 0.001
    loaded = np.array([[0.05, 0.0, 0.0]])
    both = np.array([[0.05, 0.0, 0.0], [0.10, 0.0, 0.0]])
    pts = [both if t % 4 < 2 else loaded for t in range(40)]
    forces = [np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 0.0]]) if t % 4 < 2 else np.array([[0.0, 0.0, 5.0]])
              for t in range(40)]
    assert cpd_m_per_s(pts, dt) > 1.0
    assert cpd_m_per_s(pts, dt, contact_forces_n=forces) == pytest.approx(0.0, abs=1e-12)


def test_force_weighted_cpd_is_the_force_weighted_mean_radius():
    dt = 0.001
    # Radii 0.02 and 0.06 m with loads 3:1 -> weighted mean 0.03 m; then loads 1:1 -> 0.04 m.
    pts = [np.array([[0.02, 0.0, 0.0], [0.0, 0.06, 0.0]])] * 10
    forces = [np.array([[3.0, 0, 0], [1.0, 0, 0]])] * 5 + [np.array([[0, 2.0, 0], [0, 0, -2.0]])] * 5
    series_jump = 0.01
    # The single step of 0.01 m shows up in two central differences of 0.01 / (2 dt) each.
    expected = 2 * (series_jump / (2 * dt)) / 10
    assert cpd_m_per_s(pts, dt, contact_forces_n=forces) == pytest.approx(expected, rel=1e-9)
    # Unweighted the radius never changes.
    assert cpd_m_per_s(pts, dt) == pytest.approx(0.0, abs=1e-12)


def test_force_weighted_cpd_treats_unloaded_steps_as_no_contact():
    dt = 0.001
    pts = [np.array([[0.05, 0.0, 0.0]])] * 10
    forces = [np.zeros((1, 3))] * 10
    assert math.isnan(cpd_m_per_s(pts, dt, contact_forces_n=forces))
    with pytest.raises(ValueError):
        cpd_m_per_s(pts, dt, contact_forces_n=forces[:3])
    with pytest.raises(ValueError):
        cpd_m_per_s(pts, dt, contact_forces_n=[np.zeros((2, 3))] * 10)


def test_cpd_paper_pads_missing_contacts_with_the_world_origin_and_differences_per_sample():
    # Object origin 0.5 m from the world origin. Samples: two contacts at radii 0.1 and 0.3,
    # then one at 0.1 (the other vanished), then none, then the two again.
    position = np.tile([0.3, 0.4, 0.0], (4, 1))
    pts = [np.array([[0.1, 0, 0], [0, 0.3, 0]]), np.array([[0.1, 0, 0]]), np.zeros((0, 3)),
           np.array([[0.1, 0, 0], [0, 0.3, 0]])]
    # Padded to 2 points per sample, a padding point 0.5 m from the object origin:
    series = np.array([(0.1 + 0.3) / 2, (0.1 + 0.5) / 2, (0.5 + 0.5) / 2, (0.1 + 0.3) / 2])  # 0.2 0.3 0.5 0.2
    # numpy.gradient, unit spacing: one-sided at the ends, central inside
    grads = np.array([0.3 - 0.2, (0.5 - 0.2) / 2, (0.2 - 0.3) / 2, 0.2 - 0.5])
    assert np.allclose(np.gradient(series), grads)
    assert cpd_paper(pts, position) == pytest.approx(np.mean(np.abs(grads)))  # 0.15 m per sample
    assert cpd_paper(pts, position) == pytest.approx(0.15)
    # Ours ignores the contacts' coming and going: only the one 3-sample run [0.2 0.3 0.5] would count,
    # and here no run reaches 3 samples, so ours is undefined where the paper's is 0.15.
    assert math.isnan(cpd_m_per_s(pts, 1e-3))


def test_cpd_paper_takes_the_surfaces_when_the_run_has_any_and_rescales_to_1_ms():
    position = np.tile([0.0, 0.0, 0.2], (3, 1))
    # Each sample: one point pair (radius 1) first, then its surface centroids (radius 0.1).
    pts = [np.array([[1.0, 0, 0], [0.1, 0, 0]]), np.array([[1.0, 0, 0], [0.1, 0, 0]]), np.array([[1.0, 0, 0]])]
    counts = [1, 1, 0]
    # Surfaces only: 0.1, 0.1, then padding 0.2 -> gradients 0, 0.05, 0.1
    assert cpd_paper(pts, position, counts) == pytest.approx(0.05)
    # No surface anywhere: every point is a point pair -> padded to 2: 0.55, 0.55, 0.6
    assert cpd_paper(pts, position) == pytest.approx(np.mean([0.0, 0.025, 0.05]))
    # Sampled every 2 ms, a sample's change is twice a 1 ms sample's: halved
    assert cpd_paper(pts, position, counts, dt_s=2e-3) == pytest.approx(0.025)


def test_cpd_paper_without_contact_is_nan():
    assert math.isnan(cpd_paper([np.zeros((0, 3))] * 5, np.zeros((5, 3))))
