"""One recommendation per simulator and contact model, each on that group's measured Pareto front
(OCAE against simulation time), and what the user gives up with it.

A user simulates in one simulator with one contact model, so a pick among all rows (often a Drake
hydroelastic row) is no use to a MuJoCo user: :func:`recommend_per_group` picks among each
(simulator, contact model) group's rows alone, with :func:`real2sim.report.pareto.recommend`'s rules.
Those rules pick the best of a set closed under domination, so the pick is non-dominated in its group;
:func:`on_front` checks it and a pick that is not raises (it would be a bug, never a result).

:func:`trade_off` says what the pick costs against the group's most accurate row and against the
exact-geometry bound of the same group (``bound_mesh``, else ``bound_round``, else ``bound_hull``;
benchmarks/bench_table1.py --bounds adds them), when the rows hold one.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from real2sim.report.pareto import is_bound, is_reference_itself, pareto_front, recommend, simulator_of

#: The bounds a pick is compared with, closest to the exact object first.
BOUND_ORDER = ("bound_mesh", "bound_round", "bound_hull")
#: The preferences whose pick lies on the OCAE-against-time front.
FRONT_PREFERENCES = ("accuracy", "speed")


def groups(rows: Sequence[Mapping]) -> list[tuple[str, str]]:
    """The (simulator, contact model) pairs of ``rows``: Drake's first, then by name."""
    pairs = {(simulator_of(r), str(r.get("contact_model", ""))) for r in rows}
    return sorted(pairs, key=lambda p: (p[0] != "drake", p))


def group_rows(rows: Sequence[Mapping], simulator: str, contact_model: str) -> list[Mapping]:
    """The rows of one (simulator, contact model) group."""
    return [r for r in rows if simulator_of(r) == simulator and str(r.get("contact_model", "")) == contact_model]


def choosable(rows: Sequence[Mapping]) -> list[Mapping]:
    """The rows a recommendation chooses among: no bound, not the reference itself."""
    return [r for r in rows if not is_bound(r) and not is_reference_itself(r)]


def on_front(row: Mapping, rows: Sequence[Mapping], x_key: str = "sim_time_s", y_key: str = "ocae_m") -> bool:
    """True when ``row`` (one of ``rows``) is not dominated on (``x_key``, ``y_key``) by any of ``rows``."""
    points = np.array([[float(r.get(x_key, math.nan)), float(r.get(y_key, math.nan))] for r in rows], dtype=float)
    mask = pareto_front(points) if len(rows) else np.zeros(0, bool)
    return any(m and r is row for r, m in zip(rows, mask))


def recommend_per_group(rows: Sequence[Mapping], preferences: Sequence[str] = FRONT_PREFERENCES
                        ) -> dict[tuple[str, str], dict[str, Mapping]]:
    """``{(simulator, contact model): {preference: row}}``, each pick among that group's choosable rows
    (:func:`choosable`) and on their OCAE-against-time front (RuntimeError if a rule ever broke that)."""
    out: dict[tuple[str, str], dict[str, Mapping]] = {}
    for sim, cm in groups(rows):
        mine = choosable(group_rows(rows, sim, cm))
        picks = {}
        for pref in preferences:
            row = recommend(mine, pref)
            if row is None:
                continue
            if pref in FRONT_PREFERENCES and not on_front(row, mine):
                raise RuntimeError(f"the {pref} pick {row.get('representation')} is not on the {sim} {cm} front")
            picks[pref] = row
        if picks:
            out[(sim, cm)] = picks
    return out


def _ratio(a: float, b: float) -> float:
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else math.nan


def trade_off(row: Mapping, rows: Sequence[Mapping]) -> dict:
    """What ``row`` gives up within its (simulator, contact model) group of ``rows``:

    ``best``: the group's most accurate choosable row (lowest OCAE); ``ocae_over_best`` its OCAE
    ratio (>= 1), ``time_over_best`` the time ratio (< 1: the pick is faster). ``bound``: the group's
    exact-geometry bound row (:data:`BOUND_ORDER`) or None; ``ocae_over_bound``: the pick's OCAE over
    the bound's, ``ocae_gap_to_bound_m`` their difference, m."""
    sim, cm = simulator_of(row), str(row.get("contact_model", ""))
    mine = group_rows(rows, sim, cm)
    usable = [r for r in choosable(mine) if math.isfinite(float(r.get("ocae_m", math.nan)))]
    best = min(usable, key=lambda r: float(r["ocae_m"])) if usable else None
    bound = next((r for name in BOUND_ORDER for r in mine if str(r.get("collision")) == name
                  and math.isfinite(float(r.get("ocae_m", math.nan)))), None)
    ocae, time_s = float(row.get("ocae_m", math.nan)), float(row.get("sim_time_s", math.nan))
    return {
        "best": best,
        "ocae_over_best": _ratio(ocae, float(best["ocae_m"])) if best else math.nan,
        "time_over_best": _ratio(time_s, float(best["sim_time_s"])) if best else math.nan,
        "bound": bound,
        "ocae_over_bound": _ratio(ocae, float(bound["ocae_m"])) if bound else math.nan,
        "ocae_gap_to_bound_m": ocae - float(bound["ocae_m"]) if bound else math.nan,
    }


def describe_trade_off(row: Mapping, rows: Sequence[Mapping]) -> str:
    """:func:`trade_off` in one plain sentence (no markup)."""
    t = trade_off(row, rows)
    parts = []
    best = t["best"]
    if best is not None and best is not row and best.get("representation") != row.get("representation"):
        parts.append(f"OCAE x{t['ocae_over_best']:.2f} the group's most accurate {best['representation']} "
                     f"at x{t['time_over_best']:.2f} its time")
    elif best is not None:
        parts.append("nothing against the group's most accurate row (it is that row)")
    if t["bound"] is not None:
        parts.append(f"OCAE x{t['ocae_over_bound']:.2f} the exact-geometry bound {t['bound']['representation']} "
                     f"({t['ocae_gap_to_bound_m'] * 1000:+.2f} mm)")
    return "; ".join(parts)
