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


def write_physical_properties(props: PhysicalProperties, path: Path, extra: dict | None = None) -> None:
    """Write ``props`` (and the ``extra`` keys beside them: where they came from, alternatives)."""
    Path(path).write_text(json.dumps({**props.to_json(), **(extra or {})}, indent=1))


def read_physical_properties(path: Path) -> PhysicalProperties:
    d = json.loads(Path(path).read_text())
    return PhysicalProperties(
        mass_kg=float(d["mass_kg"]),
        com_m=tuple(float(v) for v in d["com_m"]),
        inertia_kg_m2=tuple(tuple(float(v) for v in row) for row in d["inertia_kg_m2"]),
        method=d.get("method", ""),
        samples_kept=int(d.get("samples_kept", 0)),
    )


#: ``frame`` of a properties file whose CoM and inertia are in the object's own mesh frame (what
#: `real2sim identify` writes); without the key a file is in the asset frame (physical_properties.json).
MESH_FRAME = "mesh"


def read_given_properties(path: Path) -> tuple[PhysicalProperties, str]:
    """A user's ``--properties`` file: (properties, frame), frame ``"mesh"`` or ``"asset"``.

    UserInputError (one line) when it is not a properties file or not physically possible: mass not
    finite and > 0, inertia not symmetric, not positive semidefinite, or breaking the triangle
    inequality of principal moments.
    """
    from real2sim.formats.errors import UserInputError

    path = Path(path)
    try:
        d = json.loads(path.read_text())
        props = PhysicalProperties(
            mass_kg=float(d["mass_kg"]), com_m=tuple(float(v) for v in d["com_m"]),
            inertia_kg_m2=tuple(tuple(float(v) for v in row) for row in d["inertia_kg_m2"]),
            method=str(d.get("method", f"given ({path.name})")), samples_kept=int(d.get("samples_kept", 0)))
        frame = str(d.get("frame", "asset"))
    except FileNotFoundError:
        raise UserInputError(f"--properties: {path} does not exist") from None
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise UserInputError(f"--properties: {path} is not a properties file with mass_kg, com_m and "
                             f"inertia_kg_m2 ({exc.__class__.__name__}: {exc})") from None
    inertia = props.inertia
    if inertia.shape != (3, 3) or len(props.com_m) != 3:
        raise UserInputError(f"--properties: {path}: com_m must have 3 values and inertia_kg_m2 be 3x3")
    if not (np.isfinite(props.mass_kg) and props.mass_kg > 0 and np.all(np.isfinite(inertia))
            and np.all(np.isfinite(props.com_m))):
        raise UserInputError(f"--properties: {path}: mass must be finite and > 0 kg, CoM and inertia finite")
    if not np.allclose(inertia, inertia.T, atol=1e-12 + 1e-9 * np.abs(inertia).max()):
        raise UserInputError(f"--properties: {path}: inertia_kg_m2 is not symmetric")
    moments = np.linalg.eigvalsh(inertia)
    tol = 1e-9 * max(float(moments.max()), 1e-12)
    if moments.min() < -tol or moments[0] + moments[1] < moments[2] - tol:
        raise UserInputError(f"--properties: {path}: inertia_kg_m2 is not a physical inertia (principal moments "
                             f"{', '.join(f'{m:.3g}' for m in moments)} kg m^2)")
    if frame not in (MESH_FRAME, "asset"):
        raise UserInputError(f"--properties: {path}: frame must be 'mesh' or 'asset', not {frame!r}")
    return props, frame


def moved_properties(props: PhysicalProperties, transform: np.ndarray, method: str | None = None) -> PhysicalProperties:
    """``props`` expressed in another frame: ``transform`` (4x4, rigid) maps points of the old frame
    into the new one."""
    t = np.asarray(transform, dtype=float)
    rotation = t[:3, :3]
    com = rotation @ np.asarray(props.com_m) + t[:3, 3]
    inertia = rotation @ props.inertia @ rotation.T
    return PhysicalProperties(mass_kg=props.mass_kg, com_m=tuple(float(v) for v in com),
                              inertia_kg_m2=tuple(tuple(float(v) for v in row) for row in inertia),
                              method=method or props.method, samples_kept=props.samples_kept)
