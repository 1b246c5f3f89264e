"""Capture stage: posed RGB images (+ masks) of an object, simulated wrist-camera capture in
Drake (:mod:`.sim.wrist_camera`), COLMAP pose refinement (:mod:`.poses.refinement`) and
segmentation masks (:mod:`.masks.methods`). Writes a dataset folder (:mod:`real2sim.formats.dataset`).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "CaptureConfig": "sim.capture_config",
    "CaptureResult": "sim.capture_config",
    "capture": "sim.wrist_camera",
    "camera_poses": "sim.wrist_camera",
    "RefineConfig": "poses.refine_config",
    "RefineResult": "poses.refine_config",
    "refine_poses": "poses.refinement",
    "MaskConfig": "masks.methods",
    "MaskResult": "masks.methods",
    "compute_masks": "masks.methods",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
