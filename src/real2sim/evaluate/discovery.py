"""Asset folders as the evaluation sees them: their representations, reference mesh and frame."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from real2sim.formats.asset_config import read_asset_contact
from real2sim.formats.contact import POINT_URDF_NAME, ContactProperties
from real2sim.plumbing.errors import UserInputError

MJCF_NAME = "model.xml"  # real2sim.asset.export.mjcf.MJCF_NAME (the asset stage is above evaluate)


@dataclass(frozen=True)
class Asset:
    """One asset folder: its name in the results (``object``), physical properties, reference mesh,
    and the contact material it was built with (None: built before asset_config.json, defaults)."""

    name: str
    asset_dir: Path
    physical_properties_path: Path
    reference_mesh_path: Path
    contact: ContactProperties | None = None


@dataclass(frozen=True)
class Representation:
    """One collision representation of an asset: a subfolder of the asset holding ``model.urdf``, and
    ``model_point.urdf`` when it has a model of its own for point contact (None otherwise)."""

    object: str
    name: str
    urdf_path: Path
    point_urdf_path: Path | None = None

    @classmethod
    def at(cls, object_name: str, rep_dir: Path) -> "Representation":
        """The representation held in ``rep_dir`` (its point-contact model if it has one)."""
        point = rep_dir / POINT_URDF_NAME
        return cls(object_name, rep_dir.name, rep_dir / "model.urdf", point if point.is_file() else None)

    @property
    def mjcf_path(self) -> Path:
        """Its MuJoCo model, ``model.xml`` beside ``model.urdf`` (``asset --format mjcf`` writes it)."""
        return self.urdf_path.parent / MJCF_NAME

    def urdf_for(self, contact_model: str) -> Path:
        """The model to simulate with ``contact_model``."""
        return self.point_urdf_path if contact_model == "point" and self.point_urdf_path else self.urdf_path


def _asset_reference_mesh(asset_dir: Path) -> Path:
    """The asset's own reference: the closed solid the fitter saw, else the visual mesh."""
    closed = asset_dir / "visual" / "collision_reference.obj"
    return closed if closed.is_file() else asset_dir / "visual" / "model.obj"


def discover_assets(asset_dirs: Sequence[Path | str]) -> list[Asset]:
    """Check each asset folder and describe it; UserInputError for anything unusable."""
    if not asset_dirs:
        raise UserInputError("no asset folder given")
    assets: list[Asset] = []
    seen: dict[str, Path] = {}
    for raw in asset_dirs:
        d = Path(raw).resolve()
        if not d.is_dir():
            from real2sim.plumbing.paths import missing

            raise UserInputError(f"{raw} is a file, not an asset folder" if d.exists() else missing(raw, "asset folder"))
        props = d / "physical_properties.json"
        if not props.is_file():
            raise UserInputError(f"{raw} is not an asset folder: physical_properties.json is missing")
        if d.name in seen and seen[d.name] != d:
            raise UserInputError(f"two asset folders share the name {d.name!r} ({seen[d.name]} and {d}); rename one")
        if d.name in seen:
            continue
        seen[d.name] = d
        assets.append(Asset(d.name, d, props, _asset_reference_mesh(d), read_asset_contact(d)))
    return assets


def discover_representations(asset_dirs: Sequence[Path | str]) -> list[Representation]:
    """Every representation (subfolder with ``model.urdf``) of every asset, sorted by object then name.

    UserInputError when a folder is not an asset (no physical_properties.json) or has no
    representation.
    """
    reps: list[Representation] = []
    for asset in discover_assets(asset_dirs):
        found = sorted(p for p in asset.asset_dir.iterdir() if p.is_dir() and (p / "model.urdf").is_file())
        if not found:
            raise UserInputError(f"{asset.asset_dir} holds no representation (no <name>/model.urdf)")
        reps.extend(Representation.at(asset.name, p) for p in found)
    return reps


def read_canonical_transform(asset_dir: Path) -> np.ndarray:
    """The 4x4 ``T_asset_from_input`` of an asset (p_asset = T @ p_input, metres)."""
    path = Path(asset_dir) / "canonical_transform.json"
    if not path.is_file():
        raise UserInputError(f"{asset_dir} has no canonical_transform.json, needed to place --reference")
    try:
        data = json.loads(path.read_text())
        matrix = data.get("T_asset_from_input", data.get("matrix", data)) if isinstance(data, dict) else data
        t = np.asarray(matrix, dtype=float)
    except (OSError, ValueError, TypeError):  # not JSON, not text, ragged or non-numeric entries
        t = np.zeros(0)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise UserInputError(f"{path} does not hold a 4x4 transform")
    return t


def place_reference_mesh(reference_mesh: Path | str, asset_dir: Path, out_path: Path) -> Path:
    """Write ``reference_mesh`` (given in the frame of the mesh the asset was built from) into
    the asset frame, as an .obj with normals at ``out_path``."""
    from real2sim.geometry.mesh_io import load_mesh

    mesh = load_mesh(reference_mesh).copy()
    mesh.apply_transform(read_canonical_transform(asset_dir))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(f".{out_path.name}.tmp.obj")
    mesh.export(tmp, include_normals=True)
    tmp.replace(out_path)
    return out_path
