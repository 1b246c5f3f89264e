"""Outputs that appear whole or not at all, and that can never destroy an input.

Every verb writes through this module (docs/reliability.md):

- a folder is built in a temporary folder beside the target and renamed into place at
  the end (:func:`atomic_output_dir`, :func:`publish_dir`); a single file is written to a
  temporary file, flushed to disk and renamed (:func:`atomic_file`, :func:`write_bytes_atomic`),
  so a crash or a full disk never leaves a truncated result;
- :func:`check_output_dir` refuses, before any work and even with ``--overwrite``, an
  output that is, contains or lies inside an input, that is or contains the working
  folder, or that is a non-empty folder real2sim did not make (no :data:`MARKER_NAME`
  file); and it checks the path itself (kind, writable parent, name length);
- :func:`~real2sim.plumbing.locks.output_lock` (importable from here too) gives one writer per
  output: a second one gets a clear :class:`UserInputError` instead of two processes sharing a
  temporary folder;
- what is written respects the user's umask (``tempfile`` alone makes folders 0700 and
  files 0600, which a colleague cannot read).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from real2sim.plumbing.errors import UserInputError
from real2sim.plumbing.inputs import check_outputs_spare_inputs, resolve_path
from real2sim.plumbing.locks import output_lock

#: File inside every output folder real2sim makes; ``--overwrite`` replaces only folders that hold it.
MARKER_NAME = ".real2sim"


def current_umask() -> int:
    """The process umask, read without changing it (``os.umask`` can only be read by setting it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    # No /proc: set and restore at once; the window is a single system call.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _apply_umask(path: Path, directory: bool) -> None:
    mode = (0o777 if directory else 0o666) & ~current_umask()
    os.chmod(path, mode)


def _first_existing(path: Path) -> Path:
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def _probe_writable(folder: Path) -> str | None:
    """None when a new entry can be made in ``folder`` (tried: a folder made and removed at once),
    else why not. ``os.access`` is not enough: root "may write" /proc, where nothing can be made."""
    probe = folder / f".real2sim-probe-{os.getpid()}-{threading.get_ident()}"
    try:
        probe.mkdir()
    except FileExistsError:
        return None
    except OSError as exc:
        if exc.errno in (errno.EACCES, errno.EPERM):
            return "permission denied"
        if exc.errno == errno.EROFS:
            return "read-only file system"
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return os.strerror(exc.errno).lower()
        return f"it takes no new files: {os.strerror(exc.errno).lower()}"
    probe.rmdir()
    return None


def check_output_path(target: Path | str, *, what: str = "output") -> Path:
    """Check that ``target`` can be created: not empty, every name short enough, no regular file or
    link loop on the way, a folder to create it in where something can really be made (tried, not
    guessed from permissions). Return the absolute path (symlinks resolved)."""
    if str(target) == "":
        raise UserInputError(f"{what} path is empty")
    target = Path(os.path.abspath(Path(target).expanduser()))
    resolve_path(target, what=f"{what} path")
    if os.path.islink(target) and not target.exists():  # writing through it would replace the link itself
        raise UserInputError(f"{what} path {target} is a symbolic link to {os.readlink(target)}, which does not "
                             "exist; remove the link or name another path")
    anchor = _first_existing(target.parent)
    try:
        name_max = os.pathconf(anchor if anchor.is_dir() else anchor.parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    for part in target.parts[1:]:
        if len(os.fsencode(part)) > name_max:
            raise UserInputError(f"{what} path {target}: the name {part[:40]}... is longer than "
                                 f"the file system allows ({name_max} bytes)")
    if not anchor.is_dir():
        raise UserInputError(f"{what} path {target} lies under {anchor}, which is a file, not a folder")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise UserInputError(f"{what} path {target}: cannot write in {anchor} (permission denied)")
    problem = _probe_writable(anchor)
    if problem:
        raise UserInputError(f"{what} path {target}: cannot write in {anchor} ({problem})")
    return target.resolve()


def check_replaceable(path: Path | str, *, what: str = "file") -> None:
    """Before work whose end replaces the existing file ``path`` (write beside it, then rename):
    UserInputError (one line) when that rename will fail, so that no work is done for nothing.

    Its folder must take a new file (:func:`check_output_path`), and the file itself must be open
    for writing: a read-only, immutable (``chattr +i``) or unwritable file is refused. The file is
    opened for appending and closed, never written."""
    path = Path(path)
    check_output_path(path, what=what)
    if not path.exists():
        return
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND)
    except OSError as exc:
        why = "read-only or protected" if exc.errno in (errno.EACCES, errno.EPERM) else os.strerror(exc.errno).lower()
        raise UserInputError(f"{what} {path} cannot be replaced ({why}); make it writable first") from None
    os.close(fd)


def _is_real2sim_output(folder: Path) -> bool:
    return (folder / MARKER_NAME).is_file() or not any(folder.iterdir())


def check_output_dir(target: Path | str, overwrite: bool, *, inputs: Iterable[Path | str] = (),
                     what: str = "output folder") -> Path:
    """Check an output folder before any work; return its absolute, resolved path.

    Refused (``UserInputError``), whatever ``overwrite`` says: a path that cannot be
    created (see :func:`check_output_path`), a file where a folder is expected, a target
    that is or contains the working folder, a target that is, contains or lies inside one
    of ``inputs``, and an existing non-empty folder without the real2sim marker. An
    existing real2sim output is refused unless ``overwrite``.
    """
    target = check_output_path(target, what=what)
    check_outputs_spare_inputs([(what, target)], [("input", Path(item)) for item in inputs], skip_missing=False)
    if target.exists():
        if not target.is_dir():
            raise UserInputError(f"{what} {target} exists and is not a folder")
        if not _is_real2sim_output(target):
            raise UserInputError(f"{what} {target} is a non-empty folder that real2sim did not make "
                                 f"(no {MARKER_NAME} file); refusing to replace it even with --overwrite")
        if not overwrite:
            raise UserInputError(f"{what} {target} exists; pass --overwrite to replace it")
        blocker = replace_blocker(target)
        if blocker:
            raise UserInputError(f"{what} {target} cannot be replaced ({blocker}); make it replaceable first")
    return target


#: Linux inode flags (``chattr``) that stop a rename or removal: immutable, append-only.
_FS_IOC_GETFLAGS = 0x80086601
_UNREPLACEABLE_FLAGS = {0x10: "immutable", 0x20: "append-only"}


def _inode_flags(path: Path) -> int:
    """The ``chattr`` flags of ``path`` (0 where the file system or platform has none)."""
    import array

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return 0
    try:
        buf = array.array("l", [0])
        fcntl.ioctl(fd, _FS_IOC_GETFLAGS, buf, True)
        return int(buf[0])
    except OSError:
        return 0
    finally:
        os.close(fd)


def replace_blocker(folder: Path) -> str | None:
    """Why the existing output folder ``folder`` could not be renamed aside and removed at the end
    of the work (then the work would be lost), or None. Read, never tried: ``chattr`` flags on it or
    on an entry in it, a mount point, a read-only file system, or a folder whose entries may not be
    removed."""
    folder = Path(folder)
    if os.path.ismount(folder):
        return "it is a mount point"
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return "read-only file system"
    except OSError:
        pass
    for path in (folder, *sorted(folder.iterdir())[:10000]):
        flags = _inode_flags(path)
        for bit, name in _UNREPLACEABLE_FLAGS.items():
            if flags & bit:
                return f"{path} is {name} (chattr +{'i' if bit == 0x10 else 'a'})"
    if not os.access(folder, os.W_OK | os.X_OK):
        return "permission denied"
    return None


def write_marker(folder: Path, made_by: str = "real2sim") -> None:
    """Mark ``folder`` as a real2sim output, so that ``--overwrite`` may later replace it."""
    from real2sim.plumbing.version import __version__

    write_bytes_atomic(Path(folder) / MARKER_NAME,
                       (json.dumps({"made_by": made_by, "version": __version__}) + "\n").encode())


def make_output_dir(path: Path, made_by: str = "real2sim") -> Path:
    """Create ``path`` (and parents) with the umask's permissions and the marker inside."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    if not (path / MARKER_NAME).exists():
        write_marker(path, made_by)
    return path


# ---------------------------------------------------------------------------------------------
# folders


@contextmanager
def atomic_output_dir(target: Path, overwrite: bool = False, *, inputs: Iterable[Path | str] = (),
                      made_by: str = "real2sim") -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``target``; move it to ``target`` on success.

    The checks of :func:`check_output_dir` run first and the output's lock is held
    throughout. On any exception the temporary folder is removed and ``target`` is untouched.
    """
    target = check_output_dir(target, overwrite, inputs=inputs)
    with output_lock(target):
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
        try:
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        publish_dir(tmp, target, made_by=made_by)


def publish_dir(finished: Path, target: Path, made_by: str = "real2sim") -> None:
    """Mark ``finished`` as ours, give it the umask's permissions, and rename it to ``target``.

    An existing ``target`` is replaced last (renamed aside, then removed), and only when
    it is a real2sim output: the same rule as :func:`check_output_dir`.
    """
    finished, target = Path(finished), Path(target)
    if not (finished / MARKER_NAME).exists():
        write_marker(finished, made_by)
    _apply_umask(finished, directory=True)
    if target.exists():
        if not target.is_dir() or not _is_real2sim_output(target):
            raise UserInputError(f"{target} appeared while real2sim was working and is not a real2sim "
                                 f"output; the finished result is kept in {finished}")
        old = target.with_name(f".{target.name}.old-{finished.name[-8:]}-{os.getpid()}")
        try:
            target.rename(old)
        except OSError as exc:  # made unreplaceable while the work ran: keep the work, say where
            raise UserInputError(f"{target} cannot be replaced ({os.strerror(exc.errno).lower()}); the finished "
                                 f"result is kept in {finished}") from None
        finished.rename(target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        finished.rename(target)


# ---------------------------------------------------------------------------------------------
# single files


@contextmanager
def atomic_file(path: Path | str) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block ends, flush it to disk and rename it
    to ``path`` (umask permissions). On an exception, or if nothing was written, ``path`` is untouched."""
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name[:200]}.tmp-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        _apply_umask(tmp, directory=False)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: Path | str, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (temporary file, fsync, rename)."""
    with atomic_file(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: Path | str, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: Path | str, data, default=None) -> None:
    """Write JSON to ``path`` whole or not at all; ``default`` is ``json.dump``'s hook for
    values JSON has no type for."""
    write_text_atomic(path, json.dumps(data, indent=2, default=default))
