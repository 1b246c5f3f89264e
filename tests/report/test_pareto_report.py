"""Pareto fronts, recommendations, summary and report.html on hand-made runs."""

from __future__ import annotations

import csv
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from real2sim.plumbing.errors import UserInputError
from real2sim.formats.results import RUN_COLUMNS, SUMMARY_COLUMNS, read_summary_csv, summarize, write_csv_atomic
from real2sim.report.pareto import PARETO_PLOTS, front_rows, pareto_front, recommend, recommend_per_contact_model
from real2sim.report.html import paper_name, read_paper_table, write_report


def test_pareto_front_small():
    pts = np.array([[1, 5], [2, 2], [3, 3], [5, 1], [2, 2], [4, 4], [np.nan, 0.1]], dtype=float)
    mask = pareto_front(pts)
    # (3,3) and (4,4) are dominated by (2,2); duplicates of a front point both stay; NaN never on it.
    assert mask.tolist() == [True, True, False, True, True, False, False]


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 10), st.floats(0, 10), st.floats(0, 10)), min_size=1, max_size=25))
def test_pareto_front_matches_definition(points):
    pts = np.array(points, dtype=float)
    mask = pareto_front(pts)
    for i, p in enumerate(pts):
        dominated = any(np.all(q <= p) and np.any(q < p) for q in pts)
        assert mask[i] == (not dominated)
    assert mask.any()  # a finite non-empty set always has a front


def _summary_rows():
    # (label, ocae, ate, cpd, time)
    data = [
        ("boxes_1_point", 0.10, 0.008, 0.014, 0.20),
        ("cylinders_10_hydroelastic", 0.024, 0.0026, 0.011, 0.49),
        ("boxes_150_hydroelastic", 0.020, 0.0013, 0.0085, 1.03),
        ("coacd_hydroelastic", 0.033, 0.0026, 0.0093, 1.01),  # dominated by cylinders_10 (Fig. 9)
        ("spheres_128_hydroelastic", 0.0396, 0.0031, 0.0025, 1.20),
        ("boxes_400_hydroelastic", 0.0174, 0.0013, 0.0099, 4.86),
    ]
    return [dict(representation=n, ocae_m=o, ate_m=a, cpd_m_per_s=c, sim_time_s=t) for n, o, a, c, t in data]


def test_front_rows_reproduce_the_papers_example():
    rows = _summary_rows()
    front = [r["representation"] for r in front_rows(rows, "sim_time_s", "ocae_m")]
    assert "coacd_hydroelastic" not in front
    assert front == ["boxes_1_point", "cylinders_10_hydroelastic", "boxes_150_hydroelastic", "boxes_400_hydroelastic"]


def test_recommendations_follow_their_rules_and_are_pareto_optimal():
    rows = _summary_rows()
    acc = recommend(rows, "accuracy")
    # Best OCAE 0.0174; within x1.10 (<= 0.01914) only boxes_400 qualifies.
    assert acc["representation"] == "boxes_400_hydroelastic"
    # With a looser tolerance boxes_150 (0.020, 5x faster) becomes the accurate choice.
    assert recommend(rows, "accuracy", accuracy_tolerance=1.2)["representation"] == "boxes_150_hydroelastic"
    # Fastest 0.20 s; within x1.25 only boxes_1; a loose tolerance admits cylinders_10.
    assert recommend(rows, "speed")["representation"] == "boxes_1_point"
    assert recommend(rows, "speed", speed_tolerance=3.0)["representation"] == "cylinders_10_hydroelastic"
    # OCAE within x1.5 of 0.0174 (<= 0.0261): lowest CPD there is boxes_150 (spheres are too inaccurate).
    assert recommend(rows, "smoothness")["representation"] == "boxes_150_hydroelastic"
    assert recommend(rows, "smoothness", smoothness_tolerance=3.0)["representation"] == "spheres_128_hydroelastic"
    for pref, (x, y) in (("accuracy", ("sim_time_s", "ocae_m")), ("speed", ("sim_time_s", "ocae_m")),
                         ("smoothness", ("ocae_m", "cpd_m_per_s"))):
        names = [r["representation"] for r in front_rows(rows, x, y)]
        assert recommend(rows, pref)["representation"] in names
    with pytest.raises(ValueError):
        recommend(rows, "beauty")
    assert recommend([], "accuracy") is None


