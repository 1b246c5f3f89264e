"""Bundled objects, made by code: no downloads, the same bytes on every machine.

Each object is a closed, textured triangle mesh in metres, standing on z = 0 in
the frame a capture rig would see it in (it is *not* canonicalised: that is a
stage of its own). They stand in for the paper's YCB mustard bottle and tomato
soup can, plus the shape set (:mod:`real2sim.geometry.shape_set`: a mug upright and
on its side, a bowl, an L-bracket, a hammer, a torus, a banana, a gear, a stool),
convex to very non-convex. Round parts are cut into flats at most
:data:`REFERENCE_SAGITTA_M` deep around their axis and ten times that along a curved profile, so
each object's chord error (:attr:`BundledObject.chord_m`) is 0 (boxes, prisms), 2.5 um (cylinders:
the can, the stool, the hammer) or 27.5 um (curved both ways: the bottle, mug, bowl, torus, banana).
The bottle, can and mug are bundled as 0.1.0 made them (:mod:`real2sim.geometry.objects_010`);
their round versions are ``make_object(name, rolling_sagitta_m=REFERENCE_SAGITTA_M)``.

* :func:`make_object` -- the watertight geometry (vertices merged), for
  geometry stages and tests.
* :func:`make_textured_object` -- the same surface with a cylindrical UV map and
  a procedural texture (vertices split along the UV seam, as any textured OBJ).
* :func:`export_object` -- writes the textured mesh as OBJ + MTL + PNG with normals.
* :func:`listing` -- one line per object, for ``real2sim objects``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from PIL import Image

from real2sim.plumbing.errors import UserInputError
from real2sim.geometry import shape_set
from real2sim.geometry.mesh_io import export_textured_mesh
from real2sim.geometry.objects_010 import MESHES_010
from real2sim.geometry.round_surfaces import DENSE_PER_M, PROFILE_SAGITTA_FACTOR, Revolved, arc, dense_curve, revolve, ring_sections, simplify_profile

_TEXTURE_PX = 512
# Cylindrical UVs wrap once around; faces crossing the seam get u + 1, so the
# texture spans u in [0, _U_SPAN] and is drawn periodic in angle over that span.
_U_SPAN = 1.25

REFERENCE_SAGITTA_M = 2.5e-6
"""How far, at most, a flat of a bundled object's mesh lies from the true round surface it stands
for around an axis of revolution, m (along a curved profile
:data:`~real2sim.geometry.round_surfaces.PROFILE_SAGITTA_FACTOR` times this). A rolling body rolls
across these flats and the ramp sees them: 2.5 um is 10x below the gaps between the best rows of
Table I (why: docs/design-notes/asset.md#bundled-objects-tessellation)."""

# Flats of a can or bottle body round enough for a body that rolls on its side, for the
# benchmarks that compare tessellations (bench_tessellation, bench_run --round-can).
ROUND_SAGITTA_M = REFERENCE_SAGITTA_M

Built = tuple[trimesh.Trimesh, tuple[Revolved, ...]]
"""A builder's result: the mesh (metres, on z = 0) and the true surfaces of its round parts."""


@dataclass(frozen=True)
class BundledObject:
    """A bundled object: its name, a suggested mass, how it looks and how round its mesh is."""

    name: str
    """Name the CLI and the benchmarks know it by."""
    mass_kg: float
    """Suggested mass, kg."""
    description: str
    """One line of what it is, for listings."""
    build: Callable[[float], Built]
    """Its mesh (metres, resting on z = 0) and true round surfaces, given the chord error in metres."""
    body_rgb: tuple[int, int, int]
    """Colour of the body, 0-255 per channel."""
    accent_rgb: tuple[int, int, int]
    """Colour of the cap or rim, 0-255 per channel."""
    accent_above_m: float
    """Height (z, metres) above which :attr:`accent_rgb` is used."""
    shape_set: bool = False
    """True: one of the shape set (convex to very non-convex, not bottles or cans; issue #66)."""
    rests_on: str = "base"
    """"base": stands on a flat face or rim as built; "side": lies on curved or slanted faces."""
    curved_directions: int = 2
    """Directions in which its round parts curve: 0 (boxes, prisms: the mesh is the object), 1 (cylinders,
    cones: around their axis only), 2 (a torus, a bulge: around and along); their chord errors add."""

    @property
    def chord_m(self) -> float:
        """Stated chord error of its round mesh (:func:`object_surfaces`): the farthest a flat lies from the
        true surface, m
        (around the axis :data:`REFERENCE_SAGITTA_M`, along a curved profile
        :data:`~real2sim.geometry.round_surfaces.PROFILE_SAGITTA_FACTOR` times it)."""
        around = REFERENCE_SAGITTA_M if self.curved_directions >= 1 else 0.0
        return around + (PROFILE_SAGITTA_FACTOR * REFERENCE_SAGITTA_M if self.curved_directions >= 2 else 0.0)


def _rings(radius_m: float, sagitta_m: float) -> int:
    return ring_sections(radius_m, sagitta_m)


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(meshes, engine="manifold")


def _bottle_radius_m(z_m: np.ndarray) -> np.ndarray:
    # A squeeze bottle like the YCB mustard bottle: bulging low, tapering to a shoulder.
    return 0.045 + 0.004 * np.sin(np.pi * z_m / 0.11) - 0.2 * np.clip(z_m - 0.09, 0, None) ** 1.1


def _bottle(sagitta_m: float) -> Built:
    # An oval body 0.096 x 0.060 m with a 4 mm fillet at its flat bottom, a shoulder, an
    # off-centre cap and nozzle; 0.19 m tall.
    z = np.linspace(0.004, 0.160, 1 + int(0.156 * DENSE_PER_M))
    body = np.column_stack([_bottle_radius_m(z), z])
    fillet_r = float(_bottle_radius_m(np.array([0.004]))[0]) - 0.004
    profile = np.concatenate([
        dense_curve(np.array([[0.0, 0.0], [fillet_r, 0.0]])),
        arc((fillet_r, 0.004), 0.004, -np.pi / 2, 0.0)[1:],
        body[1:],
        dense_curve(np.array([body[-1], [0.016, 0.163], [0.0, 0.163]]))[1:],
    ])
    shell = revolve(simplify_profile(profile, PROFILE_SAGITTA_FACTOR * sagitta_m), _rings(float(profile[:, 0].max()), sagitta_m))
    stretch = (1.0, 0.64, 1.0)
    shell.apply_scale(stretch)
    cap = dense_curve(np.array([[0.0, 0.160], [0.0135, 0.160], [0.0135, 0.182], [0.0, 0.182]]))
    nozzle = dense_curve(np.array([[0.0, 0.182], [0.007, 0.182], [0.0, 0.190]]))
    parts = [shell]
    for p in (cap, nozzle):
        part = revolve(simplify_profile(p, PROFILE_SAGITTA_FACTOR * sagitta_m), _rings(float(p[:, 0].max()), sagitta_m))
        part.apply_translation([0.008, 0.0, 0.0])
        parts.append(part)
    surfaces = (Revolved((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), profile, stretch),
                Revolved((0.008, 0.0, 0.0), (0.0, 0.0, 1.0), cap),
                Revolved((0.008, 0.0, 0.0), (0.0, 0.0, 1.0), nozzle))
    return _union(parts), surfaces


def _can(sagitta_m: float) -> Built:
    # A soup can: radius 0.034 m, height 0.10 m, with rims 1 mm proud at both ends (a straight profile).
    profile = np.array([[0.0, 0.0], [0.0335, 0.0], [0.034, 0.002], [0.034, 0.098], [0.0335, 0.100], [0.0, 0.100]])
    return revolve(profile, _rings(0.034, sagitta_m)), (Revolved((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), dense_curve(profile)),)


def _mug(sagitta_m: float) -> Built:
    # A mug: outer radius 0.04 m, height 0.095 m, 3 mm wall, 6 mm floor, a ring handle.
    outer = np.array([[0.0, 0.0], [0.040, 0.0], [0.040, 0.095], [0.0, 0.095]])
    cavity = np.array([[0.0, 0.006], [0.037, 0.006], [0.037, 0.101], [0.0, 0.101]])
    cup = trimesh.boolean.difference([revolve(outer, _rings(0.040, sagitta_m)), revolve(cavity, _rings(0.037, sagitta_m))],
                                     engine="manifold")
    tube = arc((0.026, 0.0), 0.006, 0.0, 2 * np.pi)
    handle = revolve(simplify_profile(tube, PROFILE_SAGITTA_FACTOR * sagitta_m), _rings(0.032, sagitta_m))  
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.048, 0.0, 0.050])
    # Cut the part of the ring that would poke into the cavity.
    keep = trimesh.creation.box(extents=[0.06, 0.03, 0.08])
    keep.apply_translation([0.068, 0.0, 0.050])
    handle = trimesh.boolean.intersection([handle, keep], engine="manifold")
    surfaces = (Revolved((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), dense_curve(outer)),
                Revolved((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), dense_curve(cavity)),
                Revolved((0.048, 0.0, 0.050), (0.0, -1.0, 0.0), tube))
    return _union([cup, handle]), surfaces


