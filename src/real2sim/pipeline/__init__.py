"""`real2sim run`: the stages chained over one dataset, resumable (:mod:`.run`, its settings in
:mod:`.run_config`, each stage's work in :mod:`.stages`), with a manifest (:mod:`.manifest`,
``ASSETDIR/.run/run.json``), the truth report of simulated captures (:mod:`.truth`, ``ASSETDIR/truth.json``),
a phone capture's own stages (:mod:`.phone`), and where the asset's bottom is closed (:mod:`.support`); one
stage is run, skipped or recorded, with its warnings, by :mod:`.runner`. `real2sim batch` (:mod:`.batch`,
:mod:`.catalogue`) runs many. The only package that imports several stages.
"""

from real2sim._lazy import lazy_exports

_EXPORTS = {
    "RunConfig": "run_config",
    "RunResult": "run_config",
    "RunProgress": "run",
    "StageFailed": "run",
    "run_pipeline": "run",
    "check_dataset": "run",
    "Manifest": "manifest",
    "build_truth": "truth",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
