"""Shared geometry below the stages: inside tests and winding numbers, fidelity (IoU,
Chamfer), meshes of collision geometry, rotations, and the bundled procedural objects.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "inside_mask": "inside",
    "winding_numbers": "inside",
    "measure_fidelity": "fidelity",
    "union_mesh": "collision_mesh",
    "shape_mesh": "collision_mesh",
    "OBJECTS": "objects",
    "make_object": "objects",
    "export_object": "objects",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
