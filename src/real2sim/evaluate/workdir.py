"""The results folder and its working folder: what the sweep may write, replace and resume.

The rules of :func:`real2sim.plumbing.outputs.check_output_dir` apply to ``--out``, with
the evaluation's inputs being what it reads (:func:`protected_inputs`), so ``--overwrite``
never deletes an asset, a representation, the reference mesh or the working folder.

Two evaluation-specific points:

- A results folder may be resumed without ``--overwrite`` (that is how a sweep is
  extended); it is replaced, whole, only when the sweep completes.
- A results folder written before real2sim marked its outputs (``runs.csv`` but no
  :data:`~real2sim.plumbing.outputs.MARKER_NAME`) is clearly the evaluation's: it is
  resumed, and marked as ours. ``--overwrite`` replaces such a folder (or an old working
  folder) only when it holds nothing but what the evaluation writes
  (:data:`RESULTS_ENTRIES`); a file the user added there would be lost, so it is refused
  instead, naming the file. The same rules apply to the hidden working folder
  ``.RESULTS.partial`` beside it.
"""

from __future__ import annotations

import fnmatch
import os
import shutil
from pathlib import Path
from typing import Iterable, Sequence

from real2sim.evaluate.discovery import Asset
from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.outputs import MARKER_NAME, check_output_dir, make_output_dir, write_marker

#: What the evaluation writes in a results folder (shell patterns; the hidden ones are the
#: temporary files of older versions).
RESULTS_ENTRIES = ("runs.csv", "summary.csv", "config.json", "report.html", "pareto_*.png", "reference_meshes",
                   "reference_cache", MARKER_NAME, ".*.tmp", ".*.tmp.*", ".*.tmp-*")


def resolve_target(out_dir: Path | str) -> Path:
    return Path(os.path.abspath(Path(out_dir).expanduser())).resolve()


def partial_dir(target: Path) -> Path:
    """The hidden working folder beside ``target`` in which the sweep runs."""
    return target.with_name(f".{target.name}.partial")


def _is_within(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def _is_results_folder(path: Path) -> bool:
    return path.is_dir() and ((path / "runs.csv").is_file() or not any(path.iterdir()))


def protected_inputs(assets: Sequence[Asset], target: Path, reference_mesh: Path | str | None) -> list[Path]:
    """The paths the sweep reads, which ``--out`` may not be, contain or lie inside.

    Each asset folder, except that the results may go to a new folder (or an existing
    results folder) *inside* an asset folder -- ``real2sim run`` writes ``ASSETDIR/results``:
    then every other entry of that asset folder is protected instead.
    """
    paths: list[Path] = []
    for asset in assets:
        folder = asset.asset_dir
        if target == folder or not _is_within(target, folder):
            paths.append(folder)
            continue
        top = folder / target.relative_to(folder).parts[0]
        for entry in folder.iterdir():
            if entry == top and (not entry.exists() or _is_results_folder(entry)):
                continue
            paths.append(entry)
    if reference_mesh is not None:
        paths.append(Path(reference_mesh))
    return paths


def _foreign_entries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir()
                  if not any(fnmatch.fnmatchcase(p.name, pattern) for pattern in RESULTS_ENTRIES))


def _unmarked_results(folder: Path) -> bool:
    """A results folder from before the marker: ours, but not yet marked."""
    return folder.is_dir() and not (folder / MARKER_NAME).exists() and (folder / "runs.csv").is_file()


def _refuse_foreign(folder: Path, what: str) -> None:
    foreign = _foreign_entries(folder)
    if foreign:
        shown = ", ".join(foreign[:5]) + (" ..." if len(foreign) > 5 else "")
        raise UserInputError(f"{what} {folder} was made by an older real2sim (no {MARKER_NAME} file) and also holds "
                             f"{shown}, which the evaluation did not write; --overwrite would delete it: move it "
                             "away or choose another --out")


def check_results_dir(target: Path, overwrite: bool, inputs: Iterable[Path]) -> Path:
    """Check ``--out`` before any work (see the module docstring); return its resolved path.

    An existing results folder passes without ``overwrite`` (the sweep resumes it); an
    unmarked one from an older version is marked as ours here (and unmarked again if a
    later check fails, so that a refused call writes nothing).
    """
    marked = False
    if _unmarked_results(target):
        if overwrite:
            _refuse_foreign(target, "the results folder")
        write_marker(target, made_by="real2sim evaluate")
        marked = True
    try:
        # Replacing a results folder is how a sweep ends, so it needs no --overwrite.
        resumable = target.is_dir() and _is_results_folder(target)
        return check_output_dir(target, overwrite or resumable, inputs=list(inputs), what="--out")
    except BaseException:
        if marked:
            (target / MARKER_NAME).unlink(missing_ok=True)
        raise


def check_partial(partial: Path, overwrite: bool, inputs: Iterable[Path]) -> bool:
    """Check the working folder (call with the output lock held); True when it holds a sweep
    to resume (``runs.csv``). UserInputError for a path that is not ours to replace."""
    inputs = list(inputs)
    if not partial.exists() and not partial.is_symlink():
        check_output_dir(partial, True, inputs=inputs, what="working folder")
        return False
    if partial.is_symlink() or not partial.is_dir():
        raise UserInputError(f"{partial} is in the way of the sweep's working folder and is not a folder; "
                             "remove it or choose another --out")
    if not (partial / MARKER_NAME).exists():
        if (partial / "runs.csv").is_file() and not overwrite:
            write_marker(partial, made_by="real2sim evaluate")  # an interrupted sweep of an older version
        else:
            _refuse_foreign(partial, "the working folder")
            if any(partial.iterdir()):
                write_marker(partial, made_by="real2sim evaluate")  # only our files: ours to replace
    check_output_dir(partial, True, inputs=inputs, what="working folder")
    return not overwrite and (partial / "runs.csv").is_file()


def fresh_partial(partial: Path, copy_of: Path | None = None) -> Path:
    """Replace the working folder with an empty one (or a copy of ``copy_of``), marked as ours."""
    shutil.rmtree(partial, ignore_errors=True)
    if copy_of is not None:
        shutil.copytree(copy_of, partial, symlinks=True)
    return make_output_dir(partial, made_by="real2sim evaluate")
