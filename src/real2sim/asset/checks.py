"""Refusals before an asset build does any work: a mesh its configuration cannot turn into a usable
asset, and given mass properties whose centre of mass lies outside the object."""

from __future__ import annotations

import numpy as np
import trimesh

from real2sim.asset.config import AssetConfig
from real2sim.formats.physical import MESH_FRAME
from real2sim.geometry.mesh_io import check_object_size
from real2sim.plumbing.errors import UserInputError

#: Largest object per resolution hint: Drake meshes compliant curved primitives with edges about
#: the hint long, and past this many hints across a single primitive costs gigabytes
#: (why: docs/design-notes/asset.md#max-extent-per-resolution-hint).
MAX_EXTENT_PER_RESOLUTION_HINT = 300.0
#: How far below the mesh the support plane may lie, as a fraction of the mesh's height:
#: a reconstruction's bottom may stop a little above the table.
SUPPORT_BELOW_TOLERANCE = 0.05
#: How far outside the object's axis-aligned bounds a given centre of mass may lie, as a fraction of
#: the object's largest extent: room for a reconstruction that misses a little of the object and an
#: identified CoM's millimetres of error; a file in another frame or unit lies far further out.
COM_MARGIN_FRACTION = 0.1


def check_given_com(config: AssetConfig, vertices: np.ndarray, label: str) -> None:
    """Refuse given properties whose centre of mass lies outside the object: beyond the axis-aligned
    bounds of ``vertices`` (the object in the frame the properties are given in, m) grown on every side by
    :data:`COM_MARGIN_FRACTION` of the bounds' largest side. UserInputError naming ``--properties``."""
    if config.given_properties is None:
        return
    vertices = np.asarray(vertices, dtype=float)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    margin = COM_MARGIN_FRACTION * float((hi - lo).max())
    com = np.asarray(config.given_properties.com_m, dtype=float)
    if np.all(com >= lo - margin) and np.all(com <= hi + margin):
        return
    frame = "the mesh's frame" if config.given_properties_frame == MESH_FRAME else "the asset frame"

    def shown(v: np.ndarray) -> str:
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"

    raise UserInputError(
        f"--properties {config.given_properties_source or '(given properties)'}: the centre of mass "
        f"{shown(com)} m ({frame}) lies outside {label}, whose bounds {shown(lo)} .. {shown(hi)} m grown by "
        f"{100 * COM_MARGIN_FRACTION:g} % of its largest extent ({margin:.3g} m) must hold it: a file in another "
        "frame or unit?")


def support_below_mesh(bottom_m: float, top_m: float, support_m: float) -> bool:
    """Whether a support plane at height ``support_m`` lies below a mesh spanning ``bottom_m`` ..
    ``top_m`` (same frame, +z up) by more than :data:`SUPPORT_BELOW_TOLERANCE` of its height: there
    is nothing to crop there and no bottom to close."""
    return support_m < bottom_m - SUPPORT_BELOW_TOLERANCE * (top_m - bottom_m)


def check_mesh_for_config(mesh: trimesh.Trimesh, config: AssetConfig, label: str = "mesh") -> None:
    """Refuse, before any work, a mesh this configuration cannot turn into a usable asset.

    UserInputError (one line): an object smaller than :data:`~real2sim.geometry.mesh_io.MIN_EXTENT_M`
    or larger than :data:`~real2sim.geometry.mesh_io.MAX_EXTENT_M` after ``mesh_units`` (the message
    names the units that fit); an object more than
    :data:`MAX_EXTENT_PER_RESOLUTION_HINT` resolution hints across when its shapes are
    hydroelastic (Drake would mesh them with millions of elements); with ``flat_bottom``, a
    support plane that is not finite, that leaves nothing of the mesh above it, or that lies
    below the mesh by more than :data:`SUPPORT_BELOW_TOLERANCE` of its height (nothing to crop,
    no bottom to close there).
    """
    vertices = np.asarray(mesh.vertices, dtype=float)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    extent = check_object_size(mesh, label, config.mesh_units)
    hint = config.contact.resolution_hint_m
    if config.contact.hydroelastic != "none" and extent > MAX_EXTENT_PER_RESOLUTION_HINT * hint:
        raise UserInputError(f"{label} is {extent:.4g} m across, over {MAX_EXTENT_PER_RESOLUTION_HINT:g} x "
                             f"--resolution-hint-m {hint:g} m = {MAX_EXTENT_PER_RESOLUTION_HINT * hint:.4g} m: Drake would "
                             f"mesh its shapes with millions of elements; use --resolution-hint-m "
                             f">= {extent / MAX_EXTENT_PER_RESOLUTION_HINT:.3g}")
    if config.fill_cavities_m is not None:
        from real2sim.geometry.envelope import check_fill_radius

        check_fill_radius(config.fill_cavities_m, extent, label)
    if config.flat_bottom:
        height = config.support_height_m
        bottom, top = float(lo[2]), float(hi[2])
        if not np.isfinite(height):
            raise UserInputError(f"--support-height-m must be a finite number of metres, got {height}")
        if height >= top:
            raise UserInputError(f"--support-height-m {height:g} m leaves nothing of {label} above it "
                                 f"(the mesh spans z = {bottom:.4g} .. {top:.4g} m)")
        if support_below_mesh(bottom, top, height):
            raise UserInputError(f"--support-height-m {height:g} m lies {bottom - height:.4g} m below {label} "
                                 f"(the mesh spans z = {bottom:.4g} .. {top:.4g} m): nothing to crop and no bottom to "
                                 "close there; give the table's height in the mesh frame")
