"""Bundled objects, made by code: no downloads, the same bytes on every machine.

Each object is a closed, textured triangle mesh in metres, standing on z = 0 in
the frame a capture rig would see it in (it is *not* canonicalised: that is a
stage of its own). They stand in for the paper's YCB mustard bottle and tomato
soup can, plus a mug whose cavity and handle make it clearly non-convex.

* :func:`make_object` -- the watertight geometry (vertices merged), for
  geometry stages and tests.
* :func:`make_textured_object` -- the same surface with a cylindrical UV map and
  a procedural texture (vertices split along the UV seam, as any textured OBJ).
* :func:`export_object` -- writes the textured mesh as OBJ + MTL + PNG with normals.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from PIL import Image

from real2sim.plumbing.errors import UserInputError
from real2sim.geometry.mesh_io import export_textured_mesh
from real2sim.geometry.tessellation import sections_for

_TEXTURE_PX = 512
# Cylindrical UVs wrap once around; faces crossing the seam get u + 1, so the
# texture spans u in [0, _U_SPAN] and is drawn periodic in angle over that span.
_U_SPAN = 1.25

# Flats (m inside the circle) of a can or bottle body tessellated round enough for a body that rolls
# on its side: ``make_object(..., rolling_sagitta_m=ROUND_SAGITTA_M)``. The bundled objects keep their
# own tessellation (why: docs/design-notes/asset.md#bundled-objects-tessellation).
ROUND_SAGITTA_M = 2.5e-6


@dataclass(frozen=True)
class BundledObject:
    """A bundled object: its name, a suggested mass and how it looks."""

    name: str
    """Name the CLI and the benchmarks know it by."""
    mass_kg: float
    """Suggested mass, kg."""
    description: str
    """One line of what it is, for listings."""
    build: Callable[[float | None], trimesh.Trimesh]
    """Its mesh (metres, standing on z = 0) given a rolling sagitta in metres, or None: as bundled."""
    body_rgb: tuple[int, int, int]
    """Colour of the body, 0-255 per channel."""
    accent_rgb: tuple[int, int, int]
    """Colour of the cap or rim, 0-255 per channel."""
    accent_above_m: float
    """Height (z, metres) above which :attr:`accent_rgb` is used."""


def _revolve(radius_m: np.ndarray, z_m: np.ndarray, sections: int) -> trimesh.Trimesh:
    """Solid of revolution about z of a profile that starts and ends on the axis."""
    profile = np.column_stack([radius_m, z_m])
    return trimesh.creation.revolve(profile, sections=sections)


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(meshes, engine="manifold")


def _bottle(sagitta_m: float | None) -> trimesh.Trimesh:
    # A squeeze bottle like the YCB mustard bottle: an oval body 0.096 x 0.060 m,
    # bulging low, tapering to a shoulder, with an off-centre cap; 0.19 m tall.
    z_body = np.linspace(0.0, 0.160, 40)
    r_body = 0.045 + 0.004 * np.sin(np.pi * z_body / 0.11) - 0.2 * np.clip(z_body - 0.09, 0, None) ** 1.1
    r_body = np.clip(r_body, 0.017, None)
    # Rounded bottom edge: a 4 mm fillet so the support face is flat but not sharp.
    fillet = np.linspace(0.0, np.pi / 2, 6)[1:]
    r_fillet = r_body[0] - 0.004 + 0.004 * np.sin(fillet)
    z_fillet = 0.004 - 0.004 * np.cos(fillet)
    radius = np.concatenate([[0.0], r_fillet, r_body[z_body > 0.004], [0.016, 0.0]])
    height = np.concatenate([[0.0], z_fillet, z_body[z_body > 0.004], [0.163, 0.163]])
    sections = 64 if sagitta_m is None else sections_for(float(radius.max()), sagitta_m)
    body = _revolve(radius, height, sections=sections)
    body.apply_scale([1.0, 0.64, 1.0])
    cap = trimesh.creation.cylinder(radius=0.0135, height=0.022, sections=32)
    cap.apply_translation([0.008, 0.0, 0.171])
    nozzle = trimesh.creation.cone(radius=0.007, height=0.008, sections=24)
    nozzle.apply_translation([0.008, 0.0, 0.182])
    mesh = _union([body, cap, nozzle])
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    return mesh


def _can(sagitta_m: float | None) -> trimesh.Trimesh:
    # A soup can: radius 0.034 m, height 0.10 m, with rims 1 mm proud at both ends.
    radius = np.array([0.0, 0.0335, 0.034, 0.034, 0.0335, 0.0])
    height = np.array([0.0, 0.0, 0.002, 0.098, 0.100, 0.100])
    return _revolve(radius, height, sections=72 if sagitta_m is None else sections_for(float(radius.max()), sagitta_m))


def _mug(sagitta_m: float | None) -> trimesh.Trimesh:
    # A mug: outer radius 0.04 m, height 0.095 m, 3 mm wall, 6 mm floor, a ring handle.
    # The handle keeps it from rolling, so ``sagitta_m`` is not used.
    outer = trimesh.creation.cylinder(radius=0.040, height=0.095, sections=64)
    outer.apply_translation([0, 0, 0.0475])
    cavity = trimesh.creation.cylinder(radius=0.037, height=0.095, sections=64)
    cavity.apply_translation([0, 0, 0.0475 + 0.006])
    cup = trimesh.boolean.difference([outer, cavity], engine="manifold")
    handle = trimesh.creation.torus(major_radius=0.026, minor_radius=0.006, major_sections=48, minor_sections=16)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.048, 0.0, 0.050])
    # Cut the part of the ring that would poke into the cavity.
    keep = trimesh.creation.box(extents=[0.06, 0.03, 0.08])
    keep.apply_translation([0.068, 0.0, 0.050])
    handle = trimesh.boolean.intersection([handle, keep], engine="manifold")
    return _union([cup, handle])


OBJECTS: dict[str, BundledObject] = {
    o.name: o
    for o in (
        BundledObject("bottle", 0.60, "squeeze bottle like the YCB mustard bottle, 0.19 m tall, oval, off-centre cap",
                      _bottle, (222, 178, 32), (200, 30, 30), 0.161),
        BundledObject("can", 0.35, "soup can like the YCB tomato soup can, r 0.034 m, h 0.10 m",
                      _can, (190, 30, 35), (200, 200, 205), 0.097),
        BundledObject("mug", 0.30, "mug with a handle (non-convex: cavity and ring), r 0.04 m, h 0.095 m",
                      _mug, (40, 90, 170), (235, 235, 235), 0.088),
    )
}


def _lookup(name: str) -> BundledObject:
    if name not in OBJECTS:
        raise UserInputError(f"unknown bundled object {name!r}; known: {', '.join(OBJECTS)}")
    return OBJECTS[name]


def make_object(name: str, rolling_sagitta_m: float | None = None) -> trimesh.Trimesh:
    """Watertight geometry of a bundled object, metres, standing on z = 0, no texture.

    ``rolling_sagitta_m``: None for the bundled object; a value tessellates the bottle's body
    or the can so that their flats lie at most that far inside the round surface they stand
    for (why: docs/design-notes/asset.md#bundled-objects-tessellation). The mug's handle
    keeps it from rolling; it is not changed."""
    mesh = _lookup(name).build(rolling_sagitta_m)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    mesh.fix_normals()
    assert mesh.is_watertight, f"bundled object {name} is not watertight"
    return mesh


def _texture(obj: BundledObject, height_m: float, seed: int) -> Image.Image:
    """Procedural texture over (angle, height): body colour, a printed label band
    with text-like marks (features for structure from motion), and an accent top."""
    rng = np.random.default_rng(seed)
    px = _TEXTURE_PX
    u = (np.arange(px) + 0.5) / px * _U_SPAN  # turns around the axis
    v = 1.0 - (np.arange(px) + 0.5) / px
    theta = 2 * np.pi * u[None, :]
    z = v[:, None] * height_m
    img = np.empty((px, px, 3), dtype=np.float32)
    img[:] = np.array(obj.body_rgb, dtype=np.float32)
    # Label band: a light panel with marks made of random angular harmonics, so the
    # pattern is periodic in angle and continuous across the UV seam.
    lo, hi = 0.25 * height_m, 0.65 * height_m
    band = (z > lo) & (z < hi)
    field = np.zeros((px, px), dtype=np.float32)
    for _ in range(24):
        k = rng.integers(3, 40)
        m = rng.uniform(40, 400)
        field += np.sin(k * theta + rng.uniform(0, 2 * np.pi)) * np.sin(m * z + rng.uniform(0, 2 * np.pi))
    marks = band & (field > 2.2)
    panel = band & ~marks
    img[np.broadcast_to(panel, field.shape)] = (245, 240, 225)
    img[np.broadcast_to(marks, field.shape)] = (30, 30, 40)
    img[np.broadcast_to(z > obj.accent_above_m, field.shape)] = obj.accent_rgb
    shade = 1.0 + 0.06 * np.sin(3 * theta) * np.ones_like(z)  # faint gradient: features off the label too
    img = np.clip(img * shade[..., None], 0, 255)
    return Image.fromarray(img.astype(np.uint8))


def make_textured_object(name: str, seed: int = 0, rolling_sagitta_m: float | None = None) -> trimesh.Trimesh:
    """The bundled object with a cylindrical UV map and procedural texture (``rolling_sagitta_m``:
    as in :func:`make_object`).

    Vertices are split where the UV map has a seam (as any textured mesh), so use
    :func:`make_object` where a merged, watertight vertex set matters.
    """
    obj = _lookup(name)
    solid = make_object(name, rolling_sagitta_m)
    normals = solid.vertex_normals.copy()
    corners = solid.vertices[solid.faces]  # (F, 3, 3)
    u = (np.arctan2(corners[..., 1], corners[..., 0]) / (2 * np.pi)) % 1.0
    # Faces that straddle the seam get their small u's shifted by one turn.
    wrap = (u.max(axis=1) - u.min(axis=1)) > 0.5
    u = np.where(wrap[:, None] & (u < 0.5), u + 1.0, u)
    height = float(solid.bounds[1, 2])
    v = corners[..., 2] / height
    uv_corner = np.stack([u / _U_SPAN, v], axis=-1).reshape(-1, 2)
    # One vertex per distinct (position, uv) pair.
    key = np.column_stack([solid.faces.reshape(-1), np.round(uv_corner * 1e6).astype(np.int64)])
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    vertex_index = solid.faces.reshape(-1)[first]
    mesh = trimesh.Trimesh(
        vertices=solid.vertices[vertex_index],
        faces=inverse.reshape(-1, 3),
        vertex_normals=normals[vertex_index],
        process=False,
    )
    material = trimesh.visual.material.SimpleMaterial(image=_texture(obj, height, seed), diffuse=(255, 255, 255, 255))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv_corner[first], material=material)
    return mesh


def export_object(name: str, obj_path: Path, seed: int = 0) -> Path:
    """Write bundled object ``name`` as a textured OBJ (+ MTL, PNG) at ``obj_path``."""
    return export_textured_mesh(make_textured_object(name, seed=seed), obj_path)
