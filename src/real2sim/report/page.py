"""The report page itself: report.html as one self-contained HTML string (:func:`render_html`),
next to the paper's Table I (:func:`read_paper_table`, names matched by :func:`paper_name`).
:mod:`real2sim.report.html` builds the results folder's outputs around it."""

from __future__ import annotations

import base64
import csv
import html
import json
import math
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from typing import Mapping, Sequence

METRICS = ("ocae_m", "ate_m", "cpd_m_per_s", "sim_time_s")
METRIC_TITLES = {"ocae_m": "OCAE [m]", "ate_m": "ATE [m]", "cpd_m_per_s": "CPD [m/s]", "sim_time_s": "ST [s]"}


def paper_name(collision: str, contact_model: str | None = None) -> str:
    """Our representation (the folder name of its SPEC) and contact model as the paper's Table I
    writes them: (``boxes_20_cylinders_20``, ``point``) -> ``mixed_20boxes_20cylinders_point``;
    single-family and baseline names are the same in both (``boxes_150_hydroelastic``,
    ``coacd_point``). The two are summary.csv's ``collision`` and ``contact_model`` columns.
    """
    contact = contact_model
    label = f"{collision}_{contact}" if contact else collision
    tokens = collision.split("_")
    parts: list[tuple[str, str]] = []
    family: list[str] = []
    for tok in tokens:
        if tok.isdigit() and family:
            parts.append(("_".join(family), tok))
            family = []
        else:
            family.append(tok)
    if family or len(parts) < 2:
        return label
    mixed = "mixed_" + "_".join(f"{count}{fam}" for fam, count in parts)
    return f"{mixed}_{contact}" if contact else mixed


def read_paper_table() -> dict[str, dict]:
    """The paper's Table I as {representation: {ocae_m, ate_m, cpd_m_per_s, sim_time_s}}."""
    text = resources.files("real2sim").joinpath("data/paper_table1.csv").read_text()
    rows = {}
    for raw in csv.DictReader(text.splitlines()):
        rows[raw["representation"]] = {k: float(raw[k]) for k in METRICS}
    return rows


def _f(value, digits: int = 4) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return html.escape(str(value))
    if not math.isfinite(v):
        return "&ndash;"
    return f"{v:.{digits}f}" if abs(v) >= 10 ** (-digits + 1) or v == 0 else f"{v:.2e}"


def _best(rows: Sequence[Mapping], key: str) -> float:
    vals = [float(r[key]) for r in rows if math.isfinite(float(r.get(key, math.nan)))]
    return min(vals) if vals else math.nan


def _summary_table(summary: Sequence[Mapping], paper: dict[str, dict]) -> str:
    best = {k: _best(summary, k) for k in METRICS}
    head = "".join(f"<th>{METRIC_TITLES[k]}</th>" for k in METRICS)
    paper_head = "".join(f"<th class='paper'>paper {METRIC_TITLES[k]}</th>" for k in METRICS)
    out = [
        "<table><thead><tr><th>representation</th>" + head + "<th>real-time factor</th><th>runs ok / failed</th>"
        "<th title='CPD with contact points weighted by force magnitude (not in the paper)'>"
        "CPD force-weighted [m/s]</th>"
        "<th title=\"CPD as the paper's code computes it (docs/evaluation.md): compare this one with the paper's CPD\">"
        "CPD paper's code [m/sample]</th>" + paper_head + "</tr></thead><tbody>"
    ]
    for r in summary:
        cells = []
        for k in METRICS:
            v = float(r[k])
            text = _f(v)
            cells.append(f"<td><b>{text}</b></td>" if math.isfinite(v) and v == best[k] else f"<td>{text}</td>")
        p = paper.get(paper_name(str(r["collision"]), str(r["contact_model"])))
        paper_cells = "".join(f"<td class='paper'>{_f(p[k])}</td>" for k in METRICS) if p else (
            "<td class='paper' colspan='4'>not in the paper's table</td>")
        failed = int(r.get("runs_failed", 0) or 0)
        runs = f"{int(r.get('runs_ok', 0) or 0)} / " + (f"<span class='err'>{failed}</span>" if failed else "0")
        out.append(
            f"<tr><td>{html.escape(str(r['representation']))}</td>{''.join(cells)}"
            f"<td>{_f(r.get('real_time_factor', math.nan), 2)}</td><td>{runs}</td>"
            f"<td>{_f(float(r.get('cpd_force_weighted_m_per_s', math.nan)))}</td>"
            f"<td>{_f(float(r.get('cpd_paper', math.nan)))}</td>{paper_cells}</tr>"
        )
    out.append("</tbody></table>")
    return "\n".join(out)