OBJECTS: dict[str, BundledObject] = {
    o.name: o
    for o in (
        BundledObject("bottle", 0.60, "squeeze bottle like the YCB mustard bottle, 0.19 m tall, oval, off-centre cap",
                      _bottle, (222, 178, 32), (200, 30, 30), 0.161),
        BundledObject("can", 0.35, "soup can like the YCB tomato soup can, r 0.034 m, h 0.10 m",
                      _can, (190, 30, 35), (200, 200, 205), 0.097, curved_directions=1),
        BundledObject("mug", 0.30, "mug with a handle (non-convex: cavity and ring), r 0.04 m, h 0.095 m",
                      _mug, (40, 90, 170), (235, 235, 235), 0.088, shape_set=True),
        BundledObject("mug_side", 0.30, "the mug on its side, resting on its rim and handle",
                      lambda s: shape_set.mug_side(_mug(s)), (40, 90, 170), (235, 235, 235), 0.075,
                      shape_set=True, rests_on="side"),
        BundledObject("bowl", 0.35, "ceramic bowl, 0.16 m across, 0.07 m tall, 6 mm walls, flat foot",
                      shape_set.bowl, (225, 220, 205), (150, 60, 40), 0.066, shape_set=True),
        BundledObject("l_bracket", 0.28, "aluminium L-bracket, 12 x 5 cm flange and 10 cm upright, 1 cm thick",
                      shape_set.l_bracket, (170, 175, 185), (60, 65, 75), 0.095, shape_set=True,
                      curved_directions=0),
        BundledObject("hammer", 0.50, "hammer lying down: 0.22 m round handle, 11 cm square head",
                      shape_set.hammer, (150, 100, 55), (70, 70, 80), 0.028, shape_set=True, rests_on="side",
                      curved_directions=1),
        BundledObject("torus", 0.24, "rubber ring lying flat, 0.13 m across, 15 mm tube",
                      shape_set.torus, (30, 30, 35), (200, 120, 30), 0.025, shape_set=True, rests_on="side"),
        BundledObject("banana", 0.18, "banana-like curved solid lying flat: a 100-degree arc of a 17 mm tube",
                      shape_set.banana, (235, 200, 40), (90, 70, 20), 0.030, shape_set=True, rests_on="side"),
        BundledObject("gear", 0.17, "nylon spur gear lying flat, 12 teeth, 0.10 m across, 2 cm thick",
                      shape_set.gear, (240, 240, 235), (40, 120, 60), 0.017, shape_set=True, curved_directions=0),
        BundledObject("stool", 0.30, "small three-legged stool, 0.16 m seat on 0.12 m legs",
                      shape_set.stool, (160, 110, 60), (110, 70, 35), 0.125, shape_set=True, curved_directions=1),
    )
}


