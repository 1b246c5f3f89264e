"""Identification of a held object's mass properties from simulated joint torques (real Drake)."""

from __future__ import annotations

import numpy as np
import pytest

from real2sim.formats.joint_log import read_joint_log
from real2sim.geometry.objects import make_object
from real2sim.identify.arm import (default_arm_urdf, load_arm, phi_from_properties, properties_from_phi,
                                   pseudo_inertia, spatial_inertia)
from real2sim.identify.regressor import _inverse_dynamics, payload_regressor
from real2sim.identify.stage import ExciteConfig, errors_against_truth, run_excite, run_identify


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """The can (0.3 kg) with 0.1 kg off-centre inside, one 6 s period of the exciting motion."""
    root = tmp_path_factory.mktemp("identify")
    mesh = make_object("can")
    config = ExciteConfig(mass_kg=0.3, extra_mass_kg=0.1, extra_mass_at_m=(0.02, 0.0, 0.03), torque_noise_n_m=0.05,
                          periods=1)
    with pytest.MonkeyPatch.context() as env:
        env.setenv("REAL2SIM_CACHE", str(root / "cache"))  # the trajectory's cache stays in the test's folder
        truth = run_excite(mesh, config, root / "log", say=lambda *_: None)
    assert (root / "cache" / "excitation").is_dir()
    return root / "log", truth


@pytest.fixture(scope="module")
def noise_free_log(small_log):
    """small_log's motion and payload with no torque noise: (log folder, truth)."""
    log_dir, _ = small_log
    config = ExciteConfig(mass_kg=0.3, extra_mass_kg=0.1, extra_mass_at_m=(0.02, 0.0, 0.03), torque_noise_n_m=0.0,
                          periods=1)
    with pytest.MonkeyPatch.context() as env:
        env.setenv("REAL2SIM_CACHE", str(log_dir.parent / "cache"))  # small_log's design: no new search
        truth = run_excite(make_object("can"), config, log_dir.parent / "noise_free", say=lambda *_: None)
    return log_dir.parent / "noise_free", truth


def test_noise_free_torques_give_the_inertia_without_bias(noise_free_log):
    """With no torque noise what is left is bias: the simulated joints' friction must act as continuous
    friction does. Held at each control tick's velocity it lagged the motion by an eighth of a millisecond,
    a torque proportional to the acceleration, and the payload's inertia came out 7.1 % off on this
    one-period capture; as continuous friction, 1.3 %."""
    log_dir, truth = noise_free_log
    _, props = run_identify(log_dir)
    err = errors_against_truth(props, truth)
    assert err["mass_rel"] < 1e-3 and err["com_m"] < 1e-4
    assert err["inertia_rel"] < 0.03, err


def test_standard_errors_and_the_designs_prediction_match_the_spread_over_noise_draws(noise_free_log):
    """The same motion under 12 draws of 0.05 N m noise: the standard errors identify reports, and the
    rotational inertia's error the trajectory's design predicted, agree with how far the
    estimates actually scatter. Without the rows' correlation the reported errors were 2-3.5 times
    too small."""
    import dataclasses

    from real2sim.formats.joint_log import ROBOT_FILE
    from real2sim.identify.solve import identify

    log_dir, truth = noise_free_log
    clean = read_joint_log(log_dir)
    arm = load_arm(log_dir / ROBOT_FILE, clean.flange_frame, clean.flange_from_object)
    rng = np.random.default_rng(7)
    phis, reported = [], []
    for _ in range(12):
        noisy = dataclasses.replace(clean, tau_n_m=clean.tau_n_m + rng.normal(scale=0.05, size=clean.tau_n_m.shape))
        result = identify(arm, noisy, physical=False)
        phis.append(result.phi)
        reported.append(result.standard_errors)
    spread = np.std(phis, axis=0, ddof=1)
    ratio = float(np.mean(spread / np.mean(reported, axis=0)))
    assert 0.6 < ratio < 1.6, ratio
    predicted = truth["predicted_inertia_standard_error_kg_m2_at_0_05_n_m"]  # what excite's design said
    actual = float(np.sqrt(np.mean(spread[4:10] ** 2)))
    assert 0.5 < actual / predicted < 2.0, (actual, predicted)


