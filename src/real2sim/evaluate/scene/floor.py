"""The floor slab of the hydroelastic scenes as a tetrahedral mesh, fine near the object, coarse far away.

Drake meshes a compliant ``Box`` with a handful of tetrahedra as wide as the box; against a 40 m floor
each of them overlaps most of a resting object's triangles, so a rigid mesh's step costs in proportion
to its triangle count (the demo's 40k-face reference: 2.3x slower than on this mesh). This module
writes the same slab, ``floor_size_m`` square and ``2 * floor_slab_thickness_m`` thick with its top at
z = 0, as a VTK file of tetrahedra: a grid whose cells are :data:`FINE_CELL_M` wide within
:data:`FINE_HALF_M` of the origin and grow by :data:`GROWTH` per cell beyond, in two layers that meet
at the slab's mid-plane. Drake's pressure field of a compliant mesh is the distance to its boundary
scaled to the modulus at the deepest point, which is the box's field (depth below the top over the
half-thickness, wherever the top is the nearest face); it is linear inside every tetrahedron here, so
the piecewise-linear field is the box's exactly and only the culling changes (why, and the
measurement: docs/design-notes/evaluate.md#floor-mesh).
"""

from __future__ import annotations

import hashlib
import itertools
import os
import tempfile
from pathlib import Path

import numpy as np

#: Width of the grid's cells near the origin, m (any width gives the same field; small ones cull well).
FINE_CELL_M = 0.2
#: Half-width of the square around the origin where the cells are :data:`FINE_CELL_M` wide, m.
FINE_HALF_M = 0.4
#: Growth of the cells' width from one cell to the next beyond :data:`FINE_HALF_M`.
GROWTH = 2.0


def grid_lines(half_m: float) -> np.ndarray:
    """The grid's lines along x (and y), m: symmetric about 0, from -``half_m`` to ``half_m``."""
    lines = list(np.arange(0.0, min(FINE_HALF_M, half_m) + 1e-9, FINE_CELL_M))
    step = FINE_CELL_M
    while lines[-1] < half_m - 1e-9:
        step *= GROWTH
        lines.append(min(half_m, lines[-1] + step))
    lines = np.asarray(lines)
    return np.concatenate([-lines[:0:-1], lines])


def slab_tetrahedra(size_m: float, half_thickness_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The slab's vertices (V, 3), m, and tetrahedra (T, 4) of vertex indices, each of positive volume:
    every grid cell split into six along its main diagonal (Kuhn), so neighbouring cells share faces."""
    xs = grid_lines(size_m / 2.0)
    zs = np.array([-2.0 * half_thickness_m, -half_thickness_m, 0.0])
    n = len(xs)
    z, y, x = np.meshgrid(zs, xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    k, j, i = np.meshgrid(np.arange(len(zs) - 1), np.arange(n - 1), np.arange(n - 1), indexing="ij")
    corner = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)  # (C, 3) cell origins in grid steps
    tets = []
    for order in itertools.permutations(range(3)):
        at = corner.copy()
        path = [at.copy()]
        for axis in order:
            at[:, axis] += 1
            path.append(at.copy())
        tets.append(np.stack([(p[:, 2] * n + p[:, 1]) * n + p[:, 0] for p in path], axis=1))
    tets = np.concatenate(tets)
    a, b, c, d = (vertices[tets[:, m]] for m in range(4))
    negative = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    tets[negative, 1], tets[negative, 2] = tets[negative, 2], tets[negative, 1].copy()
    return vertices, tets


def floor_mesh_path(size_m: float, half_thickness_m: float) -> Path:
    """The slab's VTK file (written once per size, in the system's temporary folder, atomically so
    that simulations side by side may ask at once)."""
    key = hashlib.sha1(repr((size_m, half_thickness_m, FINE_CELL_M, FINE_HALF_M, GROWTH)).encode()).hexdigest()[:12]
    path = Path(tempfile.gettempdir()) / "real2sim" / f"floor_{key}.vtk"
    if path.is_file():
        return path
    vertices, tets = slab_tetrahedra(size_m, half_thickness_m)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# vtk DataFile Version 3.0", "real2sim floor slab", "ASCII", "DATASET UNSTRUCTURED_GRID",
             f"POINTS {len(vertices)} double", *(" ".join(f"{v:.12g}" for v in row) for row in vertices),
             f"CELLS {len(tets)} {5 * len(tets)}", *("4 " + " ".join(map(str, row)) for row in tets),
             f"CELL_TYPES {len(tets)}", *(["10"] * len(tets))]
    fd, tmp = tempfile.mkstemp(suffix=".vtk", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path
