"""How finely a circle must be cut into a polygon so that its flats stay shallow. Pure math."""

from __future__ import annotations

import math


def sections_for(radius_m: float, sagitta_m: float) -> int:
    """Sections (a multiple of 8, at least 8) of a polygon inscribed in a circle of ``radius_m``
    whose flats lie at most ``sagitta_m`` inside it: ``radius_m (1 - cos(pi / n)) <= sagitta_m``.

    A body that rolls on a polygon rolls on its flats
    (why: docs/design-notes/asset.md#bundled-objects-tessellation)."""
    if not (0 < sagitta_m < radius_m):
        raise ValueError(f"the sagitta must lie in (0, radius): {sagitta_m} m for radius {radius_m} m")
    n = math.ceil(math.pi / math.acos(1.0 - sagitta_m / radius_m))
    return max(8, -(-n // 8) * 8)
