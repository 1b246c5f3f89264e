"""Loading user meshes with clear errors, and writing visual meshes Drake accepts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from real2sim.plumbing.errors import UserInputError

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Metres per unit of a mesh file (``--mesh-units``): scans and CAD exports are often in mm.
MESH_UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: Largest object (bounding-box side), m: real2sim models objects a robot handles; a bigger
#: mesh is almost always in other units (millimetres read as metres).
MAX_EXTENT_M = 5.0
#: Smallest object (bounding-box side), m: below it a mesh is almost always in other units
#: (metres read as millimetres), and nothing a gripper handles is that small.
MIN_EXTENT_M = 0.005
#: Sizes (bounding-box side, m) of the tabletop objects a unit hint aims at.
TABLETOP_EXTENT_M = (0.02, 0.5)


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
        from real2sim.plumbing.paths import missing

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


def check_object_size(mesh: trimesh.Trimesh, label: str = "mesh", units: str = "m") -> float:
    """The mesh's largest bounding-box side, m (the mesh in metres, read from a file in ``units``);
    UserInputError below :data:`MIN_EXTENT_M` or above :data:`MAX_EXTENT_M`, naming the ``--mesh-units``
    that would make it a tabletop object."""
    extent = float((mesh.bounds[1] - mesh.bounds[0]).max())
    if MIN_EXTENT_M <= extent <= MAX_EXTENT_M:
        return extent
    side = "under the smallest" if extent < MIN_EXTENT_M else "over the largest"
    limit = MIN_EXTENT_M if extent < MIN_EXTENT_M else MAX_EXTENT_M
    read_as = f" read in {units}" if units != "m" else ""
    raise UserInputError(f"{label}{read_as} is {_length(extent)} across, {side} object real2sim handles "
                         f"({_length(limit)}): {_units_hint(extent, units)}")


def _length(metres: float) -> str:
    """A length in the unit a person would say it in: mm below 1 m."""
    return f"{metres * 1000:.3g} mm" if metres < 1.0 else f"{metres:.4g} m"


def _units_hint(extent_m: float, units: str) -> str:
    """Which ``--mesh-units`` makes an object ``extent_m`` across (read in ``units``) a tabletop object
    (:data:`TABLETOP_EXTENT_M`): the first in :data:`MESH_UNITS_M`'s order (metric first), else the one
    nearest that range that real2sim accepts."""
    in_file = extent_m / MESH_UNITS_M.get(units, 1.0)
    lo, hi = TABLETOP_EXTENT_M
    others = [u for u in MESH_UNITS_M if u != units]
    fits = [u for u in others if lo <= in_file * MESH_UNITS_M[u] <= hi]
    best = fits[0] if fits else min(others, key=lambda u: abs(np.log(in_file * MESH_UNITS_M[u] / np.sqrt(lo * hi))))
    size = in_file * MESH_UNITS_M[best]
    if not MIN_EXTENT_M <= size <= MAX_EXTENT_M:
        return f"no --mesh-units ({', '.join(MESH_UNITS_M)}) makes it a tabletop object; check the file's scale"
    return f"the file in {best} would make it {_length(size)} across; pass --mesh-units {best}"


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
    from real2sim.plumbing.outputs import write_bytes_atomic

    obj_path = Path(obj_path)
    obj_path.parent.mkdir(parents=True, exist_ok=True)
    files = textured_mesh_files(mesh, obj_path)
    for name in list(files)[1:] + [obj_path.name]:
        write_bytes_atomic(obj_path.parent / name, files[name])
    return obj_path
