"""One writer per output: a second real2sim process that would write the same output gets a clear
:class:`~real2sim.plumbing.errors.UserInputError` at once, instead of two processes sharing a
temporary folder (:func:`output_lock`)."""

from __future__ import annotations

import errno
import fcntl
import os
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.paths import missing

_held_locks: dict[Path, list] = {}
_held_guard = threading.Lock()


def _lock_path(target: Path, inside: bool) -> Path:
    return target / ".real2sim.lock" if inside else target.with_name(f".{target.name}.lock")


@contextmanager
def output_lock(target: Path | str, *, inside: bool = False) -> Iterator[None]:
    """Hold the lock of output ``target`` for the block: a ``.NAME.lock`` file beside it, or
    with ``inside`` (a folder edited in place, such as a dataset) a file in it.

    Re-entrant within a process. A second process gets ``UserInputError`` at once rather
    than waiting: two writers of one output are a mistake to report, not to queue.
    """
    target = Path(os.path.abspath(target))
    path = _lock_path(target, inside)
    with _held_guard:
        held = _held_locks.get(path)
        if held is not None:
            held[1] += 1
    if held is not None:
        try:
            yield
        finally:
            with _held_guard:
                held[1] -= 1
        return
    if inside and not target.is_dir():
        raise UserInputError(f"{target} is not a folder" if target.exists() else missing(target, "folder"))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise UserInputError(f"cannot write {target}: {path.parent} is not a folder") from None
    except OSError as exc:
        raise UserInputError(f"cannot write {target}: {os.strerror(exc.errno).lower()}") from None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except PermissionError:
            raise UserInputError(f"cannot write {target}: {path.parent} is read-only for you") from None
        except OSError as exc:  # /proc and the like: the folder exists, but nothing can be made in it
            raise UserInputError(f"cannot write {target}: nothing can be made in {path.parent} "
                                 f"({os.strerror(exc.errno).lower()})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise UserInputError(f"another real2sim process is writing {target} (lock {path}); "
                                     "wait for it to finish or choose another output") from None
            raise
        # The holder before us may have unlinked the file between our open and flock: then
        # we hold a lock nobody else can see; take the lock on the file that is there now.
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    with _held_guard:
        _held_locks[path] = [fd, 1]
    try:
        yield
    finally:
        with _held_guard:
            entry = _held_locks[path]
            entry[1] -= 1
            release = entry[1] == 0
            if release:
                del _held_locks[path]
        if release:
            path.unlink(missing_ok=True)
            os.close(fd)
