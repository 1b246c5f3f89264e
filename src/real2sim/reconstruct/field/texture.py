"""Texture for the reconstructed mesh (paper IV-B3), and rendering a textured mesh to check it.

The mesh is unwrapped with xatlas. Each texel that a triangle covers in the
atlas is mapped back to its 3D point and the triangle's normal; the texel's
colour is the field's colour along a short ray that starts a little outside the
surface and looks back along the normal (the view that sees the surface
head-on). Empty texels take the colour of the nearest filled one, so that
bilinear sampling across an atlas seam does not bleed in black.

Texture images follow OBJ: u to the right, v up (row 0 of the image is v = 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from PIL import Image, ImageDraw
from scipy.ndimage import distance_transform_edt

from real2sim.formats.dataset import CameraIntrinsics
from real2sim.reconstruct.field.radiance import VoxelRadianceField
from real2sim.multiview.views import PosedViews, pixel_rays, project


def unwrap(mesh: trimesh.Trimesh, faces_per_piece: int = 5000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xatlas atlas: vertices (V', 3), faces (F, 3) and per-vertex UVs (V', 2) in [0, 1].

    The mesh is cut into slabs of about ``faces_per_piece`` faces along its longest side and
    the slabs are charted as separate meshes of one atlas: xatlas charts each mesh on its own
    thread, and its charting cost grows faster than the face count (why:
    docs/design-notes/reconstruct.md#texture-atlas). The cuts only add chart seams, which the
    atlas has everywhere anyway. The number of slabs depends on the mesh alone, so the atlas
    does not change with the machine.
    """
    import xatlas

    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces)
    pieces = max(1, int(np.ceil(len(faces) / faces_per_piece)))
    axis = int(np.argmax(np.ptp(vertices, axis=0)))
    order = np.argsort(vertices[faces].mean(axis=1)[:, axis], kind="stable")
    atlas = xatlas.Atlas()
    piece_vertices = []
    for part in np.array_split(order, pieces):
        used, local = np.unique(faces[part], return_inverse=True)
        atlas.add_mesh(vertices[used].astype(np.float32), local.reshape(-1, 3).astype(np.uint32))
        piece_vertices.append(used)
    atlas.generate()
    out_vertices, out_faces, out_uvs, offset = [], [], [], 0
    for i, used in enumerate(piece_vertices):
        vmapping, piece_faces, uvs = atlas[i]
        out_vertices.append(vertices[used[vmapping]])
        out_faces.append(piece_faces.astype(np.int64) + offset)
        out_uvs.append(uvs.astype(np.float64))
        offset += len(vmapping)
    return np.concatenate(out_vertices), np.concatenate(out_faces), np.concatenate(out_uvs)


def texel_faces(faces: np.ndarray, uvs: np.ndarray, size_px: int) -> np.ndarray:
    """(size, size) int: the face covering each texel (image rows, row 0 = v 1), -1 where none."""
    image = Image.new("I", (size_px, size_px), 0)
    draw = ImageDraw.Draw(image)
    pix = np.column_stack([uvs[:, 0] * size_px, (1.0 - uvs[:, 1]) * size_px])
    for f, tri in enumerate(faces):
        draw.polygon([tuple(p) for p in pix[tri]], fill=f + 1)
    return np.asarray(image, dtype=np.int64) - 1


def _barycentric_2d(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(-1), (v0 * v1).sum(-1), (v1 * v1).sum(-1)
    d20, d21 = (v2 * v0).sum(-1), (v2 * v1).sum(-1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) < 1e-20, 1e-20, den)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.clip(np.column_stack([1 - v - w, v, w]), 0.0, 1.0)


@dataclass(frozen=True)
class _Texels:
    """The atlas of a mesh and, for every covered texel, its image position, 3D point and normal."""

    verts: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    size_px: int


def _texels(mesh: trimesh.Trimesh, size_px: int) -> _Texels:
    verts, faces, uvs = unwrap(mesh)
    owner = texel_faces(faces, uvs, size_px)
    rows, cols = np.nonzero(owner >= 0)
    face = owner[rows, cols]
    texel_uv = np.column_stack([(cols + 0.5) / size_px, 1.0 - (rows + 0.5) / size_px])
    tri_uv = uvs[faces[face]]
    bary = _barycentric_2d(texel_uv, tri_uv[:, 0], tri_uv[:, 1], tri_uv[:, 2])
    bary /= bary.sum(axis=1, keepdims=True)
    points = np.einsum("nk,nkd->nd", bary, verts[faces[face]])
    normals = trimesh.Trimesh(verts, faces, process=False).face_normals[face]
    return _Texels(verts, faces, uvs, rows, cols, points, normals, size_px)


def _textured(texels: _Texels, colour: np.ndarray, known: np.ndarray) -> trimesh.Trimesh:
    """The unwrapped mesh with ``colour`` (N, 3) at its texels; unknown texels take the mean colour."""
    colour = colour.copy()
    colour[~known] = colour[known].mean(axis=0) if known.any() else 0.5
    size = texels.size_px
    image = np.zeros((size, size, 3), dtype=np.float32)
    filled = np.zeros((size, size), dtype=bool)
    image[texels.rows, texels.cols] = np.clip(colour, 0.0, 1.0)
    filled[texels.rows, texels.cols] = True
    _, (near_r, near_c) = distance_transform_edt(~filled, return_indices=True)
    image = image[near_r, near_c]
    material = trimesh.visual.material.SimpleMaterial(image=Image.fromarray((image * 255).round().astype(np.uint8)))
    visual = trimesh.visual.TextureVisuals(uv=texels.uvs, material=material)
    return trimesh.Trimesh(texels.verts, texels.faces, visual=visual, process=False)