def test_the_regressor_is_drakes_inverse_dynamics_exactly():
    grasp = np.eye(4)
    grasp[:3, 3] = [0.01, -0.02, 0.03]
    arm = load_arm(default_arm_urdf(), "flange", grasp)
    rng = np.random.default_rng(1)
    q, v, a = rng.uniform(-1, 1, (20, 7)), rng.normal(size=(20, 7)), rng.normal(size=(20, 7))
    tau_arm, y = payload_regressor(arm, q, v, a)
    phi = phi_from_properties(0.7, np.array([0.01, -0.02, 0.06]), np.diag([1e-3, 2e-3, 1.5e-3]))
    direct = _inverse_dynamics(arm, q, v, a, spatial_inertia(phi))
    assert np.abs(tau_arm + y @ phi - direct).max() < 1e-9
    # gravity is in it: a 1 kg payload held still loads the shoulder by newton-metres
    _, y_still = payload_regressor(arm, np.tile([0, 0.5, 0, -1.3, 0, 0.9, 0], (1, 1)), np.zeros((1, 7)),
                                   np.zeros((1, 7)))
    assert abs(y_still[0, 1, 0]) > 1.0


def test_excite_then_identify_recovers_mass_and_centre_of_mass(small_log):
    log_dir, truth = small_log
    log = read_joint_log(log_dir)
    assert log.q_rad.shape == (len(log.time_s), 7) and np.allclose(np.diff(log.time_s), 1e-3)
    result, props = run_identify(log_dir)
    err = errors_against_truth(props, truth)
    assert err["mass_rel"] < 0.01
    assert err["com_m"] < 2e-3
    # friction is identified beside the payload (the simulated joints: 1.0 ... 0.2 N m Coulomb)
    assert result.friction_coulomb_n_m[0] == pytest.approx(1.0, abs=0.1)
    assert props["frame"] == "mesh" and props["identification"]["standard_errors"]["mass_kg"] > 0


def test_noisy_data_still_gives_a_physically_consistent_payload(small_log, tmp_path):
    import shutil

    log_dir, _ = small_log
    noisy = tmp_path / "noisy"
    shutil.copytree(log_dir, noisy)
    text = (noisy / "joints.csv").read_text().splitlines()
    header = text[0].split(",")
    rng = np.random.default_rng(0)
    rows = np.array([[float(x) for x in line.split(",")] for line in text[1:]])
    tau_cols = [i for i, c in enumerate(header) if c.startswith("tau")]
    rows[:, tau_cols] += rng.normal(scale=1.0, size=(len(rows), len(tau_cols)))  # 20x the default noise
    (noisy / "joints.csv").write_text("\n".join([text[0]] + [",".join(f"{v:.9g}" for v in r) for r in rows]) + "\n")
    from real2sim.identify.solve import identify

    log = read_joint_log(noisy)
    arm = load_arm(noisy / "robot.urdf", log.flange_frame, log.flange_from_object)
    # without the constraint, these data give a payload no mass distribution has
    plain = identify(arm, log, physical=False)
    assert np.linalg.eigvalsh(pseudo_inertia(plain.phi)).min() < -1e-6
    result, props = run_identify(noisy)
    assert np.linalg.eigvalsh(pseudo_inertia(result.phi)).min() > -1e-7
    mass, _, inertia = properties_from_phi(result.phi)
    moments = np.linalg.eigvalsh(inertia)
    assert mass > 0 and moments.min() > -1e-7 and moments[0] + moments[1] >= moments[2] - 1e-7


def test_the_shape_keeps_the_mass_inside_the_object_and_fills_in_what_the_data_cannot_say(small_log):
    """A log far too noisy to place the centre of mass: alone it lands outside the can; with the can's
    shape the mass stays inside the can's bounding ellipsoid and near the uniform-density estimate."""
    from real2sim.identify.shape import bounding_ellipsoid, shape_prior_from_mesh
    from real2sim.identify.solve import identify

    mesh = make_object("can")
    centre, matrix = bounding_ellipsoid(mesh.vertices)
    inside = lambda p: float((p - centre) @ matrix @ (p - centre)) <= 1 + 1e-6  # noqa: E731
    assert all(inside(v) for v in mesh.vertices)
    log_dir, truth = small_log
    log = read_joint_log(log_dir)
    rng = np.random.default_rng(3)
    noisy = type(log)(log.time_s, log.q_rad, log.v_rad_per_s, log.tau_n_m + rng.normal(scale=20.0, size=log.tau_n_m.shape),
                      None, log.flange_from_object, log.flange_frame)
    arm = load_arm(log_dir / "robot.urdf", log.flange_frame, log.flange_from_object)
    alone = identify(arm, noisy)
    prior = shape_prior_from_mesh(mesh, 0.4)
    shaped = identify(arm, noisy, shape=prior)
    com_alone, com_shaped = alone.properties()[1], shaped.properties()[1]
    assert not inside(com_alone)
    assert inside(com_shaped)
    uniform_com = properties_from_phi(prior.uniform_phi)[1]
    assert np.linalg.norm(com_shaped - uniform_com) < np.linalg.norm(com_alone - uniform_com)
