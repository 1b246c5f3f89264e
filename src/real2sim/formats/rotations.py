"""The rotation conventions of the files, in one place (numpy; the fitter's batched torch
version is :func:`real2sim.collision.primitive_sdf.quaternion_to_matrix`).

Poses written for people use xyz + a unit quaternion (w, x, y, z); where URDF and
SDFormat need roll-pitch-yaw it is Drake's convention, R = Rz(yaw) Ry(pitch) Rx(roll)
(extrinsic x-y-z).
"""

from __future__ import annotations

import warnings

import numpy as np


def quaternion_to_matrix(q_wxyz) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) with w >= 0 of a 3x3 rotation matrix."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat()
    q = np.array([w, x, y, z])
    if q[0] < 0:
        q = -q
    q = q / np.linalg.norm(q)
    return tuple(float(v) for v in q)


def quaternion_to_rpy(q_wxyz) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad) of a unit quaternion (w, x, y, z) in Drake's/URDF's convention.

    The returned angles satisfy R(q) = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic rotations
    about the fixed x, then y, then z axes), which is what URDF ``rpy`` and SDFormat
    ``<pose>`` mean. Near pitch = +-90 degrees (gimbal lock) roll and yaw are not unique;
    the composed rotation still equals R(q).
    """
    from scipy.spatial.transform import Rotation

    w, x, y, z = (float(v) for v in q_wxyz)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # gimbal lock: angles not unique, rotation still exact
        roll, pitch, yaw = Rotation.from_quat([x, y, z, w]).as_euler("xyz")  # lowercase = extrinsic
    return float(roll), float(pitch), float(yaw)


def rpy_to_matrix(rpy) -> np.ndarray:
    """3x3 rotation Rz(yaw) Ry(pitch) Rx(roll) of roll-pitch-yaw angles (rad)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about x."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about y."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def quaternions_to_matrices(q_wxyz: np.ndarray) -> np.ndarray:
    """``(T, 4)`` unit quaternions (w, x, y, z) -> ``(T, 3, 3)`` rotation matrices."""
    w, x, y, z = np.asarray(q_wxyz).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )
