"""Textures of the simulated capture: procedural, feature-rich noise for the table and for
untextured objects, and the OBJ export the renderer reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh


#: Noise octaves (cells across the texture, weight) of :func:`procedural_texture`, and the finer grain
#: a texture seen close up adds (cells down to 2 px of a 4096 px texture: 1.2 mm on a 2.4 m table).
OCTAVES = ((8, 0.5), (32, 0.35), (128, 0.25))
GRAIN_OCTAVES = ((512, 0.2), (2048, 0.15))


def procedural_texture(size_px: int, seed: int, contrast: float = 1.0, grain: bool = False) -> np.ndarray:
    """(size, size, 3) uint8 colourful multi-scale noise with sharp blobs: rich in SIFT features; ``grain``
    adds :data:`GRAIN_OCTAVES` (after the others, so the coarse pattern stays as without)."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    img = np.zeros((size_px, size_px, 3), np.float32 if grain else float)
    # Band-limited noise at several octaves gives features at many scales.
    for octave, weight in OCTAVES:
        grid = Image.fromarray((255 * rng.random((octave, octave, 3))).astype(np.uint8))
        img += weight / 255.0 * np.asarray(grid.resize((size_px, size_px), Image.BICUBIC), dtype=float)
    img = (img - img.min()) / (np.ptp(img) + 1e-9)
    # Hard-edged discs and bars: corners and blobs for the detector (drawn in local windows).
    for _ in range(size_px // 6):
        cx, cy = rng.integers(0, size_px, 2)
        r = int(rng.integers(size_px // 150 + 2, size_px // 30 + 4))
        col = rng.random(3)
        y0, y1, x0, x1 = max(cy - r, 0), min(cy + r + 1, size_px), max(cx - r, 0), min(cx + r + 1, size_px)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        if rng.random() < 0.5:
            sel = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        else:
            sel = np.abs(yy - cy) < r // 2 + 1
        img[y0:y1, x0:x1][sel] = col
    if grain:  # its own stream: the coarse pattern and the blobs stay as without
        fine = np.random.default_rng((seed, 3))
        for octave, weight in GRAIN_OCTAVES:
            cells = Image.fromarray((255 * fine.random((min(octave, size_px), min(octave, size_px), 3))).astype(np.uint8))
            img += weight / 255.0 * (np.asarray(cells.resize((size_px, size_px), Image.BICUBIC), np.float32) - 127.5)
    img = 0.5 + contrast * (img - 0.5)
    return (255 * np.clip(img, 0, 1)).astype(np.uint8)


def has_texture(mesh: trimesh.Trimesh) -> bool:
    vis = mesh.visual
    return (getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None
            and getattr(getattr(vis, "material", None), "image", None) is not None)


def with_procedural_texture(mesh: trimesh.Trimesh, seed: int = 0) -> trimesh.Trimesh:
    """A copy of ``mesh`` with a cylindrical UV map and a procedural texture (for untextured meshes)."""
    from PIL import Image

    m = mesh.copy()
    v = m.vertices
    c = v.mean(axis=0)
    z0, z1 = v[:, 2].min(), v[:, 2].max()
    u = np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0]) / (2 * np.pi) + 0.5
    w = (v[:, 2] - z0) / max(z1 - z0, 1e-9)
    image = Image.fromarray(procedural_texture(512, seed))
    m.visual = trimesh.visual.TextureVisuals(uv=np.c_[u, w], image=image)
    return m


def export_textured_obj(mesh: trimesh.Trimesh, path: Path) -> Path:
    """Write ``mesh`` as OBJ with normals + MTL + PNG beside it, white diffuse so the texture shows as is."""
    from real2sim.geometry.mesh_io import export_textured_mesh

    path = export_textured_mesh(mesh, Path(path))
    for mtl in path.parent.glob("*.mtl"):
        lines = []
        for line in mtl.read_text().splitlines():
            key = line.split(" ", 1)[0]
            if key == "Kd":
                line = "Kd 1.0 1.0 1.0"
            elif key in ("Ks", "Ka"):
                line = f"{key} 0.0 0.0 0.0"
            lines.append(line)
        mtl.write_text("\n".join(lines) + "\n")
    return path
