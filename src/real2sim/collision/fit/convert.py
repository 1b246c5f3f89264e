"""A fit result out of unit-sphere coordinates: its SDF, dead-primitive pruning, and the
collision geometry in metres in the asset frame (``asset = centre_m + scale_m * unit``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from real2sim.collision.primitive_sdf import HAS_ROTATION
from real2sim.collision.superquadric import DEFAULT_VERTICES, superquadric_hull
from real2sim.formats.collision import CollisionGeometry, CollisionShape
from real2sim.formats.spec import CollisionSpec, parse_spec
from real2sim.collision.fit.config import FitResult
from real2sim.collision.fit.params import Layout
from real2sim.collision.fit.union import closest


def result_sdf(result: FitResult, points_unit) -> np.ndarray:
    """Union signed distance (N,) of a fit at points in unit-sphere coordinates."""
    pts = torch.as_tensor(np.asarray(points_unit, dtype=np.float64))
    kinds = tuple(dict.fromkeys(result.kinds))
    layout = Layout.of(tuple((kind, result.kinds.count(kind)) for kind in kinds))
    packed = [torch.as_tensor(result.packed(kind)) for kind in kinds]
    dist, _ = closest(layout, packed, pts)
    return dist.numpy()


def to_collision_geometry(
    result: FitResult, centre_m, scale_m: float, spec: CollisionSpec | str, rep_dir=None, *,
    superquadric_vertices: int = DEFAULT_VERTICES
) -> CollisionGeometry:
    """Primitives in metres in the asset frame (``asset = centre_m + scale_m * unit``).

    rotated_box -> ``box`` with its quaternion; box -> ``box`` with the identity; full edge
    lengths for boxes and full lengths for cylinders/capsules (axis = z of the shape frame).
    Superquadrics, which no simulator has as a shape, become ``convex`` pieces: their
    volume-matched polytopes (:mod:`real2sim.collision.superquadric`) are written to
    ``rep_dir/pieces/superquadric_NNN.obj`` in the shape frame, so ``rep_dir`` is required then.
    """
    centre = np.asarray(centre_m, dtype=float).reshape(3)
    scale = float(scale_m)
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale_m must be positive, got {scale_m}")
    if "superquadric" in result.kinds and rep_dir is None:
        raise ValueError("superquadrics are written as convex mesh pieces: pass rep_dir")
    shapes = []
    for kind, row in zip(result.kinds, result.parameters):
        p = np.asarray(row, dtype=float)
        pos = tuple(float(v) for v in centre + scale * p[:3])
        quat = (1.0, 0.0, 0.0, 0.0)
        if HAS_ROTATION[kind]:
            q = p[-4:] / np.linalg.norm(p[-4:])
            quat = tuple(float(v) for v in (q if q[0] >= 0 else -q))
        if kind == "sphere":
            shapes.append(CollisionShape("sphere", (scale * p[3],), pos))
        elif kind in ("box", "rotated_box"):
            shapes.append(CollisionShape("box", tuple(float(2 * scale * v) for v in p[3:6]), pos, quat))
        elif kind in ("cylinder", "capsule"):
            shapes.append(CollisionShape(kind, (float(scale * p[3]), float(2 * scale * p[4])), pos, quat))
        elif kind == "ellipsoid":
            shapes.append(CollisionShape("ellipsoid", tuple(float(scale * v) for v in p[3:6]), pos, quat))
        elif kind == "superquadric":
            rel = f"pieces/superquadric_{len(shapes):03d}.obj"
            hull = superquadric_hull(scale * p[3:6], p[6:8], superquadric_vertices)
            (Path(rep_dir) / rel).parent.mkdir(parents=True, exist_ok=True)
            hull.export(Path(rep_dir) / rel, include_normals=False)
            shapes.append(CollisionShape("convex", (), pos, quat, mesh_file=rel))
        else:
            raise ValueError(f"unknown primitive kind {kind!r}")
    if isinstance(spec, str):  # callers holding the SPEC object pass it through unparsed
        spec = parse_spec(spec)
    return CollisionGeometry(name=spec.name, spec=spec.text, shapes=tuple(shapes))


def superquadric_parameters(result: FitResult, scale_m: float) -> list[dict]:
    """The fitted superquadrics in metres (semi-axes, exponents), for the fit report: the
    collision pieces themselves are polytopes and do not keep them."""
    return [
        {"index": i, "semi_axes_m": [float(scale_m * v) for v in row[3:6]], "exponents": [float(v) for v in row[6:8]]}
        for i, (kind, row) in enumerate(zip(result.kinds, result.parameters))
        if kind == "superquadric"
    ]