def _breakdown_table(rows: Sequence[Mapping]) -> str:
    """Means per (object, task) for each representation: where the averages come from."""
    import numpy as np

    groups: dict[tuple, list[Mapping]] = {}
    for r in rows:
        if not r["error"]:
            groups.setdefault((f"{r['representation']}_{r['contact_model']}", r["object"], r["task"]), []).append(r)
    out = ["<table><thead><tr><th>representation</th><th>object</th><th>task</th><th>runs</th>"
           + "".join(f"<th>{METRIC_TITLES[k]}</th>" for k in METRICS) + "</tr></thead><tbody>"]
    for (label, obj, task), group in sorted(groups.items()):
        cells = []
        for k in METRICS:
            vals = np.array([g[k] for g in group], dtype=float)
            vals = vals[np.isfinite(vals)]
            cells.append(f"<td>{_f(vals.mean()) if len(vals) else '&ndash;'}</td>")
        out.append(f"<tr><td>{html.escape(label)}</td><td>{html.escape(obj)}</td><td>{html.escape(task)}</td>"
                   f"<td>{len(group)}</td>{''.join(cells)}</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _recommendations(summary: Sequence[Mapping]) -> str:
    from real2sim.report.pareto import PREFERENCES, RECOMMENDATION_RULES, is_reference_itself, recommend, simulator_of
    from real2sim.report.recommend import describe_trade_off, recommend_per_group

    items = []
    for pref in PREFERENCES:
        row = recommend(summary, pref)
        if row is None:
            items.append(f"<li><b>{pref}</b>: no representation has the needed metrics.</li>")
            continue
        items.append(
            f"<li><b>{pref}</b>: <code>{html.escape(str(row['representation']))}</code> "
            f"(OCAE {_f(row['ocae_m'])} m, ATE {_f(row['ate_m'])} m, CPD {_f(row['cpd_m_per_s'])} m/s, "
            f"{_f(row['sim_time_s'], 3)} s per run) &mdash; rule: {html.escape(RECOMMENDATION_RULES[pref])}.</li>"
        )
    # A user simulates in one simulator with one contact model: the best of that group's rows, on its own
    # measured front, which the overall pick (often a Drake hydroelastic row) does not give.
    by_group = recommend_per_group(summary)
    if len(by_group) > 1 or any(simulator_of(r) != "drake" for r in summary):
        for (sim, model), by_pref in by_group.items():
            picks = [f"{pref}: <code>{html.escape(str(row['representation']))}</code> "
                     f"(OCAE {_f(row['ocae_m'])} m, {_f(row['sim_time_s'], 3)} s per run; gives up: "
                     f"{html.escape(describe_trade_off(row, summary) or 'nothing measured')})"
                     for pref, row in by_pref.items()]
            mujoco_rows = any(simulator_of(r) == "mujoco" for r in summary)
            who = (f" (Isaac Sim, PyBullet{'' if mujoco_rows else ', MuJoCo'})"
                   if (sim, model) == ("drake", "point") else "")
            label = f"{model} contact only" if sim == "drake" else f"{sim}, {model} contact"
            items.append(f"<li><b>{html.escape(label)}</b>{who}: " + "; ".join(picks) + ".</li>")
        items.append("<li>Each pick above is made among its simulator and contact model's rows alone and lies on "
                     "their measured Pareto front (OCAE against simulation time); 'gives up' compares it with the "
                     "group's most accurate row and, where the rows hold one, its exact-geometry bound.</li>")
    same = [str(r["representation"]) for r in summary if is_reference_itself(r)]
    note = (
        "<p>Not considered: " + ", ".join(f"<code>{html.escape(n)}</code>" for n in same)
        + " (zero error: identical to the reference, not a simplification).</p>"
        if same else ""
    )
    return "<ul>" + "\n".join(items) + "</ul>" + note


def _pareto_lists(summary: Sequence[Mapping]) -> str:
    from real2sim.report.pareto import AXIS_LABELS, PARETO_PLOTS, front_rows

    items = []
    for x_key, y_key, _name, fig in PARETO_PLOTS:
        front = front_rows(summary, x_key, y_key)
        names = ", ".join(f"<code>{html.escape(str(r['representation']))}</code>" for r in front) or "(none)"
        items.append(f"<li>{AXIS_LABELS[y_key]} vs {AXIS_LABELS[x_key]} ({fig}): {names}</li>")
    return "<ul>" + "\n".join(items) + "</ul>"


def _config_block(config: Mapping) -> str:
    if not config:
        return "<p>No config.json was found beside runs.csv.</p>"
    scene = config.get("scene", {})
    general = {k: v for k, v in config.items() if k not in ("scene", "metrics")}
    rows = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td><code>{html.escape(json.dumps(v) if not isinstance(v, str) else v)}</code></td></tr>"
        for k, v in general.items()
    )
    metrics = "".join(
        f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in config.get("metrics", {}).items()
    )
    scene_rows = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td><code>{html.escape(json.dumps(v))}</code></td></tr>"
        for k, v in (scene.items() if isinstance(scene, dict) else [])
    )
    return (
        f"<table>{rows}</table><h3>Metrics</h3><ul>{metrics}</ul>"
        f"<h3>Scene parameters (SI units)</h3><table>{scene_rows}</table>"
    )


