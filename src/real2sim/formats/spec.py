"""Collision SPEC strings: ``spheres:128``, ``boxes:20+cylinders:20``, ``coacd``.

A SPEC names one collision representation. Its canonical name on disk turns
``:`` and ``+`` into ``_`` (``boxes_20_cylinders_20``), matching the paper's Table I.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from real2sim.plumbing.errors import UserInputError

# SPEC family -> primitive kind used in collision.json and by the fitter.
PRIMITIVE_FAMILIES: dict[str, str] = {
    "spheres": "sphere",
    "boxes": "box",  # axis-aligned in the asset frame
    "rotated_boxes": "rotated_box",  # free orientation
    "cylinders": "cylinder",
    "ellipsoids": "ellipsoid",
    "capsules": "capsule",
    "superquadrics": "superquadric",  # beyond the paper; simulated as convex mesh pieces
}
BASELINES: tuple[str, ...] = ("coacd", "vhacd", "mesh")
MAX_PRIMITIVES = 2000

_PART = re.compile(r"^([a-z_]+):(\d+)$")


@dataclass(frozen=True)
class CollisionSpec:
    """A parsed SPEC.

    ``parts`` holds ``(family, count)`` pairs for primitive fits (empty for a baseline);
    ``baseline`` is one of BASELINES or None.
    """

    text: str
    parts: tuple[tuple[str, int], ...] = ()
    baseline: str | None = None

    @property
    def name(self) -> str:
        """Canonical folder name: ``boxes:20+cylinders:20`` -> ``boxes_20_cylinders_20``."""
        return self.text.replace(":", "_").replace("+", "_")

    @property
    def is_primitive_fit(self) -> bool:
        return self.baseline is None

    @property
    def num_primitives(self) -> int:
        return sum(count for _, count in self.parts)


def parse_spec(text: str) -> CollisionSpec:
    """Parse one SPEC; raise UserInputError with a one-line reason when it is malformed."""
    text = text.strip()
    if text in BASELINES:
        return CollisionSpec(text=text, baseline=text)
    if not text:
        raise UserInputError("empty collision SPEC")
    parts: list[tuple[str, int]] = []
    for piece in text.split("+"):
        match = _PART.match(piece)
        if match is None:
            raise UserInputError(
                f"malformed collision SPEC {text!r}: expected FAMILY:COUNT joined by '+' "
                f"(families: {', '.join(PRIMITIVE_FAMILIES)}) or one of {', '.join(BASELINES)}"
            )
        family, count = match.group(1), int(match.group(2))
        if family not in PRIMITIVE_FAMILIES:
            raise UserInputError(
                f"unknown primitive type {family!r} in SPEC {text!r}; "
                f"known: {', '.join(PRIMITIVE_FAMILIES)} (baselines: {', '.join(BASELINES)})"
            )
        if any(f == family for f, _ in parts):
            raise UserInputError(f"primitive type {family!r} appears twice in SPEC {text!r}")
        parts.append((family, count))
    total = sum(c for _, c in parts)
    if any(c < 1 for _, c in parts) or total > MAX_PRIMITIVES:
        raise UserInputError(
            f"SPEC {text!r}: each count must be at least 1 and the total at most {MAX_PRIMITIVES}"
        )
    return CollisionSpec(text=text, parts=tuple(parts))
