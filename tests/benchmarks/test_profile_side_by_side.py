"""bench_profile.py's before/now table: phases matched within their own stage, never across stages."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import bench_profile as bp  # noqa: E402


def test_phases_of_the_same_name_stay_in_their_stages():
    before = [["**evaluate**", "", 46.0, 84.0, 15.0], ["", "candidate simulations", 30.0, 60.0, 10.0],
              ["", "done", 3.0, 3.0, 1.0],
              ["**evaluate_truth**", "", 52.0, 92.0, 17.0], ["", "candidate simulations", 45.0, 81.0, 14.0],
              ["**total**", "", 98.0, 176.0, 100.0]]
    after = [["**evaluate**", "", 40.0, 80.0, 14.0], ["", "candidate simulations", 25.0, 50.0, 9.0],
             ["**evaluate_truth**", "", 50.0, 90.0, 17.0], ["", "candidate simulations", 44.0, 80.0, 15.0],
             ["", "done", 4.0, 4.0, 1.0],
             ["**asset**", "", 7.0, 7.0, 2.0],
             ["**total**", "", 97.0, 177.0, 100.0]]
    rows = bp.side_by_side(before, after)
    assert rows == [
        ["**evaluate**", "", 46.0, 40.0, 84.0, 80.0],
        ["", "candidate simulations", 30.0, 25.0, 60.0, 50.0],
        ["", "done", 3.0, "", 3.0, ""],  # only before had it: under its own stage
        ["**evaluate_truth**", "", 52.0, 50.0, 92.0, 90.0],
        ["", "candidate simulations", 45.0, 44.0, 81.0, 80.0],
        ["", "done", "", 4.0, "", 4.0],
        ["**asset**", "", "", 7.0, "", 7.0],
        ["**total**", "", 98.0, 97.0, 176.0, 177.0],  # last
    ]
