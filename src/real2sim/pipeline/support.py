"""Where `run` closes the asset's flat bottom: the plane the object stands on.

* A dataset with a table plane (the default): the table, z = ``table_z_m`` of the dataset's
  world frame (0 for a capture and for a COLMAP dataset put in the robot frame).
* A dataset that says its images show no table (``transforms.json`` ``"table_plane": false``:
  an object on a turntable or a thin stand) and states the height of what the object stands on
  (``"support_z_m"``, as ``capture --no-table`` does): that height (`reconstruct` has cut there).
* Such a dataset that does not state it: the reconstructed object's own lowest points,
  :func:`lowest_seen_height_m`.

Why not simply the mesh's lowest vertex (or a low percentile of its vertices): with the cameras
above the object's bottom, nothing under the bottom is seen by any view, and the visual hull
there is a downward cone under the bottom (how deep: docs/design-notes/pipeline.md#support). A
support at the cone's apex would stand the asset on a point, with mass where the object has none. The cone's faces are
the ones no camera looks at: they face down, away from every view. So the support is the lowest
part of the surface the cameras *see*: faces whose normal is within :data:`SEEN_WITHIN_DEG` of
the direction to at least :data:`SEEN_BY_VIEWS` camera centres, and among those the height
below which :data:`LOW_AREA_FRACTION` of their area lies (a percentile by area, so that a
stray sliver of a face does not set it, and the mesh's tessellation does not weigh in).
Occlusion is not tested: a bottom is seen from the side, where the object does not hide its own
lowest rim.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: A face counts as seen by a view when its outward normal is within this angle of the view's
#: direction. Marching-cubes normals scatter by ~15 deg: 66 deg keeps the unseen cone out.
SEEN_WITHIN_DEG = 66.0
#: ... by at least this many views (one view's grazing look at a noisy face is not enough).
SEEN_BY_VIEWS = 2
#: The support: the height below which this fraction of the seen faces' area lies.
LOW_AREA_FRACTION = 0.005


def lowest_seen_height_m(mesh, camera_centres_m: np.ndarray) -> float:
    """The height (world z, metres) of the lowest part of ``mesh`` (trimesh, world frame, z up)
    that the cameras at ``camera_centres_m`` ((N, 3), world frame, metres) look at; see the module
    docstring. The mesh's lowest vertex when no face is seen by enough views."""
    centres = np.asarray(camera_centres_m, dtype=float).reshape(-1, 3)
    centre_of_face = np.asarray(mesh.triangles_center)
    normals = np.asarray(mesh.face_normals)
    lowest_of_face = np.asarray(mesh.vertices)[np.asarray(mesh.faces)][:, :, 2].min(axis=1)
    min_cos = math.cos(math.radians(SEEN_WITHIN_DEG))
    views = np.zeros(len(centre_of_face), dtype=int)
    for centre in centres:  # one view at a time: faces x views x 3 would not fit for big captures
        towards = centre - centre_of_face
        cos = np.einsum("fk,fk->f", normals, towards) / np.maximum(np.linalg.norm(towards, axis=1), 1e-12)
        views += cos > min_cos
    seen = views >= SEEN_BY_VIEWS
    if not seen.any():
        return float(np.asarray(mesh.vertices)[:, 2].min())
    heights, area = lowest_of_face[seen], np.asarray(mesh.area_faces)[seen]
    order = np.argsort(heights)
    cumulative = np.cumsum(area[order])
    index = int(np.searchsorted(cumulative, LOW_AREA_FRACTION * cumulative[-1]))
    return float(heights[order][min(index, len(order) - 1)])


def support_height_m(dataset: Path, mesh_path: Path, table_z_m: float) -> tuple[float, str]:
    """(support height, world z in metres; how it was chosen, one phrase for run.json and the docs)
    for the reconstruction ``mesh_path`` (world frame) of ``dataset``; see the module docstring."""
    from real2sim.formats.dataset import SUPPORT_Z_KEY, has_table_plane, read_dataset, stated_support_z_m

    ds = read_dataset(dataset, check_files=False)
    if has_table_plane(ds):
        return float(table_z_m), f"the dataset's table plane, z = {table_z_m:g} m"
    stated = stated_support_z_m(ds)
    if stated is not None:
        return stated, f"no table plane; the support the dataset states ({SUPPORT_Z_KEY}), z = {stated:g} m"
    from real2sim.geometry.mesh_io import load_mesh

    height = lowest_seen_height_m(load_mesh(mesh_path), ds.poses_c2w_gl()[:, :3, 3])
    return height, ("no table plane in the dataset: the lowest part of the reconstruction that the cameras see, "
                    f"z = {height:.4f} m")
