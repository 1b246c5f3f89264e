"""Loading user meshes with clear errors, and writing visual meshes Drake accepts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.formats.errors import UserInputError

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Metres per unit of a mesh file (``--mesh-units``): scans and CAD exports are often in mm.
MESH_UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: Largest object (bounding-box side), m: real2sim models objects a robot handles; a bigger
#: mesh is almost always in other units (millimetres read as metres).
MAX_EXTENT_M = 10.0


def load_mesh(path: Path | str, units: str = "m") -> trimesh.Trimesh:
    """Load a triangle mesh (OBJ, PLY, STL, GLB, OFF), merging scenes into one mesh, and return it in
    metres: coordinates are read in ``units`` (a key of :data:`MESH_UNITS_M`) and scaled.

    Raises UserInputError for a missing file, a file that is not a mesh, or an
    empty or degenerate mesh (no faces, zero volume bounding box, non-finite vertices).
    """
    if units not in MESH_UNITS_M:
        raise UserInputError(f"unknown mesh units {units!r} (choose from {', '.join(MESH_UNITS_M)})")
    path = Path(path)
    if not path.exists():
        from real2sim.formats.paths import missing

        raise UserInputError(missing(path, "mesh file"))
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
    if units != "m":
        mesh.apply_scale(MESH_UNITS_M[units])
    validate_mesh(mesh, str(path))
    return mesh


def check_object_size(mesh: trimesh.Trimesh, label: str = "mesh") -> float:
    """The mesh's largest bounding-box side, m; UserInputError above :data:`MAX_EXTENT_M`."""
    extent = float((mesh.bounds[1] - mesh.bounds[0]).max())
    if extent > MAX_EXTENT_M:
        guess = "mm" if extent / 1000.0 <= MAX_EXTENT_M else "another unit"
        raise UserInputError(f"{label} is {extent:.4g} m across, over the {MAX_EXTENT_M:g} m limit of real2sim's "
                             f"objects: a mesh in {guess}? real2sim reads metres; pass --mesh-units mm|cm|in")
    return extent


def validate_mesh(mesh: trimesh.Trimesh, label: str = "mesh") -> None:
    """Raise UserInputError when a mesh cannot describe a solid object."""
    if len(mesh.faces) == 0 or len(mesh.vertices) < 4:
        raise UserInputError(f"{label} is empty (no faces)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserInputError(f"{label} has non-finite vertex coordinates")
    extents = mesh.bounds[1] - mesh.bounds[0]
    if np.min(extents) <= 1e-9 or float(mesh.area) <= 0:
        raise UserInputError(f"{label} is degenerate (flat or zero area; extents {extents.round(6).tolist()} m)")


def textured_mesh_files(mesh: trimesh.Trimesh, obj_path: Path | str) -> dict[str, bytes]:
    """The files of ``mesh`` as an OBJ at ``obj_path``: ``{file name: bytes}``, OBJ first.

    The MTL is ``STEM.mtl`` and every texture image ``STEM_<name>.png``: trimesh names textures
    ``material_0.png`` whatever the OBJ is called, so two meshes exported into one folder
    would otherwise overwrite each other's texture.
    """
    stem = Path(obj_path).stem
    mtl_name = f"{stem}.mtl"
    text, files = trimesh.exchange.obj.export_obj(
        mesh, include_normals=True, include_texture=True, return_texture=True, mtl_name=mtl_name
    )
    renamed = {name: name if name == mtl_name or name.startswith(f"{stem}_") else f"{stem}_{name}"
               for name in files}
    out = {Path(obj_path).name: text.encode("utf-8")}
    for name, data in files.items():
        if name == mtl_name:
            lines = data.decode("utf-8").splitlines()
            for i, line in enumerate(lines):
                key, _, value = line.partition(" ")
                if key.startswith("map_") and value.strip() in renamed:
                    lines[i] = f"{key} {renamed[value.strip()]}"
            data = ("\n".join(lines) + "\n").encode("utf-8")
        out[renamed[name]] = data
    return out


def export_textured_mesh(mesh: trimesh.Trimesh, obj_path: Path) -> Path:
    """Write a mesh as OBJ with normals (+ MTL and PNG when textured); return the OBJ path.

    Drake needs normals in a visual OBJ; file names inside are relative. Each file is
    written whole or not at all (temporary file, fsync, rename), the OBJ last, so a
    full disk never leaves a truncated mesh at ``obj_path``.
    """
    from real2sim.formats.outputs import write_bytes_atomic

    obj_path = Path(obj_path)
    obj_path.parent.mkdir(parents=True, exist_ok=True)
    files = textured_mesh_files(mesh, obj_path)
    for name in list(files)[1:] + [obj_path.name]:
        write_bytes_atomic(obj_path.parent / name, files[name])
    return obj_path
