"""Physical properties of an asset and their ``physical_properties.json`` file."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class PhysicalProperties:
    """Mass, centre of mass and inertia about the centre of mass, in the asset frame.

    ``inertia_kg_m2`` is the 3x3 rotational inertia about the CoM (kg m^2), expressed
    in the asset frame's axes.
    """

    mass_kg: float
    com_m: tuple[float, float, float]
    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    method: str = "uniform density over interior samples (paper IV-D, eq. 15-16)"
    samples_kept: int = 0

    @property
    def inertia(self) -> np.ndarray:
        return np.asarray(self.inertia_kg_m2, dtype=float)

    def to_json(self) -> dict:
        d = asdict(self)
        d["com_m"] = list(self.com_m)
        d["inertia_kg_m2"] = [list(r) for r in self.inertia_kg_m2]
        return d


def write_physical_properties(props: PhysicalProperties, path: Path) -> None:
    Path(path).write_text(json.dumps(props.to_json(), indent=1))


def read_physical_properties(path: Path) -> PhysicalProperties:
    d = json.loads(Path(path).read_text())
    return PhysicalProperties(
        mass_kg=float(d["mass_kg"]),
        com_m=tuple(float(v) for v in d["com_m"]),
        inertia_kg_m2=tuple(tuple(float(v) for v in row) for row in d["inertia_kg_m2"]),
        method=d.get("method", ""),
        samples_kept=int(d.get("samples_kept", 0)),
    )
