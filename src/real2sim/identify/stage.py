"""The two verbs as plain functions: `excite` (simulate an arm holding the object, write a joint log)
and `identify` (a joint log in, the payload's mass properties out)."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.formats.joint_log import ROBOT_FILE, TRUTH_FILE, read_joint_log, write_joint_log
from real2sim.formats.physical import MESH_FRAME
from real2sim.plumbing.progress import ProgressFn
from real2sim.identify.arm import default_arm_urdf, load_arm
from real2sim.identify.excitation import DEFAULT_PERIODS
from real2sim.identify.solve import PARAMETER_NAMES, Identification, identify


@dataclass(frozen=True)
class ExciteConfig:
    """What `excite` simulates: the object the arm holds, how noisy its torques are, and how long
    it moves."""

    mass_kg: float
    """Mass of the object's body at uniform density, kg, > 0."""
    extra_mass_kg: float = 0.0
    """A point mass added inside the object at ``extra_mass_at_m``, kg, >= 0 (0: none)."""
    extra_mass_at_m: tuple[float, float, float] | None = None
    """Where the extra mass sits, metres in the mesh's frame, inside the object; needed when
    ``extra_mass_kg`` > 0."""
    torque_noise_n_m: float = 0.05
    """RMS of the white noise on each joint's logged torque, N m, >= 0."""
    seed: int = 0
    """Seed of the trajectory design and of the measurement noise."""
    robot_urdf: Path | None = None
    """The arm's URDF; None: the bundled 7-joint arm (:func:`real2sim.identify.arm.default_arm_urdf`)."""
    periods: int = DEFAULT_PERIODS
    """Periods of the exciting motion (6 s each, plus 2 s of rise and fall), >= 1.
    (why: docs/design-notes/identify.md#default-duration)"""


def default_grasp(mesh) -> np.ndarray:
    """The object's frame in the flange frame: the centre of its bounding box's bottom face 1 cm out
    from the flange, its axes the flange's (held by its base, standing out along the flange's z)."""
    lo, hi = mesh.bounds
    bottom_centre = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    grasp = np.eye(4)
    grasp[:3, 3] = np.array([0.0, 0.0, 0.01]) - bottom_centre
    return grasp


