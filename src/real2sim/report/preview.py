"""An asset's preview: its visual mesh beside the collision geometry of its representations, one
camera for all, each panel named. The picture in an asset folder's ``preview.png`` and the README's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Panels per row of a preview.
PANELS_PER_ROW = 4


def asset_preview(asset_dir: Path, representations: list[str] | None = None, panel_px: int = 240) -> np.ndarray:
    """RGB image (H, W, 3, uint8): the visual mesh, then each representation's collision geometry
    (all of them by default, in folder order), ``panel_px`` square panels with their names. Empty
    (0, 0, 3) when the asset has no readable visual mesh."""
    from PIL import Image, ImageDraw

    from real2sim.report.pictures import asset_picture_pngs

    import io

    pngs = asset_picture_pngs(Path(asset_dir), width_px=panel_px, height_px=panel_px)
    if "visual" not in pngs:
        return np.zeros((0, 0, 3), dtype=np.uint8)
    names = ["visual"] + [n for n in (representations or sorted(pngs)) if n != "visual" and n in pngs]
    cols = min(len(names), PANELS_PER_ROW)
    rows = (len(names) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * panel_px, rows * panel_px), "white")
    draw = ImageDraw.Draw(sheet)
    for k, name in enumerate(names):
        x, y = (k % cols) * panel_px, (k // cols) * panel_px
        sheet.paste(Image.open(io.BytesIO(pngs[name])).convert("RGB"), (x, y))
        draw.text((x + 6, y + 4), name if name != "visual" else "visual mesh", fill=(20, 20, 20))
    return np.asarray(sheet)


def write_asset_preview(asset_dir: Path, out_path: Path, representations: list[str] | None = None,
                        panel_px: int = 240) -> bool:
    """Write :func:`asset_preview` as a PNG at ``out_path`` (whole or not at all); False when the
    asset has no picture to show."""
    from PIL import Image

    from real2sim.plumbing.outputs import atomic_file

    image = asset_preview(asset_dir, representations, panel_px)
    if image.size == 0:
        return False
    with atomic_file(out_path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", optimize=True)
    return True
