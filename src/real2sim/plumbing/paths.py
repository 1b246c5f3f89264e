"""What stands where a path was expected: the words for "not found" when something else is there.

A symbolic link loop, a link to nothing, a file where a folder is on the way, or a folder the user
may not enter all read as "does not exist" to ``Path.exists``; saying "not found" then sends the
user looking for a file that is right there.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path


def missing(path: Path | str, what: str) -> str:
    """The one-line message for ``path`` (a ``what``: "dataset", "mesh file", ...) that cannot be
    used because it does not exist as such: ``"{what} not found: {path}"`` unless a link loop, a
    broken link, a file on the way or a permission explains it."""
    text = str(path)
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return f"{what} {text} is a symbolic link loop (a link that points back to itself)"
        if exc.errno == errno.ENOTDIR:
            return f"{what} {text}: a file stands where a folder is on the way"
        if exc.errno == errno.EACCES:
            return f"{what} {text} cannot be reached (permission denied on the way)"
        if exc.errno == errno.ENAMETOOLONG:
            return f"{what} {text}: a name is longer than the file system allows"
        if os.path.islink(path):
            return f"{what} {text} is a symbolic link to {os.readlink(path)}, which does not exist"
        return f"{what} not found: {text}"
    except ValueError:  # an embedded NUL byte
        return f"{what} path {text!r} holds a NUL character"
    return f"{what} not found: {text}"