def _errors_block(rows: Sequence[Mapping], limit: int = 50) -> str:
    bad = [r for r in rows if r["error"]]
    if not bad:
        return "<p>No simulation failed.</p>"
    items = "".join(
        f"<li><code>{html.escape(' / '.join(str(r[c]) for c in ('object', 'representation', 'contact_model', 'task', 'run')))}"
        f"</code>: {html.escape(r['error'])}</li>"
        for r in bad[:limit]
    )
    more = f"<p>... and {len(bad) - limit} more (see runs.csv).</p>" if len(bad) > limit else ""
    return f"<p>{len(bad)} of {len(rows)} simulations failed; their rows are excluded from the means.</p><ul>{items}</ul>{more}"


def render_html(summary: Sequence[Mapping], rows: Sequence[Mapping], config: Mapping, plots: Sequence[Path],
                results_dir: Path | None = None) -> str:
    """The report page as one HTML string (plots and pictures inlined as base64 PNG).

    With ``results_dir``, the asset folders its config.json names add sections: the warnings
    `real2sim run` recorded making them, pictures of every representation, and the truth (for
    assets with a truth.json).
    """
    from real2sim.report.sections import animations_section, pictures_section, truth_section, warnings_section

    warned = warnings_section(results_dir, config) if results_dir is not None else ""
    truth = truth_section(results_dir, config) if results_dir is not None else ""
    pictures = pictures_section(results_dir, config, rows) if results_dir is not None else ""
    animations = animations_section(results_dir) if results_dir is not None else ""
    try:
        paper = read_paper_table()
    except Exception:  # pragma: no cover - the CSV ships with the package
        paper = {}
    imgs = []
    for p in plots:
        data = base64.b64encode(Path(p).read_bytes()).decode("ascii")
        imgs.append(f"<figure><img alt='{html.escape(p.name)}' src='data:image/png;base64,{data}'/>"
                    f"<figcaption>{html.escape(p.name)}</figcaption></figure>")
    objects = sorted({r["object"] for r in rows})
    tasks = sorted({r["task"] for r in rows})
    matched = sum(1 for r in summary if paper_name(str(r["collision"]), str(r["contact_model"])) in paper)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    style = (
        "body{font-family:system-ui,sans-serif;margin:2em;max-width:1400px}"
        "table{border-collapse:collapse;font-size:13px;margin:0.5em 0}"
        "td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}"
        "td:first-child,th:first-child{text-align:left}"
        ".paper{background:#f4f4f8;color:#446}.err{color:#b00}"
        "figure{display:inline-block;margin:0.5em}img{max-width:640px}img.pic{width:200px}"
        "code{font-size:12px}"
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>real2sim evaluation report</title>
<style>{style}</style></head><body>
<h1>real2sim evaluation report</h1>
<p>{len(rows)} simulations of {len(summary)} representation/contact-model pairs; objects: {html.escape(', '.join(objects))};
tasks: {html.escape(', '.join(tasks))}. Generated {stamp}.
Protocol: {html.escape(str(config.get('protocol', 'unknown')))}.</p>
{warned}

<h2>Summary (layout of the paper's Table I)</h2>
<p>Means over objects, tasks and runs; OCAE and ATE in metres, CPD in m/s, ST = wall-clock seconds per
simulation (measured while the sweep ran {html.escape(str(config.get('jobs', '?')))} simulations in parallel, so
compare times only within one report). Bold: best in its column. Shaded: the paper's Table I values for the
same name ({matched} of {len(summary)} matched); they come from different objects (YCB mustard bottle and soup
can), scenes and machines, so only orders of magnitude and trends are comparable.</p>
{_summary_table(summary, paper)}

<h2>Recommendations</h2>
{_recommendations(summary)}

{truth}

<h2>Pareto fronts</h2>
<p>Every metric is lower-is-better; in the plots better is down and to the left, and Pareto-optimal
points are outlined and labelled (the paper's Fig. 9 flips both axes).</p>
{_pareto_lists(summary)}
{''.join(imgs)}

<h2>Representations</h2>
{pictures}

{animations}

<h2>Per object and task</h2>
{_breakdown_table(rows)}

<h2>Failures</h2>
{_errors_block(rows)}

<h2>Protocol and parameters</h2>
{_config_block(config)}
</body></html>
"""
