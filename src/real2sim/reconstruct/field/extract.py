"""Meshes from a trained field: marching cubes on its density, or TSDF fusion of rendered depth.

World frame, metres; the table top is z = 0.

* ``density``: the field's density sampled on a grid (``upsample`` x its own
  resolution), surface at a given level: the one the masks choose
  (:func:`silhouette_surface_level`), or where one voxel of the field's grid lets
  half the light through (``ln 2`` per voxel). The object's unseen inside keeps
  whatever density training left it, so the solid is closed first: the region
  above the surface level is filled (holes of the solid, with the table closing
  it from below), and the bottom cap lands on the table plane.
* ``tsdf``: the paper's way (IV-B2). Colour and depth are rendered from the field
  along a camera trajectory interpolated between the training poses and fused
  into a truncated signed distance volume with Open3D; the surface is its zero
  level. The unseen bottom stays open (the asset stage closes it at the table).
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from scipy.ndimage import binary_fill_holes

from real2sim.plumbing.progress import ProgressFn
from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.voxel_grid import VoxelGrid, largest_parts, surface_from_grid
from real2sim.reconstruct.field.ray_pool import occupancy_ranges
from real2sim.multiview.views import PosedViews, pixel_rays

SURFACE_DENSITY_PER_VOXEL = float(np.log(2.0))
#: Unseen voids (:func:`unseen_voids`): openings at most twice this many voxels wide are shut, and voids of
#: at least this share of the solid's volume are filled.
UNSEEN_VOID_GAP_VOXELS = 1
MIN_UNSEEN_VOID_FRACTION = 0.001
MIN_EDGE_PIXELS = 100  # fewer mask-edge pixels than this: the surface is cut at ln 2 per voxel


def _sampled_density(field: VoxelRadianceField, upsample: int = 1) -> tuple[np.ndarray, VoxelGrid]:
    """The field's density (per voxel length) at the nodes of its grid refined ``upsample`` times."""
    base = field.grid
    shape = tuple(int(n) for n in (np.asarray(base.shape) - 1) * upsample + 1)
    grid = VoxelGrid(base.origin_m, base.voxel_m / upsample, shape)
    centres = torch.from_numpy(grid.centres().astype(np.float32)).to(field.device)
    with torch.no_grad():
        density = torch.cat([field.density(c) for c in centres.split(262_144)]).cpu().numpy().reshape(shape)
    return density, grid


def density_mesh(field: VoxelRadianceField, *, upsample: int = 1, table_z_m: float = 0.0,
                 level_per_voxel: float = SURFACE_DENSITY_PER_VOXEL, void_gap_voxels: int = UNSEEN_VOID_GAP_VOXELS,
                 report: dict | None = None) -> trimesh.Trimesh:
    """Marching cubes on the field's density at ``level_per_voxel``, closed underneath and with its unseen
    voids filled (:func:`unseen_voids`, ``void_gap_voxels``; 0 fills only the sealed ones); see the module
    docstring and :func:`silhouette_surface_level` for a level chosen by the masks. ``report``, when given,
    gets the voxels and volume (ml) of the unseen voids filled."""
    density, grid = _sampled_density(field, upsample)
    solid = density >= level_per_voxel
    # the table closes the solid from below: fill with a solid layer under the grid, then drop it
    filled = binary_fill_holes(np.concatenate([np.ones_like(solid[:, :, :1]), solid], axis=2))[:, :, 1:]
    voids = unseen_voids(filled, void_gap_voxels) if void_gap_voxels > 0 else np.zeros_like(filled)
    if report is not None:
        report.update(unseen_voids_filled_voxels=int(voids.sum()),
                      unseen_voids_filled_ml=round(float(voids.sum()) * grid.voxel_m ** 3 * 1e6, 3))
    density = np.where((filled | voids) & ~solid, 10.0 * level_per_voxel, density)
    mesh = surface_from_grid(density, grid, level_per_voxel, table_z_m)
    return largest_parts(mesh)


def unseen_voids(solid: np.ndarray, gap_voxels: int = UNSEEN_VOID_GAP_VOXELS,
                 min_fraction: float = MIN_UNSEEN_VOID_FRACTION) -> np.ndarray:
    """The empty voxels of ``solid`` (bool, a grid whose last axis is up and whose lowest layer stands on
    the table) that no view can see into: enclosed but for openings at most ``2 * gap_voxels`` wide
    (:func:`~real2sim.multiview.voxel_grid.closed_off`), in connected parts of at least ``min_fraction`` of
    the solid's volume.

    Rays stop at the first opaque surface, so the field's inside is never trained: where its surface
    lets a few rays through (a blurred video frame, a pose a little off), training empties the space
    behind and the mesh gets a cave through a pinhole, with walls inside the object; cavities open
    wide (a mug's) are not closed off, and crevices below ``min_fraction`` stay as trained (why:
    docs/design-notes/reconstruct.md#unseen-voids)."""
    from real2sim.multiview.voxel_grid import closed_off, voxel_parts

    voids = closed_off(~solid, gap_voxels)
    if not voids.any():
        return voids
    labels, sizes = voxel_parts(voids)  # the outside's count is 0, so it is never big
    big = sizes >= max(min_fraction * float(solid.sum()), 1.0)
    return big[labels]


