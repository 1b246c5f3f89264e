"""Still pictures of meshes by ray casting (embree through trimesh): no OpenGL, no display.

Used for the report's picture of every representation beside the visual mesh. Every
picture of one asset uses one camera (:func:`look_at_camera` from the visual mesh's
bounds), so representations can be compared at a glance. Shading is Lambertian from a
head light plus an ambient term; a textured mesh shows its texture, any other mesh the
colour it is given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class PictureCamera:
    """A pinhole camera in the mesh's frame that a picture is cast from."""

    position_m: tuple[float, float, float]
    """Centre of projection, metres, in the mesh's frame."""
    forward: tuple[float, float, float]
    """Unit viewing direction, in the mesh's frame."""
    right: tuple[float, float, float]
    """Unit image x axis (towards increasing column), perpendicular to :attr:`forward`."""
    up: tuple[float, float, float]
    """Unit image up axis (towards decreasing row), perpendicular to :attr:`forward` and :attr:`right`."""
    fov_deg: float = 35.0
    """Horizontal field of view, degrees, in (0, 180)."""
    width_px: int = 320
    """Image width, pixels, >= 1."""
    height_px: int = 240
    """Image height, pixels, >= 1."""


def look_at_camera(bounds_m: np.ndarray, azimuth_deg: float = 35.0, elevation_deg: float = 25.0,
                   fov_deg: float = 35.0, width_px: int = 320, height_px: int = 240,
                   margin: float = 1.15) -> PictureCamera:
    """A camera looking at the centre of ``bounds_m`` (2x3, metres) from the given azimuth about
    +z and elevation above the xy plane, far enough that the bounding sphere fills the view."""
    bounds_m = np.asarray(bounds_m, dtype=float)
    centre = bounds_m.mean(axis=0)
    radius = 0.5 * float(np.linalg.norm(bounds_m[1] - bounds_m[0]))
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    half_fov = np.radians(fov_deg) / 2 * min(1.0, height_px / width_px)
    distance = margin * radius / np.sin(half_fov)
    position = centre + distance * direction
    forward = -direction
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return PictureCamera(tuple(position), tuple(forward), tuple(right), tuple(up), fov_deg, width_px, height_px)


def _rays(camera: PictureCamera) -> tuple[np.ndarray, np.ndarray]:
    w, h = camera.width_px, camera.height_px
    focal_px = 0.5 * w / np.tan(np.radians(camera.fov_deg) / 2)
    u, v = np.meshgrid(np.arange(w) + 0.5 - w / 2, np.arange(h) + 0.5 - h / 2)
    directions = (np.asarray(camera.forward) * focal_px + u[..., None] * np.asarray(camera.right)
                  - v[..., None] * np.asarray(camera.up)).reshape(-1, 3)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    origins = np.broadcast_to(np.asarray(camera.position_m, dtype=float), directions.shape)
    return np.ascontiguousarray(origins), directions


def _texture_colours(mesh: trimesh.Trimesh, faces: np.ndarray, points: np.ndarray) -> np.ndarray | None:
    visual = mesh.visual
    uv = getattr(visual, "uv", None)
    image = getattr(getattr(visual, "material", None), "image", None)
    if uv is None or image is None:
        return None
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[faces], points)
    coords = np.einsum("nk,nkd->nd", bary, np.asarray(uv)[mesh.faces[faces]])
    texture = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
    rows, cols = texture.shape[:2]
    col = np.clip((coords[:, 0] % 1.0 * cols).astype(int), 0, cols - 1)
    row = np.clip(((1.0 - coords[:, 1] % 1.0) * rows).astype(int), 0, rows - 1)
    return texture[row, col]


def render_picture(parts: list[tuple[trimesh.Trimesh, tuple[float, float, float] | None]], camera: PictureCamera,
                   background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> np.ndarray:
    """An RGB picture (H, W, 3) uint8 of ``parts``: (mesh, colour in [0, 1]) pairs, colour None
    for a textured mesh. The nearest surface along each pixel's ray wins."""
    origins, directions = _rays(camera)
    count = len(directions)
    depth = np.full(count, np.inf)
    colour = np.tile(np.asarray(background, dtype=np.float32), (count, 1))
    head_light = -directions
    for mesh, rgb in parts:
        if len(mesh.faces) == 0:
            continue
        points, ray_idx, faces = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
        if not len(ray_idx):
            continue
        dist = np.einsum("nd,nd->n", points - origins[ray_idx], directions[ray_idx])
        nearer = dist < depth[ray_idx]
        points, ray_idx, faces, dist = points[nearer], ray_idx[nearer], faces[nearer], dist[nearer]
        base = _texture_colours(mesh, faces, points) if rgb is None else None
        if base is None:
            base = np.tile(np.asarray(rgb if rgb is not None else (0.7, 0.7, 0.7), dtype=np.float32), (len(faces), 1))
        lambert = np.abs(np.einsum("nd,nd->n", mesh.face_normals[faces], head_light[ray_idx]))
        depth[ray_idx] = dist
        colour[ray_idx] = base * (0.35 + 0.65 * lambert)[:, None]
    image = colour.reshape(camera.height_px, camera.width_px, 3)
    return (np.clip(image, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)


#: Colours of successive collision shapes (a qualitative palette; repeats after ten).
SHAPE_COLOURS = ((0.90, 0.45, 0.10), (0.20, 0.55, 0.85), (0.30, 0.70, 0.30), (0.85, 0.25, 0.35),
                 (0.60, 0.40, 0.80), (0.95, 0.75, 0.20), (0.25, 0.75, 0.75), (0.65, 0.50, 0.35),
                 (0.55, 0.55, 0.55), (0.90, 0.55, 0.75))
