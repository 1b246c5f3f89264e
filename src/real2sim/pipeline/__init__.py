"""`real2sim run`: the stages chained over one dataset, resumable (:mod:`.run`), with a manifest
(:mod:`.manifest`, ``ASSETDIR/.run/run.json``) and the truth report of simulated captures
(:mod:`.truth`, ``ASSETDIR/truth.json``), the robot frame of a COLMAP capture (:mod:`.normalise`,
math in :mod:`.robot_frame`), and where the asset's bottom is closed (:mod:`.support`); one stage is
run, skipped or recorded, with its warnings, by :mod:`.runner`. The only package that imports several stages.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "RunConfig": "run",
    "RunResult": "run",
    "RunProgress": "run",
    "StageFailed": "run",
    "run_pipeline": "run",
    "check_dataset": "run",
    "Manifest": "manifest",
    "build_truth": "truth",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