def test_paper_names():
    assert paper_name("boxes_20_cylinders_20", "point") == "mixed_20boxes_20cylinders_point"
    assert paper_name("boxes_100_cylinders_50", "hydroelastic") == "mixed_100boxes_50cylinders_hydroelastic"
    assert paper_name("rotated_boxes_50", "point") == "rotated_boxes_50_point"
    assert paper_name("coacd", "hydroelastic") == "coacd_hydroelastic"
    table = read_paper_table()
    assert len(table) == 64
    assert table["boxes_400_hydroelastic"]["ate_m"] == pytest.approx(0.0013)
    assert paper_name("boxes_20_cylinders_20", "hydroelastic") in table


def _runs():
    """Hand-made runs.csv rows: 2 objects x 2 tasks x 2 runs for two representations, one failure."""
    rows = []
    base = {"boxes_10": (0.04, 0.003, 0.008, 0.3), "spheres_64": (0.03, 0.002, 0.004, 0.9)}
    for (rep, (o, a, c, t)), cm, obj, task, run in itertools.product(
        base.items(), ("point", "hydroelastic"), ("can", "bottle"), ("push", "ramp"), (0, 1)
    ):
        k = 1.0 + 0.1 * run + (0.5 if cm == "point" else 0.0)
        rows.append(dict(object=obj, representation=rep, contact_model=cm, task=task, run=run,
                         ate_m=a * k, ocae_m=o * k, cpd_m_per_s=c * k, sim_time_s=t * k, sim_duration_s=1.5,
                         real_time_factor=1.5 / (t * k), error=""))
    rows[0] = dict(rows[0], ate_m=math.nan, ocae_m=math.nan, cpd_m_per_s=math.nan, sim_time_s=math.nan,
                   real_time_factor=math.nan, error="SimulationError: exploded at t=0.3 s")
    return rows


