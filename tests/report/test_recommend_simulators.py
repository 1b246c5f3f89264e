"""One recommendation per simulator and contact model, each on that group's measured Pareto front."""

from __future__ import annotations

import numpy as np

from real2sim.report.pareto import pareto_front, recommend
from real2sim.report.recommend import describe_trade_off, on_front, recommend_per_group, trade_off


def _row(collision, contact, simulator, ocae, time_s):
    label = f"{collision}_{contact}" + ("" if simulator == "drake" else f"_{simulator}")
    return {"representation": label, "collision": collision, "contact_model": contact, "simulator": simulator,
            "ocae_m": ocae, "ate_m": ocae / 10, "cpd_m_per_s": 0.1, "sim_time_s": time_s}


def _rows(seed: int = 0):
    """Random rows in three groups, each group's OCAE and time drawn so that its best rows differ from the
    others' (MuJoCo fast, Drake hydroelastic accurate), plus a bound and the reference itself."""
    rng = np.random.default_rng(seed)
    rows = []
    for sim, cm, scale_ocae, scale_t in (("drake", "point", 2.0, 1.0), ("drake", "hydroelastic", 1.0, 3.0),
                                         ("mujoco", "point", 1.5, 0.05)):
        for k in range(12):
            rows.append(_row(f"family_{k}", cm, sim, scale_ocae * (0.005 + 0.02 * rng.random()),
                             scale_t * (0.05 + rng.random())))
        rows.append(_row("bound_mesh", cm, sim, scale_ocae * 0.001, scale_t * 0.02))  # dominates all, never chosen
    rows.append(_row("mesh", "hydroelastic", "drake", 0.0, 2.0))  # the reference itself
    return rows


def test_each_pick_lies_on_its_own_groups_front():
    for seed in range(20):
        rows = _rows(seed)
        picks = recommend_per_group(rows)
        assert set(picks) == {("drake", "point"), ("drake", "hydroelastic"), ("mujoco", "point")}
        for (sim, cm), by_pref in picks.items():
            group = [r for r in rows if r["simulator"] == sim and r["contact_model"] == cm
                     and not r["collision"].startswith("bound_") and r["ocae_m"] > 0]
            pts = np.array([[r["sim_time_s"], r["ocae_m"]] for r in group])
            front = {group[i]["representation"] for i in np.flatnonzero(pareto_front(pts))}
            for pref, row in by_pref.items():
                assert row["simulator"] == sim and row["contact_model"] == cm
                assert row["representation"] in front, (seed, sim, cm, pref)
                assert on_front(row, group)
                # no row of the group is both at least as fast and at least as accurate, and better in one
                assert not any(r["sim_time_s"] <= row["sim_time_s"] and r["ocae_m"] <= row["ocae_m"]
                               and (r["sim_time_s"] < row["sim_time_s"] or r["ocae_m"] < row["ocae_m"])
                               for r in group)


def test_the_overall_pick_is_not_a_mujoco_users_pick():
    rows = _rows(3)
    overall = recommend(rows, "accuracy")
    assert overall["simulator"] == "drake"  # hydroelastic is the most accurate
    assert recommend_per_group(rows)[("mujoco", "point")]["accuracy"]["simulator"] == "mujoco"
    assert recommend(rows, "accuracy", simulator="mujoco")["simulator"] == "mujoco"


def test_what_the_pick_gives_up_against_the_best_row_and_the_bound():
    rows = [_row("a", "point", "mujoco", 0.010, 1.0), _row("b", "point", "mujoco", 0.0105, 0.2),
            _row("c", "point", "mujoco", 0.030, 0.1), _row("bound_mesh", "point", "mujoco", 0.004, 0.5),
            _row("a", "point", "drake", 0.001, 9.0)]
    pick = recommend_per_group(rows)[("mujoco", "point")]["accuracy"]
    assert pick["collision"] == "b"  # within 10 % of the best OCAE, and the fastest of those
    t = trade_off(pick, rows)
    assert t["best"]["collision"] == "a"  # the group's, not Drake's more accurate row
    assert t["ocae_over_best"] == 0.0105 / 0.010 and t["time_over_best"] == 0.2 / 1.0
    assert t["bound"]["collision"] == "bound_mesh" and t["ocae_gap_to_bound_m"] == 0.0105 - 0.004
    text = describe_trade_off(pick, rows)
    assert "a_point_mujoco" in text and "bound_mesh_point_mujoco" in text and "+6.50 mm" in text
    assert trade_off(_row("a", "point", "drake", 0.001, 9.0), rows)["bound"] is None
