"""Exciting trajectories: a finite Fourier series per joint, chosen so the payload is identifiable.

``q_j(t) = q0_j + s(t) sum_l [a_jl sin(l w t) + b_jl cos(l w t)]``, ``w = 2 pi / period``; the
envelope ``s`` rises from 0 to 1 over ``ramp_s`` at the start and falls back at the end, so the arm
starts and ends at rest at ``q0``. Candidates are scaled into the position, velocity and
acceleration limits and kept clear of the table (the payload's origin at least ``clearance_m``
above z = 0 and away from the arm's base column); among them the one that predicts the smallest
standard error of the payload's rotational inertia is kept, then improved by random local search.

Why that and not the condition number alone: the condition number scales every column to unit
norm, so it cannot tell a trajectory whose inertia torques are twice as large from another; the
rotational inertia is what the torque noise hides (a 0.3 kg object's shows as ~1e-3 N m against
0.05 N m of noise), so the design asks for it directly: the least-squares covariance of the six
inertia parameters, friction columns included, over the rows :func:`real2sim.identify.solve.identify`
keeps (those away from a joint's velocity reversal); it identifies the inertia better
(docs/design-notes/identify.md#trajectory-design). The condition number is still reported,
and a candidate above :data:`MAX_DESIGN_CONDITION` is refused.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.identify.arm import ArmWithPayload
from real2sim.identify.regressor import friction_regressor, payload_regressor
from real2sim.identify.solve import CUTOFF_HZ, MIN_SPEED_RAD_PER_S

#: A neutral pose: elbow up, the flange in front of the base at about table height + 0.5 m.
DEFAULT_Q0_RAD = (0.0, 0.5, 0.0, -1.3, 0.0, 0.9, 0.0)
#: Acceleration limits, rad/s^2, shoulder to wrist: the payload's rotational inertia shows only in
#: torques proportional to its angular acceleration, which the light wrist joints can give.
DEFAULT_ACCEL_LIMITS_RAD_PER_S2 = (3.0, 3.0, 5.0, 5.0, 15.0, 15.0, 20.0)
#: One period of the Fourier series and the rise (and fall) at each end, seconds.
PERIOD_S = 6.0
RAMP_S = 1.0
#: How long the arm moves by default (six minutes): the rotational inertia's error falls with one
#: over the root of it (docs/design-notes/identify.md#default-duration).
DEFAULT_PERIODS = 60
DEFAULT_DURATION_S = DEFAULT_PERIODS * PERIOD_S + 2.0 * RAMP_S
#: A design must keep every inertial parameter excited (column-scaled regressor).
MAX_DESIGN_CONDITION = 20.0


@dataclass(frozen=True)
class FourierTrajectory:
    """``coeff_sin``, ``coeff_cos``: (n, L) rad; ``q0_rad``: (n,); seconds throughout."""

    q0_rad: np.ndarray
    coeff_sin: np.ndarray
    coeff_cos: np.ndarray
    period_s: float
    ramp_s: float
    periods: int = 1

    @property
    def duration_s(self) -> float:
        return self.periods * self.period_s + 2.0 * self.ramp_s

    def sample(self, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q rad, v rad/s, a rad/s^2), each (T, n), at ``time_s``."""
        t = np.asarray(time_s, dtype=float)[:, None, None]
        harmonics = np.arange(1, self.coeff_sin.shape[1] + 1)[None, None, :]
        w = 2.0 * np.pi / self.period_s * harmonics
        s_, c_ = np.sin(w * t), np.cos(w * t)
        a_, b_ = self.coeff_sin[None], self.coeff_cos[None]
        f = (a_ * s_ + b_ * c_).sum(-1)
        df = (w * (a_ * c_ - b_ * s_)).sum(-1)
        ddf = (-w ** 2 * (a_ * s_ + b_ * c_)).sum(-1)
        e, de, dde = _envelope(t[:, 0, 0], self.ramp_s, self.duration_s)
        q = self.q0_rad[None] + e[:, None] * f
        v = de[:, None] * f + e[:, None] * df
        a = dde[:, None] * f + 2.0 * de[:, None] * df + e[:, None] * ddf
        return q, v, a

    def to_json(self) -> dict:
        return {"q0_rad": self.q0_rad.tolist(), "coeff_sin": self.coeff_sin.tolist(),
                "coeff_cos": self.coeff_cos.tolist(), "period_s": self.period_s, "ramp_s": self.ramp_s,
                "periods": self.periods}

    @staticmethod
    def from_json(d: dict) -> "FourierTrajectory":
        return FourierTrajectory(np.asarray(d["q0_rad"], float), np.asarray(d["coeff_sin"], float),
                                 np.asarray(d["coeff_cos"], float), float(d["period_s"]), float(d["ramp_s"]),
                                 int(d.get("periods", 1)))