def test_a_report_rewritten_on_the_same_runs_keeps_its_plots_and_redraws_them_when_runs_change(tmp_path):
    """run rewrites an evaluation's report once truth.json and the warnings are known: the runs are the
    same, so the plots are taken as they are; runs that changed get new plots."""
    rows = _runs()
    write_csv_atomic(tmp_path / "runs.csv", rows, RUN_COLUMNS)
    write_report(tmp_path)
    first = PARETO_PLOTS[0][2]
    marker = Image.new("RGB", (400, 400), (255, 0, 0))
    marker.save(tmp_path / first)  # stands for the plot drawn the first time
    marked = (tmp_path / first).read_bytes()
    text = write_report(tmp_path).read_text()
    assert (tmp_path / first).read_bytes() == marked
    assert text.count("data:image/png;base64,") == len(PARETO_PLOTS)
    write_csv_atomic(tmp_path / "runs.csv", [dict(r, ocae_m=2 * r["ocae_m"]) for r in rows], RUN_COLUMNS)
    write_report(tmp_path)
    assert (tmp_path / first).read_bytes() != marked  # drawn again from the new runs
    with Image.open(tmp_path / first) as im:
        assert im.size[0] > 300 and im.getpixel((im.size[0] // 2, 5)) != (255, 0, 0)
    assert not list(tmp_path.glob(".*tmp*"))


def test_summarize_means_and_failures():
    rows = _runs()
    summary = {r["representation"]: r for r in summarize(rows)}
    assert set(summary) == {"boxes_10_point", "boxes_10_hydroelastic", "spheres_64_point", "spheres_64_hydroelastic"}
    s = summary["spheres_64_hydroelastic"]
    assert s["runs_ok"] == 8 and s["runs_failed"] == 0
    assert s["ocae_m"] == pytest.approx(0.03 * 1.05)  # mean of k over runs 0 and 1
    assert s["sim_time_s"] == pytest.approx(0.9 * 1.05)
    assert s["real_time_factor"] == pytest.approx(8 * 1.5 / (8 * 0.9 * 1.05))
    b = summary["boxes_10_point"]
    assert b["runs_ok"] == 7 and b["runs_failed"] == 1
    assert math.isfinite(b["ocae_m"])  # the failed row is excluded, not propagated as NaN


def test_report_written_from_runs_csv(tmp_path):
    rows = _runs()
    write_csv_atomic(tmp_path / "runs.csv", rows, RUN_COLUMNS)
    report = write_report(tmp_path)
    assert report == tmp_path / "report.html"
    text = report.read_text()
    assert "spheres_64_hydroelastic" in text and "Recommendations" in text
    assert text.count("data:image/png;base64,") == len(PARETO_PLOTS)
    assert "exploded at t=0.3 s" in text  # failures are listed
    for _x, _y, name, _fig in PARETO_PLOTS:
        with Image.open(tmp_path / name) as im:
            assert im.size[0] > 300 and im.size[1] > 300
    with open(tmp_path / "summary.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == SUMMARY_COLUMNS
    assert header[:5] == ["representation", "ocae_m", "ate_m", "cpd_m_per_s", "sim_time_s"]  # Table I
    summary = read_summary_csv(tmp_path / "summary.csv")
    assert [r["representation"] for r in summary] == sorted(r["representation"] for r in summary)
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary files left behind


def test_report_bad_input(tmp_path):
    with pytest.raises(UserInputError):
        write_report(tmp_path / "missing")
    with pytest.raises(UserInputError):
        write_report(tmp_path)  # no runs.csv
    (tmp_path / "runs.csv").write_text("a,b\n1,2\n")
    with pytest.raises(UserInputError):
        write_report(tmp_path)


def test_recommend_skips_the_reference_itself():
    rows = _summary_rows() + [dict(representation="mesh_hydroelastic", ocae_m=2e-16, ate_m=9e-18, cpd_m_per_s=0.001,
                                   sim_time_s=0.3)]
    assert recommend(rows, "accuracy")["representation"] == "boxes_400_hydroelastic"
    assert recommend(rows, "smoothness")["representation"] == "boxes_150_hydroelastic"
    assert recommend(rows, "accuracy", exclude_reference=False)["representation"] == "mesh_hydroelastic"


def test_recommendation_per_contact_model_picks_the_best_point_row():
    """A point-contact user (MuJoCo, Isaac Sim, PyBullet) gets the pick among point rows: overall the
    hydroelastic rows win, and a hydroelastic pick is no use in a simulator without that model."""
    data = [  # (collision, contact model, OCAE m, ATE m, CPD m/s, s): Table I's shape (benchmarks/results/table1.md)
        ("ellipsoids_64", "hydroelastic", 0.0089, 0.0005, 0.24, 5.9),
        ("coacd", "hydroelastic", 0.0119, 0.0009, 0.39, 0.78),
        ("cylinders_10", "hydroelastic", 0.0168, 0.0007, 0.62, 1.2),
        ("ellipsoids_64", "point", 0.0169, 0.0011, 0.29, 0.41),
        ("coacd", "point", 0.0230, 0.0014, 0.17, 0.21),
        ("boxes_10", "point", 0.0453, 0.0024, 1.68, 0.21),
        ("boxes_1", "point", 0.1887, 0.0152, 1.16, 0.16),
    ]
    rows = [dict(representation=f"{c}_{m}", collision=c, contact_model=m, ocae_m=o, ate_m=a, cpd_m_per_s=p,
                 sim_time_s=t) for c, m, o, a, p, t in data]
    assert recommend(rows, "accuracy")["representation"] == "ellipsoids_64_hydroelastic"
    assert recommend(rows, "accuracy", contact_model="point")["representation"] == "ellipsoids_64_point"
    assert recommend(rows, "accuracy", contact_model="hydroelastic")["representation"] == "ellipsoids_64_hydroelastic"
    # Within x1.25 of the fastest point row (0.16 s, so up to 0.20 s) there is only boxes_1; at x1.4 coacd joins.
    assert recommend(rows, "speed", contact_model="point")["representation"] == "boxes_1_point"
    assert recommend(rows, "speed", contact_model="point", speed_tolerance=1.4)["representation"] == "coacd_point"
    assert recommend(rows, "accuracy", contact_model="none") is None
    by_model = recommend_per_contact_model(rows)
    assert by_model["point"]["accuracy"]["representation"] == "ellipsoids_64_point"
    assert by_model["point"]["speed"]["representation"] == "boxes_1_point"
    assert recommend_per_contact_model([r for r in rows if r["contact_model"] == "point"]) == {}


def test_report_names_the_pick_of_each_contact_model(tmp_path):
    write_csv_atomic(tmp_path / "runs.csv", _runs(), RUN_COLUMNS)
    text = write_report(tmp_path).read_text()
    # Overall the hydroelastic rows win (the point runs are 1.5x worse in _runs); the point user still gets one.
    assert "point contact only" in text and "hydroelastic contact only" in text
    point_item = next(line for line in text.splitlines() if "point contact only" in line)
    assert "spheres_64_point" in point_item and "_hydroelastic" not in point_item
