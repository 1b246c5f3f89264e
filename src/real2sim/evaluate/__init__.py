"""Evaluate stage: assets -> RESULTS (Drake pushing and ramp tasks, reference against every
representation and contact model, equation-error metrics, the resumable sweep).
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "EvaluationConfig": "sweep",
    "EvaluationResult": "sweep",
    "evaluate": "sweep",
    "discover_representations": "discovery",
    "score": "scoring",
    "Trajectory": "simulate",
    "simulate_reference": "simulate",
    "simulate_candidate": "simulate",
    "SceneConfig": "scene.scene_config",
    "RunSpec": "scene.tasks",
    "make_run_specs": "scene.tasks",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
