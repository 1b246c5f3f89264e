"""Resolve the unseen bottom of a reconstruction: crop at the support plane and close it flat (paper IV-C1).

The capture never sees the object's underside, so a reconstruction has arbitrary
triangles below the table. We assume a flat bottom: remove everything below the
support plane ``{p : p . up < support_height_m}`` and make the result a closed
solid whose bottom is exactly that plane. Three ways to the closed solid, tried in
order (each result is checked to be a closed oriented 2-manifold by manifold3d):

1. **trim** -- the input is already a closed manifold: manifold3d cuts it by the
   plane and caps the cut exactly.
2. **cap** -- the part above the plane is clean (garbage only below it): crop the
   triangles at the plane, and triangulate the boundary loops that lie in the
   plane (manifold3d's polygon triangulator) into a flat floor. Exact.
3. **remesh** -- anything else (holes, internal sheets, debris crossing the
   plane): a signed distance field of the cropped mesh on a voxel grid (sign from
   the generalized winding number, robust to holes; exact distances in a narrow
   band) is contoured by marching cubes into a closed surface and trimmed at the
   plane. Near the open bottom the winding number is ambiguous (it is ~0.5 on the
   opening), so the solid may be dented just above the plane; a thin floor slab,
   ``p . up`` in ``[h, h + slab]``, is united with it (manifold3d):

   * ``floor="section"`` (default, ours): the solid's own cross-section at
     ``h + slab``, extruded down to the plane. It follows a concave footprint
     exactly and costs milliseconds.
   * ``floor="vhacd"`` (the paper's): a convex decomposition (V-HACD, ``vhacdx``)
     of the closed, remeshed solid (V-HACD cannot fill an open mesh), each hull
     that reaches the bottom band extended down to the plane and cut to the slab.
     Convex hulls bulge over a concave footprint, and V-HACD costs seconds.

Paths 1 and 2 are exact and need no slab. The path taken is recorded in the
result's ``metadata["flat_bottom_method"]`` ("trim", "cap" or "remesh"), the
plane in ``metadata["support_height_m"]`` and ``metadata["support_up"]``.
"""

from __future__ import annotations

import numpy as np
import trimesh

from real2sim.geometry.collision_mesh import from_manifold, to_manifold


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"up must be a non-zero vector, got {v}")
    return v / n


def default_support_height(mesh: trimesh.Trimesh, up=(0.0, 0.0, 1.0)) -> float:
    """Lowest point along ``up`` of the mesh's largest connected piece (by area).

    A heuristic for when the table height is not known: debris detached from the
    object is ignored, debris attached to it is not. Pass the known height when
    you have it (the capture knows where the table is).
    """
    up = _unit(up)
    pieces = mesh.split(only_watertight=False)
    largest = max(pieces, key=lambda m: m.area) if len(pieces) else mesh
    return float((largest.vertices @ up).min())


def _crop(mesh: trimesh.Trimesh, up: np.ndarray, height: float) -> trimesh.Trimesh:
    """Triangles above the plane, those crossing it cut exactly at it (open where cut)."""
    vertices, faces, _ = trimesh.intersections.slice_faces_plane(
        np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces), plane_normal=up, plane_origin=up * height
    )
    if faces is None or len(faces) == 0:
        raise ValueError("nothing of the mesh lies above the support plane")
    vertices = np.array(vertices, dtype=np.float64)
    # put the cut vertices exactly on the plane (interpolation leaves ~1e-17 m of noise)
    off = vertices @ up - height
    on_plane = np.abs(off) <= 1e-12 * max(float(np.abs(vertices).max()), 1.0)
    vertices[on_plane] -= off[on_plane, None] * up
    cropped = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    cropped.merge_vertices()
    cropped.update_faces(cropped.nondegenerate_faces())
    cropped.remove_unreferenced_vertices()
    return cropped


