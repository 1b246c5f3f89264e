"""Physical properties of an asset and their ``physical_properties.json`` file."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
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
    mass_standard_error_kg: float | None = field(default=None, compare=False)

    @property
    def inertia(self) -> np.ndarray:
        return np.asarray(self.inertia_kg_m2, dtype=float)

    def to_json(self) -> dict:
        d = asdict(self)
        d["com_m"] = list(self.com_m)
        d["inertia_kg_m2"] = [list(r) for r in self.inertia_kg_m2]
        if self.mass_standard_error_kg is None:
            del d["mass_standard_error_kg"]
        return d


def write_physical_properties(props: PhysicalProperties, path: Path, extra: dict | None = None) -> None:
    """Write ``props`` (and the ``extra`` keys beside them: where they came from, alternatives)."""
    Path(path).write_text(json.dumps({**props.to_json(), **(extra or {})}, indent=1))


#: Heaviest object real2sim takes, kg: the range of ``--mass-kg`` and of a properties file's ``mass_kg``.
MAX_MASS_KG = 1000.0
#: ``frame`` of a properties file whose CoM and inertia are in the object's own mesh frame (what
#: `real2sim identify` writes); without the key a file is in the asset frame (physical_properties.json).
MESH_FRAME = "mesh"
#: Relative tolerance (of the largest principal moment) of the inertia checks: rounding of a file
#: written by another program, not a physical allowance.
INERTIA_RTOL = 1e-6
#: Smallest principal moment over the largest that still counts as positive-definite: a wire
#: 0.1 mm across and 0.2 m long is 1.5e-6; a mass on a line (singular inertia) is refused.
MIN_MOMENT_RATIO = 1e-9


def _shown(value: object) -> str:
    """``value`` as the message shows it: floats as Python prints them, anything else as JSON, cut short."""
    if isinstance(value, float):
        return f"{value:g}"
    try:
        text = json.dumps(value)
    except (RecursionError, ValueError):
        return "a value nested too deep to show"
    return text if len(text) <= 40 else text[:37] + "..."


def _is_number(value: object) -> bool:
    """A JSON number: int or float, never ``true``/``false`` (bool is an int in Python) nor a string."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite(value: object) -> float | None:
    """``value`` as a finite float when it is a JSON number that is one, else None (an integer of
    400 digits overflows a float)."""
    if not _is_number(value):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if np.isfinite(number) else None


def _numbers(value: object, count: int) -> list[float] | None:
    """``value`` as ``count`` finite floats when it is a JSON list of that many finite numbers, else None."""
    if not isinstance(value, list) or len(value) != count:
        return None
    floats = [_finite(v) for v in value]
    return None if any(v is None for v in floats) else floats


def _mass_standard_error(d: dict, fail) -> float | None:
    """The mass's standard error a file carries: ``mass_standard_error_kg`` (an asset built from
    identified properties) or identify's ``identification.standard_errors.mass_kg``; None without one."""
    if "mass_standard_error_kg" in d:
        name, value = "mass_standard_error_kg", d["mass_standard_error_kg"]
    else:
        identification = d.get("identification")
        errors = identification.get("standard_errors") if isinstance(identification, dict) else None
        if not isinstance(errors, dict) or "mass_kg" not in errors:
            return None
        name, value = "identification.standard_errors.mass_kg", errors["mass_kg"]
    error = _finite(value)
    if error is None or error < 0:
        fail(f"{name} must be a finite number >= 0 kg, got {_shown(value)}")
    return error


