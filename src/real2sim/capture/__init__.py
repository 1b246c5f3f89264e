"""Capture stage: posed RGB images (+ masks) of an object, simulated wrist-camera capture in
Drake (:mod:`.wrist_camera`), COLMAP pose refinement (:mod:`.pose_refinement`) and
segmentation masks (:mod:`.masking`). Writes a dataset folder (:mod:`real2sim.formats.dataset`).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "CaptureConfig": "wrist_camera",
    "CaptureResult": "wrist_camera",
    "capture": "wrist_camera",
    "camera_poses": "wrist_camera",
    "RefineConfig": "pose_refinement",
    "RefineResult": "pose_refinement",
    "refine_poses": "pose_refinement",
    "MaskConfig": "masking",
    "MaskResult": "masking",
    "compute_masks": "masking",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