def _trim_closed(mesh: trimesh.Trimesh, up: np.ndarray, height: float) -> trimesh.Trimesh:
    solid = to_manifold(mesh).trim_by_plane(tuple(up), float(height))
    if solid.is_empty():
        raise ValueError("nothing of the mesh lies above the support plane")
    return from_manifold(solid)


def _boundary_loops(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Directed boundary loops (vertex index arrays) of an oriented mesh; ValueError if not simple."""
    edges = mesh.edges  # directed half-edges, (3F, 2)
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = edges[counts[inverse.reshape(-1)] == 1]
    if len(boundary) == 0:
        return []
    nxt: dict[int, int] = {}
    for a, b in boundary:
        if int(a) in nxt:
            raise ValueError("boundary is not a set of simple loops")
        nxt[int(a)] = int(b)
    loops, seen = [], set()
    for start in list(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            if v not in nxt:
                raise ValueError("open boundary chain")
            v = nxt[v]
        if v != start:
            raise ValueError("boundary loops touch")
        loops.append(np.asarray(loop))
    return loops


def _cap_cropped(cropped: trimesh.Trimesh, up: np.ndarray, height: float) -> trimesh.Trimesh:
    """Close a cropped mesh whose only holes are loops in the support plane with a flat floor."""
    import manifold3d

    loops = _boundary_loops(cropped)
    if not loops:
        raise ValueError("cropped mesh has no opening at the support plane")
    v = np.asarray(cropped.vertices)
    scale = float(np.ptp(v, axis=0).max())
    for loop in loops:
        if np.abs(v[loop] @ up - height).max() > 1e-9 * max(scale, 1.0):
            raise ValueError("a hole away from the support plane")
    # 2-D basis (e1, e2) with e1 x e2 = -up, so counter-clockwise triangles face down (outward)
    e1 = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.5:
        e1 = np.cross(up, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(-up, e1)
    # A boundary half-edge a->b of an outward-oriented mesh appears as b->a in the missing
    # cap, so the cap's polygons are the loops reversed.
    polygons = [loop[::-1] for loop in loops]
    coords = [np.stack([v[p] @ e1, v[p] @ e2], axis=1) for p in polygons]
    signed = sum(0.5 * float(np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])) for c in coords)
    if signed < 0:  # faces were oriented inward: flip everything consistently
        polygons = [p[::-1] for p in polygons]
        coords = [c[::-1] for c in coords]
    tris = np.asarray(manifold3d.triangulate(coords), dtype=np.int64)
    index = np.concatenate(polygons)
    faces = np.concatenate([np.asarray(cropped.faces), index[tris]])
    closed = trimesh.Trimesh(vertices=v, faces=faces, process=False)
    if signed < 0:
        closed.invert()
    return from_manifold(to_manifold(closed))


def _sdf_grid_mesh(cropped: trimesh.Trimesh, voxel_m: float) -> trimesh.Trimesh:
    """Closed surface of the solid bounded by ``cropped`` by marching cubes on a signed distance grid."""
    import igl
    from scipy import ndimage
    from skimage.measure import marching_cubes

    from real2sim.geometry.inside import winding_numbers

    lo = cropped.bounds[0] - 3 * voxel_m
    hi = cropped.bounds[1] + 3 * voxel_m
    shape = np.ceil((hi - lo) / voxel_m).astype(int) + 1
    axes = [lo[i] + voxel_m * np.arange(shape[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    from real2sim.geometry.inside import compact_triangles

    inside = (np.abs(winding_numbers(compact_triangles(cropped), grid)) > 0.5).reshape(shape)
    # exact distances only where the sign changes nearby; elsewhere a clamped value
    band = ndimage.binary_dilation(inside, iterations=2) & ~ndimage.binary_erosion(inside, iterations=2)
    sdf = np.where(inside, -2.0 * voxel_m, 2.0 * voxel_m)
    pts = grid[band.reshape(-1)]
    if len(pts):
        d2, _, _ = igl.point_mesh_squared_distance(
            np.ascontiguousarray(pts), np.ascontiguousarray(cropped.vertices, dtype=np.float64), np.ascontiguousarray(cropped.faces, dtype=np.int64)
        )
        d = np.minimum(np.sqrt(d2), 2.0 * voxel_m)
        sdf[band] = np.where(inside[band], -d, d)
    # an outside layer all round guarantees a closed contour even when stray open
    # sheets push the winding number past 0.5 at the edge of the grid
    sdf = np.pad(sdf, 1, constant_values=2.0 * voxel_m)
    verts, faces, _, _ = marching_cubes(sdf, level=0.0, spacing=(voxel_m,) * 3)
    surface = trimesh.Trimesh(vertices=verts + (lo - voxel_m), faces=faces, process=False)
    if surface.volume < 0:
        surface.invert()
    return surface


def closed_solid(mesh: trimesh.Trimesh, voxel_m: float | None = None) -> trimesh.Trimesh:
    """``mesh`` itself when it is a closed oriented 2-manifold; otherwise the solid it bounds, closed.

    Scans have holes, and CoACD and V-HACD read an open mesh as a shell, not as the solid it bounds
    (why: docs/design-notes/asset.md#closed-solids-for-decomposition). The closed solid is the remesh
    path of :func:`close_flat_bottom` without the plane: the generalized winding number says what is inside
    (robust to holes), and marching cubes on a signed distance grid of ``voxel_m`` (default 1/100 of
    the largest extent) closes it. ``metadata["closed_by"]``: ``"as is"`` or ``"remesh"``."""
    try:
        to_manifold(mesh)
        closed, how = mesh, "as is"
    except ValueError:
        extent = float(np.ptp(mesh.vertices, axis=0).max())
        surface = _sdf_grid_mesh(mesh, float(voxel_m) if voxel_m is not None else extent / 100.0)
        try:
            body = to_manifold(surface)
        except ValueError:
            surface.merge_vertices()
            body = to_manifold(surface)
        closed, how = from_manifold(body), "remesh"
    closed.metadata["closed_by"] = how
    return closed


def _slab_hulls(solid: trimesh.Trimesh, up: np.ndarray, height: float, slab_m: float, max_hulls: int) -> list:
    """Convex pieces of ``solid`` (V-HACD) near the support plane, cut to height <= p.up <= height + slab.

    A remeshed solid stops about half a voxel above the plane, so each piece that
    reaches into the bottom band is extended straight down to the plane first (its
    points in the band projected onto it); pieces higher up get no floor under them.
    """
    import manifold3d

    from real2sim.collision.decomposition import VhacdConfig, vhacd_point_sets

    hulls = vhacd_point_sets(solid, VhacdConfig(max_convex_hulls=max_hulls, resolution=20_000))
    pieces = []
    for points in hulls:
        if len(points) < 4:
            continue
        level = points @ up - height
        low = points[level < 2.0 * slab_m]
        if len(low) == 0:
            continue
        extended = np.concatenate([points, low - np.outer(low @ up - height, up)])
        hull = manifold3d.Manifold.hull_points(np.asarray(extended, dtype=np.float64))
        piece = hull.trim_by_plane(tuple(up), float(height)).trim_by_plane(tuple(-up), float(-(height + slab_m)))
        if not piece.is_empty():
            pieces.append(piece)
    return pieces


def _rotation_to_z(up: np.ndarray) -> np.ndarray:
    """A rotation R with R @ up = +z."""
    from scipy.spatial.transform import Rotation

    rotation, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up])
    return rotation.as_matrix()


def _section_slab(body, up: np.ndarray, height: float, slab_m: float) -> list:
    """The body's cross-section at height + slab, extruded down to the plane (a prism)."""
    import manifold3d

    rotation = _rotation_to_z(up)
    to_z = np.hstack([rotation, np.zeros((3, 1))]).tolist()
    back = np.hstack([rotation.T, np.zeros((3, 1))]).tolist()
    section = body.transform(to_z).slice(float(height + slab_m))
    if section.area() <= 0:
        return []
    prism = manifold3d.Manifold.extrude(section, float(slab_m)).translate((0.0, 0.0, float(height)))
    return [prism.transform(back)]


def close_flat_bottom(
    mesh: trimesh.Trimesh,
    support_height_m: float | None = None,
    *,
    up=(0.0, 0.0, 1.0),
    slab_m: float | None = None,
    voxel_m: float | None = None,
    floor: str = "section",
    max_hulls: int = 16,
) -> trimesh.Trimesh:
    """Crop ``mesh`` below the support plane and close it into a solid with a flat bottom.

    Parameters, all in the mesh's own frame and units (metres):

    * ``support_height_m``: the plane is ``p . up = support_height_m``; default
      :func:`default_support_height`. For a mesh reconstructed in the robot frame
      the table is known: pass its height with ``up = (0, 0, 1)``. For a mesh
      already in the asset frame, pass the table plane mapped by the canonical
      transform (``up = R @ [0, 0, 1]``, height ``table_z + up . t``).
    * ``slab_m``: thickness of the floor slab (remesh path), default 3 voxels. The
      remeshed solid is rounded off within about a voxel of the opening, so without
      a slab there is no flat floor (why: docs/design-notes/asset.md#flat-bottom-slab-and-voxel).
    * ``voxel_m``: grid spacing of the remesh path, default 1/100 of the largest
      extent of the cropped mesh (about 2 mm on a 19 cm bottle).
    * ``floor``: how the remesh path closes the floor, ``"section"`` or
      ``"vhacd"`` (see the module docstring); ``max_hulls`` bounds V-HACD.

    Returns a new watertight mesh lying in ``p . up >= support_height_m`` and
    touching that plane with a flat face (texture coordinates are not kept: this
    is collision/inertia geometry). Its ``metadata`` records the method and the
    plane. Raises ValueError when nothing lies above the plane.
    """
    import manifold3d

    up = _unit(up)
    height = default_support_height(mesh, up) if support_height_m is None else float(support_height_m)
    if not np.isfinite(height):
        raise ValueError(f"support height must be finite, got {support_height_m}")

    def done(closed: trimesh.Trimesh, method: str) -> trimesh.Trimesh:
        closed.metadata.update({"flat_bottom_method": method, "support_height_m": height, "support_up": up.tolist()})
        return closed

    try:
        return done(_trim_closed(mesh, up, height), "trim")
    except ValueError as err:
        if "nothing of the mesh" in str(err):
            raise
    cropped = _crop(mesh, up, height)
    try:
        return done(_cap_cropped(cropped, up, height), "cap")
    except ValueError:
        pass

    extent = float(np.ptp(cropped.vertices, axis=0).max())
    voxel = float(voxel_m) if voxel_m is not None else extent / 100.0
    slab = float(slab_m) if slab_m is not None else 3.0 * voxel
    surface = _sdf_grid_mesh(cropped, voxel)
    try:
        body = to_manifold(surface)
    except ValueError:
        surface.merge_vertices()
        body = to_manifold(surface)
    body = body.trim_by_plane(tuple(up), height)
    if floor == "section":
        pieces = [body] + _section_slab(body, up, height, slab)
    elif floor == "vhacd":
        # decompose the closed, remeshed body: V-HACD cannot fill the inside of an open mesh
        pieces = [body] + _slab_hulls(from_manifold(body), up, height, slab, max_hulls)
    else:
        raise ValueError(f"floor must be 'section' or 'vhacd', got {floor!r}")
    closed = manifold3d.Manifold.batch_boolean(pieces, manifold3d.OpType.Add)
    return done(from_manifold(closed), "remesh")
