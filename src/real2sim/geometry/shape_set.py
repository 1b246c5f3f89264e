"""The shape set: objects from convex to very non-convex that are not bottles or cans, made by code.

Each builder takes the sagitta its round parts keep to (m, per curved direction, as the bundled
objects: :mod:`real2sim.geometry.objects`) and returns the watertight mesh, in metres, resting on
z = 0 in the stable pose nearest the one it was drawn in (:func:`rest`), centred on the z axis, and
the true surfaces of its round parts (:class:`~real2sim.geometry.round_surfaces.Revolved`). The
same rules build every shape: nothing is tuned per shape.
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.transformations import rotation_matrix

from real2sim.geometry.round_surfaces import PROFILE_SAGITTA_FACTOR, Revolved, arc, dense_curve, revolve, ring_sections, simplify_profile

Z = (0.0, 0.0, 1.0)


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(meshes, engine="manifold")


def _solid(profile: np.ndarray, sagitta_m: float, curved_profile: bool) -> trimesh.Trimesh:
    """A profile revolved about z, its rings and (when curved) its profile to ``sagitta_m``."""
    points = simplify_profile(profile, PROFILE_SAGITTA_FACTOR * sagitta_m) if curved_profile else profile
    return revolve(points, ring_sections(float(np.max(profile[:, 0])), sagitta_m))


def _cylinder(radius_m: float, z0_m: float, z1_m: float, sagitta_m: float) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A cylinder about z between heights z0 and z1 (mesh, dense true profile)."""
    corners = np.array([[0.0, z0_m], [radius_m, z0_m], [radius_m, z1_m], [0.0, z1_m]])
    return revolve(corners, ring_sections(radius_m, sagitta_m)), dense_curve(corners)


def _moved(surface: Revolved, matrix: np.ndarray) -> Revolved:
    """``surface`` after the rigid transform ``matrix`` (4, 4)."""
    assert surface.stretch == (1.0, 1.0, 1.0), "a stretched surface cannot be moved rigidly"
    origin = matrix[:3, :3] @ np.asarray(surface.axis_origin_m) + matrix[:3, 3]
    direction = matrix[:3, :3] @ np.asarray(surface.axis_direction)
    return Revolved(tuple(map(float, origin)), tuple(map(float, direction)), surface.profile_m)


def rest(mesh: trimesh.Trimesh, surfaces: tuple[Revolved, ...]) -> tuple[trimesh.Trimesh, tuple[Revolved, ...]]:
    """``mesh`` tilted onto the face of its convex hull that it is statically stable on (its
    centre of mass projects inside it) and that faces down the most as drawn; then put on z = 0
    and centred on the z axis. ``surfaces`` follow it."""
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)  # merging would close manifold3d's 1e-8 slivers
    hull = mesh.convex_hull
    com = mesh.center_mass
    normals, tri = hull.face_normals, hull.triangles  # (F, 3), (F, 3, 3)
    # Each hull triangle on its own (trimesh's facets merge a cylinder's nearly coplanar strips).
    foot = com - np.einsum("ij,ij->i", com - tri[:, 0], normals)[:, None] * normals
    stable = (trimesh.triangles.points_to_barycentric(tri, foot) >= -1e-9).all(axis=1)
    best = normals[np.flatnonzero(stable)[np.argmin(normals[stable, 2])]]
    # Already down (to 5e-8 rad): no turn, so vertices a boolean left 1e-8 apart stay apart.
    matrix = np.eye(4) if best[2] < -1 + 1e-15 else trimesh.geometry.align_vectors(best, [0.0, 0.0, -1.0])
    moved = mesh.copy()
    moved.apply_transform(matrix)
    shift = np.eye(4)
    shift[:3, 3] = [-moved.bounds[:, 0].mean(), -moved.bounds[:, 1].mean(), -moved.bounds[0, 2]]
    moved.apply_transform(shift)
    full = shift @ matrix
    return moved, tuple(_moved(s, full) for s in surfaces)


def mug_side(mug: tuple[trimesh.Trimesh, tuple[Revolved, ...]]):
    """The bundled mug (given as built) laid on its side, handle sideways; it settles onto its handle."""
    mesh, surfaces = mug
    turn = rotation_matrix(np.pi / 2, [1, 0, 0])
    mesh = mesh.copy()
    mesh.apply_transform(turn)
    return rest(mesh, tuple(_moved(s, turn) for s in surfaces))


def bowl(sagitta_m: float):
    """A bowl 16 cm across and 7 cm tall: a spherical shell, 6-7 mm walls, on a flat foot."""
    r_out, r_in, lift, base = 0.080, 0.074, 0.010, -0.070
    foot = float(np.sqrt(r_out ** 2 - base ** 2))
    rim_in = float(np.sqrt(r_in ** 2 - lift ** 2))
    profile = np.concatenate([
        dense_curve(np.array([[0.0, base], [foot, base]])),
        arc((0.0, 0.0), r_out, float(np.arctan2(base, foot)), 0.0)[1:],
        dense_curve(np.array([[r_out, 0.0], [rim_in, 0.0]]))[1:],
        arc((0.0, lift), r_in, float(np.arctan2(-lift, rim_in)), -np.pi / 2)[1:],
    ])
    return rest(_solid(profile, sagitta_m, True), (Revolved((0.0, 0.0, 0.0), Z, profile),))


