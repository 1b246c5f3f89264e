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

import json
from pathlib import Path
from typing import Sequence

from real2sim.plumbing.errors import UserInputError
from real2sim.report.page import METRIC_TITLES, METRICS, paper_name, read_paper_table, render_html  # noqa: F401

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
    from real2sim.plumbing.outputs import write_text_atomic
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
    plots = _unchanged_plots(results_dir, out)
    if plots is None:
        plots = write_pareto_plots(summary, out)
    page = render_html(summary, rows, config, plots, results_dir=results_dir)
    report = out / "report.html"
    write_text_atomic(report, page)
    return summary, plots, report


def _unchanged_plots(results_dir: Path, out: Path) -> list[Path] | None:
    """The plots of ``results_dir`` copied into ``out`` when they were drawn from the very summary just
    written there (the same summary.csv, byte for byte): a report rewritten for its warnings or truth
    does not draw them again (matplotlib is a sixth of a small run's evaluation). None otherwise."""
    import shutil

    from real2sim.report.pareto import PARETO_PLOTS

    if out == results_dir or not (results_dir / "summary.csv").is_file():
        return None
    if (results_dir / "summary.csv").read_bytes() != (out / "summary.csv").read_bytes():
        return None
    names = [name for _x, _y, name, _fig in PARETO_PLOTS]
    if not all((results_dir / name).is_file() and not (results_dir / name).is_symlink() for name in names):
        return None
    for name in names:
        shutil.copyfile(results_dir / name, out / name)
    return [out / name for name in names]


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

    from real2sim.plumbing.outputs import output_lock
    from real2sim.formats.results import describe_torn, load_runs_csv

    results_dir = Path(results_dir)
    if not results_dir.is_dir():
        from real2sim.plumbing.paths import missing

        if results_dir.exists():
            raise UserInputError(f"{results_dir} is a file, not a results folder (give the folder that "
                                 "`real2sim evaluate --out` made)")
        raise UserInputError(missing(results_dir, "results folder"))
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
