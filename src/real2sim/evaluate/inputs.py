"""Up-front checks of the sweep's inputs: every asset and reference mesh is refused here,
naming the file, rather than publishing a results folder in which every row failed (or
letting Drake abort on a NaN mass, or a worker spin or swell without end).

Checked before anything is written:

- ``physical_properties.json``: readable, finite positive mass, finite CoM, a finite,
  symmetric, physically possible inertia tensor (principal moments >= 0 and the triangle
  inequality, which Drake also asserts);
- every mesh file a representation's ``model.urdf`` names exists (an unparsable URDF is
  left to the sweep: it costs that representation's rows, as before);
- the reference mesh of each asset (its own, or ``--reference`` placed in its frame):
  a readable .obj mesh whose size suits the tabletop scenes
  (:data:`OBJECT_SIZE_RANGE_M`), and around the asset's centre of mass (otherwise it has
  no resting pose: the placement's stable-pose analysis would never end).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Sequence

import numpy as np

from real2sim.evaluate.discovery import Asset, Representation, read_canonical_transform
from real2sim.plumbing.errors import UserInputError
from real2sim.formats.physical import PhysicalProperties, read_physical_properties

#: Smallest and largest bounding-box side of an object the scenes can take, m: the ramp's table
#: is 0.8 m wide and the pusher's sphere 0.05 m in radius (why an upper bound at all:
#: docs/design-notes/evaluate.md#object-size); below 5 mm the 1 ms step and the 1 mm drop
#: clearance dominate.
OBJECT_SIZE_RANGE_M = (0.005, 1.0)


def check_physical_properties(path: Path) -> PhysicalProperties:
    """Read ``physical_properties.json``; UserInputError naming the file for anything Drake
    would reject (or abort on)."""
    try:
        props = read_physical_properties(path)
        com = np.asarray(props.com_m, dtype=float)
        inertia = np.asarray(props.inertia_kg_m2, dtype=float)
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:  # JSON, shape, types
        detail = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
        raise UserInputError(f"{path} is not a readable physical_properties.json ({detail})") from None
    mass = props.mass_kg
    if not (math.isfinite(mass) and mass > 0):
        raise UserInputError(f"{path}: mass_kg must be a finite number > 0, got {mass}")
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise UserInputError(f"{path}: com_m must be 3 finite numbers (m)")
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise UserInputError(f"{path}: inertia_kg_m2 must be a 3x3 matrix of finite numbers")
    scale = float(np.abs(inertia).max())
    if scale <= 0:
        raise UserInputError(f"{path}: inertia_kg_m2 is zero")
    if not np.allclose(inertia, inertia.T, rtol=0, atol=1e-9 * scale):
        raise UserInputError(f"{path}: inertia_kg_m2 is not symmetric")
    moments = np.sort(np.linalg.eigvalsh(inertia))
    tolerance = 1e-6 * scale
    if moments[0] < -tolerance or moments[0] + moments[1] < moments[2] - tolerance:
        raise UserInputError(f"{path}: inertia_kg_m2 is not a physical inertia (principal moments "
                             f"{np.round(moments, 12).tolist()} kg m^2 must be >= 0 and obey the triangle inequality)")
    return props


def _urdf_mesh_files(urdf: Path) -> list[tuple[str, Path]]:
    """(as written, resolved path) of every mesh a URDF names; [] when it does not parse."""
    try:
        root = ET.parse(urdf).getroot()
    except (ET.ParseError, OSError):
        return []  # the sweep records the representation's rows as failed, as before
    found = []
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if not name or name.startswith("package://"):
            continue  # package paths resolve through Drake's package map, not the file system
        path = Path(name.removeprefix("file://"))
        found.append((name, path if path.is_absolute() else urdf.parent / path))
    return found


def check_representations(reps: Sequence[Representation]) -> None:
    """Every mesh file a representation's URDF names exists."""
    for rep in reps:
        for urdf in filter(None, (rep.urdf_path, rep.point_urdf_path)):
            for name, path in _urdf_mesh_files(urdf):
                if not path.is_file():
                    raise UserInputError(f"{urdf} names the mesh {name}, which is missing")


def _check_reference_vertices(vertices: np.ndarray, asset: Asset, props: PhysicalProperties, label: str) -> None:
    from real2sim.evaluate.scene.placement import com_inside_hull

    extents = vertices.max(axis=0) - vertices.min(axis=0)
    size_m = float(extents.max())
    low, high = OBJECT_SIZE_RANGE_M
    if not (low <= size_m <= high):
        raise UserInputError(f"{label} is {size_m:.4g} m across (largest bounding-box side); the evaluation's "
                             f"tabletop scenes take objects from {low:g} m to {high:g} m -- is it in metres?")
    if not com_inside_hull(vertices, props.com_m):
        raise UserInputError(
            f"the centre of mass {np.round(props.com_m, 4).tolist()} m of {asset.name} (physical_properties.json) "
            f"is not inside {label}: an open surface that does not enclose the object, or a mesh that is not "
            "in the asset's frame, has no resting pose to start from")


def check_inputs(assets: Sequence[Asset], reps: Sequence[Representation],
                 reference_mesh: Path | str | None = None, reference_properties: Path | str | None = None) -> None:
    """All the checks of the module docstring; UserInputError for the first problem found.

    ``reference_properties``: the reference's own physical_properties.json (one asset only).
    """
    from real2sim.geometry.mesh_io import load_mesh

    check_representations(reps)
    given = load_mesh(reference_mesh) if reference_mesh is not None else None  # UserInputError: not a mesh
    if reference_properties is not None and len(assets) != 1:
        raise UserInputError("reference mass properties are those of one object: evaluate one asset with them")
    for asset in assets:
        props = check_physical_properties(asset.physical_properties_path)
        if reference_properties is not None:
            props = check_physical_properties(Path(reference_properties))
        if given is not None:
            transform = read_canonical_transform(asset.asset_dir)
            vertices = np.asarray(given.vertices, dtype=float) @ transform[:3, :3].T + transform[:3, 3]
            label = f"the reference mesh {Path(reference_mesh).name} (placed in {asset.name}'s frame)"
        else:
            path = asset.reference_mesh_path
            if not path.is_file():
                raise UserInputError(f"{asset.asset_dir} has no visual/model.obj to use as the reference")
            vertices = np.asarray(load_mesh(path).vertices, dtype=float)
            label = f"the reference mesh {path.relative_to(asset.asset_dir.parent)}"
        _check_reference_vertices(vertices, asset, props, label)
