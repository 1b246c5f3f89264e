"""Griffe extension for the docs site: the source's reST roles read as code in the rendered docstrings.

The docstrings name other objects the Sphinx way (``:class:`~real2sim.api.Asset```, ``:attr:`mass_kg```);
Markdown would print the role. Each becomes a code span of the name as written (the last part after a
``~``), so a docstring reads the same in ``help()`` and on the site.
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|data|mod|exc|obj|const|term|ref):`(~?)([^`]+)`")


def _plain(match: re.Match) -> str:
    name = match.group(2)
    return f"`{name.rsplit('.', 1)[-1] if match.group(1) else name}`"


class SphinxRoles(griffe.Extension):
    def on_object(self, *, obj, loader, **kwargs) -> None:
        if obj.docstring is not None and ":" in obj.docstring.value:
            obj.docstring.value = ROLE.sub(_plain, obj.docstring.value)