def parse_properties(path: Path | str, label: str = "") -> tuple[PhysicalProperties, str]:
    """The one reader of properties files (physical_properties.json, identify's props.json, ``--properties``):
    (properties, frame), frame :data:`MESH_FRAME` or ``"asset"``.

    UserInputError (one line, ``label`` then the file, then the field) when the file is missing or not
    UTF-8 JSON, not a JSON object, nested too deep to parse; ``mass_kg`` not a JSON number (``true`` or
    ``"0.4"`` is refused), not finite, <= 0 or above :data:`MAX_MASS_KG`; ``com_m`` not 3 finite
    numbers; ``inertia_kg_m2`` not 3 rows of 3 finite numbers, zero, not symmetric, not positive-definite
    (smallest principal moment at most :data:`MIN_MOMENT_RATIO` of the largest) or breaking the triangle
    inequality of principal moments (both within :data:`INERTIA_RTOL` of the largest);
    ``samples_kept`` not an integer >= 0; ``method`` not a string; ``frame`` not "mesh" or "asset";
    a mass standard error (:func:`_mass_standard_error`) not a finite number >= 0.
    """
    from real2sim.plumbing.errors import UserInputError

    path = Path(path)

    def fail(why: str):
        raise UserInputError(f"{label}{path}: {why}")

    try:
        text = path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise UserInputError(f"{label}{path} does not exist") from None
    except UnicodeDecodeError as exc:
        raise UserInputError(f"{label}{path} is not a readable properties file: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise UserInputError(f"{label}{path} is not a readable properties file ({exc.strerror or exc})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UserInputError(f"{label}{path} is not a readable properties file: not JSON ({exc.msg} at line "
                             f"{exc.lineno} column {exc.colno})") from None
    except RecursionError:
        raise UserInputError(f"{label}{path} is not a readable properties file: JSON nested too deep to read") from None
    if not isinstance(d, dict):
        raise UserInputError(f"{label}{path} is not a readable properties file: not a JSON object with mass_kg, "
                             "com_m and inertia_kg_m2")
    for key in ("mass_kg", "com_m", "inertia_kg_m2"):
        if key not in d:
            fail(f"{key} is missing (a properties file has mass_kg, com_m and inertia_kg_m2)")
    mass = d["mass_kg"]
    if not _is_number(mass):
        fail(f"mass_kg must be a JSON number (kg), got {_shown(mass)}")
    mass = _finite(mass)
    if mass is None or mass <= 0:
        fail(f"mass_kg must be a finite number > 0, got {_shown(d['mass_kg'])}")
    if mass > MAX_MASS_KG:
        fail(f"mass_kg must be at most {MAX_MASS_KG:g} kg, got {_shown(mass)}")
    com = _numbers(d["com_m"], 3)
    if com is None:
        fail(f"com_m must be a list of 3 finite numbers (m), got {_shown(d['com_m'])}")
    rows = d["inertia_kg_m2"]
    inertia_rows = [_numbers(row, 3) for row in rows] if isinstance(rows, list) and len(rows) == 3 else [None]
    if any(row is None for row in inertia_rows):
        fail(f"inertia_kg_m2 must be 3 rows of 3 finite numbers (kg m^2), got {_shown(rows)}")
    inertia = np.asarray(inertia_rows)
    scale = float(np.abs(inertia).max())
    if scale <= 0:
        fail("inertia_kg_m2 is zero")
    if not np.allclose(inertia, inertia.T, rtol=0.0, atol=1e-9 * scale):
        fail("inertia_kg_m2 is not symmetric")
    moments = np.linalg.eigvalsh(inertia)
    shown = ", ".join(f"{m:.3g}" for m in moments)
    if moments[0] <= MIN_MOMENT_RATIO * max(float(moments[2]), 0.0):
        fail(f"inertia_kg_m2 is not a physical inertia: principal moments {shown} kg m^2 must all be > 0 "
             f"(more than {MIN_MOMENT_RATIO:g} of the largest)")
    if moments[0] + moments[1] < moments[2] * (1.0 - INERTIA_RTOL):
        fail(f"inertia_kg_m2 is not a physical inertia: principal moments {shown} kg m^2 break the triangle "
             "inequality (the two smaller must sum to at least the largest)")
    samples = d.get("samples_kept", 0)
    whole = _finite(samples)
    if whole is None or whole < 0 or not whole.is_integer():
        fail(f"samples_kept must be an integer >= 0, got {_shown(samples)}")
    method = d.get("method", f"given ({path.name})" if label else "")
    if not isinstance(method, str):
        fail(f"method must be a string, got {_shown(method)}")
    frame = d.get("frame", "asset")
    if frame not in (MESH_FRAME, "asset"):
        fail(f"frame must be 'mesh' or 'asset', got {_shown(frame)}")
    props = PhysicalProperties(mass_kg=mass, com_m=tuple(com), inertia_kg_m2=tuple(tuple(r) for r in inertia_rows),
                               method=method, samples_kept=int(whole),
                               mass_standard_error_kg=_mass_standard_error(d, fail))
    return props, frame


def read_physical_properties(path: Path) -> PhysicalProperties:
    """An asset's ``physical_properties.json`` (asset frame), through :func:`parse_properties`:
    UserInputError naming the file and the field when it is not a physical one."""
    return parse_properties(path)[0]


def read_given_properties(path: Path) -> tuple[PhysicalProperties, str]:
    """A user's ``--properties`` file: (properties, frame), frame ``"mesh"`` or ``"asset"``; the
    checks of :func:`parse_properties`, each error starting with ``--properties``."""
    return parse_properties(path, "--properties ")


def moved_properties(props: PhysicalProperties, transform: np.ndarray, method: str | None = None) -> PhysicalProperties:
    """``props`` expressed in another frame: ``transform`` (4x4, rigid) maps points of the old frame
    into the new one."""
    t = np.asarray(transform, dtype=float)
    rotation = t[:3, :3]
    com = rotation @ np.asarray(props.com_m) + t[:3, 3]
    inertia = rotation @ props.inertia @ rotation.T
    return PhysicalProperties(mass_kg=props.mass_kg, com_m=tuple(float(v) for v in com),
                              inertia_kg_m2=tuple(tuple(float(v) for v in row) for row in inertia),
                              method=method or props.method, samples_kept=props.samples_kept,
                              mass_standard_error_kg=props.mass_standard_error_kg)
