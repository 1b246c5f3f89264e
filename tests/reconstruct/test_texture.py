"""The xatlas unwrap in slabs: the same surface, every face once, charts that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from real2sim.reconstruct.field.texture import texel_faces, unwrap


def _uv_area(faces: np.ndarray, uvs: np.ndarray) -> float:
    a, b, c = (uvs[faces[:, i]] for i in range(3))
    return float(0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]).sum())


@pytest.mark.parametrize("faces_per_piece", [10**9, 1500])
def test_unwrap_keeps_every_face_and_packs_charts_without_overlap(bottle_mesh, faces_per_piece):
    mesh = bottle_mesh  # 5938 faces: one piece, or four slabs
    verts, faces, uvs = unwrap(mesh, faces_per_piece=faces_per_piece)
    assert len(faces) == len(mesh.faces) and len(verts) == len(uvs)
    assert uvs.min() >= 0.0 and uvs.max() <= 1.0
    # every output triangle is an input triangle, each input triangle appears once
    key = lambda tri: np.sort(np.round(tri.reshape(len(tri), -1, 3) * 1e6).astype(np.int64), axis=1).reshape(len(tri), -1)
    out = {tuple(k) for k in key(verts[faces])}
    assert out == {tuple(k) for k in key(np.asarray(mesh.vertices)[mesh.faces])}
    assert trimesh.Trimesh(verts, faces, process=False).area == pytest.approx(mesh.area, rel=1e-9)
    # overlapping charts would cover fewer texels than their UV area
    size = 512
    covered = float((texel_faces(faces, uvs, size) >= 0).sum()) / size**2
    area = _uv_area(faces, uvs)
    assert 0.5 < area < 1.0
    assert covered == pytest.approx(area, rel=0.1)


def test_unwrap_in_slabs_depends_on_the_mesh_alone(bottle_mesh):
    a = unwrap(bottle_mesh, faces_per_piece=1500)
    b = unwrap(bottle_mesh, faces_per_piece=1500)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
