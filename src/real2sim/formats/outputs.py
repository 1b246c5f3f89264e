"""Output folders that appear whole or not at all.

Every verb writes into a temporary folder beside the target and renames it into
place at the end, so a crash or a bad input never leaves a half-written result.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from real2sim.formats.errors import UserInputError


def check_output_dir(target: Path, overwrite: bool) -> Path:
    """Refuse an existing output folder unless ``overwrite``; return the resolved path."""
    target = Path(target).resolve()
    if target.exists() and not overwrite:
        raise UserInputError(f"output folder {target} exists; pass --overwrite to replace it")
    if target.exists() and not target.is_dir():
        raise UserInputError(f"output path {target} exists and is not a folder")
    return target


@contextmanager
def atomic_output_dir(target: Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``target``; move it to ``target`` on success.

    On any exception the temporary folder is removed and ``target`` is untouched.
    """
    target = check_output_dir(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, target)


def publish_dir(finished: Path, target: Path) -> None:
    """Rename the finished folder to ``target``, replacing an existing ``target`` last."""
    if target.exists():
        old = target.with_name(f".{target.name}.old-{finished.name[-8:]}-{os.getpid()}")
        target.rename(old)
        finished.rename(target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        finished.rename(target)
