"""Score a candidate trajectory against the reference: ATE, OCAE, CPD (paper V-C)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _align(reference: Any, candidate: Any) -> tuple[np.ndarray, ...]:
    """Reference and candidate poses on the reference's time steps (candidate interpolated if needed)."""
    t_ref = np.asarray(reference.times_s, dtype=float)
    t_c = np.asarray(candidate.times_s, dtype=float)
    p_ref = np.asarray(reference.object_position_m, dtype=float)
    q_ref = np.asarray(reference.object_quaternion_wxyz, dtype=float)
    p_c = np.asarray(candidate.object_position_m, dtype=float)
    q_c = np.asarray(candidate.object_quaternion_wxyz, dtype=float)
    if t_c.shape == t_ref.shape and np.allclose(t_c, t_ref, atol=1e-9):
        return p_ref, q_ref, p_c, q_c
    # Different sampling: compare on the common time span, candidate linearly interpolated
    # (quaternions sign-aligned, lerped and renormalised; steps are 1 ms, so this is exact enough).
    keep = (t_ref >= t_c[0] - 1e-9) & (t_ref <= t_c[-1] + 1e-9)
    if keep.sum() < 2:
        raise RuntimeError("candidate and reference trajectories do not overlap in time")
    t = t_ref[keep]
    q_c = _sign_continuous(q_c)
    p_i = np.stack([np.interp(t, t_c, p_c[:, k]) for k in range(3)], axis=1)
    q_i = np.stack([np.interp(t, t_c, q_c[:, k]) for k in range(4)], axis=1)
    q_i /= np.linalg.norm(q_i, axis=1, keepdims=True)
    return p_ref[keep], q_ref[keep], p_i, q_i


def _sign_continuous(q: np.ndarray) -> np.ndarray:
    """Flip quaternion signs so consecutive ones are in the same hemisphere (for interpolation)."""
    # Flipping q[i] flips its dot product with q[i+1] too, hence the running product of signs.
    d = np.sum(q[1:] * q[:-1], axis=1)
    signs = np.concatenate([[1.0], np.where(d < 0, -1.0, 1.0)]).cumprod()
    return q * signs[:, None]


def score(reference: Any, candidate: Any, lever_m: float = 1.0) -> dict[str, float]:
    """ATE, OCAE (m) of ``candidate`` against ``reference``, and the candidate's CPD: ours (m/s), as the
    paper defines it in words and force-weighted (:func:`real2sim.evaluate.metrics.cpd_m_per_s`), and
    the paper's code's (m per 1 ms sample, :func:`real2sim.evaluate.metrics.cpd_paper`)."""
    from real2sim.evaluate.metrics import ate_m, cpd_m_per_s, cpd_paper, ocae_m, real_time_factor

    p_ref, q_ref, p_c, q_c = _align(reference, candidate)
    times = np.asarray(candidate.times_s, dtype=float)
    dt_s = float(np.median(np.diff(times))) if len(times) > 1 else float("nan")
    # Sample r + 1 holds the contacts of the first step after the reset at step r: cut the
    # contact series there, so that the reset's jump does not count as a discontinuity.
    breaks = np.asarray(getattr(candidate, "reset_steps", ()), dtype=int) + 1
    cpd = cpd_m_per_s(candidate.contact_points_object_m, dt_s, breaks) if math.isfinite(dt_s) else float("nan")
    forces = getattr(candidate, "contact_forces_object_n", None)
    cpd_fw = (cpd_m_per_s(candidate.contact_points_object_m, dt_s, breaks, contact_forces_n=forces)
              if forces and math.isfinite(dt_s) else float("nan"))
    surfaces = getattr(candidate, "contact_surface_counts", None)
    surfaces = surfaces if surfaces is not None and len(surfaces) == len(candidate.contact_points_object_m) else None
    paper = (cpd_paper(candidate.contact_points_object_m, candidate.object_position_m, surfaces, dt_s)
             if math.isfinite(dt_s) else float("nan"))
    return {
        "ate_m": ate_m(p_ref, p_c),
        "ocae_m": ocae_m(p_ref, q_ref, p_c, q_c, lever_m=lever_m),
        "cpd_m_per_s": cpd,
        "cpd_force_weighted_m_per_s": cpd_fw,
        "cpd_paper": paper,
        "sim_time_s": float(candidate.sim_time_s),
        "sim_duration_s": float(candidate.sim_duration_s),
        "real_time_factor": real_time_factor(candidate.sim_duration_s, candidate.sim_time_s),
    }
