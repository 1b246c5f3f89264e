"""Reconstruct stage: posed, masked images -> textured mesh in the dataset's world (robot) frame.

``stage`` chains the pieces: ``views`` (images, masks, cameras, checked),
``hull`` (visual hull: bounds, carving, its surface), ``field`` and ``train``
(voxel radiance field and its training), ``extract`` (marching cubes on the
density, or TSDF fusion of rendered depth), ``texture`` (xatlas unwrap, colours
from the field or the images), ``external`` (a nerfstudio mesh put back in the
world frame), ``truth`` (errors against a simulated capture's true object).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "ReconstructConfig": "stage",
    "Reconstruction": "stage",
    "reconstruct": "stage",
    "import_external": "stage",
    "write_reconstruction": "stage",
    "FieldConfig": "train",
    "train_field": "train",
    "VoxelRadianceField": "field",
    "load_views": "views",
    "visual_hull_mesh": "hull",
    "import_nerfstudio_mesh": "external",
    "compare_to_truth": "truth",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
