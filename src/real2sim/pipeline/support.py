"""Where `run` closes the asset's flat bottom: the plane the object stands on.

* A dataset with a table plane (the default): the table, z = ``table_z_m`` of the dataset's
  world frame (0 for a capture and for a COLMAP dataset put in the robot frame).
* A dataset that says its images show no table (``transforms.json`` ``"table_plane": false``:
  an object on a turntable or a thin stand) and states the height of what the object stands on
  (``"support_z_m"``, as ``capture --no-table`` does): that height (`reconstruct` has cut there).
* Such a dataset that does not state it: the reconstructed object's own lowest points that the
  cameras see (:func:`real2sim.geometry.support_height.lowest_seen_height_m`, which says why not
  the lowest vertex).
"""

from __future__ import annotations

from pathlib import Path


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
    from real2sim.formats.mesh_io import load_mesh
    from real2sim.geometry.support_height import lowest_seen_height_m

    height = lowest_seen_height_m(load_mesh(mesh_path), ds.poses_c2w_gl()[:, :3, 3])
    return height, ("no table plane in the dataset: the lowest part of the reconstruction that the cameras see, "
                    f"z = {height:.4f} m")
