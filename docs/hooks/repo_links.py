"""MkDocs hook: links from a page to a repository file that is not on the site.

The pages link to source files, benchmarks and folders beside ``docs/`` (``../src/...``,
``../benchmarks/results/``) and to the files the site leaves out (``docs/benchmarks/``). Such a link
that resolves in the repository becomes a link to the file on the repository's web page
(``repo_url``), or, without one, the path written out; one that resolves nowhere is a build warning,
so ``mkdocs build --strict`` fails on it as on any broken link.
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

log = logging.getLogger("mkdocs.hooks.repo_links")

LINK = re.compile(r"(?P<bang>!?)\[(?P<text>[^\]\n]*)\]\((?P<target>[^)\s]+)(?P<title>\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.M | re.S)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def _on_site(rel_docs: str, docs_dir: Path, config) -> bool:
    """Whether a docs-relative path is a file the site builds (not a folder, not excluded)."""
    path = docs_dir / rel_docs
    if not path.is_file():
        return False
    spec = config.get("exclude_docs")
    return not (spec is not None and spec.match_file(rel_docs))


def _rewrite(match: re.Match, page_dir: Path, docs_dir: Path, repo: Path, config, page: str) -> str:
    target = match["target"]
    if SCHEME.match(target) or target.startswith(("#", "/")):
        return match[0]
    path_part, _, anchor = target.partition("#")
    if not path_part:
        return match[0]
    resolved = Path(os.path.normpath(page_dir / path_part))
    try:
        rel_docs = resolved.relative_to(docs_dir).as_posix()
    except ValueError:
        rel_docs = None
    if rel_docs is not None and (_on_site(rel_docs, docs_dir, config) or not resolved.exists()):
        return match[0]  # a page or file of the site, or missing in docs/: mkdocs' own check judges it
    try:
        rel_repo = resolved.relative_to(repo).as_posix()
    except ValueError:
        log.warning(f"Doc file '{page}' links to '{target}', outside the repository")
        return match[0]
    if not resolved.exists():
        log.warning(f"Doc file '{page}' contains a link to '{target}', but the repository has no '{rel_repo}'")
        return match["text"]  # said once, here, not again by mkdocs' own check
    if match["bang"]:
        log.warning(f"Doc file '{page}' shows the image '{target}' from outside the site: move it into docs/")
        return match[0]
    repo_url = (config.get("repo_url") or "").rstrip("/")
    if repo_url:
        kind = "tree" if resolved.is_dir() else "blob"
        url = f"{repo_url}/{kind}/main/{rel_repo}" + (f"#{anchor}" if anchor else "")
        return f"[{match['text']}]({url}{match['title'] or ''})"
    text = match["text"]
    shown = f"`{rel_repo}`"
    return shown if text.strip("` ") in (rel_repo, path_part, Path(rel_repo).name) else f"{text} ({shown})"


def on_page_markdown(markdown: str, page, config, files):
    docs_dir = Path(config["docs_dir"]).resolve()
    repo = Path(config["config_file_path"]).resolve().parent
    page_dir = (docs_dir / page.file.src_path).parent
    out, last = [], 0
    for fence in FENCE.finditer(markdown):  # links inside fenced code are text
        out.append(LINK.sub(lambda m: _rewrite(m, page_dir, docs_dir, repo, config, page.file.src_path),
                            markdown[last:fence.start()]))
        out.append(fence[0])
        last = fence.end()
    out.append(LINK.sub(lambda m: _rewrite(m, page_dir, docs_dir, repo, config, page.file.src_path), markdown[last:]))
    return "".join(out)
