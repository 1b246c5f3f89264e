"""``config.json`` of a results folder: what a sweep was run with, and whether a resume
may add rows to it (the settings that change what a row means must match).

Paths are recorded relative to the results folder (the asset folders, typically
``../box``) and the ``--reference`` mesh by file name and content hash: a results folder
or report that is shared does not tell where the user's files live.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any, Sequence

from real2sim.evaluate.discovery import Asset
from real2sim.plumbing.errors import UserInputError

# Settings that change the meaning of a row: a resumed sweep must use the same ones. The simulator is
# in each row's key (runs.csv's ``simulator``), so simulators may be added; MuJoCo's settings may not change.
PINNED_SETTINGS = ("seed", "scene", "simulation_error", "reference", "reference_contact", "reference_properties",
                   "mujoco")


def _sha1_file(path: Path) -> str:
    digest = hashlib.sha1()
    with open(path, "rb") as fh:
        while block := fh.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def _recorded_path(path: Path, target: Path, partial: Path) -> str:
    """A path as config.json records it: relative to the results folder, never absolute."""
    path = Path(path)
    if partial == path or partial in path.parents:  # written into the results folder itself
        return path.relative_to(partial).as_posix()
    return Path(os.path.relpath(path, target)).as_posix()


def config_record(config, assets: Sequence[Asset], reference_meshes: dict[str, Path],
                   reference_arg: Path | None, target: Path, partial: Path,
                   reference_properties: Path | None = None) -> dict:
    import platform

    try:
        import pydrake

        drake_version = getattr(pydrake, "__version__", "unknown")
    except Exception:  # pragma: no cover
        drake_version = "unknown"
    try:
        import mujoco

        mujoco_version = getattr(mujoco, "__version__", "unknown")
    except Exception:  # pragma: no cover - MuJoCo is an extra
        mujoco_version = "not installed"
    scene = dataclasses.asdict(config.scene) if dataclasses.is_dataclass(config.scene) else repr(config.scene)
    return {
        "seed": config.seed,
        "scene": json.loads(json.dumps(scene, default=str)),
        "simulation_error": config.simulation_error,
        # The reference by name and content: where it lives is the user's business (and private).
        "reference": ({"file": Path(reference_arg).name, "sha1": _sha1_file(Path(reference_arg))}
                      if reference_arg else "asset"),
        # The reference's mass properties: each asset's own, or a given file (by name and content).
        "reference_properties": ({"file": Path(reference_properties).name,
                                  "sha1": _sha1_file(Path(reference_properties))}
                                 if reference_properties else "asset"),
        "tasks": list(config.tasks),
        "contact_models": list(config.contact_models),
        "simulators": list(config.simulators),
        # MuJoCo's contact settings (evaluate.mujoco.config.MujocoConfig), chosen by measurement:
        # docs/design-notes/evaluate.md#mujoco-contact-settings. The same for every MuJoCo row.
        "mujoco": json.loads(json.dumps(dataclasses.asdict(config.mujoco))),
        "runs": config.runs,
        "jobs": config.jobs,
        "executor": config.executor,
        "sim_timeout_s": config.sim_timeout_s,
        "assets": {a.name: _recorded_path(a.asset_dir, target, partial) for a in assets},
        "reference_meshes": {k: _recorded_path(v, target, partial) for k, v in reference_meshes.items()},
        "reference_contact": {a.name: dataclasses.asdict(a.contact) if a.contact else "defaults (no asset_config.json)"
                              for a in assets},
        "protocol": (
            "simulation error: free roll-outs from the same initial state"
            if config.simulation_error or not config.scene.reset_interval_s
            else f"equation error: candidate state reset to the reference state every "
            f"{config.scene.reset_interval_s:g} s (paper V-C: 0.1 s)"
        ),
        "metrics": {
            "ate_m": "mean Euclidean distance between reference and candidate object positions (eq. 17)",
            "ocae_m": "mean ATE of three points at 1 m along the object's x, y, z axes",
            "cpd_m_per_s": "mean |d/dt| (central differences) of the mean contact-point distance from the "
            "object origin, inside contiguous contact runs of >= 3 steps, cut at equation-error resets",
            "cpd_force_weighted_m_per_s": "as cpd_m_per_s, with the mean contact-point distance weighted by "
            "contact force magnitude (not in the paper)",
            "cpd_paper": "the paper's code's CPD: mean |numpy.gradient| per 1 ms sample of the mean distance of the "
            "contact points (missing ones padded with the world origin) from the object origin, whole run "
            "(docs/evaluation.md)",
            "sim_time_s": "wall-clock seconds per candidate simulation (measured under the sweep's parallel load); "
            "Drake: its bare AdvanceTo between resets, MuJoCo: its mj_step loop between resets, set points included",
        },
        "software": {"python": platform.python_version(), "drake": drake_version, "mujoco": mujoco_version,
                     "machine": platform.machine(),
                     "cpus": os.cpu_count()},
    }


def _pinned(key: str, value: Any) -> Any:
    # Before paths were kept private, "reference" was the mesh's absolute path: compare by name then.
    if key == "reference" and isinstance(value, str) and value != "asset":
        return {"file": Path(value).name}
    if key == "reference" and isinstance(value, dict):
        return {"file": value.get("file")}
    return value


def check_resume_settings(folder: Path, target: Path, record: dict) -> None:
    path = folder / "config.json"
    if not path.exists():
        return
    try:
        old = json.loads(path.read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise UserInputError(f"{target.name}/config.json cannot be read ({type(exc).__name__}), so its rows cannot be "
                             "resumed; pass --overwrite to start again, or choose another --out") from None
    for key in PINNED_SETTINGS:
        if key not in old:
            continue
        same = old[key] == record[key]
        if key == "reference" and not same:
            same = _pinned(key, old[key]) == _pinned(key, record[key]) and not (
                isinstance(old[key], dict) and old[key].get("sha1") != record[key].get("sha1"))
        if not same:
            raise UserInputError(
                f"{target.name} holds results made with a different {key}; "
                "pass --overwrite to start again, or choose another --out"
            )
