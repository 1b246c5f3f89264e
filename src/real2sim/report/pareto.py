"""Pareto fronts, the paper's trade-off plots (Figs. 9, 11-13), and recommendations.

Every metric here is "lower is better" (OCAE, ATE, CPD, simulation time), so a point
is Pareto-optimal when no other point is at least as low on both axes and strictly
lower on one. The plots keep matplotlib's usual orientation -- both axes log scale,
values growing up and to the right -- so **better is down and to the left** (the paper's
Fig. 9 flips both axes so that better is up and to the right; the front is the same).

Summary rows are dicts as written to ``summary.csv``: ``representation`` (the
``<collision>_<contactmodel>[_<simulator>]`` label), ``ocae_m``, ``ate_m``, ``cpd_m_per_s``, ``sim_time_s``,
``collision``, ``contact_model`` and ``simulator`` (absent: Drake's). With rows of several simulators
each plot draws each simulator's own front (its rows alone), since a user simulates in one of them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from real2sim.plumbing.outputs import atomic_file

# (x metric, y metric, file name, paper figure)
PARETO_PLOTS: tuple[tuple[str, str, str, str], ...] = (
    ("sim_time_s", "ocae_m", "pareto_ocae_vs_time.png", "Fig. 9"),
    ("sim_time_s", "ate_m", "pareto_ate_vs_time.png", "Fig. 11"),
    ("ocae_m", "cpd_m_per_s", "pareto_cpd_vs_ocae.png", "Fig. 12"),
    ("sim_time_s", "cpd_m_per_s", "pareto_cpd_vs_time.png", "Fig. 13"),
)
AXIS_LABELS = {
    "sim_time_s": "simulation time per run [s]",
    "ocae_m": "OCAE [m]",
    "ate_m": "ATE [m]",
    "cpd_m_per_s": "CPD [m/s]",
}

# Recommendation tolerances (see :func:`recommend`).
ACCURACY_TOLERANCE = 1.10  # accept OCAE within 10 % of the best, then take the fastest
SPEED_TOLERANCE = 1.25  # accept time within 25 % of the fastest, then take the most accurate
SMOOTHNESS_OCAE_TOLERANCE = 1.5  # accept OCAE within 50 % of the best, then take the lowest CPD
PREFERENCES = ("accuracy", "speed", "smoothness")
REFERENCE_TOLERANCE_M = 1e-9  # below this OCAE and ATE a row reproduces the reference
BOUND_PREFIX = "bound_"  # benchmarks' exact-geometry rows (bound_mesh, bound_hull, bound_round): bounds, not fits
#: Marker per (simulator, contact model); any other pair is a square.
MARKERS = {("drake", "point"): "o", ("drake", "hydroelastic"): "^", ("mujoco", "point"): "D"}
FRONT_STYLES = {"drake": "-", "mujoco": "--"}


def simulator_of(row: Mapping) -> str:
    """The row's simulator; a row written before the column existed is Drake's."""
    return str(row.get("simulator") or "drake")


def is_bound(row: Mapping) -> bool:
    """True for an exact-geometry bound row (``bound_mesh``, ``bound_hull``, ``bound_round``): what a
    perfect fit could reach, never a representation to choose."""
    return str(row.get("collision", "")).startswith(BOUND_PREFIX)


def is_reference_itself(row: Mapping) -> bool:
    """True when a summary row reproduces the reference (both OCAE and ATE below 1 nm)."""
    return all(float(row.get(k, math.nan)) < REFERENCE_TOLERANCE_M for k in ("ocae_m", "ate_m"))


def pareto_front(points: np.ndarray) -> np.ndarray:
    """Boolean mask of the non-dominated rows of ``points`` ``(N, D)``, minimising every column.

    Rows with a non-finite value are never on the front. Exact duplicates of a
    front point are all kept (neither dominates the other).
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2:
        raise ValueError("points must be (N, D)")
    finite = np.all(np.isfinite(pts), axis=1)
    # dominated[i] if some j <= i everywhere and < i somewhere.
    le = np.all(pts[:, None, :] <= pts[None, :, :], axis=2)  # le[j, i]: j <= i everywhere
    lt = np.any(pts[:, None, :] < pts[None, :, :], axis=2)
    dominates = le & lt & finite[:, None]
    dominated = np.any(dominates, axis=0)
    return finite & ~dominated


def _values(rows: Sequence[Mapping], key: str) -> np.ndarray:
    return np.array([float(r.get(key, math.nan)) for r in rows], dtype=float)


def front_rows(rows: Sequence[Mapping], x_key: str, y_key: str) -> list[Mapping]:
    """The rows on the Pareto front of (x_key, y_key), sorted by x."""
    mask = pareto_front(np.stack([_values(rows, x_key), _values(rows, y_key)], axis=1)) if rows else []
    chosen = [r for r, m in zip(rows, mask) if m]
    return sorted(chosen, key=lambda r: float(r[x_key]))


