"""Whose is ``DATASET/masks_<method>/``: `real2sim mask` replaces only a folder it made, and only
when every file in it is one it wrote, unchanged.

The folder's marker (:data:`~real2sim.plumbing.outputs.MARKER_NAME`) lists the masks `mask` wrote
with their SHA-256. On a rerun the folder is replaced whole when it holds exactly those files, as
written; anything else in it stops the rerun with one line naming it, before any work: a file the
user added (never deleted: the user moves it and runs again), or a mask edited by hand (replaced
only with ``mask --overwrite``). A folder without the marker is the user's unless it holds nothing but masks the frames of
transforms.json point to (one made by `mask` before the marker existed), and is never replaced.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from real2sim.formats.dataset import Dataset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME, write_bytes_atomic


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_mask_marker(folder: Path, method: str, names: list[str]) -> None:
    """The marker of a finished ``masks_<method>/``: made by `mask`, and the masks it wrote (SHA-256)."""
    from real2sim.plumbing.version import __version__

    record = {"made_by": f"real2sim mask --method {method}", "version": __version__,
              "files": {name: _sha256(folder / name) for name in sorted(names)}}
    write_bytes_atomic(folder / MARKER_NAME, (json.dumps(record, indent=1) + "\n").encode())


def _listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir())


def _name_them(folder: Path, names: list[str]) -> str:
    more = f" (and {len(names) - 1} more files)" if len(names) > 1 else ""
    return f"{folder / names[0]}{more}"


#: What may be replaced: "unchanged" (the masks `mask` wrote, as written), "edited" (also masks
#: edited since: ``mask --overwrite``), "any" (anything: `run`'s private copy of a dataset).
REPLACE_POLICIES = ("unchanged", "edited", "any")


def check_mask_folder(root: Path, ds: Dataset, method: str, may_replace: str = "unchanged") -> None:
    """UserInputError (one line) when ``root/masks_<method>/`` may not be replaced under ``may_replace``
    (:data:`REPLACE_POLICIES`, module docstring)."""
    folder = Path(root) / f"masks_{method}"
    if may_replace == "any" or not folder.is_dir():
        return  # absent, or a file: check_dataset_outputs names that one
    present = [name for name in _listing(folder) if ".tmp-" not in name]
    if not present:
        return
    marker = folder / MARKER_NAME
    if not marker.is_file():
        pointed = {Path(f.mask_path).name for f in ds.frames
                   if f.mask_path and Path(f.mask_path).parent.as_posix() == folder.name}
        if all(name in pointed for name in present):
            return  # masks the frames point to, written by `mask` before it marked its folders
        raise UserInputError(f"{folder} was not made by `real2sim mask` (no {MARKER_NAME} file) and holds "
                             "files of yours; it is never replaced: move or rename it, then run again")
    try:
        written = json.loads(marker.read_text()).get("files")
    except (OSError, ValueError, AttributeError):
        written = None
    if not isinstance(written, dict):
        raise UserInputError(f"{marker} does not list the masks `mask` wrote, so the files in {folder} cannot "
                             "be told apart from yours: move the folder away, then run again")
    extra = [name for name in present if name != MARKER_NAME and name not in written]
    if extra:
        raise UserInputError(f"{_name_them(folder, extra)} was not written by `real2sim mask`, and a rerun replaces "
                             f"{folder.name}/ whole: move your files out of it, then run again")
    edited = [name for name in sorted(written) if (folder / name).is_file() and _sha256(folder / name) != written[name]]
    if edited and may_replace != "edited":
        raise UserInputError(f"{_name_them(folder, edited)} changed after `real2sim mask` wrote it (edited by hand?); "
                             "copy what you want to keep, then pass --overwrite to replace it with new masks")
