"""The joint log that `excite` writes and `identify` reads: the contract for real robots too.

``LOG/`` holds

* ``robot.urdf``: the arm's model (relative paths only), base welded to the world at its origin,
  z up; its identification is trusted (the payload is what is identified);
* ``grasp.json``: ``{"flange_frame": NAME, "flange_from_object": 4x4}``, the object's own frame
  (the frame of its mesh) in the flange frame, metres; a rigid transform;
* ``joints.csv``: one row per sample, columns ``time_s``, then for each joint ``j`` (1-based, in
  the model's joint order) ``q{j}_rad``, ``v{j}_rad_per_s``, ``tau{j}_n_m`` (measured joint
  torque: what the motors apply, friction included), and optionally ``a{j}_rad_per_s2``;
* ``truth.json``: only in simulated logs, the payload's true mass properties.

Plain numpy and json: importable without Drake.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import write_text_atomic

ROBOT_FILE = "robot.urdf"
GRASP_FILE = "grasp.json"
JOINTS_FILE = "joints.csv"
TRUTH_FILE = "truth.json"


@dataclass(frozen=True)
class JointLog:
    """Samples of an arm's joints. ``time_s``: (T,); ``q_rad``, ``v_rad_per_s``, ``tau_n_m``,
    ``a_rad_per_s2`` (or None): (T, n) in the model's joint order; ``flange_from_object``: 4x4,
    metres; ``flange_frame``: the model's frame the grasp is given in."""

    time_s: np.ndarray
    q_rad: np.ndarray
    v_rad_per_s: np.ndarray
    tau_n_m: np.ndarray
    a_rad_per_s2: np.ndarray | None
    flange_from_object: np.ndarray
    flange_frame: str = "flange"

    @property
    def num_joints(self) -> int:
        return int(self.q_rad.shape[1])


def _columns(n: int, with_acceleration: bool) -> list[str]:
    cols = ["time_s"]
    for kind in ("q{}_rad", "v{}_rad_per_s", "tau{}_n_m") + (("a{}_rad_per_s2",) if with_acceleration else ()):
        cols += [kind.format(j + 1) for j in range(n)]
    return cols


def write_joint_log(folder: Path, log: JointLog, robot_urdf_text: str, truth: dict | None = None) -> None:
    """Write ``log`` into ``folder`` (which exists) in the layout of the module docstring."""
    folder = Path(folder)
    n = log.num_joints
    blocks = [log.time_s[:, None], log.q_rad, log.v_rad_per_s, log.tau_n_m]
    if log.a_rad_per_s2 is not None:
        blocks.append(log.a_rad_per_s2)
    table = np.hstack(blocks)
    lines = [",".join(_columns(n, log.a_rad_per_s2 is not None))]
    lines += [",".join(f"{v:.9g}" for v in row) for row in table]
    write_text_atomic(folder / JOINTS_FILE, "\n".join(lines) + "\n")
    write_text_atomic(folder / ROBOT_FILE, robot_urdf_text)
    write_text_atomic(folder / GRASP_FILE, json.dumps(
        {"flange_frame": log.flange_frame, "flange_from_object": np.asarray(log.flange_from_object).tolist()},
        indent=1))
    if truth is not None:
        write_text_atomic(folder / TRUTH_FILE, json.dumps(truth, indent=1))


def _rigid(matrix: np.ndarray) -> bool:
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        return False
    rotation = matrix[:3, :3]
    return (np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6) and np.linalg.det(rotation) > 0
            and np.allclose(matrix[3], [0, 0, 0, 1], atol=1e-9))


def read_grasp(folder: Path) -> tuple[str, np.ndarray]:
    path = Path(folder) / GRASP_FILE
    try:
        data = json.loads(path.read_text())
        matrix = np.asarray(data["flange_from_object"], dtype=float)
        frame = str(data.get("flange_frame", "flange"))
    except FileNotFoundError:
        raise UserInputError(f"{path} is missing: the log needs the grasp (the object frame in the flange frame)") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"{path} is not a grasp file ({exc.__class__.__name__}: {exc})") from None
    if not _rigid(matrix):
        raise UserInputError(f"{path}: flange_from_object is not a rigid transform (a 4x4 with a rotation and "
                             "a last row 0 0 0 1)")
    return frame, matrix


def read_joint_log(folder: Path) -> JointLog:
    """Read and check ``folder``'s log; every problem is one UserInputError line."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UserInputError(f"{folder} is not a log folder")
    path = folder / JOINTS_FILE
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise UserInputError(f"{path} is missing: the log needs the joint samples") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UserInputError(f"{path} is not a CSV file ({exc})") from None
    if not rows:
        raise UserInputError(f"{path} is empty")
    header, body = rows[0], [r for r in rows[1:] if r]
    n = sum(1 for c in header if c.startswith("q") and c.endswith("_rad"))
    if n == 0:
        raise UserInputError(f"{path} has no joint position columns (q1_rad, q2_rad, ...)")
    with_acc = any(c.startswith("a") and c.endswith("_rad_per_s2") for c in header)
    expected = _columns(n, with_acc)
    missing = [c for c in expected if c not in header]
    if missing:
        raise UserInputError(f"{path} is missing columns: {', '.join(missing[:6])}"
                             + (" ..." if len(missing) > 6 else ""))
    short = [i + 2 for i, r in enumerate(body) if len(r) != len(header)]
    if short:
        raise UserInputError(f"{path}: line {short[0]} has {len(body[short[0] - 2])} fields, the header "
                             f"{len(header)} (mismatched lengths)")
    try:
        table = np.array(body, dtype=float).reshape(len(body), len(header))
    except ValueError as exc:
        raise UserInputError(f"{path} holds a value that is not a number ({exc})") from None
    if not np.all(np.isfinite(table)):
        line = int(np.argwhere(~np.isfinite(table))[0, 0]) + 2
        raise UserInputError(f"{path}: line {line} holds NaN or infinity")
    col = {c: i for i, c in enumerate(header)}
    pick = lambda fmt: table[:, [col[fmt.format(j + 1)] for j in range(n)]]  # noqa: E731
    time_s = table[:, col["time_s"]]
    if len(time_s) < 2 or np.any(np.diff(time_s) <= 0):
        raise UserInputError(f"{path}: time_s must increase from row to row")
    frame, grasp = read_grasp(folder)
    if not (folder / ROBOT_FILE).is_file():
        raise UserInputError(f"{folder / ROBOT_FILE} is missing: the log needs the robot's model")
    return JointLog(time_s=time_s, q_rad=pick("q{}_rad"), v_rad_per_s=pick("v{}_rad_per_s"),
                    tau_n_m=pick("tau{}_n_m"), a_rad_per_s2=pick("a{}_rad_per_s2") if with_acc else None,
                    flange_from_object=grasp, flange_frame=frame)
