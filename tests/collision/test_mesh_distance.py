"""Signed distance and winding-number signs (real2sim.collision.mesh_distance); the samples built on them
are tested in test_sdf_sampling.py."""

from __future__ import annotations

import numpy as np
import trimesh

from real2sim.collision.mesh_distance import boundary_edges, signed_distance_winding


def test_boundary_edges_of_closed_holey_and_misoriented_meshes():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert len(boundary_edges(sphere.faces)) == 0
    a, b = sphere.face_adjacency[0]
    holey = np.delete(sphere.faces, [a, b], axis=0)  # two adjacent faces removed: a 4-edge hole
    assert len(boundary_edges(holey)) == 4
    flipped = sphere.faces.copy()
    flipped[0] = flipped[0][::-1]  # one face against its neighbours: its three edges no longer cancel
    assert len(boundary_edges(flipped)) == 3
    doubled = np.vstack([sphere.faces, sphere.faces])  # a duplicated closed shell is still closed
    assert len(boundary_edges(doubled)) == 0


def test_signed_distance_of_a_box_is_negative_inside_and_exact_outside():
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    points = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, -1.5]])
    calls = []
    for method in ("fast", "exact"):
        sdf, winding = signed_distance_winding(np.asarray(box.vertices, dtype=float), np.asarray(box.faces),
                                               points, method, before_signs=lambda: calls.append(method))
        np.testing.assert_allclose(sdf, [-1.0, 1.0, 0.5], atol=1e-9)
        assert abs(winding[0]) > 0.5 and abs(winding[1]) < 0.5
    assert calls == ["fast", "exact"]