def silhouette_surface_level(field: VoxelRadianceField, views: PosedViews, *, band_px: int = 2,
                             rays_per_view: int = 800, step_voxels: float = 0.5, seed: int = 0,
                             search: tuple[float, float] = (1 / 16, 4.0)) -> dict:
    """The density level (per voxel length) whose surface's silhouettes agree best with the masks.

    Half the light through one voxel (``SURFACE_DENSITY_PER_VOXEL``) is where a ray crossing the
    surface head-on stops, but the masks are made by rays that graze it, and a trained field's
    surface is a layer a voxel or two thick: a grazing ray crosses that layer over many voxels and
    turns opaque at a lower density than a head-on one, so the ``ln 2`` surface lies inside the true
    one (docs/design-notes/reconstruct.md#surface-level). So the pixels near each mask's edge (within
    ``band_px``) are cast as rays; a ray hits the solid at level L when the density sampled along
    it (the same node values marching cubes interpolates, every ``step_voxels``) reaches L. The
    level is the one that misclassifies fewest of those pixels, searched within ``search`` times
    ``SURFACE_DENSITY_PER_VOXEL`` (the middle, in log, of the best stretch).

    Returns ``level_per_voxel``, ``edge_pixels`` and the share of them misclassified at that level
    and at ``ln 2`` (``disagreement``, ``disagreement_ln2``); with fewer than ``MIN_EDGE_PIXELS``
    edge pixels, ``ln 2`` and no shares (None).
    """
    from scipy.ndimage import binary_dilation, binary_erosion

    density, grid = _sampled_density(field)
    table = torch.from_numpy(density.reshape(-1).astype(np.float32)).to(field.device)
    rng = np.random.default_rng(seed)
    k = views.intrinsics
    origins, directions, inside = [], [], []
    ring = np.ones((2 * band_px + 1,) * 2, dtype=bool)
    for i in range(views.count):
        mask = views.mask[i] >= 0.5
        band = binary_dilation(mask, ring) & ~binary_erosion(mask, ring, border_value=1)
        v_px, u_px = np.nonzero(band)
        if len(u_px) > rays_per_view:
            pick = rng.choice(len(u_px), rays_per_view, replace=False)
            v_px, u_px = v_px[pick], u_px[pick]
        o, d = pixel_rays(k, views.c2w_cv[i], u_px + 0.5, v_px + 0.5)
        origins.append(o)
        directions.append(d)
        inside.append(mask[v_px, u_px])
    to = lambda a: torch.from_numpy(np.concatenate(a).astype(np.float32)).to(field.device)
    o, d, inside = to(origins), to(directions), np.concatenate(inside)
    if len(inside) < MIN_EDGE_PIXELS:  # masks without edges (nothing in view, or all object) say nothing
        return {"level_per_voxel": SURFACE_DENSITY_PER_VOXEL, "edge_pixels": int(len(inside)),
                "disagreement": None, "disagreement_ln2": None}
    t_in, t_out = occupancy_ranges(field, o, d)
    step = step_voxels * grid.voxel_m
    counts = torch.ceil((t_out - t_in).clamp_min(0.0) / step).long()
    peak = torch.zeros(len(o), device=field.device)
    with torch.no_grad():
        for rays in torch.arange(len(o), device=field.device).split(4096):
            n = counts[rays]
            ray = torch.repeat_interleave(rays, n)
            if len(ray) == 0:
                continue
            first = torch.cumsum(n, 0) - n
            j = torch.arange(len(ray), device=field.device) - torch.repeat_interleave(first, n)
            points = o[ray] + (t_in[ray] + (j.float() + 0.5) * step)[:, None] * d[ray]
            values = field.blend_nodes(table, points)
            peak.scatter_reduce_(0, ray, values, reduce="amax")
    peak = peak.cpu().numpy()
    lo, hi = (f * SURFACE_DENSITY_PER_VOXEL for f in search)
    # misclassified at level L: inside pixels whose peak < L, outside pixels whose peak >= L;
    # evaluated between consecutive sorted peaks (where the count changes)
    order = np.argsort(peak, kind="stable")
    p, y = peak[order], inside[order]
    cuts = np.concatenate([[lo], np.clip((p[1:] + p[:-1]) / 2, lo, hi), [hi]])
    below = np.searchsorted(p, cuts, side="left")  # pixels with peak < cut
    inside_below = np.concatenate([[0], np.cumsum(y)])[below]
    outside_above = (len(y) - y.sum()) - (below - inside_below)
    errors = inside_below + outside_above
    best = errors == errors.min()
    level = float(np.exp(0.5 * (np.log(cuts[best].min()) + np.log(cuts[best].max()))))

    def disagreement(level_: float) -> float:
        return float(np.mean(np.where(inside, peak < level_, peak >= level_)))

    return {"level_per_voxel": level, "edge_pixels": int(len(y)), "disagreement": disagreement(level),
            "disagreement_ln2": disagreement(SURFACE_DENSITY_PER_VOXEL)}


