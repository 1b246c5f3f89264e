"""A simulated run as arrays (:class:`Trajectory`), and its .npz file in the reference cache.

Plain numpy: the evaluation writes it, the sweep caches references with it, and nothing
here needs Drake.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Trajectory:
    """One simulated run, as arrays over the T = num_steps + 1 samples.

    times_s: (T,) sample times, s (step index * time_step_s).
    object_position_m: (T, 3) world position of the object's asset-frame origin, m.
    object_quaternion_wxyz: (T, 4) world orientation of the asset frame: Drake's state as
        is (so a reset restores it bit for bit): unit only to ~1e-12, sign not canonical;
        normalise before building a rotation matrix.
    object_spatial_velocity: (T, 6) [angular rad/s, linear m/s] of the asset-frame origin,
        both in world (Drake's free-body velocity state).
    actuated_positions: (T, k) the pusher's (x, y, m) or the table's (angle, rad) joint positions.
    actuated_velocities: (T, k) their time derivatives.
    contact_points_object_m: per sample, (k_t, 3) points where the object touches anything,
        expressed in the object's (asset) frame, m: point contact -> each point pair's
        contact point; hydroelastic -> each contact surface's centroid. They are the
        contacts of that sample's state (what the next step's contact forces act at;
        Drake's unsampled contact-results port), at a reset step those of the prediction.
    contact_forces_object_n: per sample, (k_t, 3) the contact force on the object at each
        of those points, N, expressed in the object frame (point contact: the pair's
        force; hydroelastic: the surface's net force). Only used to weight the
        force-weighted CPD; empty in trajectories saved before it existed.
    contact_surface_counts: (T,) int, how many of each sample's contact points (the last ones)
        are hydroelastic surface centroids, the others being point pairs (the paper's CPD
        picks one kind per run); empty in trajectories saved before it existed.
    sim_time_s: wall seconds of the bare timed run (see module docstring); NaN for a reference,
        which is not timed.
    sim_duration_s: simulated seconds.
    instrumented_time_s: wall seconds of the per-step logging run.
    reset_steps: (r,) step indices where the state was reset to the reference (multiples of
        the reset interval, 0 < step < num_steps; the shared start at step 0 is not counted).
    task, contact_model, representation, run: identification.
    """

    times_s: np.ndarray
    object_position_m: np.ndarray
    object_quaternion_wxyz: np.ndarray
    object_spatial_velocity: np.ndarray
    actuated_positions: np.ndarray
    actuated_velocities: np.ndarray
    contact_points_object_m: list
    sim_time_s: float
    sim_duration_s: float
    instrumented_time_s: float
    reset_steps: np.ndarray
    task: str
    contact_model: str
    representation: str
    run: int
    contact_forces_object_n: list = field(default_factory=list)
    contact_surface_counts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def save_trajectory(traj: Any, path: Path) -> None:
    """Save a Trajectory dataclass (arrays, scalars, lists of per-step arrays) to .npz, atomically."""
    arrays: dict[str, np.ndarray] = {}
    for f in dataclasses.fields(traj):
        value = getattr(traj, f.name)
        if isinstance(value, (list, tuple)):  # per-step point lists (contact points)
            parts = [np.asarray(v, dtype=float).reshape(-1, 3) for v in value]
            arrays[f"{f.name}__counts"] = np.array([len(p) for p in parts], dtype=np.int64)
            arrays[f"{f.name}__stack"] = np.concatenate(parts) if parts else np.zeros((0, 3))
        else:
            arrays[f.name] = np.asarray(value)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def load_trajectory(path: Path) -> Trajectory:
    data = np.load(path)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(Trajectory):
        if f"{f.name}__counts" in data:
            counts = data[f"{f.name}__counts"]
            kwargs[f.name] = list(np.split(data[f"{f.name}__stack"], np.cumsum(counts)[:-1])) if len(counts) else []
        elif f.name in data:
            v = data[f.name]
            kwargs[f.name] = v.item() if v.ndim == 0 else v
    return Trajectory(**kwargs)
