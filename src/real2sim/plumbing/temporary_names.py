"""Temporary names out of messages: an error raised while writing names the output the user asked
for, not the temporary path beside it that was removed on the way out (:func:`public_paths`)."""

from __future__ import annotations

import re
from pathlib import Path

#: A temporary name made here (``.NAME.tmp-XXXXXXXX`` and, for a file, its suffix again): group 1 is NAME.
_TEMPORARY_NAME = re.compile(r"\.([^/\s'\"]+?)\.tmp-[a-z0-9_]{8}(?:\.[A-Za-z0-9]{1,8})?(?=$|[/\s'\":,;)])")


def public_paths(text: str) -> str:
    """``text`` with each temporary name (``.NAME.tmp-XXXXXXXX``) that no longer exists replaced by
    the NAME it was going to become: a message about a failed write names the output the user asked
    for, not a temporary path that was removed on the way out. Temporary paths that still exist
    (a result kept on purpose) stay as they are."""
    def public(match: re.Match) -> str:
        start = text.rfind(" ", 0, match.start()) + 1
        prefix = text[start:match.start()].lstrip("'\"(")
        if Path(prefix + match.group(0)).exists():
            return match.group(0)
        return match.group(1)

    return _TEMPORARY_NAME.sub(public, text)
