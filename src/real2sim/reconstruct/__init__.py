"""Reconstruct stage: posed, masked images -> textured mesh in the dataset's world (robot) frame.

``stage`` chains the pieces over :mod:`real2sim.multiview` (the views and the visual hull):
``field/`` (the voxel radiance field, its training, surface extraction and texture),
``carving/`` (photo carving), ``poses/`` (camera poses from silhouettes), ``external``
(a nerfstudio mesh put back in the world frame), ``truth`` (errors against a simulated
capture's true object).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "ReconstructConfig": "config",
    "Reconstruction": "stage",
    "reconstruct": "stage",
    "import_external": "stage",
    "write_reconstruction": "stage",
    "FieldConfig": "field.train",
    "train_field": "field.train",
    "VoxelRadianceField": "field.radiance",
    "import_nerfstudio_mesh": "external",
    "compare_to_truth": "truth",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