def bake_texture(mesh: trimesh.Trimesh, field: VoxelRadianceField, *, size_px: int = 1024,
                 offset_voxels: float = 3.0) -> trimesh.Trimesh:
    """The mesh, unwrapped, with a texture image of the field's colours (see the module docstring)."""
    tx = _texels(mesh, size_px)
    offset = offset_voxels * field.grid.voxel_m
    to = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(field.device)
    out = field.render_chunked(to(tx.points + offset * tx.normals), to(-tx.normals), chunk=32768,
                               max_distance_m=2.0 * offset)
    opacity = out.opacity.cpu().numpy()
    colour = out.rgb.cpu().numpy() / np.maximum(opacity, 1e-6)[:, None]
    return _textured(tx, colour, opacity > 0.05)


def bake_texture_from_images(mesh: trimesh.Trimesh, views: PosedViews, *, size_px: int = 1024,
                             candidates: int = 3) -> trimesh.Trimesh:
    """The mesh, unwrapped, textured from the images: each texel from the view that sees it most head-on.

    Of the ``candidates`` best-facing views in whose image the texel lies, the first
    from which the mesh does not hide it (a ray cast towards the camera) gives the colour.
    """
    tx = _texels(mesh, size_px)
    k = views.intrinsics
    centres = views.c2w_cv[:, :3, 3]
    order = np.empty((len(tx.points), candidates), dtype=np.int64)
    best_facing = np.empty((len(tx.points), candidates))
    uv_best = np.empty((len(tx.points), candidates, 2), dtype=np.float32)
    for s in range(0, len(tx.points), 20_000):  # (texels, views) arrays, bounded
        pts, nrm = tx.points[s:s + 20_000], tx.normals[s:s + 20_000]
        to_cam = centres[None] - pts[:, None]
        facing = np.einsum("nvd,nd->nv", to_cam, nrm) / np.maximum(np.linalg.norm(to_cam, axis=-1), 1e-9)
        uv, z = project(k, views.c2w_cv, pts)
        inside = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < k.width) & (uv[..., 1] >= 0) & (uv[..., 1] < k.height)
        facing = np.where(inside.T, facing, -np.inf)
        best = np.argsort(-facing, axis=1)[:, :candidates]
        order[s:s + 20_000] = best
        best_facing[s:s + 20_000] = np.take_along_axis(facing, best, axis=1)
        uv_best[s:s + 20_000] = uv.transpose(1, 0, 2)[np.arange(len(pts))[:, None], best]
    colour = np.zeros((len(tx.points), 3))
    known = np.zeros(len(tx.points), dtype=bool)
    eps = 1e-4 * float(np.linalg.norm(mesh.extents))
    for rank in range(order.shape[1]):
        todo = np.nonzero(~known & (best_facing[:, rank] > 0))[0]
        if len(todo) == 0:
            break
        view = order[todo, rank]
        start = tx.points[todo] + eps * tx.normals[todo]
        direction = centres[view] - start
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        # the object is always in front of the cameras, so any hit on the way hides the texel
        visible = ~mesh.ray.intersects_any(start, direction)
        todo, view, px = todo[visible], view[visible], uv_best[todo[visible], rank].astype(int)
        px = np.clip(px, 0, [k.width - 1, k.height - 1])
        colour[todo] = views.rgb[view, px[:, 1], px[:, 0]]
        known[todo] = True
    return _textured(tx, colour, known)


def render_textured_mesh(mesh: trimesh.Trimesh, k: CameraIntrinsics, c2w_cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unlit colour (H, W, 3) in [0, 1] and coverage (H, W) bool of a textured mesh seen by one camera (ray cast)."""
    v_px, u_px = np.mgrid[0:k.height, 0:k.width]
    o, d = pixel_rays(k, c2w_cv, u_px.ravel() + 0.5, v_px.ravel() + 0.5)
    locations, ray_idx, tri_idx = mesh.ray.intersects_location(o, d, multiple_hits=False)
    image = np.zeros((k.height * k.width, 3), dtype=np.float32)
    covered = np.zeros(k.height * k.width, dtype=bool)
    if len(ray_idx):
        bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri_idx], locations)
        uv = np.einsum("nk,nkd->nd", bary, mesh.visual.uv[mesh.faces[tri_idx]])
        texture = np.asarray(mesh.visual.material.image.convert("RGB"), dtype=np.float32) / 255.0
        size_y, size_x = texture.shape[:2]
        col = np.clip((uv[:, 0] * size_x).astype(int), 0, size_x - 1)
        row = np.clip(((1.0 - uv[:, 1]) * size_y).astype(int), 0, size_y - 1)
        image[ray_idx] = texture[row, col]
        covered[ray_idx] = True
    return image.reshape(k.height, k.width, 3), covered.reshape(k.height, k.width)
