"""Reusing the representations of an earlier asset build: a rerun of `run` that adds a SPEC, or
changes only the mass, the contact material or the formats, fits nothing it fitted before.

A representation's geometry depends on the input mesh (its bytes) and on every asset setting but
:data:`NOT_GEOMETRY`; asset_config.json records both (``input_mesh_sha256``), so an earlier folder
tells by itself whether its fits still hold.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from real2sim.formats.asset_config import ASSET_CONFIG_NAME
from real2sim.formats.collision import CollisionGeometry
from real2sim.plumbing.errors import UserInputError

#: Settings of asset_config.json that do not shape the collision geometry: a representation fitted
#: under other values of these is still valid (its model files are rewritten, see rewrite_models).
NOT_GEOMETRY = ("mass_kg", "collision", "contact", "mujoco", "formats", "properties")
#: What write_representation writes into a representation folder.
MODEL_FILES = ("model.urdf", "model_point.urdf", "model.sdf", "model.xml", "model_portable.urdf", "scene.xml",
               "model.usda")


def reusable_representations(previous_dir: Path | str, config_path: Path) -> dict[str, Path]:
    """``{SPEC text: folder}`` of the representations in the asset folder ``previous_dir`` that a build
    with the asset_config.json at ``config_path`` may reuse: both records name the same input mesh
    (SHA-256) and agree on every setting but :data:`NOT_GEOMETRY` (software versions included), and
    the folder's fit_report.json names the same SPEC. Empty when anything is unreadable."""
    try:
        before = json.loads((Path(previous_dir) / ASSET_CONFIG_NAME).read_text())
        now = json.loads(Path(config_path).read_text())
    except (OSError, ValueError):
        return {}
    if not isinstance(before, dict) or "input_mesh_sha256" not in before:
        return {}
    if any(before.get(k) != now.get(k) for k in set(before) | set(now) if k not in NOT_GEOMETRY):
        return {}
    from real2sim.formats.spec import parse_spec

    found = {}
    for text in before.get("collision", []):
        try:
            folder = Path(previous_dir) / parse_spec(text).name
            report = json.loads((folder / "fit_report.json").read_text())
        except (OSError, ValueError, UserInputError):
            continue
        if report.get("spec") == text and (folder / "collision.json").is_file():
            found[text] = folder
    return found


def reuse_collision(source: Path, rep_dir: Path) -> tuple[CollisionGeometry, dict]:
    """An earlier fit of the same SPEC and geometry settings: its folder copied without model files."""
    from real2sim.formats.collision import read_collision_json

    shutil.copytree(source, rep_dir, dirs_exist_ok=True, ignore=shutil.ignore_patterns(*MODEL_FILES))
    report = json.loads((rep_dir / "fit_report.json").read_text())
    report.pop("mjcf_notes", None)  # written again for this build's formats
    report["reused"] = "fitted by an earlier build with the same mesh and geometry settings"
    return read_collision_json(rep_dir / "collision.json"), report
