"""bench_table1.py's verdicts of issue #66 on hand-made runs.csv rows with known answers."""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import bench_table1 as t1  # noqa: E402


def run(obj, rep, ocae_m, sim_time_s, cpd_paper, simulator="drake", contact_model="hydroelastic", task="push",
        error=""):
    """One runs.csv row as csv.DictReader gives it: every field text."""
    return {"object": obj, "representation": rep, "contact_model": contact_model, "simulator": simulator,
            "task": task, "run": "0", "ocae_m": str(ocae_m), "sim_time_s": str(sim_time_s),
            "cpd_paper": str(cpd_paper), "error": error}


def both_tasks(obj, rep, ocae_m, sim_time_s, cpd_paper, **kw):
    """Push and ramp rows whose means are the given values (ramp's OCAE 0.01 m above push's, means as given)."""
    return [run(obj, rep, ocae_m - 0.005, sim_time_s, cpd_paper, task="push", **kw),
            run(obj, rep, ocae_m + 0.005, sim_time_s, cpd_paper, task="ramp", **kw)]


ROWS = [
    *both_tasks("can", "coacd", 0.020, 1.0, 0.010),
    *both_tasks("can", "boxes_10", 0.015, 0.5, 0.008),      # faster, more accurate, smoother: a winner
    *both_tasks("can", "spheres_64", 0.030, 0.2, 0.005),    # faster but less accurate: excluded
    *both_tasks("can", "cylinders_10", 0.010, 0.3, 0.020),  # faster, most accurate, worse cpd_paper: excluded
    *both_tasks("can", "ellipsoids_64", 0.012, 2.0, 0.001),  # slower: excluded
    *both_tasks("can", "bound_mesh", 0.002, 0.1, 0.001),     # a bound: never a primitive
    *both_tasks("can", "bound_hull", 0.004, 0.1, 0.001),
    run("can", "boxes_10", 0.0, 0.0, 0.0, error="timeout"),  # a failed run stays out of the means
    *both_tasks("can", "coacd", 0.020, 1.0, 0.010, simulator="mujoco", contact_model="point"),
    *both_tasks("can", "spheres_64", 0.030, 0.2, 0.005, simulator="mujoco", contact_model="point"),
    *both_tasks("gear", "coacd", 0.010, 1.0, 0.010),
    *both_tasks("gear", "boxes_10", 0.020, 0.1, 0.001),     # faster but less accurate: gear has no winner
]


def test_object_means_average_runs_and_tasks_without_failed_rows():
    means = t1.object_means(ROWS)
    assert math.isclose(means[("can", "drake", "hydroelastic", "boxes_10")]["ocae_m"], 0.015)
    assert math.isclose(means[("can", "drake", "hydroelastic", "boxes_10")]["sim_time_s"], 0.5)
    assert ("can", "mujoco", "point", "coacd") in means


def test_faster_and_as_accurate_primitives_against_coacd():
    verdicts = {(v["object"], v["setting"]): v for v in t1.against_coacd(ROWS)}
    can = verdicts[("can", "drake hydroelastic")]
    assert can["winners"] == ["boxes_10"]
    assert can["best"] == "cylinders_10" and math.isclose(can["best_means"]["ocae_m"], 0.010)
    assert verdicts[("gear", "drake hydroelastic")]["winners"] == []
    assert verdicts[("can", "mujoco point")]["winners"] == []
    assert ("can", "drake point") not in verdicts  # no CoACD row there: not compared
    assert t1.setting_counts(list(verdicts.values())) == {"drake hydroelastic": (1, 2), "mujoco point": (0, 1)}
    assert t1.half_or_more(1, 2) and not t1.half_or_more(0, 1) and not t1.half_or_more(0, 0)


def test_cpd_paper_undefined_for_both_counts_as_no_worse():
    nan = float("nan")
    baseline = {"ocae_m": 0.02, "sim_time_s": 1.0, "cpd_paper": nan}
    assert t1.faster_and_as_accurate({"ocae_m": 0.02, "sim_time_s": 0.5, "cpd_paper": nan}, baseline)
    assert not t1.faster_and_as_accurate({"ocae_m": 0.02, "sim_time_s": 0.5, "cpd_paper": 0.001},
                                         {**baseline, "cpd_paper": 0.0})


def test_gap_share_to_bound_mesh():
    gaps = {g["object"]: g for g in t1.gap_rows(ROWS)}
    can = gaps["can"]
    # (0.020 - 0.010) / (0.020 - 0.002): the best primitive by OCAE is cylinders_10
    assert can["best"] == "cylinders_10" and math.isclose(can["share"], 0.010 / 0.018)
    assert math.isclose(can["bound_hull_ocae_m"], 0.004)
    gear = gaps["gear"]  # no bound rows: the share is undefined and stays out of the mean
    assert math.isnan(gear["bound_mesh_ocae_m"]) and math.isnan(gear["bound_hull_ocae_m"]) and math.isnan(gear["share"])
    share, count = t1.mean_share(list(gaps.values()))
    assert count == 1 and math.isclose(share, 0.010 / 0.018)
    assert math.isnan(t1.gap_share(0.01, 0.005, 0.02))  # CoACD already better than the bound: no gap


def test_primitive_rows_and_coacd_fit_report():
    assert t1.is_primitive("spheres_64_hint0.01") and t1.is_primitive("boxes_10_polytopes")
    assert not any(t1.is_primitive(r) for r in ("coacd", "vhacd", "mesh", "bound_mesh", "bound_round"))
    assert t1.coacd_fit({"num_primitives": 7, "num_pieces": 7, "fit_seconds": 3.5}) == (7, 3.5)
    hulls, fit_s = t1.coacd_fit({"num_pieces": 2})
    assert hulls == 2 and math.isnan(fit_s)


def test_verdict_sections_state_the_targets(tmp_path):
    build = tmp_path / "build" / "can" / "coacd" / "coacd"
    build.mkdir(parents=True)
    (build / "fit_report.json").write_text('{"num_primitives": 3, "fit_seconds": 1.25}')
    text = t1.verdict_sections(ROWS, tmp_path, ["can", "gear"], bounds=True)
    assert "- drake hydroelastic: 1 of 2 objects have one; target (at least half): met" in text
    assert "- mujoco point: 0 of 1 objects have one; target (at least half): not met" in text
    assert "mean share over 1 objects: 0.556; target (at least 0.5): met" in text
    assert "| can | 3 | 1.25 |" in text


def test_object_names_expand_the_shape_set():
    names = t1.object_names("bottle,shapes,carton")
    assert names[0] == "bottle" and names[-1] == "carton" and "mug_side" in names and "gear" in names
    assert len(names) == len(set(names))
