"""``summary.csv``, the Pareto plots and a self-contained ``report.html`` from ``runs.csv``.

``real2sim report RESULTS`` calls :func:`write_report`, which rebuilds all three
from ``RESULTS/runs.csv`` (and the protocol recorded in ``RESULTS/config.json``),
so a report can be regenerated after editing or merging runs.

The report puts our summary next to the paper's Table I (shipped in
``real2sim/data/paper_table1.csv``) where the names match; the paper names mixed
representations ``mixed_20boxes_20cylinders``, ours ``boxes_20_cylinders_20``, and
:func:`paper_name` maps one onto the other. Plots are embedded as base64 PNGs, so
the HTML file is one self-contained page.
"""

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

from real2sim.formats.errors import UserInputError

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


def _read_config(path: Path) -> dict:
    """config.json of a results folder ({} when there is none); UserInputError when unreadable."""
    if not path.exists():
        return {}
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # a folder, unreadable, not UTF-8, not JSON
        raise UserInputError(f"could not read {path} ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    if not isinstance(config, dict):
        raise UserInputError(f"{path} is not a results config.json (not a JSON object)")
    return config


def _private_config(value, base: Path):
    """``value`` (config.json) with absolute paths relative to ``base``: older versions recorded
    where the user's files live, which a shared report should not tell."""
    from real2sim.formats.results import relative_paths_in_text

    if isinstance(value, dict):
        return {k: _private_config(v, base) for k, v in value.items()}
    if isinstance(value, list):
        return [_private_config(v, base) for v in value]
    return relative_paths_in_text(value, base) if isinstance(value, str) else value


def build_outputs(results_dir: Path, rows: Sequence[dict], *, config: dict | None = None,
                  write_to: Path | None = None) -> tuple[list[dict], list[Path], Path]:
    """Write summary.csv, the Pareto PNGs and report.html for ``rows`` (each file whole or not at all).

    results_dir: the results folder (its config.json is read unless ``config`` is given; paths
    in the report are relative to it); write_to: where the files go (default ``results_dir``).
    """
    from real2sim.formats.outputs import write_text_atomic
    from real2sim.formats.results import SUMMARY_COLUMNS, relative_paths_in_text, summarize, write_csv_atomic
    from real2sim.report.pareto import write_pareto_plots

    results_dir = Path(results_dir)
    out = Path(write_to) if write_to is not None else results_dir
    if config is None:
        config = _read_config(results_dir / "config.json")
    config = _private_config(config, results_dir)
    rows = [dict(r, error=relative_paths_in_text(r["error"], results_dir)) if r["error"] else r for r in rows]
    summary = summarize(rows)
    write_csv_atomic(out / "summary.csv", summary, SUMMARY_COLUMNS)
    plots = write_pareto_plots(summary, out)
    page = render_html(summary, rows, config, plots, results_dir=results_dir)
    report = out / "report.html"
    write_text_atomic(report, page)
    return summary, plots, report


def _output_names() -> list[str]:
    from real2sim.report.pareto import PARETO_PLOTS

    return ["summary.csv", *(name for _x, _y, name, _fig in PARETO_PLOTS), "report.html"]


def _commit(stage: Path, results_dir: Path, names: Sequence[str]) -> None:
    """Move the staged files over the results folder's; on an error put back those already moved."""
    import os

    backups = stage / ".previous"
    backups.mkdir()
    moved: list[str] = []
    try:
        for name in names:
            if (results_dir / name).exists():
                os.link(results_dir / name, backups / name)  # a second name for the old file, for a roll-back
            os.replace(stage / name, results_dir / name)
            moved.append(name)
    except BaseException:
        for name in reversed(moved):
            if (backups / name).exists():
                os.replace(backups / name, results_dir / name)
            else:
                (results_dir / name).unlink(missing_ok=True)
        raise


def write_report(results_dir: Path | str, log=None) -> Path:
    """Rebuild summary.csv, the plots and report.html of ``results_dir`` from its runs.csv.

    All or nothing: the new files are made in a hidden folder inside ``results_dir`` and moved
    over the old ones only when every one of them is ready (an error puts back the old ones),
    under the results folder's lock. Torn rows of runs.csv are left out; ``log`` (a callable
    taking one line) hears about them. UserInputError, with nothing changed, for a folder that
    is not a results folder, an unreadable runs.csv or config.json, or an output name taken
    by something other than a file.
    """
    import os
    import shutil
    import tempfile

    from real2sim.formats.outputs import output_lock
    from real2sim.formats.results import describe_torn, load_runs_csv

    results_dir = Path(results_dir)
    if not results_dir.is_dir():
        raise UserInputError(f"results folder not found: {results_dir}")
    runs = results_dir / "runs.csv"
    if not runs.exists():
        raise UserInputError(f"{results_dir} holds no runs.csv (run `real2sim evaluate` first)")
    table = load_runs_csv(runs)
    if table.torn_lines and log is not None:
        log(f"warning: {describe_torn(table, runs)} left out of the report")
    if not table.rows:
        raise UserInputError(f"{runs} holds no complete rows")
    config = _read_config(results_dir / "config.json")
    names = _output_names()
    for name in names:
        path = results_dir / name
        if path.is_symlink() or (path.exists() and not path.is_file()):
            raise UserInputError(f"{path} is in the way of the report and is not a file; remove it")
    for folder in (results_dir, results_dir.resolve().parent):  # the files, and the lock beside the folder
        if not os.access(folder, os.W_OK | os.X_OK):
            raise UserInputError(f"cannot write in {folder} (permission denied)")
    with output_lock(results_dir.resolve()):
        stage = Path(tempfile.mkdtemp(prefix=".report.tmp-", dir=results_dir))
        try:
            build_outputs(results_dir, table.rows, config=config, write_to=stage)
            _commit(stage, results_dir, names)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    return results_dir / "report.html"


# ---------------------------------------------------------------------------------------
# HTML


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
        "CPD force-weighted [m/s]</th>" + paper_head + "</tr></thead><tbody>"
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
            f"<td>{_f(float(r.get('cpd_force_weighted_m_per_s', math.nan)))}</td>{paper_cells}</tr>"
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
    from real2sim.report.pareto import PREFERENCES, RECOMMENDATION_RULES, is_reference_itself, recommend

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

    With ``results_dir``, the asset folders its config.json names add two sections: pictures
    of every representation, and the truth (for assets with a truth.json).
    """
    from real2sim.report.sections import animations_section, pictures_section, truth_section

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

