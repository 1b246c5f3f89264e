"""Pictures for the report: every representation's collision geometry beside the visual mesh.

One camera per asset (from the visual mesh's bounds, the same azimuth and elevation
for every asset), so the pictures of one asset line up. Each collision shape has its
own colour; convex pieces and primitives are drawn as the meshes the fidelity
measurement uses (:func:`real2sim.geometry.collision_mesh.shape_mesh`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from real2sim.plumbing.outputs import write_bytes_atomic

PICTURE_DIRNAME = "pictures"


def _png_bytes(image: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()


def asset_picture_pngs(asset_dir: Path, width_px: int = 320, height_px: int = 240) -> dict[str, bytes]:
    """PNG bytes of the visual mesh ("visual") and of every representation's collision geometry, one
    camera for all. Representations whose files cannot be read are left out (the report says so);
    an asset without a readable visual mesh has no pictures at all."""
    import trimesh

    from real2sim.formats.collision import read_collision_json
    from real2sim.geometry.collision_mesh import shape_mesh
    from real2sim.geometry.picture import SHAPE_COLOURS, look_at_camera, render_picture

    asset_dir = Path(asset_dir)
    try:
        visual = trimesh.load(asset_dir / "visual" / "model.obj", process=False, force="mesh")
    except Exception:  # noqa: BLE001 -- no visual mesh: no pictures for this asset, the report goes on
        return {}
    camera = look_at_camera(visual.bounds, width_px=width_px, height_px=height_px)
    pictures = {"visual": _png_bytes(render_picture([(visual, None)], camera))}
    for collision_json in sorted(asset_dir.glob("*/collision.json")):
        rep_dir = collision_json.parent
        try:
            geometry = read_collision_json(collision_json)
            parts = [(shape_mesh(shape, rep_dir), SHAPE_COLOURS[k % len(SHAPE_COLOURS)])
                     for k, shape in enumerate(geometry.shapes)]
        except Exception:  # noqa: BLE001 -- one unreadable representation must not cost the others their pictures
            continue
        pictures[rep_dir.name] = _png_bytes(render_picture(parts, camera))
    return pictures


def asset_pictures(asset_dir: Path, out_dir: Path, width_px: int = 320, height_px: int = 240) -> dict[str, Path]:
    """Write :func:`asset_picture_pngs` as ``out_dir/<asset>__<name>.png``; return {name: path}."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = {}
    for name, data in asset_picture_pngs(asset_dir, width_px, height_px).items():
        written[name] = out_dir / f"{Path(asset_dir).name}__{name}.png"
        write_bytes_atomic(written[name], data)
    return written
