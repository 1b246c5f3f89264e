"""The results folder's CSV files: runs.csv (one row per simulation) and summary.csv (one
row per ``<representation>_<contactmodel>``, the layout of the paper's Table I).

Written by the evaluation, read by the report; neither imports the other.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from real2sim.formats.errors import UserInputError


RUN_COLUMNS = (
    "object", "representation", "contact_model", "task", "run", "ate_m", "ocae_m", "cpd_m_per_s",
    "cpd_force_weighted_m_per_s", "sim_time_s", "sim_duration_s", "real_time_factor", "error",
)


# Added after the first release: a runs.csv without them still reads (as NaN).
_OPTIONAL_RUN_COLUMNS = ("cpd_force_weighted_m_per_s",)


KEY_COLUMNS = ("object", "representation", "contact_model", "task", "run")


FLOAT_COLUMNS = ("ate_m", "ocae_m", "cpd_m_per_s", "cpd_force_weighted_m_per_s", "sim_time_s", "sim_duration_s",
                 "real_time_factor")


SUMMARY_COLUMNS = (
    "representation", "ocae_m", "ate_m", "cpd_m_per_s", "sim_time_s",  # the layout of the paper's Table I
    "cpd_force_weighted_m_per_s", "collision", "contact_model", "sim_duration_s", "real_time_factor",
    "runs_ok", "runs_failed",
)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


def write_csv_atomic(path: Path, rows: Iterable[dict], columns: Sequence[str]) -> None:
    """Write ``rows`` to ``path`` via a temporary file and a rename (never half-written)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_fmt(row.get(c, "")) for c in columns])
    tmp.replace(path)


def read_runs_csv(path: Path) -> list[dict]:
    """runs.csv rows with floats parsed and ``run`` as int."""
    rows = []
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        missing = set(RUN_COLUMNS) - set(reader.fieldnames or ()) - set(_OPTIONAL_RUN_COLUMNS)
        if missing:
            raise UserInputError(f"{path} is not a runs.csv (missing columns {', '.join(sorted(missing))})")
        for raw in reader:
            row: dict[str, Any] = {c: raw.get(c, "") for c in RUN_COLUMNS}
            row["run"] = int(raw["run"])
            for c in FLOAT_COLUMNS:
                row[c] = float(raw.get(c) or "nan")
            row["error"] = raw["error"] or ""
            rows.append(row)
    return rows


def row_key(row: dict) -> tuple:
    return tuple(row[c] for c in KEY_COLUMNS)


def summarize(rows: Sequence[dict]) -> list[dict]:
    """One row per ``<representation>_<contactmodel>``: means over objects, tasks and runs.

    Only rows without an error enter the means (``runs_failed`` counts the others).
    ``sim_time_s`` is the mean wall-clock seconds per simulation, as the paper's ST;
    ``real_time_factor`` is total simulated time over total wall time. CPD ignores
    runs where it is undefined (no sustained contact).
    """
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["representation"], r["contact_model"]), []).append(r)
    out = []
    for (rep, cm), group in sorted(groups.items()):
        ok = [r for r in group if not r["error"]]

        def mean(col: str, src=ok) -> float:
            vals = np.array([r.get(col, math.nan) for r in src], dtype=float)
            vals = vals[np.isfinite(vals)]
            return float(np.mean(vals)) if len(vals) else math.nan

        total_time = float(np.nansum([r["sim_time_s"] for r in ok])) if ok else math.nan
        total_duration = float(np.nansum([r["sim_duration_s"] for r in ok])) if ok else math.nan
        out.append({
            "representation": f"{rep}_{cm}",
            "ocae_m": mean("ocae_m"),
            "ate_m": mean("ate_m"),
            "cpd_m_per_s": mean("cpd_m_per_s"),
            "sim_time_s": mean("sim_time_s"),
            "cpd_force_weighted_m_per_s": mean("cpd_force_weighted_m_per_s"),
            "collision": rep,
            "contact_model": cm,
            "sim_duration_s": mean("sim_duration_s"),
            "real_time_factor": total_duration / total_time if ok and total_time > 0 else math.nan,
            "runs_ok": len(ok),
            "runs_failed": len(group) - len(ok),
        })
    return out


def read_summary_csv(path: Path) -> list[dict]:
    rows = []
    with open(path, newline="") as fh:
        for raw in csv.DictReader(fh):
            row: dict[str, Any] = dict(raw)
            for c in FLOAT_COLUMNS:
                if c in row:
                    row[c] = float(row[c]) if row[c] not in ("", None) else math.nan
            for c in ("runs_ok", "runs_failed"):
                if c in row and row[c] not in ("", None):
                    row[c] = int(row[c])
            rows.append(row)
    return rows
