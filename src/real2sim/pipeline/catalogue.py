"""A batch's catalogue folder: its layout (one asset folder per object, named after its dataset, and each
object's outcome in ``CATALOGUE/.batch/<name>.json``), and what is written at the end: ``catalogue.csv``,
``timings.csv`` and a self-contained ``index.html``.

catalogue.csv has one row per object (COLUMNS), in the order the datasets were given, and holds only
what the objects' results are, never how long they took or when: the same batch gives the same bytes,
interrupted and resumed or not. Numbers are written with 6 significant digits. The stage times are
in timings.csv (name, stage, wall_s) and on the page.

Recommendations: an evaluated object (``results/summary.csv``) gets the representation recommended
for accuracy and for speed by the report's own rules (:func:`real2sim.report.pareto.recommend`), with
its OCAE and simulation time; one that was not evaluated gets them from its fits alone (accuracy: the
highest IoU; speed: the fewest primitives, then the highest IoU), without OCAE and simulation time.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
from pathlib import Path
from typing import Any, Sequence

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME, check_output_dir, write_json_atomic, write_text_atomic
from real2sim.pipeline import manifest as mf

BATCH_DIRNAME = ".batch"
MADE_BY = "real2sim batch"

COLUMNS = (
    "name", "status", "reason", "mass_kg", "size_x_m", "size_y_m", "size_z_m", "representations", "basis",
    "accuracy_representation", "accuracy_ocae_m", "accuracy_sim_time_s", "accuracy_iou",
    "speed_representation", "speed_ocae_m", "speed_sim_time_s", "speed_iou",
    "truth_chamfer_mm", "truth_iou", "truth_com_error_mm", "truth_inertia_max_rel_error", "report",
)
PICTURE_PX = 160  # the picture's longer side on the page


def dataset_folder(dataset: Path | str) -> Path:
    """The dataset's folder, resolved (``run`` also takes the path of its transforms.json)."""
    dataset = Path(dataset).resolve()
    return dataset.parent if dataset.name == "transforms.json" and dataset.is_file() else dataset


def check_names(datasets: list[Path]) -> list[str]:
    """The objects' names (their datasets' folder names); UserInputError when two are the same."""
    seen: dict[str, Path] = {}
    for ds in datasets:
        name = dataset_folder(ds).name
        if name.startswith("."):
            raise UserInputError(f"{ds}: a dataset folder's name becomes its folder in CATALOGUE, and {name!r} "
                                 "is hidden; rename it")
        if name in seen:
            raise UserInputError(f"two datasets are both named {name!r} ({seen[name]} and {ds}); each object's "
                                 "folder in CATALOGUE is its dataset's name: rename one")
        seen[name] = Path(ds)
    return list(seen)


def check_catalogue(out: Path | str, datasets: list[Path]) -> Path:
    """CATALOGUE resolved: new, empty, or an earlier batch's (resumed); UserInputError otherwise."""
    out = check_output_dir(out, overwrite=True, inputs=datasets, what="CATALOGUE")
    marker = out / MARKER_NAME
    if marker.is_file():
        try:
            made_by = json.loads(marker.read_text()).get("made_by")
        except (OSError, ValueError, AttributeError):
            made_by = None
        if made_by != MADE_BY:
            raise UserInputError(f"CATALOGUE {out} is a real2sim output but not a batch's ({made_by or 'unknown'}); "
                                 "choose a new folder")
    return out


def state_path(out: Path, name: str) -> Path:
    """Where CATALOGUE ``out`` records the outcome of object ``name`` (its status, reason and key)."""
    return out / BATCH_DIRNAME / f"{name}.json"


def finished_before(out: Path, name: str, asset_dir: Path, key: str) -> bool:
    """Whether an earlier batch into ``out`` finished object ``name`` under the same ``key`` (dataset and
    settings), and its asset folder still holds run's record."""
    try:
        state = json.loads(state_path(out, name).read_text())
    except (OSError, ValueError):
        return False
    return state.get("status") == "done" and state.get("key") == key and (
        asset_dir / mf.RUN_DIRNAME / mf.MANIFEST_NAME).is_file()


def record_outcome(out: Path, outcome: dict, key: str) -> dict:
    """Record the outcome of object ``outcome["name"]`` (its status and reason) under ``key`` in CATALOGUE
    ``out``; returns the record."""
    state = {"name": outcome["name"], "status": outcome["status"], "reason": outcome.get("reason", ""), "key": key}
    write_json_atomic(state_path(out, outcome["name"]), state)
    return state