def l_bracket(sagitta_m: float):
    """An aluminium L-bracket: a 12 x 5 cm flange, 1 cm thick, and a 10 cm upright at one end (no round part)."""
    flange = trimesh.creation.box((0.12, 0.05, 0.01))
    flange.apply_translation([0.0, 0.0, 0.005])
    upright = trimesh.creation.box((0.01, 0.05, 0.10))
    upright.apply_translation([0.055, 0.0, 0.05])
    return rest(_union([flange, upright]), ())


def hammer(sagitta_m: float):
    """A hammer lying on the table: a 22 cm handle, 13 mm in radius, and an 11 cm head (3 x 3 cm)."""
    handle, profile = _cylinder(0.013, -0.11, 0.11, sagitta_m)
    turn = rotation_matrix(np.pi / 2, [0, 1, 0])  # handle along x
    handle.apply_transform(turn)
    head = trimesh.creation.box((0.03, 0.11, 0.03))
    head.apply_translation([0.11, 0.0, 0.0])
    return rest(_union([handle, head]), (_moved(Revolved((0.0, 0.0, 0.0), Z, profile), turn),))


def torus(sagitta_m: float):
    """A rubber ring lying flat: 13 cm across, a 15 mm tube about a 5 cm circle."""
    tube = arc((0.050, 0.0), 0.015, 0.0, 2 * np.pi)
    return rest(_solid(tube, sagitta_m, True), (Revolved((0.0, 0.0, 0.0), Z, tube),))


def banana(sagitta_m: float):
    """A curved banana-like solid lying flat: a 100-degree arc of a 17 mm tube about a 9 cm circle,
    its cut ends capped by spheres 0.8 times as wide (narrower tips; no tangent surfaces to union)."""
    r_arc, r_tube, half = 0.090, 0.017, np.deg2rad(50.0)
    tube = arc((r_arc, 0.0), r_tube, 0.0, 2 * np.pi)
    ring = _solid(tube, sagitta_m, True)
    reach = 2 * (r_arc + r_tube)
    corners = [[0.0, 0.0]] + [[reach * np.cos(a), reach * np.sin(a)] for a in np.linspace(-half, half, 5)]
    wedge = trimesh.convex.convex_hull([[x, y, z] for x, y in corners for z in (-0.05, 0.05)])
    parts = [trimesh.boolean.intersection([ring, wedge], engine="manifold")]
    sphere_profile = arc((0.0, 0.0), 0.8 * r_tube, -np.pi / 2, np.pi / 2)
    surfaces = [Revolved((0.0, 0.0, 0.0), Z, tube)]
    for a in (-half, half):
        end = (r_arc * np.cos(a), r_arc * np.sin(a), 0.0)
        cap = _solid(sphere_profile, sagitta_m, True)
        cap.apply_translation(end)
        parts.append(cap)
        surfaces.append(Revolved(tuple(map(float, end)), Z, sphere_profile))
    return rest(_union(parts), tuple(surfaces))


def gear(sagitta_m: float):
    """A nylon spur gear lying flat: 12 straight-flanked teeth from 4 to 5 cm radius, 2 cm thick (no round part)."""
    teeth, r_root, r_tip, thick = 12, 0.040, 0.050, 0.020
    step = 2 * np.pi / teeth
    angles, radii = [], []
    for k in range(teeth):  # root, flank up, tip, flank down: the tip narrower than the root gap
        a = k * step
        angles += [a, a + 0.30 * step, a + 0.45 * step, a + 0.75 * step]
        radii += [r_root, r_tip, r_tip, r_root]
    ring = np.column_stack([np.cos(angles) * radii, np.sin(angles) * radii])
    n = len(ring)
    vertices = np.vstack([np.column_stack([ring, np.zeros(n)]), np.column_stack([ring, np.full(n, thick)]),
                          [[0.0, 0.0, 0.0], [0.0, 0.0, thick]]])
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.vstack([np.column_stack([np.full(n, 2 * n), j, i]),  # bottom fan, facing down
                       np.column_stack([np.full(n, 2 * n + 1), n + i, n + j]),  # top fan
                       np.column_stack([i, j, n + j]), np.column_stack([i, n + j, n + i])])
    return rest(trimesh.Trimesh(vertices, faces, process=True), ())


def stool(sagitta_m: float):
    """A small three-legged stool: a 16 cm seat, 15 mm thick, on 8 mm legs 12 cm long."""
    seat, seat_profile = _cylinder(0.080, 0.120, 0.135, sagitta_m)
    parts, surfaces = [seat], [Revolved((0.0, 0.0, 0.0), Z, seat_profile)]
    for a in (0.0, 2 * np.pi / 3, 4 * np.pi / 3):
        leg, leg_profile = _cylinder(0.008, 0.0, 0.121, sagitta_m)  # 1 mm into the seat: one solid
        at = (0.060 * np.cos(a), 0.060 * np.sin(a), 0.0)
        leg.apply_translation(at)
        parts.append(leg)
        surfaces.append(Revolved(tuple(map(float, at)), Z, leg_profile))
    return rest(_union(parts), tuple(surfaces))
