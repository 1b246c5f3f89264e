"""The solid with its open cavities filled: what a floor, a ramp or a pusher can touch.

A cup's cavity, the hole through a mug's handle or a bowl's hollow are open to the outside, so a
closed mesh keeps them; fitted primitives then spend their pieces on walls a few millimetres thick
although nothing in a push or a tilt ever touches the inside (why: docs/design-notes/asset.md#filled-envelope).
:func:`filled_envelope` closes the solid morphologically with a ball: every place the ball
cannot reach without entering the solid becomes solid. Cavities narrower than the ball fill;
convex parts and concave parts wider than it stay as they are. The lid over an opening of radius a
is where the ball rests on its rim, so it sags into the opening by R - sqrt(R^2 - a^2) (a 45 mm ball
over a 36 mm opening: 18 mm); a ball twice the opening's radius sags a seventh of it.

How: the solid's inside on a voxel grid (winding numbers, :func:`real2sim.geometry.inside.inside_mask`),
dilated and then eroded by the radius through Euclidean distance transforms, eroded one voxel more
so that the voxel surface stays inside the true one, meshed with marching cubes and united with the
solid itself (manifold3d): the true surface is kept wherever the closing adds nothing, and new
surface appears only across the openings it fills.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError

#: Voxels along the solid's longest side.
ENVELOPE_VOXELS = 128


def check_fill_radius(radius_m: float, extent_m: float, label: str = "the object",
                      voxels: int = ENVELOPE_VOXELS) -> None:
    """UserInputError (one line) unless a ball of ``radius_m`` can close an object ``extent_m`` across
    (its longest side) on a grid of ``voxels``: at least two voxels, at most the object's longest side
    (a ball that large fills like the convex hull; use a convex representation instead)."""
    least_m = 2.0 * extent_m / voxels
    if not (math.isfinite(radius_m) and least_m <= radius_m <= extent_m):
        raise UserInputError(f"--fill-cavities-m {radius_m:g} m: must lie between {least_m:.3g} m (two voxels of the "
                             f"{voxels} across {label}) and its longest side, {extent_m:.3g} m")


def filled_envelope(solid: trimesh.Trimesh, radius_m: float, voxels: int = ENVELOPE_VOXELS) -> trimesh.Trimesh:
    """``solid`` (closed, m) closed by a ball of ``radius_m``: a watertight mesh holding the solid,
    with every cavity, hole and notch narrower than the ball filled (same frame, m).

    UserInputError when :func:`check_fill_radius` refuses ``radius_m`` for this solid.
    """
    from scipy import ndimage
    from skimage.measure import marching_cubes

    from real2sim.geometry.inside import inside_mask

    lo, hi = np.asarray(solid.bounds, dtype=float)
    extent = float((hi - lo).max())
    check_fill_radius(radius_m, extent, voxels=voxels)
    pitch = extent / voxels
    pad = int(math.ceil(radius_m / pitch)) + 3
    shape = np.ceil((hi - lo) / pitch).astype(int) + 1
    axes = [lo[k] + pitch * np.arange(shape[k]) for k in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = np.zeros(tuple(shape + 2 * pad), dtype=bool)
    inside[pad:-pad, pad:-pad, pad:-pad] = inside_mask(solid, centres).reshape(tuple(shape))
    radius_vox = radius_m / pitch
    dilated = ndimage.distance_transform_edt(~inside) <= radius_vox
    # one voxel more than the closing: the voxel surface then lies inside the true one where nothing fills
    closed = ndimage.distance_transform_edt(dilated) > radius_vox + 1.0
    if not closed.any():
        return solid.copy()
    grid = np.pad(closed, 1).astype(np.float32)
    vertices, faces, _, _ = marching_cubes(grid, level=0.5)
    vertices = lo + pitch * (vertices - 1 - pad)
    filler = trimesh.Trimesh(vertices, faces[:, ::-1] if _inward(vertices, faces) else faces, process=True)
    envelope = trimesh.boolean.union([solid, filler], engine="manifold")
    return trimesh.Trimesh(envelope.vertices, envelope.faces, process=True)


def _inward(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether marching cubes' triangles face inward (negative signed volume)."""
    tri = vertices[faces]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) < 0