def _num(value: Any) -> str:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return ""
    return f"{x:.6g}" if math.isfinite(x) else ""


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _size_m(obj: Path) -> list[float] | None:
    """The axis-aligned extent of an OBJ's vertices (the asset frame), metres."""
    import numpy as np

    try:
        rows = [line.split()[1:4] for line in obj.read_text().splitlines() if line.startswith("v ")]
        vertices = np.asarray(rows, dtype=float)
    except (OSError, ValueError):
        return None
    return (vertices.max(axis=0) - vertices.min(axis=0)).tolist() if len(vertices) else None


def _fits(asset_dir: Path) -> dict[str, dict]:
    """{representation folder: fit_report.json} of every fitted representation."""
    return {p.parent.name: _json(p) for p in sorted(asset_dir.glob("*/fit_report.json"))}


def _from_fits(fits: dict[str, dict]) -> dict:
    if not fits:
        return {}
    def iou(name: str) -> float:
        value = fits[name].get("iou")
        return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else -math.inf

    best = max(fits, key=lambda n: (iou(n), n))
    fastest = min(fits, key=lambda n: (fits[n].get("num_primitives") or math.inf, -iou(n), n))
    return {"accuracy_representation": best, "accuracy_iou": _num(fits[best].get("iou")),
            "speed_representation": fastest, "speed_iou": _num(fits[fastest].get("iou"))}


def _from_evaluation(summary_csv: Path, fits: dict[str, dict]) -> dict:
    from real2sim.report.pareto import recommend

    try:
        with open(summary_csv, newline="", encoding="utf-8") as f:
            raw = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error):
        return {}
    rows = [{**r, **{k: _float(r.get(k)) for k in ("ocae_m", "ate_m", "sim_time_s", "cpd_m_per_s")}} for r in raw]
    found = {}
    for preference in ("accuracy", "speed"):
        row = recommend(rows, preference)
        if row is None:
            continue
        name = row.get("collision") or row.get("representation", "")
        found.update({f"{preference}_representation": row.get("representation", ""),
                      f"{preference}_ocae_m": _num(row.get("ocae_m")),
                      f"{preference}_sim_time_s": _num(row.get("sim_time_s")),
                      f"{preference}_iou": _num(fits.get(name, {}).get("iou"))})
    return found


def object_row(name: str, asset_dir: Path, state: dict | None) -> dict:
    """One object's row of catalogue.csv (COLUMNS, every value a string)."""
    row = dict.fromkeys(COLUMNS, "")
    row.update(name=name, status=(state or {}).get("status", "not run"), reason=(state or {}).get("reason", ""))
    if row["status"] != "done":
        return row
    row["mass_kg"] = _num(_json(asset_dir / "physical_properties.json").get("mass_kg"))
    size = _size_m(asset_dir / "visual" / "model.obj")
    if size:
        row.update(size_x_m=_num(size[0]), size_y_m=_num(size[1]), size_z_m=_num(size[2]))
    fits = _fits(asset_dir)
    row["representations"] = ";".join(fits)
    summary = asset_dir / "results" / "summary.csv"
    evaluated = _from_evaluation(summary, fits) if summary.is_file() else {}
    row.update(evaluated or _from_fits(fits))
    row["basis"] = "evaluation" if evaluated else ("fit" if fits else "")
    truth = _json(asset_dir / "truth.json")
    rec, phys = truth.get("reconstruction") or {}, truth.get("physical_properties") or {}
    row.update(truth_chamfer_mm=_num(rec.get("chamfer_mm")), truth_iou=_num(rec.get("iou")),
               truth_com_error_mm=_num(phys.get("com_error_mm")),
               truth_inertia_max_rel_error=_num(phys.get("inertia_eigenvalue_max_rel_error")))
    for report in ("results/report.html", "truth.json", mf.RUN_DIRNAME + "/" + mf.MANIFEST_NAME):
        if (asset_dir / report).is_file():
            row["report"] = f"{name}/{report}"
            break
    return row


def stage_times(asset_dir: Path) -> dict[str, float]:
    """{stage: wall seconds} of the object's run.json, in stage order."""
    manifest = mf.Manifest.load(asset_dir)
    stages = manifest.data["stages"] if manifest is not None else {}
    return {stage: float(e.get("wall_seconds") or 0.0) for stage, e in stages.items()}