def _lookup(name: str) -> BundledObject:
    if name not in OBJECTS:
        raise UserInputError(f"unknown bundled object {name!r}; known: {', '.join(OBJECTS)}")
    return OBJECTS[name]


def object_surfaces(name: str, sagitta_m: float | None = None) -> Built:
    """A bundled object's watertight mesh (metres, resting on z = 0, no texture) and the true
    surfaces of its round parts (:class:`~real2sim.geometry.round_surfaces.Revolved`, object frame).

    ``sagitta_m``: how far its flats may lie from the true surface per curved direction, m;
    None: :data:`REFERENCE_SAGITTA_M`, as bundled (chord error :attr:`BundledObject.chord_m`)."""
    mesh, surfaces = _lookup(name).build(REFERENCE_SAGITTA_M if sagitta_m is None else float(sagitta_m))
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    if not mesh.is_watertight:  # a builder's parts meet at repeated vertices; a closed one keeps its 1e-8 slivers
        mesh.merge_vertices()
    mesh.fix_normals()
    assert mesh.is_watertight, f"bundled object {name} is not watertight"
    return mesh, surfaces


def make_object(name: str, rolling_sagitta_m: float | None = None) -> trimesh.Trimesh:
    """Watertight geometry of a bundled object, metres, resting on z = 0, no texture.

    ``rolling_sagitta_m``: None for the bundled object as 0.1.0 made it where it has such a mesh (the
    bottle, can and mug: :mod:`real2sim.geometry.objects_010`), else its round mesh; a value cuts every
    round part to that sagitta around its axis (and :data:`~real2sim.geometry.round_surfaces.PROFILE_SAGITTA_FACTOR`
    times it along a curved profile), m: :data:`REFERENCE_SAGITTA_M` gives the round reference whose chord
    error :attr:`BundledObject.chord_m` states (why: docs/design-notes/asset.md#bundled-objects-tessellation)."""
    if rolling_sagitta_m is None and name in MESHES_010:
        built = MESHES_010[name]()
        mesh = trimesh.Trimesh(built.vertices, built.faces, process=True)
        mesh.fix_normals()
        return mesh
    return object_surfaces(name, rolling_sagitta_m)[0]


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


def listing() -> list[str]:
    """One line per bundled object: name, suggested mass, chord error, shape-set mark, description."""
    lines = []
    for obj in OBJECTS.values():
        mark = "shape set, " if obj.shape_set else ""
        rest = "" if obj.rests_on == "base" else ", rests on its side"
        mesh = "0.1.0 mesh; round reference" if obj.name in MESHES_010 else "round mesh"
        lines.append(f"{obj.name:10s} mass {obj.mass_kg:.2f} kg  {mesh} chord error <= {obj.chord_m * 1e6:g} um  "
                     f"[{mark}{obj.curved_directions} curved directions{rest}]  {obj.description}")
    return lines
