"""The first hit along rays from Embree's distances: where trimesh's own ray query puts it."""

from __future__ import annotations

import numpy as np
import trimesh

from real2sim.geometry.objects import make_object
from real2sim.multiview.rays import SurfaceRays


def test_first_hits_are_where_trimesh_finds_them_and_misses_are_infinite():
    """Rays from all around the bundled mug (handle, cavity and misses included), in metres and far from the
    origin (Embree works in float32 on the scaled box): the distance to the first hit agrees with trimesh's
    ``intersects_location`` within a micrometre, on the same rays; rays that miss give inf; a box seen from
    inside gives the distance to its wall."""
    mesh = make_object("mug").copy()
    mesh.apply_translation([250.0, -40.0, 3.0])
    rng = np.random.default_rng(0)
    centre = mesh.bounds.mean(axis=0)
    origins = centre + rng.normal(size=(4000, 3)) * 0.3
    targets = centre + rng.normal(size=(4000, 3)) * 0.04
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    t = SurfaceRays(mesh).first_hit(origins, directions)
    hits, rays, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    expected = np.full(len(origins), np.inf)
    expected[rays] = np.einsum("nd,nd->n", hits - origins[rays], directions[rays])
    assert 0.2 * len(origins) < np.isfinite(expected).sum() < 0.95 * len(origins)  # hits and misses both
    assert np.array_equal(np.isfinite(t), np.isfinite(expected))
    assert np.abs(t[np.isfinite(t)] - expected[np.isfinite(t)]).max() < 1e-6
    box = trimesh.creation.box((2.0, 2.0, 2.0))
    inside = SurfaceRays(box).first_hit(np.zeros((2, 3)), np.array([[1.0, 0, 0], [0, 0, -1.0]]))
    assert np.allclose(inside, 1.0, atol=1e-6)
    assert SurfaceRays(box).first_hit(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