def _envelope(t: np.ndarray, ramp_s: float, total_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A C2 rise and fall (quintic smoothstep) and its two derivatives."""
    def smooth(x):
        x = np.clip(x, 0.0, 1.0)
        return 10 * x**3 - 15 * x**4 + 6 * x**5, 30 * x**2 - 60 * x**3 + 30 * x**4, 60 * x - 180 * x**2 + 120 * x**3
    up, dup, ddup = smooth(t / ramp_s)
    down, ddown, dddown = smooth((total_s - t) / ramp_s)
    inside_up = (t > 0) & (t < ramp_s)
    inside_down = (t > total_s - ramp_s) & (t < total_s)
    e = up * down
    de = np.where(inside_up, dup / ramp_s, 0.0) * down - up * np.where(inside_down, ddown / ramp_s, 0.0)
    dde = (np.where(inside_up, ddup / ramp_s**2, 0.0) * down + up * np.where(inside_down, dddown / ramp_s**2, 0.0)
           - 2 * np.where(inside_up, dup / ramp_s, 0.0) * np.where(inside_down, ddown / ramp_s, 0.0))
    return e, de, dde


@dataclass(frozen=True)
class ExcitationQuality:
    """``condition_number``, ``smallest_singular_value``: of the payload regressor stacked over the
    trajectory, columns scaled to unit norm. ``inertia_standard_error_kg_m2``: the predicted standard
    error of the payload's rotational inertia (RMS over its six parameters) at 0.05 N m of white torque
    noise per joint logged at 1 kHz; it scales with the noise and with one over the root of the length."""

    condition_number: float
    smallest_singular_value: float
    inertia_standard_error_kg_m2: float = float("nan")


def quality(arm: ArmWithPayload, traj: FourierTrajectory, samples: int = 160,
            torque_noise_n_m: float = 0.05, log_rate_hz: float = 1000.0) -> ExcitationQuality:
    t = np.linspace(0.0, traj.duration_s, samples)
    q, v, a = traj.sample(t)
    _, y = payload_regressor(arm, q, v, a)
    stacked = y.reshape(-1, 10)
    sv = np.linalg.svd(stacked / np.linalg.norm(stacked, axis=0).clip(1e-12), compute_uv=False)
    # identification keeps a joint's rows only away from its reversals (faster than its minimum speed
    # over the filter's reach, about a period of its cut-off); approximated here by the time the joint
    # needs to get back to that speed
    kept = np.abs(v) >= MIN_SPEED_RAD_PER_S + np.abs(a) / CUTOFF_HZ
    rows = (np.concatenate([y, friction_regressor(v)], axis=2) * kept[..., None]).reshape(-1, 10 + 2 * v.shape[1])
    # each row stands for (duration / samples) s of white noise logged at log_rate_hz
    per_row = traj.duration_s / samples * log_rate_hz
    cov = np.linalg.pinv(rows.T @ rows) * torque_noise_n_m ** 2 / per_row
    se = float(np.sqrt(max(np.trace(cov[4:10, 4:10]), 0.0) / 6.0))
    return ExcitationQuality(float(sv[0] / max(sv[-1], 1e-15)), float(sv[-1]), se)


def _fit_limits(arm: ArmWithPayload, traj: FourierTrajectory, margin: float, accel_limit) -> FourierTrajectory:
    """``traj`` with its coefficients scaled down (per joint) until positions, velocities and
    accelerations stay within ``margin`` of the limits."""
    t = np.linspace(0.0, traj.duration_s, 600)
    q, v, a = traj.sample(t)
    dev = np.abs(q - traj.q0_rad).max(axis=0).clip(1e-9)
    room = np.minimum(arm.position_upper_rad - traj.q0_rad, traj.q0_rad - arm.position_lower_rad) * margin
    scale = np.minimum.reduce([np.ones_like(dev), room / dev,
                               margin * arm.velocity_limit_rad_per_s / np.abs(v).max(axis=0).clip(1e-9),
                               margin * accel_limit / np.abs(a).max(axis=0).clip(1e-9)])
    return FourierTrajectory(traj.q0_rad, traj.coeff_sin * scale[:, None], traj.coeff_cos * scale[:, None],
                             traj.period_s, traj.ramp_s, traj.periods)


def clearance_ok(arm: ArmWithPayload, traj: FourierTrajectory, clearance_m: float, samples: int = 200) -> bool:
    """The payload's origin stays ``clearance_m`` above the table (z = 0) and outside a cylinder of
    that radius around the base's vertical axis (the arm's own column)."""
    plant, ctx = arm.plant, arm.context
    frame = arm.payload.body_frame()
    q, _, _ = traj.sample(np.linspace(0.0, traj.duration_s, samples))
    for qt in q:
        plant.SetPositions(ctx, qt)
        p = plant.CalcRelativeTransform(ctx, plant.world_frame(), frame).translation()
        if p[2] < clearance_m or np.hypot(p[0], p[1]) < clearance_m:
            return False
    return True


def periods_for(duration_s: float, period_s: float = PERIOD_S, ramp_s: float = RAMP_S) -> int:
    """Whole periods that make a trajectory about ``duration_s`` long, ramps included (at least one)."""
    return max(1, int(round((duration_s - 2.0 * ramp_s) / period_s)))


def design_excitation(arm: ArmWithPayload, *, seed: int = 0, harmonics: int = 6, period_s: float = PERIOD_S,
                      periods: int = DEFAULT_PERIODS, ramp_s: float = RAMP_S, candidates: int = 24, refinements: int = 24,
                      margin: float = 0.8, accel_limit_rad_per_s2=DEFAULT_ACCEL_LIMITS_RAD_PER_S2, clearance_m: float = 0.2,
                      q0_rad: tuple[float, ...] = DEFAULT_Q0_RAD) -> tuple[FourierTrajectory, ExcitationQuality]:
    """The feasible trajectory found that predicts the smallest inertia error (module docstring), made
    ``periods`` periods long, and its quality over that length."""
    rng = np.random.default_rng(seed)
    n = arm.num_joints
    q0 = np.asarray(q0_rad[:n] if len(q0_rad) >= n else np.zeros(n), dtype=float)
    decay = 1.0 / np.arange(1, harmonics + 1)

    def candidate(base: FourierTrajectory | None, step: float) -> FourierTrajectory:
        # judged over one period: the motion repeats, so what a second of it gives does too
        if base is None:
            sin, cos = rng.normal(size=(n, harmonics)) * decay, rng.normal(size=(n, harmonics)) * decay
        else:
            sin = base.coeff_sin + step * rng.normal(size=(n, harmonics)) * decay
            cos = base.coeff_cos + step * rng.normal(size=(n, harmonics)) * decay
        return _fit_limits(arm, FourierTrajectory(q0, sin, cos, period_s, ramp_s, 1), margin,
                           np.resize(np.asarray(accel_limit_rad_per_s2, dtype=float), n))

    best, best_q = None, None
    for k in range(candidates + refinements):
        traj = candidate(None if k < candidates or best is None else best, 0.3)
        if not clearance_ok(arm, traj, clearance_m):
            continue
        score = quality(arm, traj)
        if score.condition_number > MAX_DESIGN_CONDITION or not np.isfinite(score.inertia_standard_error_kg_m2):
            continue
        if best_q is None or score.inertia_standard_error_kg_m2 < best_q.inertia_standard_error_kg_m2:
            best, best_q = traj, score
    if best is None:
        raise RuntimeError("no exciting trajectory keeps the payload clear of the table and every inertial "
                           "parameter excited; check the grasp")
    whole = FourierTrajectory(best.q0_rad, best.coeff_sin, best.coeff_cos, period_s, ramp_s, periods)
    return whole, quality(arm, whole, samples=max(160, int(np.ceil(30 * whole.duration_s))))


def cached_excitation(arm: ArmWithPayload, robot_key: str, grasp: np.ndarray, cache_dir: Path | None,
                      seed: int = 0, periods: int = DEFAULT_PERIODS) -> tuple[FourierTrajectory, ExcitationQuality]:
    """:func:`design_excitation`, computed once per robot model, grasp, seed and length and kept in
    ``cache_dir`` (None: not kept)."""
    key = hashlib.sha256(json.dumps([robot_key, np.round(grasp, 9).tolist(), seed, periods, 2]).encode()).hexdigest()[:16]
    path = cache_dir / f"excitation_{key}.json" if cache_dir else None
    if path is not None and path.is_file():
        try:
            d = json.loads(path.read_text())
            return FourierTrajectory.from_json(d["trajectory"]), ExcitationQuality(**d["quality"])
        except (ValueError, KeyError, TypeError):
            pass  # a damaged cache entry is recomputed
    traj, score = design_excitation(arm, seed=seed, periods=periods)
    if path is not None:
        from real2sim.plumbing.outputs import write_text_atomic

        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps({"trajectory": traj.to_json(), "quality": score.__dict__}))
    return traj, score
