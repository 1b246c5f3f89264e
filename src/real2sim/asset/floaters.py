"""Debris that floats apart from the object: scans and reconstructions carry it, the asset must not.

Inertia already ignores it (:mod:`real2sim.asset.inertia` drops small clusters of interior
samples), but collision geometry is fitted to the whole mesh: a speck of debris takes a piece of
a fit and becomes a collider where the object has nothing (why: docs/design-notes/asset.md#floaters).

Parts are told apart by where they are, not by how the mesh is stitched: a CAD export's handle
may be its own shell, overlapping the body, and belongs to it. The mesh's connected parts are
joined into *bodies* when their surfaces come within a voxel of each other (a grid of
``gap_fraction`` of the mesh's largest extent, surfaces sampled densely), and bodies with less
than ``min_area_fraction`` of the surface area are dropped; the largest body always stays.
Units: metres, any frame.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.ndimage import label


def without_floaters(mesh: trimesh.Trimesh, *, min_area_fraction: float = 0.01, gap_fraction: float = 0.02,
                     samples: int = 200_000, seed: int = 0) -> trimesh.Trimesh:
    """``mesh`` without the bodies (see the module docstring) holding less than ``min_area_fraction``
    of its area; ``mesh`` itself when nothing is dropped. ``metadata["floater_faces_dropped"]``: how
    many faces went."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = len(mesh.faces)
    adjacency = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(adjacency)), (adjacency[:, 0], adjacency[:, 1])), shape=(faces, faces))
    parts, part_of_face = connected_components(graph, directed=False)
    if parts <= 1:
        mesh.metadata["floater_faces_dropped"] = 0
        return mesh
    points, face_index = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    # every face's centroid too, so that a part too small to be sampled still has a voxel
    points = np.concatenate([points, mesh.triangles_center])
    point_part = part_of_face[np.concatenate([face_index, np.arange(faces)])]
    voxel = gap_fraction * float(np.ptp(mesh.vertices, axis=0).max())
    cell = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    occupied = np.zeros(cell.max(axis=0) + 1, bool)
    occupied[tuple(cell.T)] = True
    clusters, cluster_count = label(occupied, np.ones((3, 3, 3), bool))
    # parts and voxel clusters as one graph: a part joins every cluster its samples fall in, so two
    # parts are one body when they share a cluster (touching), and so are a part's scattered clusters
    point_cluster = clusters[tuple(cell.T)] - 1
    links = np.unique(np.stack([point_part, parts + point_cluster], axis=1), axis=0)
    nodes = parts + cluster_count
    _, body_of_node = connected_components(
        coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(nodes, nodes)), directed=False)
    body_of_face = body_of_node[part_of_face]
    area = np.bincount(body_of_face, weights=mesh.area_faces)
    keep_body = area >= min_area_fraction * area.sum()
    keep_body[np.argmax(area)] = True
    keep = keep_body[body_of_face]
    if keep.all():
        mesh.metadata["floater_faces_dropped"] = 0
        return mesh
    kept = mesh.copy()
    kept.update_faces(keep)
    kept.remove_unreferenced_vertices()
    kept.metadata["floater_faces_dropped"] = int((~keep).sum())
    return kept
