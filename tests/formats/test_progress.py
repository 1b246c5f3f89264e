"""The progress protocol's helpers (real2sim.plumbing.progress)."""

from __future__ import annotations

from real2sim.plumbing.progress import null_progress, prefixed
from tests.progress_check import Recorder


def test_prefixed_names_the_sub_stage_and_keeps_the_counts():
    progress = Recorder()
    inner = prefixed(progress, "collision boxes:3")
    inner("fit", 10, 100)
    inner("", 0, 0)
    assert progress.check() == [("collision boxes:3: fit", 10, 100), ("collision boxes:3", 0, 0)]
    prefixed(None, "nowhere")("fit", 1, 2)  # no progress given: reports nowhere
    assert null_progress("anything", 1, 2) is None
