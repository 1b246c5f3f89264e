"""Content digests of files and folders: what a stage's cache key and an asset's provenance are made of."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterable


def file_sha256(path: Path | str, chunk: int = 1 << 20) -> str:
    """SHA-256 (hex) of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def files_digest(root: Path, relpaths: Iterable[str]) -> dict:
    """``{"files": n, "bytes": total, "sha256": digest}`` over (relative path, content hash) of each file."""
    root = Path(root)
    digest = hashlib.sha256()
    count = size = 0
    for rel in sorted(set(relpaths)):
        path = root / rel
        digest.update(rel.encode())
        digest.update(file_sha256(path).encode() if path.is_file() else b"<missing>")
        count += 1
        size += path.stat().st_size if path.is_file() else 0
    return {"files": count, "bytes": size, "sha256": digest.hexdigest()}


def tree_files(root: Path) -> list[str]:
    """Every regular file below ``root`` (relative paths), hidden temporary names excluded."""
    root = Path(root)
    return [p.relative_to(root).as_posix() for p in sorted(root.rglob("*"))
            if p.is_file() and ".tmp-" not in p.as_posix()]


def all_files(root: Path) -> list[str]:
    """Every regular file below ``root`` (relative paths), hidden ones included."""
    root = Path(root)
    return [p.relative_to(root).as_posix() for p in sorted(root.rglob("*")) if p.is_file()]
