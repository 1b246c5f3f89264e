"""Loading user meshes with clear errors, and writing visual meshes Drake accepts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.errors import UserInputError

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")


def load_mesh(path: Path | str) -> trimesh.Trimesh:
    """Load a triangle mesh (OBJ, PLY, STL, GLB, OFF) in metres, merging scenes into one mesh.

    Raises UserInputError for a missing file, a file that is not a mesh, or an
    empty or degenerate mesh (no faces, zero volume bounding box, non-finite vertices).
    """
    path = Path(path)
    if not path.exists():
        raise UserInputError(f"mesh file not found: {path}")
    if not path.is_file():
        raise UserInputError(f"not a file: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise UserInputError(f"{path} is not a mesh file (expected one of {', '.join(MESH_SUFFIXES)})")
    try:
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many kinds on garbage
        raise UserInputError(f"could not read {path} as a mesh: {type(exc).__name__}: {exc}".splitlines()[0]) from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)] if loaded.geometry else []
        if not geoms:
            raise UserInputError(f"{path} holds no triangle mesh")
        mesh = trimesh.util.concatenate(geoms) if len(geoms) > 1 else geoms[0]
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
    else:
        raise UserInputError(f"{path} holds no triangle mesh (found {type(loaded).__name__})")
    validate_mesh(mesh, str(path))
    return mesh


def validate_mesh(mesh: trimesh.Trimesh, label: str = "mesh") -> None:
    """Raise UserInputError when a mesh cannot describe a solid object."""
    if len(mesh.faces) == 0 or len(mesh.vertices) < 4:
        raise UserInputError(f"{label} is empty (no faces)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserInputError(f"{label} has non-finite vertex coordinates")
    extents = mesh.bounds[1] - mesh.bounds[0]
    if np.min(extents) <= 1e-9 or float(mesh.area) <= 0:
        raise UserInputError(f"{label} is degenerate (flat or zero area; extents {extents.round(6).tolist()} m)")


def export_textured_mesh(mesh: trimesh.Trimesh, obj_path: Path) -> Path:
    """Write a mesh as OBJ with normals (+ MTL and PNG when textured); return the OBJ path.

    Drake needs normals in a visual OBJ; file names inside are relative.
    """
    obj_path = Path(obj_path)
    obj_path.parent.mkdir(parents=True, exist_ok=True)
    stem = obj_path.stem
    text, files = trimesh.exchange.obj.export_obj(
        mesh, include_normals=True, include_texture=True, return_texture=True, mtl_name=f"{stem}.mtl"
    )
    obj_path.write_text(text)
    for fname, data in files.items():
        (obj_path.parent / fname).write_bytes(data)
    return obj_path
