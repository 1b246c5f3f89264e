"""Report sections about the assets themselves: their pictures and, for assets made by
``real2sim run`` from a simulated capture, how far each stage is from the truth.

Both read the asset folders named in the results folder's ``config.json`` (paths relative
to the results folder); an asset that moved or has no ``truth.json`` simply has no such
section. Pictures are embedded as base64 PNGs, so the page stays self-contained.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Mapping, Sequence


def asset_folders(results_dir: Path, config: Mapping) -> dict[str, Path]:
    """{asset name: folder} of the assets config.json names that exist (relative or absolute paths)."""
    folders = {}
    for name, recorded in (config.get("assets") or {}).items():
        path = Path(recorded)
        path = path if path.is_absolute() else (Path(results_dir) / path)
        if path.is_dir():
            folders[str(name)] = path.resolve()
    return folders


def _f(value, digits: int = 3) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "&ndash;"
    return f"{v:.{digits}g}" if math.isfinite(v) else "&ndash;"


def _img(data: bytes, alt: str) -> str:
    return f"<img class='pic' alt='{html.escape(alt)}' src='data:image/png;base64,{base64.b64encode(data).decode()}'/>"


def pictures_section(results_dir: Path, config: Mapping, rows: Sequence[Mapping]) -> str:
    """Every representation's collision geometry beside the asset's visual mesh, with its metrics."""
    import numpy as np

    from real2sim.report.pictures import asset_picture_pngs

    parts = []
    for name, folder in sorted(asset_folders(results_dir, config).items()):
        pictures = asset_picture_pngs(folder)
        if not pictures:
            continue
        contacts = sorted({r["contact_model"] for r in rows if r["object"] == name})
        head = "".join(f"<th>OCAE [m] {html.escape(c)}</th><th>ST [s] {html.escape(c)}</th>" for c in contacts)
        table = [f"<h3>{html.escape(name)}</h3><p>{_img(pictures['visual'], name + ' visual mesh')}<br/>"
                 "visual mesh; below, each representation's collision geometry from the same camera "
                 "(one colour per shape)</p>",
                 f"<table><thead><tr><th>representation</th><th>collision geometry</th>{head}</tr></thead><tbody>"]
        for rep in sorted(k for k in pictures if k != "visual"):
            cells = []
            for contact in contacts:
                ok = [r for r in rows if r["object"] == name and r["representation"] == rep
                      and r["contact_model"] == contact and not r["error"]]
                for key in ("ocae_m", "sim_time_s"):
                    vals = np.array([r[key] for r in ok], dtype=float)
                    vals = vals[np.isfinite(vals)]
                    cells.append(f"<td>{_f(vals.mean()) if len(vals) else '&ndash;'}</td>")
            table.append(f"<tr><td>{html.escape(rep)}</td><td>{_img(pictures[rep], rep)}</td>{''.join(cells)}</tr>")
        table.append("</tbody></table>")
        parts.append("\n".join(table))
    return "\n".join(parts) if parts else "<p>No asset folder of this sweep could be read for pictures.</p>"


def _truth_table(truth: Mapping) -> str:
    poses = truth.get("camera_poses") or {}
    rec = truth.get("reconstruction") or {}
    phys = truth.get("physical_properties") or {}
    masks = truth.get("masks_iou") or {}
    lines = []

    def pose(entry):
        return (f"{_f(entry.get('trans_mean_mm'))} mm / {_f(entry.get('rot_mean_deg'))} deg"
                if entry else "&ndash;")

    lines.append(("camera poses, mean error before refinement", pose(poses.get("before_refinement"))))
    lines.append(("camera poses, mean error after refinement",
                  pose(poses.get("after_refinement")) if poses.get("after_refinement")
                  else html.escape(str(poses.get("refinement_outcome") or "not refined"))))
    lines.append(("mask IoU against the rendered masks (mean / min)",
                  f"{_f(masks.get('mean'), 4)} / {_f(masks.get('min'), 4)}" if masks else "&ndash;"))
    lines.append(("reconstruction: Chamfer [mm], IoU, F-score at 1 mm",
                  f"{_f(rec.get('chamfer_mm'))}, {_f(rec.get('iou'))}, {_f(rec.get('fscore_1mm'))}" if rec
                  else "&ndash;"))
    lines.append(("centre of mass error [mm]", _f(phys.get("com_error_mm"))))
    lines.append(("inertia: largest relative error of the principal moments",
                  f"{100 * float(phys['inertia_eigenvalue_max_rel_error']):.2f} %"
                  if "inertia_eigenvalue_max_rel_error" in phys else "&ndash;"))
    uniform = truth.get("physical_properties_uniform_density")
    if uniform:  # the asset was given measured properties: what uniform density would have said, beside them
        lines.append(("uniform density instead: centre of mass error [mm]", _f(uniform.get("com_error_mm"))))
        lines.append(("uniform density instead: inertia, largest relative error",
                      f"{100 * float(uniform['inertia_eigenvalue_max_rel_error']):.2f} %"))
    return ("<table><tbody>" + "".join(f"<tr><td>{label}</td><td>{value}</td></tr>" for label, value in lines)
            + "</tbody></table>")


def _dynamics_table(dynamics: Mapping) -> str:
    rows = dynamics.get("representations") or []
    if not rows:
        return ""
    out = ["<table><thead><tr><th>representation</th><th>contact</th><th>OCAE [m] vs reconstruction (paper)</th>"
           "<th>OCAE [m] vs truth</th><th>ATE [m] vs truth</th><th>truth / reconstruction</th></tr></thead><tbody>"]
    for r in rows:
        out.append(f"<tr><td>{html.escape(str(r['representation']))}</td><td>{html.escape(str(r['contact_model']))}</td>"
                   f"<td>{_f(r.get('ocae_vs_reconstruction_m'))}</td><td>{_f(r.get('ocae_vs_truth_m'))}</td>"
                   f"<td>{_f(r.get('ate_vs_truth_m'))}</td><td>{_f(r.get('truth_over_reconstruction'))}</td></tr>")
    out.append("</tbody></table>")
    return ("<p>Each representation simulated against the reconstruction (the paper's protocol) and against "
            "the true object (true mesh, true mass properties) with the same settings. The <code>mesh</code> row "
            "is the reconstruction itself.</p>" + "\n".join(out))


def truth_section(results_dir: Path, config: Mapping) -> str:
    """How far each stage of each asset is from the true object (from ASSETDIR/truth.json), or ''."""
    parts = []
    for name, folder in sorted(asset_folders(results_dir, config).items()):
        path = folder / "truth.json"
        try:
            truth = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(truth, dict):
            continue
        parts.append(f"<h3>{html.escape(name)}</h3>{_truth_table(truth)}{_dynamics_table(truth.get('dynamics') or {})}")
    if not parts:
        return ""
    return ("<h2>Against the truth</h2><p>The capture was simulated from a known object, so every stage is "
            "judged against it (ASSETDIR/truth.json).</p>" + "\n".join(parts))


#: Where `real2sim run` records each stage of an asset folder, with the warnings it raised
#: (real2sim.pipeline.manifest; read here as a file, the report being below the pipeline).
RUN_MANIFEST = Path(".run") / "run.json"


def asset_warnings(folder: Path) -> list[dict]:
    """The warnings `real2sim run` recorded for the asset in ``folder`` (``{"stage", "message"}``, in
    the order of its stages), [] for an asset not made by run or an unreadable record."""
    try:
        stages = json.loads((Path(folder) / RUN_MANIFEST).read_text()).get("stages")
    except (OSError, ValueError, AttributeError):
        return []
    found: list[dict] = []
    for name, entry in stages.items() if isinstance(stages, dict) else ():
        texts = entry.get("warnings") if isinstance(entry, dict) else None
        if isinstance(texts, list):
            found += [{"stage": str(name), "message": str(text)} for text in texts]
    return found


def warnings_section(results_dir: Path, config: Mapping) -> str:
    """What degraded while `real2sim run` made the assets (a fallback, poses that stayed unrefined), or ''.
    Near the top of the page: every number below is to be read with it."""
    items = [f"<li><b>{html.escape(name)}</b>, stage {html.escape(w['stage'])}: {html.escape(w['message'])}</li>"
             for name, folder in sorted(asset_folders(results_dir, config).items()) for w in asset_warnings(folder)]
    if not items:
        return ""
    return ("<h2 class='err'>Warnings</h2><p class='err'>Making the assets fell back or degraded on the way "
            "(ASSETDIR/.run/run.json); the results below are those of the assets as made.</p><ul>"
            + "".join(items) + "</ul>")


def animations_section(results_dir: Path) -> str:
    """Links to RESULTS/animations/*.html (self-contained Meshcat pages), or ''."""
    pages = sorted((Path(results_dir) / "animations").glob("*.html"))
    if not pages:
        return ""
    links = "".join(f"<li><a href='animations/{html.escape(p.name)}'>{html.escape(p.stem)}</a></li>" for p in pages)
    return ("<h2>Animations</h2><p>One run of each task: the reference (grey) beside the representation "
            "recommended for accuracy (orange), simulated from the same start without resets. Each page is "
            f"self-contained (Drake's Meshcat, no network); press play in its controls.</p><ul>{links}</ul>")
