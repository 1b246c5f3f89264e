"""Asset stage: mesh + mass -> ASSETDIR (canonical pose, flat bottom, inertia, one collision
representation per SPEC through :mod:`real2sim.collision`, URDF / SDFormat writers).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "AssetConfig": "config",
    "AssetResult": "build",
    "RepresentationResult": "build",
    "build_asset": "build",
    "build_collision": "fits",
    "write_representation": "export.writers",
    "build_urdf": "export.writers",
    "build_sdf": "export.writers",
    "canonical_transform": "canonical",
    "canonicalize": "canonical",
    "close_flat_bottom": "bottom",
    "estimate_physical_properties": "inertia",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
