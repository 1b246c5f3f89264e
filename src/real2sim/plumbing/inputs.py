"""What a command reads, and the one rule that keeps it: no output may overlap an input.

Every verb declares the paths it reads and writes (``real2sim.cli.options.declare_paths``); before
any work :func:`check_outputs_spare_inputs` refuses an output that is, contains or lies inside
any input, or any file an input brings with it (:func:`companion_files`: an OBJ's material
library and textures, a URDF's meshes), whatever ``--overwrite`` says. The library functions that
publish outputs (:func:`real2sim.plumbing.outputs.check_output_dir`) apply the same rule to the
inputs they are given.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Iterable

from real2sim.plumbing.errors import UserInputError

#: Companion files are looked for in inputs up to this size; a larger OBJ is read for its
#: ``mtllib`` lines only in its first part (they come first in every exporter we know of).
_SCAN_BYTES = 64 << 20

_MTLLIB = re.compile(rb"^[ \t]*mtllib[ \t]+([^\r\n]+?)[ \t]*\r?$", re.MULTILINE)
_MAP = re.compile(rb"^[ \t]*(?:map_\w+|bump|disp|decal|norm|refl)[ \t]+(?:-\S+(?:[ \t]+[-\d.]+)*[ \t]+)*([^\r\n]+?)[ \t]*\r?$",
                  re.MULTILINE)
_URDF_MESH = re.compile(r"""<mesh\b[^>]*\bfilename\s*=\s*["']([^"']+)["']""")


def resolve_path(path: Path | str, *, what: str = "path") -> Path:
    """``path`` absolute with symbolic links resolved; UserInputError (one line) for a link loop,
    which ``Path.resolve`` reports as a RuntimeError (Python 3.11) or an OSError."""
    try:
        return Path(path).expanduser().resolve()
    except (RuntimeError, OSError):
        raise UserInputError(f"{what} {path}: a symbolic link loop (a link that points back to itself)") from None


def is_within(child: Path, parent: Path) -> bool:
    """True when ``child`` is ``parent`` or lies below it (both absolute, resolved)."""
    return child == parent or parent in child.parents


def overlap(output: Path, source: Path) -> str | None:
    """How the output path ``output`` overlaps the input ``source`` (both resolved): ``"is"``,
    ``"contains"`` or ``"lies inside"``; None when they are apart."""
    if output == source:
        return "is"
    if is_within(source, output):
        return "contains"
    if is_within(output, source):
        return "lies inside"
    return None


def _read_head(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(_SCAN_BYTES)
    except OSError:
        return b""


def _names(pattern: re.Pattern, data: bytes) -> list[str]:
    return [m.group(1).decode("utf-8", "replace") for m in pattern.finditer(data)]


def companion_files(path: Path | str) -> list[Path]:
    """The files that reading ``path`` also reads, as absolute paths: an OBJ's ``mtllib`` files and
    the texture maps they name, a URDF's relative ``<mesh filename=...>`` files. Empty for other
    inputs (a dataset keeps every file it names inside its own folder) and for unreadable ones."""
    path = Path(path)
    if not path.is_file():
        return []
    suffix = path.suffix.lower()
    found: list[Path] = []
    if suffix == ".obj":
        for library in _names(_MTLLIB, _read_head(path)):
            mtl = path.parent / library
            found.append(mtl)
            found.extend(mtl.parent / image for image in _names(_MAP, _read_head(mtl)) if mtl.is_file())
    elif suffix == ".urdf":
        text = _read_head(path).decode("utf-8", "replace")
        found.extend(path.parent / name for name in _URDF_MESH.findall(text) if "://" not in name)
    return [Path(os.path.abspath(p)) for p in found]


def check_outputs_spare_inputs(outputs: Iterable[tuple[str, Path]], inputs: Iterable[tuple[str, Path]], *,
                               skip_missing: bool = True) -> None:
    """Refuse (UserInputError, one line naming both options) an output that is or contains the
    working folder, or that is, contains or lies inside an input or a file an input brings with it
    (:func:`companion_files`).

    ``outputs`` and ``inputs`` are ``(option, path)`` pairs, e.g. ``("--out", Path("log"))``. Inputs
    that do not exist are skipped unless ``skip_missing`` is False: they hold nothing to lose (and a
    bundled object's name, such as ``can``, is no path)."""
    sources: list[tuple[str, Path]] = []
    for label, item in inputs:
        if skip_missing and not os.path.lexists(item):
            continue
        sources.append((label, resolve_path(item, what=label)))
        sources.extend((f"a file that {label} reads", resolve_path(p, what=label)) for p in companion_files(item))
    cwd = Path.cwd().resolve()
    for out_label, out in outputs:
        target = resolve_path(Path(os.path.abspath(Path(out).expanduser())), what=out_label)
        if is_within(cwd, target):
            raise UserInputError(f"{out_label} {out} is or contains the working folder; choose a new folder")
        for in_label, source in sources:
            relation = overlap(target, source)
            if relation == "lies inside" and source.is_file():
                raise UserInputError(f"{out_label} {out} lies under {source}, which is a file, not a folder")
            if relation is not None:
                raise UserInputError(f"{out_label} {out} {relation} the input {source} ({in_label}); "
                                     "choose an output apart from every input (--overwrite never removes an input)")
