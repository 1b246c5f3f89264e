"""The room behind a simulated handheld capture's table (:mod:`real2sim.capture.sim.handheld_scene`): walls,
a floor, shelves with boxes on them and a few things on the table far from the object, all textured and
all from one seed, so that the background of a photo has depth, parallax and clutter like a real one.

World frame: the table top z = 0, z up, metres; the object stands at the origin. Nothing of the room comes
nearer the origin than ``table_clutter_radius_m``, so that no view of the object is blocked.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from real2sim.capture.sim.capture_output import save_png
from real2sim.capture.sim.textures import procedural_texture

#: How far below the table top the floor lies, metres (a table's height).
FLOOR_BELOW_M = 0.75
#: Height of the walls above the floor, metres.
WALL_HEIGHT_M = 2.6
#: Things on the table stand at least this far from the object's centre, metres.
TABLE_CLUTTER_RADIUS_M = (0.55, 1.05)
#: Side of the room's textures, px (walls are seen far and small; 1024 is sharper than they are rendered).
TEXTURE_PX = 1024


@dataclass(frozen=True)
class RoomPart:
    """One piece of the room: a ``kind`` ("box", "cylinder", "sphere") of ``size_m`` (box: x, y, z sides;
    cylinder: radius, length; sphere: radius), placed by ``pose_m`` (4x4, world from the shape's centre),
    and its texture (``texture`` index into the room's textures) or plain ``colour`` (RGB 0-1)."""

    name: str
    kind: str
    size_m: tuple[float, ...]
    pose_m: np.ndarray
    texture: int | None = None
    colour: tuple[float, float, float] = (0.6, 0.6, 0.6)


def _pose(xyz: np.ndarray, yaw_rad: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    out = np.eye(4)
    out[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    out[:3, 3] = xyz
    return out


def room_parts(table_size_m: float, seed: int) -> list[RoomPart]:
    """The room around a square table of side ``table_size_m`` centred on the origin: four walls (one a
    little nearer than the others), a floor, two or three shelves along the walls with boxes on each board,
    and four to seven boxes, cans and balls on the table at 0.55-1.05 m from the object."""
    rng = np.random.default_rng((seed, 41))
    parts: list[RoomPart] = []
    half = 0.5 * table_size_m
    walls = half + rng.uniform(0.6, 1.6, 4)  # distance of each wall from the origin, +x, +y, -x, -y
    floor_z = -FLOOR_BELOW_M
    span = 2 * walls.max() + 0.2
    parts.append(RoomPart("floor", "box", (span, span, 0.02), _pose(np.array([0.0, 0.0, floor_z - 0.01])), 0))
    for k, d in enumerate(walls):
        yaw = k * np.pi / 2
        direction = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        centre = direction * (d + 0.05) + [0.0, 0.0, floor_z + WALL_HEIGHT_M / 2]
        parts.append(RoomPart(f"wall{k}", "box", (0.1, span, WALL_HEIGHT_M), _pose(centre, yaw), 1 + k % 3))
    for k in rng.choice(4, size=int(rng.integers(2, 4)), replace=False):
        parts += _shelf(rng, int(k), float(walls[k]), floor_z, len(parts))
    for k in range(int(rng.integers(4, 8))):
        radius, angle = rng.uniform(*TABLE_CLUTTER_RADIUS_M), rng.uniform(0, 2 * np.pi)
        xy = radius * np.array([np.cos(angle), np.sin(angle)])
        kind = ("box", "cylinder", "sphere")[k % 3]
        if kind == "box":
            size = tuple(rng.uniform(0.05, 0.22, 3))
            z = size[2] / 2
        elif kind == "cylinder":
            size = (rng.uniform(0.03, 0.07), rng.uniform(0.08, 0.25))
            z = size[1] / 2
        else:
            size = (rng.uniform(0.03, 0.08),)
            z = size[0]
        parts.append(RoomPart(f"table_thing{k}", kind, size, _pose(np.r_[xy, z], rng.uniform(0, np.pi)),
                              texture=ATLAS))
    return parts


def _shelf(rng: np.random.Generator, wall: int, wall_m: float, floor_z: float, count: int) -> list[RoomPart]:
    """A bookcase against wall ``wall``: a back panel, three or four boards and boxes of random sizes and
    colours on each board."""
    yaw = wall * np.pi / 2
    out, depth, width = [], 0.3, rng.uniform(0.8, 1.6)
    along = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    inward = -np.array([np.cos(yaw), np.sin(yaw), 0.0])
    offset = rng.uniform(-0.8, 0.8)
    base = -inward * wall_m + along * offset
    boards = int(rng.integers(3, 5))
    height = boards * 0.4
    out.append(RoomPart(f"shelf{wall}_back", "box", (0.02, width, height),
                        _pose(base + inward * 0.01 + [0, 0, floor_z + height / 2], yaw), ATLAS))
    for b in range(boards):
        z = floor_z + 0.05 + b * 0.4
        out.append(RoomPart(f"shelf{wall}_board{b}", "box", (depth, width, 0.025),
                            _pose(base + inward * depth / 2 + [0, 0, z], yaw), colour=(0.55, 0.4, 0.25)))
        x = -width / 2 + 0.03
        while True:
            w = rng.uniform(0.03, 0.12)
            if x + w > width / 2:
                break
            h, d = rng.uniform(0.12, 0.33), rng.uniform(0.12, depth - 0.02)
            centre = base + inward * d / 2 + along * (x + w / 2) + [0, 0, z + 0.0125 + h / 2]
            colour = tuple(float(c) for c in rng.uniform(0.1, 0.9, 3))
            out.append(RoomPart(f"shelf{wall}_box{b}_{len(out)}", "box", (d, w, h), _pose(centre, yaw),
                                texture=None if rng.random() < 0.5 else ATLAS,
                                colour=colour))
            x += w + rng.uniform(0.0, 0.04)
    return out


def room_textures(work: Path, seed: int) -> list[Path]:
    """The room's textures as PNGs in ``work``: the floor, three wall papers (softer than the table's: walls
    are plain-ish, not a feature carpet), and the atlas the shelves and things take their tiles from."""
    paths = []
    for k, (side, contrast) in enumerate(((TEXTURE_PX // 2, 0.7), (TEXTURE_PX // 2, 0.35), (TEXTURE_PX // 2, 0.4),
                                          (TEXTURE_PX // 2, 0.3), (TEXTURE_PX, 0.9))):
        path = work / f"room_texture{k}.png"
        save_png(path, procedural_texture(side, seed * 100 + 53 + k, contrast=contrast))
        paths.append(path)
    return paths


#: Index of the atlas among :func:`room_textures`; parts with a texture index at or above it take a tile of it.
ATLAS = 4


def _shape_mesh(part: RoomPart):
    import trimesh

    if part.kind == "box":
        mesh = trimesh.creation.box(extents=part.size_m)
    elif part.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=part.size_m[0], height=part.size_m[1], sections=24)
    else:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=part.size_m[0])
    return mesh.apply_transform(part.pose_m)


def clutter_mesh(parts: list[RoomPart], seed: int):
    """Every part that is not a wall or the floor as one textured mesh (one registration in the renderer,
    where 150 shapes each cost one): each face planar-mapped into a tile of the atlas; a part with a plain
    ``colour`` takes a small tile (nearly its own colour), a textured one a large tile."""
    import trimesh

    rng = np.random.default_rng((seed, 47))
    vertices, faces, uvs = [], [], []
    count = 0
    for part in parts:
        mesh = _shape_mesh(part)
        tri = mesh.vertices[mesh.faces]  # (F, 3, 3): one vertex per face corner, each face mapped on its own
        axis = np.abs(mesh.face_normals).argmax(axis=1)
        plane = np.stack([np.delete(t, a, axis=1) for t, a in zip(tri, axis)])  # (F, 3, 2)
        lo, extent = tri.reshape(-1, 3).min(0), max(float(np.ptp(tri.reshape(-1, 3), axis=0).max()), 1e-6)
        tile = 0.02 if part.texture is None else 0.3
        origin = rng.uniform(0, 1 - tile, 2)
        local = (plane - np.stack([np.delete(lo, a) for a in axis])[:, None, :]) / extent
        uvs.append((origin + tile * np.clip(local, 0, 1)).reshape(-1, 2))
        vertices.append(tri.reshape(-1, 3))
        faces.append(count + np.arange(len(tri) * 3).reshape(-1, 3))
        count += len(tri) * 3
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False), np.concatenate(uvs)
