"""An asset folder's own README.md: what made it, from what, its mass properties, the file per simulator, the fits.

In the manner of MuJoCo Menagerie's model folders, every asset folder says by itself where it came
from and how good it is. The README is written last, from the files of the folder itself
(asset_config.json, physical_properties.json, each representation's fit_report.json and model files),
so a build that reuses earlier fits describes exactly what the folder holds.
"""

from __future__ import annotations

import datetime as _dt
import json
import shlex
import struct
import sys
from pathlib import Path

from real2sim.asset.export.writers import SIMULATOR_FILES

README_NAME = "README.md"
PREVIEW_NAME = "preview.png"
#: Side of each square panel of an asset's preview.png, px: about a second of ray casting per panel on a
#: shared 2-core machine (measured in docs/design-notes/asset.md#asset-folder-readme-and-preview).
PREVIEW_PANEL_PX = 160

#: How each key of SIMULATOR_FILES reads in the README.
SIMULATOR_NAMES = {
    "drake": "Drake (hydroelastic contact)",
    "drake_point": "Drake (point contact)",
    "mujoco": "MuJoCo",
    "pybullet": "PyBullet",
    "isaac": "Isaac Sim (USD)",
    "gazebo": "Gazebo (SDFormat)",
    "urdf": "any other URDF reader",
}


def invocation() -> str | None:
    """The ``real2sim ...`` command line when this process is the real2sim command, else None."""
    if Path(sys.argv[0]).name != "real2sim":
        return None
    return "real2sim " + shlex.join(sys.argv[1:])


def png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) in px of the PNG at ``path``; None when it is not a PNG."""
    try:
        head = Path(path).read_bytes()[:24]
    except OSError:
        return None
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", head[16:24])


def _json(path: Path) -> dict:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def _mm(values) -> str:
    return "(" + ", ".join(f"{1e3 * float(v):.2f}" for v in values) + ") mm"


def _mass_section(asset_dir: Path, config: dict) -> list[str]:
    props = _json(asset_dir / "physical_properties.json")
    if not props:
        return ["No physical_properties.json."]
    import numpy as np

    inertia = np.asarray(props.get("inertia_kg_m2", np.zeros((3, 3))), dtype=float)
    principal = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    source = props.get("source")
    if source:
        where = f"given: `{source}` ({props.get('method', 'method not stated')})"
    else:
        where = (f"uniform density from the measured mass {float(config.get('mass_kg', props['mass_kg'])):g} kg "
                 f"({props.get('method', 'uniform density')})")
    return [
        "| property | value |",
        "|---|---|",
        f"| mass | {float(props['mass_kg']):g} kg |",
        f"| centre of mass (asset frame) | {_mm(props.get('com_m', (0, 0, 0)))} |",
        "| principal moments of inertia about it | " + ", ".join(f"{m:.4g}" for m in principal) + " kg m^2 |",
        "",
        f"Where they come from: {where}. The whole tensor is in `physical_properties.json`; the asset frame "
        "(centred, principal axis +z) against the input mesh's in `canonical_transform.json`.",
    ]


def representations(asset_dir: Path) -> list[tuple[str, dict]]:
    """(folder name, fit_report.json) of every representation of the asset, in folder order."""
    return [(p.parent.name, _json(p.parent / "fit_report.json"))
            for p in sorted(Path(asset_dir).glob("*/collision.json"))]


def _simulator_section(asset_dir: Path, reps: list[tuple[str, dict]]) -> list[str]:
    rows = []
    for key, (name, _) in SIMULATOR_FILES.items():
        have = [rep for rep, _ in reps if (asset_dir / rep / name).is_file()]
        if have:
            example = f"`{have[0]}/{name}`"
            rows.append(f"| {SIMULATOR_NAMES.get(key, key)} | `{name}` | {example}"
                        + ("" if len(have) == len(reps) else f" (only in {', '.join(have)})") + " |")
    if not rows:
        return ["No model files."]
    return ["| simulator | file in each representation's folder | e.g. |", "|---|---|---|", *rows]


def _fit_section(reps: list[tuple[str, dict]]) -> list[str]:
    def num(report: dict, key: str, fmt: str) -> str:
        value = report.get(key)
        return format(float(value), fmt) if isinstance(value, (int, float)) else "-"

    rows = []
    for name, report in reps:
        made = ("reused from an earlier build" if "reused" in report
                else f"{num(report, 'fit_seconds', '.1f')} s" if "fit_seconds" in report else "-")
        rows.append(f"| {name} | `{report.get('spec', '?')}` | {report.get('num_primitives', '-')} | "
                    f"{num(report, 'iou', '.3f')} | {num(report, 'chamfer_mm', '.2f')} | "
                    f"{report.get('method', '-')} | {made} |")
    return ["| representation | SPEC | pieces | IoU | Chamfer (mm) | method | fitted in |",
            "|---|---|---|---|---|---|---|", *rows, "",
            "IoU (volume) and symmetric Chamfer distance of each collision geometry against the input's closed "
            "solid (`visual/collision_reference.obj`), from each folder's `fit_report.json` (which also holds "
            "the fit's own figures)."]


def asset_readme(asset_dir: Path | str, *, mesh: str, command: str | None = None, date: str | None = None) -> str:
    """The text of an asset folder's README.md, read from the folder's own files.

    Args:
        asset_dir: the asset folder (or its staged copy before publication).
        mesh: the input mesh as the build was given it (a path or a name).
        command: the command line or call that built it; None: "from Python".
        date: UTC date and time to state; None: now.

    Returns:
        Markdown, about 40 lines.
    """
    asset_dir = Path(asset_dir)
    config = _json(asset_dir / "asset_config.json")
    version = (config.get("software") or {}).get("real2sim", "unknown")
    date = date or _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    made = f"`{command}`" if command else "a call from Python (`real2sim.build_asset` or `real2sim.asset.build_asset`)"
    digest = config.get("input_mesh_sha256")
    reps = representations(asset_dir)
    lines = [
        "# Simulation asset",
        "",
        f"A simulation asset made by real2sim {version} on {date} with {made}.",
        "",
        f"Input: `{mesh}`" + (f" (SHA-256 `{digest}`)" if digest else "")
        + f", units {config.get('mesh_units', 'm')}" + (", its bottom closed flat" if config.get("flat_bottom") else "")
        + ". Every setting of the build is in `asset_config.json`.",
        "",
    ]
    size = png_size(asset_dir / PREVIEW_NAME)
    if size:
        lines += [f"![the visual mesh beside each representation's collision geometry]({PREVIEW_NAME})", "",
                  f"`{PREVIEW_NAME}` ({size[0]} x {size[1]} px): the visual mesh beside each representation's "
                  "collision geometry, one camera for all.", ""]
    lines += ["## Mass properties", "", *_mass_section(asset_dir, config), "",
              "## Which file for which simulator", "", *_simulator_section(asset_dir, reps), "",
              "## Representations and their fit", "", *_fit_section(reps), ""]
    return "\n".join(lines)


def write_asset_readme(asset_dir: Path | str, *, mesh: str, command: str | None = None,
                       date: str | None = None) -> Path:
    """Write :func:`asset_readme` as ``asset_dir/README.md`` (the folder is the build's staged one, so the
    file appears with the rest); returns its path."""
    path = Path(asset_dir) / README_NAME
    path.write_text(asset_readme(asset_dir, mesh=mesh, command=command, date=date))
    return path