def _csv(rows: Sequence[dict], columns: Sequence[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def _picture(dataset: Path) -> str:
    """The dataset's first image as an inline JPEG data URL, PICTURE_PX on its longer side; '' when none."""
    from PIL import Image

    from real2sim.formats.dataset import read_dataset

    try:
        frames = read_dataset(dataset, check_files=False).frames
        path = dataset / frames[0].file_path
        with Image.open(path) as image:
            image = image.convert("RGB")
            image.thumbnail((PICTURE_PX, PICTURE_PX))
            buffer = io.BytesIO()
            image.save(buffer, format="JPEG", quality=85)
    except Exception:  # noqa: BLE001 -- a page without a picture beats no page
        return ""
    return "data:image/jpeg;base64," + base64.b64encode(buffer.getvalue()).decode()


def write_catalogue(out: Path, jobs: Sequence, outcomes: dict[str, dict]) -> list[dict]:
    """Write catalogue.csv, timings.csv and index.html for ``jobs`` (ObjectJob) into ``out``; the rows."""
    rows, timings, cards = [], [], []
    for job in jobs:
        state = outcomes.get(job.name)
        if state is None:  # not in this batch's outcomes: an earlier batch's, if any
            state = _json(state_path(out, job.name)) or None
        row = object_row(job.name, job.asset_dir, state)
        rows.append(row)
        times = stage_times(job.asset_dir) if row["status"] == "done" else {}
        timings += [{"name": job.name, "stage": s, "wall_s": f"{t:.1f}"} for s, t in times.items()]
        cards.append(_card(row, times, _picture(job.dataset)))
    write_text_atomic(out / "catalogue.csv", _csv(rows, COLUMNS))
    write_text_atomic(out / "timings.csv", _csv(timings, ("name", "stage", "wall_s")))
    write_text_atomic(out / "index.html", _page(rows, cards))
    return rows


def _cell(value: str, unit: str = "", scale: float = 1.0, digits: int = 3) -> str:
    if value == "":
        return "&ndash;"
    return f"{float(value) * scale:.{digits}g}{unit}"


def _card(row: dict, times: dict[str, float], picture: str) -> str:
    e = html.escape
    img = f'<img src="{picture}" alt="{e(row["name"])}">' if picture else '<div class="none">no picture</div>'
    if row["status"] != "done":
        return (f'<tr class="failed"><td>{img}</td><td><b>{e(row["name"])}</b></td>'
                f'<td colspan="6">{e(row["status"])}: {e(row["reason"])}</td></tr>')
    size = " &times; ".join(_cell(row[f"size_{a}_m"], "", 1000, 3) for a in "xyz") + " mm"
    recs = []
    for pref in ("accuracy", "speed"):
        extra = [f"IoU {_cell(row[f'{pref}_iou'])}"] if row[f"{pref}_iou"] else []
        if row[f"{pref}_ocae_m"]:
            extra += [f"OCAE {_cell(row[f'{pref}_ocae_m'], ' mm', 1000)}",
                      f"sim {_cell(row[f'{pref}_sim_time_s'], ' s')}"]
        recs.append(f"{pref}: <b>{e(row[f'{pref}_representation'])}</b> ({', '.join(extra)})")
    truth = "&ndash;"
    if row["truth_chamfer_mm"]:
        truth = (f"Chamfer {_cell(row['truth_chamfer_mm'], ' mm')}, IoU {_cell(row['truth_iou'])}, "
                 f"CoM {_cell(row['truth_com_error_mm'], ' mm')}, "
                 f"inertia {_cell(row['truth_inertia_max_rel_error'], ' %', 100)}")
    stages = ", ".join(f"{e(s)} {t:.0f} s" for s, t in times.items())
    link = f'<a href="{e(row["report"])}">{e(row["report"].split("/", 1)[-1])}</a>' if row["report"] else ""
    return (f'<tr><td>{img}</td><td><b>{e(row["name"])}</b></td><td>{_cell(row["mass_kg"], " kg")}</td>'
            f'<td>{size}</td><td>{"<br>".join(recs)}<br><small>from the {e(row["basis"])}</small></td>'
            f"<td>{truth}</td><td>{stages}</td><td>{link}</td></tr>")


def _page(rows: list[dict], cards: list[str]) -> str:
    done = sum(r["status"] == "done" for r in rows)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>real2sim catalogue</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; }}
td, th {{ border-bottom: 1px solid #ccc; padding: 0.4em 0.7em; text-align: left; vertical-align: top; }}
tr.failed td {{ background: #fdecea; }}
img {{ max-width: {PICTURE_PX}px; }}
.none {{ color: #888; }}
</style></head><body>
<h1>real2sim catalogue</h1>
<p>{done} of {len(rows)} objects done, {len(rows) - done} failed. The same rows: <a href="catalogue.csv">catalogue.csv</a>;
stage times: <a href="timings.csv">timings.csv</a>.</p>
<table>
<tr><th>picture</th><th>object</th><th>mass</th><th>size (asset axes)</th><th>recommended representation</th>
<th>against the truth</th><th>stage times</th><th>report</th></tr>
{chr(10).join(cards)}
</table></body></html>
"""
