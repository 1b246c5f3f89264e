"""Collision geometry as plain data, and its ``collision.json`` file.

Every piece of a collision representation is a :class:`CollisionShape` posed in the
asset frame (metres; the asset frame is the canonical frame: centred, principal
axis along +z). Primitive shapes follow Drake's conventions:

===========  ==============================================  ======================
kind         ``size_m``                                      shape frame
===========  ==============================================  ======================
sphere       (radius,)                                       centre
box          (x, y, z) full edge lengths                     centre, edges along axes
cylinder     (radius, length)                                centre, axis along z
ellipsoid    (a, b, c) semi-axes along x, y, z               centre
capsule      (radius, length of the cylindrical part)        centre, axis along z
convex       ()  -- geometry in ``mesh_file``                 mesh vertices in the shape frame
mesh         ()  -- geometry in ``mesh_file`` (non-convex)    mesh vertices in the shape frame
===========  ==============================================  ======================

``rotated_box`` primitives from the fitter are written as kind ``box`` with a
non-identity quaternion; the fitter's families live in :mod:`real2sim.formats.spec`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from real2sim.formats.rotations import quaternion_to_matrix


SHAPE_KINDS = ("sphere", "box", "cylinder", "ellipsoid", "capsule", "convex", "mesh")


_SIZE_LEN = {"sphere": 1, "box": 3, "cylinder": 2, "ellipsoid": 3, "capsule": 2, "convex": 0, "mesh": 0}


IDENTITY_WXYZ = (1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CollisionShape:
    """One collision shape in the asset frame (metres, unit quaternion w, x, y, z)."""

    kind: str
    size_m: tuple[float, ...] = ()
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quaternion_wxyz: tuple[float, float, float, float] = IDENTITY_WXYZ
    mesh_file: str | None = None  # relative to the representation folder, for convex/mesh

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"unknown collision shape kind {self.kind!r}")
        if len(self.size_m) != _SIZE_LEN[self.kind]:
            raise ValueError(f"{self.kind} needs {_SIZE_LEN[self.kind]} sizes, got {self.size_m}")
        if self.kind in ("convex", "mesh") and not self.mesh_file:
            raise ValueError(f"a {self.kind} shape needs mesh_file")
        if any(not np.isfinite(s) or s <= 0 for s in self.size_m):
            raise ValueError(f"{self.kind} sizes must be positive and finite, got {self.size_m}")
        q = np.asarray(self.quaternion_wxyz, dtype=float)
        if q.shape != (4,) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise ValueError(f"quaternion must be unit (w, x, y, z), got {self.quaternion_wxyz}")

    @property
    def rotation(self) -> np.ndarray:
        """3x3 rotation from the shape frame to the asset frame."""
        return quaternion_to_matrix(self.quaternion_wxyz)

    def to_json(self) -> dict:
        out: dict = {"type": self.kind, "parameters": _parameters(self)}
        out["pose"] = {"xyz": list(map(float, self.position_m)), "quaternion_wxyz": list(map(float, self.quaternion_wxyz))}
        return out

    @staticmethod
    def from_json(data: dict) -> "CollisionShape":
        kind = data["type"]
        p = data["parameters"]
        size: tuple[float, ...]
        mesh_file = None
        if kind == "sphere":
            size = (p["radius_m"],)
        elif kind == "box":
            size = tuple(p["size_m"])
        elif kind in ("cylinder", "capsule"):
            size = (p["radius_m"], p["length_m"])
        elif kind == "ellipsoid":
            size = tuple(p["semi_axes_m"])
        else:
            size = ()
            mesh_file = p["mesh_file"]
        pose = data["pose"]
        return CollisionShape(
            kind=kind,
            size_m=tuple(float(s) for s in size),
            position_m=tuple(float(v) for v in pose["xyz"]),
            quaternion_wxyz=tuple(float(v) for v in pose["quaternion_wxyz"]),
            mesh_file=mesh_file,
        )


def _parameters(shape: CollisionShape) -> dict:
    s = [float(v) for v in shape.size_m]
    if shape.kind == "sphere":
        return {"radius_m": s[0]}
    if shape.kind == "box":
        return {"size_m": s}
    if shape.kind in ("cylinder", "capsule"):
        return {"radius_m": s[0], "length_m": s[1]}
    if shape.kind == "ellipsoid":
        return {"semi_axes_m": s}
    return {"mesh_file": shape.mesh_file}


@dataclass(frozen=True)
class CollisionGeometry:
    """A whole collision representation: the shapes of one SPEC, in the asset frame."""

    name: str  # canonical folder name, e.g. "boxes_100"
    spec: str  # the SPEC text, e.g. "boxes:100"
    shapes: tuple[CollisionShape, ...] = field(default_factory=tuple)

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "spec": self.spec,
            "frame": "asset (canonical): metres, quaternions w, x, y, z",
            "num_shapes": len(self.shapes),
            "shapes": [s.to_json() for s in self.shapes],
        }

    @staticmethod
    def from_json(data: dict) -> "CollisionGeometry":
        return CollisionGeometry(
            name=data["name"], spec=data["spec"], shapes=tuple(CollisionShape.from_json(s) for s in data["shapes"])
        )


def write_collision_json(geometry: CollisionGeometry, path: Path) -> None:
    Path(path).write_text(json.dumps(geometry.to_json(), indent=1))


def read_collision_json(path: Path) -> CollisionGeometry:
    return CollisionGeometry.from_json(json.loads(Path(path).read_text()))