def excitation_cache_dir() -> Path:
    root = os.environ.get("REAL2SIM_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "real2sim") / "excitation"


def run_excite(mesh, config: ExciteConfig, out_dir: Path, *, overwrite: bool = False, inputs: tuple = (), say=print,
               progress: ProgressFn | None = None) -> dict:
    """Simulate the arm holding ``mesh`` (closed, metres) and write the log into ``out_dir`` (whole or
    not at all). ``inputs``: the files the mesh was read from; the log may not overlap them, nor
    ``config.robot_urdf``. Returns the truth written to ``truth.json``."""
    from real2sim.plumbing.outputs import atomic_output_dir
    from real2sim.identify.excitation import cached_excitation
    from real2sim.identify.excite import Measurement, closed_solid, payload_truth, simulate_excitation

    mesh = closed_solid(mesh)
    if config.extra_mass_kg > 0:
        if config.extra_mass_at_m is None:
            raise UserInputError("--extra-mass-kg needs --extra-mass-at-m X Y Z (metres, the mesh's frame)")
        if not bool(mesh.contains(np.asarray([config.extra_mass_at_m], dtype=float))[0]):
            raise UserInputError(f"--extra-mass-at-m {' '.join(f'{v:g}' for v in config.extra_mass_at_m)} is not inside "
                                 "the object (metres, the mesh's own frame)")
    if not mesh.is_watertight:
        raise UserInputError("the object's mesh must be a closed solid for its true mass properties")
    urdf = Path(config.robot_urdf) if config.robot_urdf else default_arm_urdf()
    grasp = default_grasp(mesh)
    arm = load_arm(urdf, "flange", grasp)  # continuous: the controller's own period sets the steps
    nominal = load_arm(urdf, "flange", grasp)
    urdf_text = urdf.read_text()
    say("designing the exciting trajectory (cached per robot and grasp)")
    traj, quality = cached_excitation(nominal, hashlib.sha256(urdf_text.encode()).hexdigest(), grasp,
                                      excitation_cache_dir(), seed=config.seed, periods=config.periods)
    say(f"trajectory: {traj.duration_s:.0f} s, regressor condition number {quality.condition_number:.2f}, "
        f"smallest singular value {quality.smallest_singular_value:.3f}, predicted inertia standard error "
        f"{quality.inertia_standard_error_kg_m2:.2g} kg m^2 at 0.05 N m of torque noise")
    truth = payload_truth(mesh, config.mass_kg, config.extra_mass_kg, config.extra_mass_at_m)
    say(f"simulating the arm holding {truth.mass_kg:.3f} kg for {traj.duration_s:.0f} s, logged at 1 kHz")
    report = None if progress is None else (lambda done, total: progress("simulating the arm", done, total))
    log = simulate_excitation(arm, nominal, traj, truth, Measurement(torque_noise_n_m=config.torque_noise_n_m),
                              seed=config.seed, progress=report)
    record = {**truth.to_json(), "mass_body_kg": config.mass_kg, "extra_mass_kg": config.extra_mass_kg,
              "extra_mass_at_m": list(config.extra_mass_at_m) if config.extra_mass_at_m is not None else None,
              "torque_noise_n_m": config.torque_noise_n_m, "seed": config.seed,
              "trajectory": traj.to_json(), "condition_number": quality.condition_number,
              "predicted_inertia_standard_error_kg_m2_at_0_05_n_m": quality.inertia_standard_error_kg_m2}
    read = [*inputs, *([config.robot_urdf] if config.robot_urdf else [])]  # never inside the log it replaces
    with atomic_output_dir(out_dir, overwrite=overwrite, inputs=read, made_by="real2sim excite") as tmp:
        write_joint_log(tmp, log, urdf_text, truth=record)
    return record


def run_identify(log_dir: Path, *, shape_dir: Path | None = None, solver: str = "clarabel") -> tuple[Identification, dict]:
    """Identify the payload of ``log_dir``; (the result, the props.json content)."""
    log = read_joint_log(log_dir)
    arm = load_arm(Path(log_dir) / ROBOT_FILE, log.flange_frame, log.flange_from_object)
    shape = None
    if shape_dir is not None:
        from real2sim.identify.shape import shape_prior_from_asset

        shape = shape_prior_from_asset(shape_dir)
    result = identify(arm, log, shape=shape, solver=solver)
    mass, com, inertia = result.properties()
    props = {
        "mass_kg": mass, "com_m": com.tolist(), "inertia_kg_m2": inertia.tolist(),
        "method": "identified from joint torques (real2sim identify: weighted least squares with a positive "
                  "semidefinite pseudo-inertia" + (", the shape's bounding ellipsoid and a uniform-density prior"
                                                 if shape is not None else "") + f", {solver})",
        "samples_kept": result.samples, "frame": MESH_FRAME,
        "identification": {
            "standard_errors": dict(zip(PARAMETER_NAMES, result.standard_errors.tolist())),
            "parameters": dict(zip(PARAMETER_NAMES, result.phi.tolist())),
            "residual_rms_n_m": result.residual_rms_n_m.tolist(),
            "friction_coulomb_n_m": result.friction_coulomb_n_m.tolist(),
            "friction_viscous_n_m_s": result.friction_viscous_n_m_s.tolist(),
            "condition_number": result.condition_number, "solver": solver,
            "log": str(log_dir), "shape": str(shape_dir) if shape_dir else None,
        },
    }
    return result, props


def errors_against_truth(props: dict, truth: dict) -> dict:
    """Mass (relative), CoM (m) and inertia about the CoM (largest relative principal-moment error)."""
    true_i = np.linalg.eigvalsh(np.asarray(truth["inertia_kg_m2"]))
    got_i = np.linalg.eigvalsh(np.asarray(props["inertia_kg_m2"]))
    return {"mass_rel": abs(props["mass_kg"] - truth["mass_kg"]) / truth["mass_kg"],
            "com_m": float(np.linalg.norm(np.asarray(props["com_m"]) - np.asarray(truth["com_m"]))),
            "inertia_rel": float(np.max(np.abs(got_i - true_i) / true_i))}


def read_truth(log_dir: Path) -> dict | None:
    """``LOG/truth.json`` (None when the log has none), checked so that :func:`errors_against_truth` can use
    it: UserInputError (one line, naming the file) unless it is JSON with a finite mass > 0, a finite CoM
    of 3 values and a finite 3x3 inertia with positive principal moments."""
    path = Path(log_dir) / TRUTH_FILE
    if not path.is_file():
        return None
    try:
        truth = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise UserInputError(f"{path} is not readable JSON ({' '.join(str(exc).split())}); fix or remove it") from None
    if not isinstance(truth, dict):
        raise UserInputError(f"{path} must hold a JSON object with mass_kg, com_m and inertia_kg_m2")
    try:
        mass = float(truth["mass_kg"])
        com = np.asarray(truth["com_m"], dtype=float)
        inertia = np.asarray(truth["inertia_kg_m2"], dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise UserInputError(f"{path} needs numbers mass_kg, com_m [x, y, z] and inertia_kg_m2 (3x3): "
                             f"{type(exc).__name__} {' '.join(str(exc).split())}") from None
    if not (np.isfinite(mass) and mass > 0):
        raise UserInputError(f"{path}: mass_kg must be a finite number > 0 (got {truth['mass_kg']!r})")
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise UserInputError(f"{path}: com_m must be 3 finite numbers (got {truth['com_m']!r})")
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)) or \
            not np.all(np.linalg.eigvalsh(0.5 * (inertia + inertia.T)) > 0):
        raise UserInputError(f"{path}: inertia_kg_m2 must be a finite 3x3 matrix with positive principal moments")
    return truth

