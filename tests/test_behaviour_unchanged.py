"""The same files with the same numbers as recorded before the source tree was regrouped (tests/golden/).

Three fixed small pipelines run through the command line only (the `real2sim` console script in a
subprocess: no internal module is imported, so moving modules cannot break this test): a seeded robot
capture of the can -> run (visual hull), a seeded phone capture on the board -> run (SfM, board frame,
parallax masks, hull), and asset of the bottle with every collision family and model format. Each output
file is compared with tests/golden/<pipeline>.json under the rules of tests/golden/record.py: byte for byte
where the recorder found the file byte-stable, else by its numbers. After an intended change of behaviour,
re-record: `.venv/bin/python -m tests.golden.record [--only NAME]`, and say why in the commit.
"""

from __future__ import annotations

import json

import pytest

from tests.golden.record import NONDETERMINISTIC, PIPELINES, compare_outputs, golden_path, run_pipeline

MAX_LINES = 60

CASES = [
    pytest.param("robot_capture", id="robot_capture"),
    # 45-55 s here on 2 cores, ~75 CPU seconds (COLMAP takes every core; the parallax masks of 60 photos
    # alone ~26 s), and only partly comparable (NONDETERMINISTIC): the slow suite's
    pytest.param("phone_capture", id="phone_capture", marks=pytest.mark.slow),
    pytest.param("asset", id="asset"),
]


@pytest.fixture(scope="module", params=CASES)
def produced(request, tmp_path_factory):
    """(pipeline name, its recorded expectations, the folder it wrote now): each pipeline runs once."""
    name = request.param
    golden = json.loads(golden_path(name).read_text())
    assert golden["commands"] == PIPELINES[name], (
        f"{name}: the commands in tests/golden/record.py are not the recorded ones; "
        f"re-record: .venv/bin/python -m tests.golden.record --only {name}")
    root = tmp_path_factory.mktemp(f"golden-{name}") / name
    run_pipeline(name, root)
    return name, golden, root


def test_outputs_are_the_recorded_ones(produced):
    name, golden, root = produced
    problems = compare_outputs(golden, root)
    shown = problems[:MAX_LINES] + ([f"... and {len(problems) - MAX_LINES} more"]
                                    if len(problems) > MAX_LINES else [])
    note = f"\n(nondeterministic there: {NONDETERMINISTIC[name]})" if name in NONDETERMINISTIC else ""
    assert not problems, (f"pipeline {name}: {len(problems)} differences from tests/golden/{name}.json "
                          f"(outputs in {root}):\n  " + "\n  ".join(shown) + note)
