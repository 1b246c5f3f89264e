"""Camera poses that look at a point: the one pose construction every simulated capture shares.

Poses are camera-to-world 4x4 in OpenGL axes (x right, y up, looking along -z); world z is up.
"""

from __future__ import annotations

import numpy as np


def look_at_c2w_gl(positions_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses (OpenGL axes) at ``positions_m`` looking at ``target_m``, no roll.

    Image "up" is world +z where defined; for cameras straight above the target it
    is the horizontal direction pointing away from the camera's azimuth.
    """
    fwd = target_m - positions_m
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    z_up = np.array([0.0, 0.0, 1.0])
    right = np.cross(fwd, z_up)
    n = np.linalg.norm(right, axis=1)
    degenerate = n < 1e-6
    if np.any(degenerate):
        right[degenerate] = [0.0, -1.0, 0.0]
        n[degenerate] = 1.0
    right /= n[:, None]
    up = np.cross(right, fwd)
    c2w = np.tile(np.eye(4), (len(positions_m), 1, 1))
    c2w[:, :3, 0] = right
    c2w[:, :3, 1] = up
    c2w[:, :3, 2] = -fwd
    c2w[:, :3, 3] = positions_m
    return c2w