def interpolated_trajectory(c2w_cv: np.ndarray, per_pair: int = 2) -> np.ndarray:
    """(M, 4, 4) poses: the given ones in order and ``per_pair - 1`` blends between consecutive ones.

    Positions are blended linearly, orientations by spherical linear interpolation.
    """
    from scipy.spatial.transform import Rotation, Slerp

    out = []
    for a, b in zip(c2w_cv[:-1], c2w_cv[1:]):
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))
        for s in np.arange(per_pair) / per_pair:
            pose = np.eye(4)
            pose[:3, :3] = slerp([s]).as_matrix()[0]
            pose[:3, 3] = (1 - s) * a[:3, 3] + s * b[:3, 3]
            out.append(pose)
    out.append(c2w_cv[-1])
    return np.stack(out)


def render_view(field: VoxelRadianceField, views: PosedViews, c2w_cv: np.ndarray, scale: float = 1.0):
    """Colour (H, W, 3) in [0, 1], opacity (H, W) and depth along the optical axis (H, W, metres) of one pose.

    ``scale`` < 1 renders a smaller image of the same camera.
    """
    k = views.intrinsics
    w, h = max(int(round(k.width * scale)), 1), max(int(round(k.height * scale)), 1)
    v_px, u_px = np.mgrid[0:h, 0:w]
    o, d = pixel_rays(k, c2w_cv, (u_px.ravel() + 0.5) / scale, (v_px.ravel() + 0.5) / scale)
    to = lambda a: torch.from_numpy(a.astype(np.float32)).to(field.device)
    origins, directions = to(o), to(d)
    # march each ray only where it crosses the carved region: most pixels miss the object
    out = field.render_chunked(origins, directions, t_range_m=occupancy_ranges(field, origins, directions))
    forward = c2w_cv[:3, 2]
    z_depth = out.depth_m.cpu().numpy() / np.maximum(out.opacity.cpu().numpy(), 1e-6) * (d @ forward)
    return (out.rgb.cpu().numpy().reshape(h, w, 3), out.opacity.cpu().numpy().reshape(h, w),
            z_depth.reshape(h, w))


def tsdf_mesh(field: VoxelRadianceField, views: PosedViews, *, per_pair: int = 2, scale: float = 0.5,
              voxel_m: float | None = None, truncation_voxels: float = 4.0, min_opacity: float = 0.5,
              table_z_m: float = 0.0, progress: ProgressFn | None = None) -> trimesh.Trimesh:
    """TSDF fusion (Open3D) of colour and depth rendered from the field; see the module docstring."""
    import open3d as o3d

    voxel = voxel_m or field.grid.voxel_m
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=voxel, sdf_trunc=truncation_voxels * voxel,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8)
    k = views.intrinsics
    poses = interpolated_trajectory(views.c2w_cv, per_pair)
    for i, pose in enumerate(poses):
        rgb, opacity, depth = render_view(field, views, pose, scale)
        h, w = depth.shape
        depth = np.where(opacity >= min_opacity, depth, 0.0).astype(np.float32)
        intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, k.fl_x * scale, k.fl_y * scale,
                                                      k.cx * scale - 0.5, k.cy * scale - 0.5)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray((rgb * 255).astype(np.uint8))), o3d.geometry.Image(depth),
            depth_scale=1.0, depth_trunc=100.0, convert_rgb_to_intensity=False)
        volume.integrate(rgbd, intrinsic, np.linalg.inv(pose))
        if progress:
            progress("TSDF fusion", i + 1, len(poses))
    mesh = volume.extract_triangle_mesh()
    verts = np.asarray(mesh.vertices)
    if len(verts) == 0:
        from real2sim.plumbing.errors import UserInputError

        raise UserInputError("TSDF fusion found no surface: the field renders no opaque pixels")
    result = trimesh.Trimesh(verts, np.asarray(mesh.triangles), process=True)
    above = result.vertices[:, 2] >= table_z_m
    result.update_faces(above[result.faces].all(axis=1))
    result.remove_unreferenced_vertices()
    return largest_parts(result)