def _family(collision: str) -> str:
    """Collision family of a representation's folder name: boxes, rotated_boxes, coacd, mixed..."""
    tokens = collision.split("_")
    if tokens and tokens[0] == "mixed":
        return "mixed"
    names: list[str] = []
    current: list[str] = []
    for tok in tokens:
        if tok.isdigit():
            if current:
                names.append("_".join(current))
            current = []
        else:
            current.append(tok)
    if current:
        names.append("_".join(current))
    return "mixed" if len(names) > 1 else (names[0] if names else collision)


def plot_pareto(rows: Sequence[Mapping], x_key: str, y_key: str, path: Path, title: str = "") -> Path:
    """Scatter ``rows`` on log-log axes, draw and label the Pareto front; write a PNG to ``path``.

    Marker shape encodes the contact model (o point, ^ hydroelastic), colour the
    collision family; front points are outlined in black, joined by a staircase, and labelled.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x_true = _values(rows, x_key)
    y_true = _values(rows, y_key)
    ok = np.isfinite(x_true) & np.isfinite(y_true)
    mask = pareto_front(np.stack([x_true, y_true], axis=1)) & ok if len(rows) else np.zeros(0, bool)
    # A log axis cannot show 0 (e.g. the reference scored against itself, 1e-17 m): values
    # below REFERENCE_TOLERANCE_M are drawn at a floor under the smallest real value, labelled "= 0".
    x, y = x_true.copy(), y_true.copy()
    zero = np.zeros(len(rows), bool)
    for v in (x, y):
        tiny = ok & (v < REFERENCE_TOLERANCE_M)
        positive = v[ok & ~tiny]
        floor = positive.min() / 3.0 if len(positive) else 1e-6
        zero |= tiny
        v[tiny] = floor
    families = sorted({_family(str(r["collision"])) for r in rows})
    cmap = plt.get_cmap("tab10")
    colour = {f: cmap(i % 10) for i, f in enumerate(families)}
    simulators = sorted({simulator_of(r) for r in rows}, key=lambda s: (s != "drake", s))
    if len(simulators) > 1:  # each simulator's own front: a user simulates in one of them
        mask = np.zeros(len(rows), bool)
        for sim in simulators:
            mine = np.array([simulator_of(r) == sim for r in rows])
            sub = pareto_front(np.stack([x_true[mine], y_true[mine]], axis=1)) & ok[mine]
            mask[np.flatnonzero(mine)[sub]] = True

    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    for i, r in enumerate(rows):
        if not ok[i]:
            continue
        ax.scatter(
            x[i], y[i], s=60 if mask[i] else 30, marker=MARKERS.get((simulator_of(r), str(r["contact_model"])), "s"),
            color=colour[_family(str(r["collision"]))],
            edgecolors="black" if mask[i] else "none", linewidths=1.2, alpha=1.0 if mask[i] else 0.6, zorder=3,
        )
    for sim in simulators:
        idx = np.flatnonzero(mask & np.array([simulator_of(r) == sim for r in rows], bool)) if len(rows) else []
        idx = np.asarray(idx, dtype=int)
        idx = idx[np.argsort(x[idx])]
        if not len(idx):
            continue
        # Staircase: the front's boundary of the dominated region (better = lower-left).
        ax.step(x[idx], y[idx], where="post", color="black", linewidth=1, alpha=0.6, zorder=2,
                linestyle=FRONT_STYLES.get(sim, ":"))
        for i in idx:
            text = str(rows[i]["representation"]) + (" (= 0)" if zero[i] else "")
            ax.annotate(text, (x[i], y[i]), textcoords="offset points", xytext=(5, 4), fontsize=7, zorder=4)
    handles = [plt.Line2D([], [], marker="o", linestyle="", color=colour[f], label=f) for f in families]
    pairs = sorted({(simulator_of(r), str(r["contact_model"])) for r in rows}) or [("drake", "point"),
                                                                                    ("drake", "hydroelastic")]
    handles += [plt.Line2D([], [], marker=MARKERS.get(p, "s"), linestyle="", color="grey",
                           label=p[1] if len(simulators) < 2 else f"{p[0]} {p[1]}") for p in pairs]
    handles += [plt.Line2D([], [], marker="o", linestyle=FRONT_STYLES.get(sim, ":"), color="black",
                           markerfacecolor="white", label="Pareto front" if len(simulators) < 2 else f"{sim} front")
                for sim in simulators]
    ax.legend(handles=handles, fontsize=7, loc="best")
    if np.any(ok):
        from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            # 1-2-5 labelled ticks: these plots often span less than a decade.
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
            axis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(AXIS_LABELS.get(x_key, x_key) + "  (lower is better)")
    ax.set_ylabel(AXIS_LABELS.get(y_key, y_key) + "  (lower is better)")
    ax.set_title((title + "\n" if title else "") + "Pareto-optimal points outlined; better = lower-left", fontsize=9)
    ax.grid(True, which="both", alpha=0.25)
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_file(path) as tmp:  # whole or not at all, no temporary file left on failure
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return path


def write_pareto_plots(rows: Sequence[Mapping], out_dir: Path) -> list[Path]:
    """Write the four trade-off plots of the paper (Figs. 9, 11, 12, 13) into ``out_dir``."""
    out = []
    for x_key, y_key, name, fig in PARETO_PLOTS:
        title = f"{AXIS_LABELS[y_key]} vs {AXIS_LABELS[x_key]} (paper {fig})"
        out.append(plot_pareto(rows, x_key, y_key, Path(out_dir) / name, title))
    return out


def _pick(rows: Sequence[Mapping], gate_key: str, tolerance: float, best_key: str, tie_key: str) -> Mapping | None:
    """Among rows with ``gate_key <= tolerance * min(gate_key)``, the lowest ``best_key`` (ties: ``tie_key``)."""
    usable = [r for r in rows if all(math.isfinite(float(r.get(k, math.nan))) for k in (gate_key, best_key, tie_key))]
    if not usable:
        return None
    best_gate = min(float(r[gate_key]) for r in usable)
    gated = [r for r in usable if float(r[gate_key]) <= tolerance * best_gate + 1e-15]
    return min(gated, key=lambda r: (float(r[best_key]), float(r[tie_key]), float(r[gate_key])))


def recommend(
    rows: Sequence[Mapping],
    preference: str = "accuracy",
    accuracy_tolerance: float = ACCURACY_TOLERANCE,
    speed_tolerance: float = SPEED_TOLERANCE,
    smoothness_tolerance: float = SMOOTHNESS_OCAE_TOLERANCE,
    exclude_reference: bool = True,
    contact_model: str | None = None,
    simulator: str | None = None,
) -> Mapping | None:
    """The summary row to use for a preference; None when no row has the needed metrics.

    ``contact_model`` ("point" or "hydroelastic"): choose among that contact model's rows only,
    for a user whose simulator has only that model (MuJoCo, Isaac Sim and PyBullet use point
    contact); None chooses among all rows. ``simulator`` ("drake", "mujoco"): among that
    simulator's rows only (:mod:`real2sim.report.recommend` makes one pick per simulator and contact
    model). Exact-geometry bound rows (:func:`is_bound`) are never chosen.

    Rules (each picks a point on the relevant Pareto front, because it is the best
    of a set that is closed under domination, with ties broken by the other metric):

    * ``accuracy``: among representations whose OCAE is within ``accuracy_tolerance``
      (x1.10) of the best OCAE, the fastest. Accuracy first, but do not pay for a
      difference in OCAE that is below run-to-run noise.
    * ``speed``: among representations whose simulation time is within
      ``speed_tolerance`` (x1.25) of the fastest, the lowest OCAE. Speed first, but
      do not accept a much worse fit for a few per cent of time.
    * ``smoothness``: among representations whose OCAE is within
      ``smoothness_tolerance`` (x1.5) of the best, the lowest CPD (ties: OCAE).
      The paper's advice: choose on accuracy, then adjust for contact continuity.

    With ``exclude_reference`` (default), rows that reproduce the reference (OCAE and ATE
    both below ``REFERENCE_TOLERANCE_M``, 1 nm) are left out: they are the reference itself
    (e.g. the ``mesh`` baseline with hydroelastic contact), not a simplification to choose.
    """
    rows = [r for r in rows if not is_bound(r)]
    if exclude_reference:
        rows = [r for r in rows if not is_reference_itself(r)]
    if simulator is not None:
        rows = [r for r in rows if simulator_of(r) == simulator]
    if contact_model is not None:
        rows = [r for r in rows if r.get("contact_model") == contact_model]
    if preference == "accuracy":
        return _pick(rows, "ocae_m", accuracy_tolerance, "sim_time_s", "ocae_m")
    if preference == "speed":
        return _pick(rows, "sim_time_s", speed_tolerance, "ocae_m", "sim_time_s")
    if preference == "smoothness":
        return _pick(rows, "ocae_m", smoothness_tolerance, "cpd_m_per_s", "ocae_m")
    raise ValueError(f"unknown preference {preference!r}; expected one of {', '.join(PREFERENCES)}")


def recommend_per_contact_model(rows: Sequence[Mapping], preferences: Sequence[str] = ("accuracy", "speed")
                                ) -> dict[str, dict[str, Mapping]]:
    """``{contact model: {preference: row}}``, each pick made among that contact model's rows alone
    (:func:`recommend`); empty when the rows hold fewer than two contact models, where the overall pick
    is already that."""
    models = sorted({str(r["contact_model"]) for r in rows if r.get("contact_model")})
    if len(models) < 2:
        return {}
    picks = {m: {p: recommend(rows, p, contact_model=m) for p in preferences} for m in models}
    return {m: {p: row for p, row in by.items() if row is not None} for m, by in picks.items()}


RECOMMENDATION_RULES = {
    "accuracy": f"fastest among those with OCAE within x{ACCURACY_TOLERANCE:g} of the best",
    "speed": f"lowest OCAE among those with simulation time within x{SPEED_TOLERANCE:g} of the fastest",
    "smoothness": f"lowest CPD among those with OCAE within x{SMOOTHNESS_OCAE_TOLERANCE:g} of the best",
}
