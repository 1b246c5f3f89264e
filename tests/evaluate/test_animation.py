"""Animations of a sweep: one self-contained page per task, linked from the report."""

from __future__ import annotations

import re

from real2sim.evaluate.sweep import EvaluationConfig, evaluate
from real2sim.formats.collision import CollisionGeometry, CollisionShape, write_collision_json
from tests.evaluate.test_sweep import BOX_EXTENTS_M, SHORT_SCENE, make_box_asset


def test_one_self_contained_page_per_task_linked_from_the_report(tmp_path):
    box = make_box_asset(tmp_path / "box", reps=("boxes_1_x1p2",))  # not the reference itself: it is recommended
    shape = CollisionShape("box", tuple(float(v) * 1.2 for v in BOX_EXTENTS_M))
    write_collision_json(CollisionGeometry("boxes_1_x1p2", "boxes:1", (shape,)), box / "boxes_1_x1p2" / "collision.json")
    config = EvaluationConfig(tasks=("push", "ramp"), contact_models=("point",), runs=1, jobs=1, scene=SHORT_SCENE)
    result = evaluate([box], tmp_path / "results", config, animations=True)
    pages = sorted(p.name for p in (result.out_dir / "animations").glob("*.html"))
    assert pages == ["push.html", "ramp.html"]
    for name in pages:
        page = (result.out_dir / "animations" / name).read_text()
        assert "boxes_1_x1p2" in page and len(page) > 100_000  # the viewer's JavaScript is inlined
        assert not re.search(r"<script[^>]+src=[\"']https?:", page)  # nothing fetched to run it
    report = result.report_path.read_text()
    assert "href='animations/push.html'" in report and "href='animations/ramp.html'" in report
    # Without the option, no animations and no section.
    plain = evaluate([box], tmp_path / "plain", config)
    assert not (plain.out_dir / "animations").exists() and "animations/" not in plain.report_path.read_text()
