"""Bring your own reconstruction: a mesh exported by nerfstudio, put back in the dataset's world frame.

nerfstudio normalises a dataset's poses before training (paper IV-B2): with the
3x4 ``transform`` [R | t] and the ``scale`` s that it writes to
``dataparser_transforms.json``, a world point p becomes ``s * (R p + t)``; the
meshes it exports live in that normalised frame. Undoing it,
``p = T^-1 (p_ns / s)`` with T the 4x4 form of [R | t], puts the mesh back in
the world (robot) frame, in metres.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError


_ON_TABLE_TOLERANCE_M = 1e-6


def read_dataparser_transforms(path: Path | str) -> tuple[np.ndarray, float]:
    """(4x4 transform, scale) from nerfstudio's ``dataparser_transforms.json``; UserInputError when malformed."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        matrix = np.asarray(data["transform"], dtype=float)
        scale = float(data["scale"])
    except FileNotFoundError:
        raise UserInputError(f"dataparser transforms not found: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"{path}: expected nerfstudio's dataparser_transforms.json with 'transform' (3x4) "
                             f"and 'scale' ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    if matrix.shape == (3, 4):
        matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)) or abs(np.linalg.det(matrix[:3, :3])) < 1e-9:
        raise UserInputError(f"{path}: 'transform' must be an invertible finite 3x4 matrix")
    if not (np.isfinite(scale) and scale > 0):
        raise UserInputError(f"{path}: 'scale' must be a finite number > 0 (got {scale})")
    return matrix, scale


def world_from_nerfstudio(matrix: np.ndarray, scale: float) -> np.ndarray:
    """4x4 taking points of nerfstudio's normalised frame to the dataset's world frame."""
    unscale = np.diag([1.0 / scale, 1.0 / scale, 1.0 / scale, 1.0])
    return np.linalg.inv(matrix) @ unscale


def import_nerfstudio_mesh(mesh_path: Path | str, dataparser_transforms: Path | str, *, table_z_m: float = 0.0,
                           min_part_volume_fraction: float = 0.05) -> trimesh.Trimesh:
    """The exported mesh in the world frame (metres), texture kept, cleaned: nothing below the table, no floaters."""
    from real2sim.geometry.mesh_io import load_mesh
    from real2sim.multiview.voxel_grid import largest_parts

    mesh = load_mesh(mesh_path)
    matrix, scale = read_dataparser_transforms(dataparser_transforms)
    mesh.apply_transform(world_from_nerfstudio(matrix, scale))
    return clean_mesh(mesh, table_z_m=table_z_m, min_part_volume_fraction=min_part_volume_fraction,
                      largest_parts=largest_parts)


def clean_mesh(mesh: trimesh.Trimesh, *, table_z_m: float, min_part_volume_fraction: float,
               largest_parts) -> trimesh.Trimesh:
    """Drop faces wholly below the table plane and the small disconnected parts (floaters, the table)."""
    # a bottom lying on the table comes back a few ulp below it from the inverse transform
    below = mesh.vertices[:, 2] < table_z_m - _ON_TABLE_TOLERANCE_M
    keep = ~below[mesh.faces].all(axis=1)
    if not keep.any():
        raise UserInputError(f"the mesh lies wholly below the table plane z = {table_z_m} m in the dataset's frame: "
                             "wrong dataparser_transforms.json?")
    mesh = mesh.copy()
    mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    return largest_parts(mesh, min_part_volume_fraction)
